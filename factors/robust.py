"""Robust kernels applied per correspondence row (per 2D residual block), GTSAM's definitions.

For a row with whitened residual ``e`` (k,) and ``s = |e|``, a kernel ``rho(s)`` replaces ``s^2/2``:

| kernel | rho(s) (c = scale) | IRLS weight w = rho'(s)/s |
|---|---|---|
| none | s^2/2 | 1 |
| huber | s^2/2 if s <= c else c s - c^2/2 | min(1, c/s) |
| cauchy | c^2/2 log(1 + s^2/c^2) | 1 / (1 + s^2/c^2) |
| tukey | c^2/6 (1 - (1 - s^2/c^2)^3) if s <= c else c^2/6 | (1 - s^2/c^2)^2 inside, 0 outside |
| geman_mcclure | c^2 s^2 / (2 (c^2 + s^2)) | c^4 / (c^2 + s^2)^2 |

Inside a least-squares factor each row is replaced by the "square-rooted" residual
``r = sqrt(2 rho(s)) e / s``: ``|r|^2 / 2 = rho(s)`` exactly, so the factor's error IS the robust
cost, and its Jacobian is exact (``dr/de = h I + (w/h - h) n n^T`` with ``h = sqrt(2 rho)/s``,
``n = e/s``), so the gradient equals the M-estimator's ``sum psi``. The rows are weighted
independently, unlike a GTSAM ``Robust`` noise model on a stacked factor.
"""

from __future__ import annotations

import numpy as np

from factors.config import KERNELS


def _check(kernel: str, scale: float):
    if kernel not in KERNELS:
        raise ValueError(f"unknown robust kernel {kernel!r}; valid: {KERNELS}")
    if not scale > 0:
        raise ValueError(f"robust kernel scale must be > 0, got {scale}")


def rho(kernel: str, s: np.ndarray, scale: float) -> np.ndarray:
    """Kernel cost rho(s) for residual norms s >= 0 (whitened units). Same shape as s."""
    _check(kernel, scale)
    s = np.asarray(s, np.float64)
    c = float(scale)
    if kernel == "none":
        return 0.5 * s * s
    if kernel == "huber":
        return np.where(s <= c, 0.5 * s * s, c * s - 0.5 * c * c)
    if kernel == "cauchy":
        return 0.5 * c * c * np.log1p((s / c) ** 2)
    if kernel == "tukey":
        x = np.minimum((s / c) ** 2, 1.0)
        return c * c / 6.0 * (1.0 - (1.0 - x) ** 3)
    return 0.5 * c * c * s * s / (c * c + s * s)  # geman_mcclure


def weight(kernel: str, s: np.ndarray, scale: float) -> np.ndarray:
    """IRLS weight w(s) = rho'(s)/s in [0, 1]. Same shape as s."""
    _check(kernel, scale)
    s = np.asarray(s, np.float64)
    c = float(scale)
    if kernel == "none":
        return np.ones_like(s)
    if kernel == "huber":
        return np.where(s <= c, 1.0, c / np.maximum(s, 1e-300))
    if kernel == "cauchy":
        return 1.0 / (1.0 + (s / c) ** 2)
    if kernel == "tukey":
        return np.where(s <= c, (1.0 - (s / c) ** 2) ** 2, 0.0)
    return c**4 / (c * c + s * s) ** 2  # geman_mcclure


def _h2(kernel: str, s: np.ndarray, c: float) -> np.ndarray:
    """2 rho(s) / s^2, evaluated without 0/0 at s = 0 (all kernels -> 1)."""
    x = (s / c) ** 2
    if kernel == "none":
        return np.ones_like(s)
    if kernel == "huber":
        return np.where(s <= c, 1.0, (2.0 * c * s - c * c) / np.maximum(s * s, 1e-300))
    if kernel == "cauchy":
        return np.where(x < 1e-8, 1.0 - 0.5 * x, np.log1p(x) / np.maximum(x, 1e-300))
    if kernel == "tukey":
        return np.where(x <= 1.0, 1.0 - x + x * x / 3.0, 1.0 / (3.0 * np.maximum(x, 1e-300)))
    return 1.0 / (1.0 + x)  # geman_mcclure


def robustify(e: np.ndarray, J: np.ndarray, kernel: str, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Square-rooted robust rows.

    e: (N, k) whitened residual rows; J: (N, k, d) their Jacobians. Returns ``r`` (N, k) with
    ``|r_i|^2/2 = rho(|e_i|)``, ``Jr`` (N, k, d) exact, and the IRLS weights ``w`` (N,).
    """
    _check(kernel, scale)
    e = np.asarray(e, np.float64)
    s = np.linalg.norm(e, axis=1)
    w = weight(kernel, s, scale)
    if kernel == "none":
        return e, J, w
    h = np.sqrt(_h2(kernel, s, float(scale)))
    n = e / np.maximum(s, 1e-300)[:, None]
    coef = np.where(s > 0, w / h - h, 0.0)
    r = h[:, None] * e
    nJ = np.einsum("ni,nid->nd", n, J)
    Jr = h[:, None, None] * J + coef[:, None, None] * n[:, :, None] * nJ[:, None, :]
    return r, Jr, w
