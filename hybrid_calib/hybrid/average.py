"""``pure-avg``: the network's per-frame SE(3) estimates combined by a robust, covariance-weighted
average on SE(3) (so that pure vs hybrid is not one frame against many).

Iteratively reweighted mean in the right tangent of the current mean ``M``: ``xi_i = Log(M^-1 T_i)``,
Mahalanobis distance ``d_i = sqrt(xi_i^T C_i^-1 xi_i)``, Cauchy weight ``w_i = 1 / (1 + (d_i / c)^2)``,
step ``(sum w_i C_i^-1)^-1 sum w_i C_i^-1 xi_i``. Frames of one drive share errors (the same network
on similar views), so each ``C_i`` is widened by the per-frame shared error ``S`` of the hybrid's
measurement model (``MeasurementConfig.shared_std``) before averaging; the average's covariance is
``(sum w_i (C_i + S)^-1)^-1`` (first order; the transport of each ``C_i`` to ``M`` is neglected, as
the estimates lie within a few degrees of each other).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.robust import weight
from hybrid_calib.geometry import check_covariance, check_transform, local_many, retract


@dataclass(frozen=True)
class AverageConfig:
    kernel_scale: float = 2.5  # Cauchy scale in Mahalanobis units
    iterations: int = 30  # at most this many reweighting steps
    tol: float = 1e-9  # stop when the step's norm is below this

    def __post_init__(self):
        from hybrid_calib.config import require_ranges

        require_ranges(self, {"kernel_scale": "(0, 100]", "iterations": "[1, 10000]", "tol": "[0, 1)"})


def _all_valid(Ts: np.ndarray, covs: np.ndarray) -> bool:
    """Every transform and covariance passes ``check_transform`` / ``check_covariance``, tested at once (per item it
    was a quadratic cost over a long drive's frames, averaged again at each; probe 57)."""
    if not (np.all(np.isfinite(Ts)) and np.all(np.isfinite(covs))):
        return False
    R = Ts[:, :3, :3]
    if not (np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-6) and np.all(np.linalg.det(R) >= 0)
            and np.allclose(Ts[:, 3], [0, 0, 0, 1], atol=1e-9)):
        return False
    scale = np.maximum(1.0, np.abs(covs).max(axis=(1, 2)))
    if not np.all(np.abs(covs - covs.transpose(0, 2, 1)) <= 1e-15 * scale[:, None, None] + 1e-9 * np.abs(covs)):
        return False
    return bool(np.all(np.linalg.eigvalsh(covs).min(axis=1) > 0))


def robust_average(Ts: np.ndarray, covs: np.ndarray, conf: AverageConfig | None = None, T0: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ts (F, 4, 4), covs (F, 6, 6) right tangent [rad, m] -> (mean (4, 4), covariance (6, 6), weights (F,)).
    ``T0``: start of the iteration (default: the first estimate)."""
    conf = conf or AverageConfig()
    Ts, covs = np.asarray(Ts, np.float64), np.asarray(covs, np.float64)
    if len(Ts) == 0 or Ts.shape[1:] != (4, 4) or covs.shape != (len(Ts), 6, 6):
        raise ValueError(f"robust_average needs (F, 4, 4) and (F, 6, 6) with F > 0, got {Ts.shape}, {covs.shape}")
    if not _all_valid(Ts, covs):  # a NaN or singular one was a numpy LinAlgError, a negative one negative variances
        for f in range(len(Ts)):  # the first one that is not, named
            check_transform(Ts[f], f"robust_average Ts[{f}]")
            check_covariance(covs[f], f"robust_average covs[{f}]")
    infos = np.linalg.inv(covs)
    M = np.asarray(Ts[0] if T0 is None else T0, np.float64).copy()
    w = np.ones(len(Ts))
    for _ in range(conf.iterations):
        xi = local_many(M, Ts)
        d2 = np.einsum("fi,fij,fj->f", xi, infos, xi)
        w = weight("cauchy", np.sqrt(np.maximum(d2, 0.0)), conf.kernel_scale)
        H = np.einsum("f,fij->ij", w, infos)
        step = np.linalg.solve(H, np.einsum("f,fij,fj->i", w, infos, xi))
        M = retract(M, step)
        if np.linalg.norm(step) < conf.tol:
            break
    H = np.einsum("f,fij->ij", w, infos)
    cov = np.linalg.inv(H)
    return M, 0.5 * (cov + cov.T), w
