"""Radar-point -> pixel residuals with the elevation ambiguity, vectorised, with analytic Jacobians.

A 2D radar records a reflector at slant range ``r`` and azimuth ``a`` with z = 0; the true reflector
lies on the vertical arc ``p(phi) = (x cos phi, y cos phi, r sin phi)`` (``(x, y)`` the recorded
point) for an unknown elevation ``phi`` inside the beam. The elevation models of
``RadarPixelFactorConfig`` (see there) all reduce to: a 3D point ``p_bar`` per row and, for the
anisotropic and height models, the arc tangent ``dp`` times the elevation standard deviation (per
row for ``height``: its elevation prior depends on the range). ``p_bar`` is the expected point
``E[p(phi)]`` (``height``: the point on the arc at the mean elevation lies ``r sigma^2 / 2``
further out, centimetres at tens of metres: a measured forward bias), ``dp`` the arc tangent at
the mean elevation.

Jacobians are with respect to the RIGHT tangent ``xi = [omega, v]`` of ``T_cam_radar``
(docs/conventions.md): ``T Exp(xi)``; ``d(R p + t) / d xi = [-R [p]x, R]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences


@dataclass(frozen=True)
class RowModel:
    """Per-row constants of a frame, computed once from the correspondences and the config.

    p_bar: (N, 3) float64, metres, radar frame: the point the pixel is compared with.
    dp: (N, 3) float64, metres per radian, radar frame: arc tangent d p / d phi (zeros = isotropic).
    w: (N,) float64, 1/pixels: whitening ``sqrt(confidence) / sigma_px``.
    kappa: (N,) float64, pixels -> whitened units times radians: ``w * sigma_elev`` (0 = isotropic).
    pixels: (N, 2) float64, observed pixels.
    K: (3, 3) float64 intrinsics.
    min_depth: float, metres.
    """

    p_bar: np.ndarray
    dp: np.ndarray
    w: np.ndarray
    kappa: np.ndarray
    pixels: np.ndarray
    K: np.ndarray
    min_depth: float

    def __len__(self) -> int:
        return len(self.p_bar)

    def rows(self, idx) -> RowModel:
        """The rows selected by an index array / slice / mask."""
        return RowModel(self.p_bar[idx], self.dp[idx], self.w[idx], self.kappa[idx], self.pixels[idx], self.K,
                        self.min_depth)


def elevation_moments(beam_deg: float, mean_deg: float) -> tuple[float, float, float]:
    """Moments of an elevation uniform in ``[mean - beam, mean + beam]``.

    Returns (E[cos phi], E[sin phi], std(phi) in radians).
    """
    b, m = np.deg2rad(beam_deg), np.deg2rad(mean_deg)
    sinc = np.sin(b) / b if b > 1e-12 else 1.0
    return float(np.cos(m) * sinc), float(np.sin(m) * sinc), float(b / np.sqrt(3.0))


def truncated_normal_moments(mu, sd, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std of ``N(mu, sd^2)`` truncated to ``[lo, hi]`` (arrays of the same shape, lo < hi; ``mu``,
    ``sd``: numbers or arrays of that shape).

    Where the window holds (numerically) none of the mass, the mean is ``mu`` clipped to the window
    and the std that of a uniform over the window (at most ``sd``).
    """
    from scipy.special import ndtr

    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    a, b = (lo - mu) / sd, (hi - mu) / sd
    pdf_a, pdf_b = np.exp(-0.5 * a**2) / np.sqrt(2 * np.pi), np.exp(-0.5 * b**2) / np.sqrt(2 * np.pi)
    Z = ndtr(b) - ndtr(a)
    ok = Z > 1e-9
    Zs = np.where(ok, Z, 1.0)
    d = (pdf_a - pdf_b) / Zs
    # a*pdf(a) with a = -inf etc. is 0; the arrays are finite here (finite windows)
    var = sd**2 * (1.0 + (a * pdf_a - b * pdf_b) / Zs - d**2)
    mean = np.where(ok, mu + sd * d, np.clip(mu, lo, hi))
    std = np.where(ok, np.sqrt(np.clip(var, 0.0, None)), np.minimum(sd, (hi - lo) / np.sqrt(12.0)))
    return mean, std


def height_elevation_prior(r: np.ndarray, conf: RadarPixelFactorConfig, with_cos: bool = False,
                           xy: np.ndarray | None = None):
    """Per-row elevation prior of the ``height`` model, from the slant range.

    r: (N,) float64, metres, recorded slant range of each row; xy: (N, 2) the recorded points (metres,
    radar frame), needed when ``conf.height_plane_normal`` is given. The reflector's height ``H`` above
    the plane through the radar with normal ``n = height_plane_normal`` (default the radar plane, n = e_z)
    is ``N(reflector_height_mean_m, reflector_height_std_m^2)``, so its radar z is
    ``h = (H - n_x x - n_y y) / n_z``, truncated to the beam ``[r sin(mean - beam), r sin(mean + beam)]``
    (``elevation_mean_deg``, ``elevation_beam_deg``): the radar only sees what is inside its beam, so near
    reflectors are confined to a few decimetres and far ones are not. Returns ``phi`` (N,) =
    ``asin(E[h] / r)`` (radians, the point the arc is linearised at) and ``sigma`` (N,) =
    ``min(std(h) / (r cos phi), beam / sqrt(3))``;
    with ``with_cos`` also ``E[cos phi]`` (N,) = ``E[sqrt(1 - h^2/r^2)] ~ 1 - E[h^2] / (2 r^2)`` (error
    O((h/r)^4)), the radial foreshortening of the expected point (``r sigma^2 / 2``: centimetres at
    tens of metres, a measured forward bias if ignored).
    """
    r = np.maximum(np.asarray(r, np.float64), 1e-6)
    beam, centre = np.deg2rad(conf.elevation_beam_deg), np.deg2rad(conf.elevation_mean_deg)
    lo, hi = r * np.sin(centre - beam), r * np.sin(centre + beam)
    mu, sd = conf.reflector_height_mean_m, conf.reflector_height_std_m
    n = conf.height_plane_normal
    if n is not None:
        if xy is None:
            raise ValueError("height_elevation_prior: a height_plane_normal needs the rows' recorded points (xy)")
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        mu = (mu - n[0] * xy[:, 0] - n[1] * xy[:, 1]) / n[2]
        sd = sd / n[2]
    if beam <= 0:
        mean_h, std_h = r * np.sin(centre), np.zeros(r.shape)
    else:
        mean_h, std_h = truncated_normal_moments(mu, sd, lo, hi)
    phi = np.arcsin(np.clip(mean_h / r, -1.0, 1.0))
    sigma = np.minimum(std_h / (r * np.cos(phi)), beam / np.sqrt(3.0))
    if not with_cos:
        return phi, sigma
    return phi, sigma, np.clip(1.0 - (mean_h**2 + std_h**2) / (2.0 * r**2), 0.0, 1.0)


def row_model(corr: Correspondences, conf: RadarPixelFactorConfig) -> RowModel:
    """Per-row constants for ``corr`` under ``conf.elevation_model``."""
    if not isinstance(conf, RadarPixelFactorConfig):
        raise TypeError(f"expected a RadarPixelFactorConfig (build it with hybrid_calib.config.merge), "
                        f"got {type(conf)}")
    if not isinstance(corr, Correspondences):
        raise TypeError(f"expected factors.correspondences.Correspondences, got {type(corr)}")
    p = np.asarray(corr.points_radar, np.float64)
    n = len(p)
    w = np.sqrt(np.asarray(corr.confidence, np.float64)) / np.asarray(corr.sigma_px, np.float64)
    if conf.elevation_model == "zero":
        # The recorded point taken literally (also the model for known 3D points).
        p_bar, dp, kappa = p.copy(), np.zeros((n, 3)), np.zeros(n)
    elif conf.elevation_model == "height":
        r = np.linalg.norm(p[:, :2], axis=1)
        phi, sigma_elev, c_mean = height_elevation_prior(r, conf, with_cos=True, xy=p[:, :2])
        c, s = np.cos(phi), np.sin(phi)
        p_bar = np.stack([p[:, 0] * c_mean, p[:, 1] * c_mean, r * s], axis=1)  # E[p]: E[h] = r sin(phi)
        dp = np.stack([-p[:, 0] * s, -p[:, 1] * s, r * c], axis=1)
        kappa = w * sigma_elev
    else:
        c_mean, s_mean, sigma_elev = elevation_moments(conf.elevation_beam_deg, conf.elevation_mean_deg)
        mu = np.deg2rad(conf.elevation_mean_deg)
        r = np.linalg.norm(p[:, :2], axis=1)
        p_bar = np.stack([p[:, 0] * c_mean, p[:, 1] * c_mean, r * s_mean], axis=1)
        dp = np.stack([-p[:, 0] * np.sin(mu), -p[:, 1] * np.sin(mu), r * np.cos(mu)], axis=1)
        kappa = w * sigma_elev if conf.elevation_model == "anisotropic" else np.zeros(n)
    return RowModel(p_bar, dp, w, kappa, np.asarray(corr.pixels, np.float64), np.asarray(corr.K, np.float64),
                    float(conf.min_depth_m))


def _skew_rows(p: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) cross-product matrices."""
    S = np.zeros((len(p), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -p[:, 2], p[:, 1]
    S[:, 1, 0], S[:, 1, 2] = p[:, 2], -p[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -p[:, 1], p[:, 0]
    return S


def project_with_jacobian(K: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera points (N, 3) -> pixels (N, 2) and the projection Jacobian d uv / d P (N, 2, 3); ``K`` (3, 3) with
    its skew ``K[0, 1]``. The one pinhole Jacobian of the factors and of the Cramer-Rao bound."""
    X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
    iz = 1.0 / Z
    xn, yn = X * iz, Y * iz
    uv = np.stack([K[0, 0] * xn + K[0, 1] * yn + K[0, 2], K[1, 1] * yn + K[1, 2]], axis=1)
    Jp = np.zeros((len(P), 2, 3))
    Jp[:, 0, 0] = K[0, 0] * iz
    Jp[:, 0, 1] = K[0, 1] * iz
    Jp[:, 0, 2] = -(K[0, 0] * xn + K[0, 1] * yn) * iz
    Jp[:, 1, 1] = K[1, 1] * iz
    Jp[:, 1, 2] = -K[1, 1] * yn * iz
    return uv, Jp


def _dproj_dir(K: np.ndarray, P: np.ndarray, c: np.ndarray) -> np.ndarray:
    """d (Jproj(P) c) / d P for a fixed direction c: (N, 2, 3)."""
    X, Y, Z = P[:, 0], P[:, 1], P[:, 2]
    iz2 = 1.0 / Z**2
    iz3 = iz2 / Z
    H = np.zeros((len(P), 2, 3))
    H[:, 0, 0] = -K[0, 0] * c[:, 2] * iz2
    H[:, 0, 1] = -K[0, 1] * c[:, 2] * iz2
    H[:, 0, 2] = -(K[0, 0] * c[:, 0] + K[0, 1] * c[:, 1]) * iz2 + 2 * (K[0, 0] * X + K[0, 1] * Y) * c[:, 2] * iz3
    H[:, 1, 1] = -K[1, 1] * c[:, 2] * iz2
    H[:, 1, 2] = -K[1, 1] * c[:, 1] * iz2 + 2 * K[1, 1] * Y * c[:, 2] * iz3
    return H


def whitened_residuals(T_cam_radar: np.ndarray, rows: RowModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened (pre-kernel) pixel residuals of every row and their Jacobians.

    T_cam_radar: (4, 4) float64. Returns ``e`` (N, 2) float64 (dimensionless, unit covariance
    under the model), ``J`` (N, 2, 6) = d e / d xi (right tangent of T), ``valid`` (N,) bool (False: the point is
    behind or closer than ``min_depth`` to the camera plane; its depth is clamped to ``min_depth``,
    which keeps the residual continuous and large, and the depth derivative is zero).

    Isotropic models: ``e = w (pi(R p_bar + t) - u)``. Anisotropic: with ``q = kappa Jpi R dp``
    (the whitened image of a 1-sigma elevation change), ``e = (I + q q^T)^(-1/2) e0``, the closed
    form of eliminating a Gaussian nuisance elevation from the linearised arc.
    """
    e, J, valid, _, _ = whitened_rows(T_cam_radar, rows)
    return e, J, valid


def _camera_points(T_cam_radar: np.ndarray, rows: RowModel):
    """The rows' modelled points in the camera: R (3, 3), P (N, 3) metres (depth clamped at
    ``min_depth``), valid (N,) in front of the camera, projected pixels uv (N, 2) and d uv / d P
    (N, 2, 3)."""
    T = np.asarray(T_cam_radar, np.float64)
    R, t = T[:3, :3], T[:3, 3]
    P = rows.p_bar @ R.T + t
    valid = P[:, 2] > rows.min_depth
    P[:, 2] = np.maximum(P[:, 2], rows.min_depth)
    uv, Jp = project_with_jacobian(rows.K, P)
    return R, P, valid, uv, Jp


def whitened_rows(T_cam_radar: np.ndarray, rows: RowModel):
    """``whitened_residuals`` plus the log-determinant rows of the anisotropic model.

    Returns ``e`` (N, 2), ``J`` (N, 2, 6), ``valid`` (N,), ``ld`` (N,) and ``Jld`` (N, 6), where
    ``ld = sqrt(log(1 + |q|^2))`` so that ``ld^2 / 2`` is the ``log det`` term of the Gaussian
    negative log-likelihood (``det(I + q q^T) = 1 + |q|^2``). The pixel covariance depends on the
    extrinsic; without this term the estimate drifts towards poses that lengthen the arcs' images
    (a measured bias in the vertical translation). Zeros for the isotropic models.
    """
    R, P, valid, uv, Jp = _camera_points(T_cam_radar, rows)
    n = len(rows)
    dP = np.concatenate([-R[None] @ _skew_rows(rows.p_bar), np.broadcast_to(R, (n, 3, 3))], axis=2)  # (N,3,6)
    dP[~valid, 2, :] = 0.0
    e0 = rows.w[:, None] * (uv - rows.pixels)
    J0 = rows.w[:, None, None] * (Jp @ dP)
    if np.any(rows.kappa > 0):
        dc = np.zeros((n, 3, 6))
        dc[:, :, :3] = -R[None] @ _skew_rows(rows.dp)
        return _anisotropic(R, rows, P, Jp, dP, e0, J0, valid, dc)
    return e0, J0, valid, np.zeros(n), np.zeros((n, 6))


def point_shift_jacobian(T_cam_radar: np.ndarray, rows: RowModel, shift: np.ndarray) -> np.ndarray:
    """d e / d s (N, 2): whitened residuals (``whitened_residuals``) when every row's modelled point
    moves by ``p_bar + s * shift`` (the elevation spread ``kappa``, ``dp`` unchanged).

    shift: (N, 3) metres per unit of ``s``, radar frame. Exact derivative of ``whitened_residuals``
    (anisotropic rows included); a point behind the camera gets no depth derivative (as there).
    Used for the per-drive scene nuisance (``factors.scene``).
    """
    R, P, valid, uv, Jp = _camera_points(T_cam_radar, rows)
    n = len(rows)
    dP = (np.asarray(shift, np.float64) @ R.T)[:, :, None]  # (N, 3, 1)
    dP[~valid, 2, :] = 0.0
    g = rows.w[:, None, None] * (Jp @ dP)  # (N, 2, 1)
    if np.any(rows.kappa > 0):
        e0 = rows.w[:, None] * (uv - rows.pixels)
        g = _anisotropic(R, rows, P, Jp, dP, e0, g, valid, np.zeros((n, 3, 1)))[1]
    return g[:, :, 0]


def _anisotropic(R, rows, P, Jp, dP, e0, J0, valid, dc):
    """``e = e0 + beta(m) (q.e0) q`` with ``beta(m) = ((1+m)^-1/2 - 1)/m``, ``m = |q|^2``; exact Jacobian.

    dP (N, 3, m), J0 (N, 2, m) and dc (N, 3, m): derivatives of the camera point, of the isotropic
    residual and of the camera-frame arc tangent with respect to the m differentiated parameters.
    """
    c = rows.dp @ R.T  # (N, 3) arc tangent in the camera frame
    kap = rows.kappa
    q = kap[:, None] * np.einsum("nij,nj->ni", Jp, c)  # (N, 2)
    dq = kap[:, None, None] * (_dproj_dir(rows.K, P, c) @ dP + Jp @ dc)  # (N, 2, 6)
    m = np.einsum("ni,ni->n", q, q)
    s = np.sqrt(1.0 + m)
    beta = -1.0 / (s * (1.0 + s))
    dbeta = (1.0 + 2.0 * s) / (2.0 * s * (s + s * s) ** 2)
    a = np.einsum("ni,ni->n", q, e0)
    dm = 2.0 * np.einsum("ni,nij->nj", q, dq)
    da = np.einsum("nij,ni->nj", dq, e0) + np.einsum("ni,nij->nj", q, J0)
    e = e0 + (beta * a)[:, None] * q
    J = (J0 + (dbeta * a)[:, None, None] * q[:, :, None] * dm[:, None, :]
         + beta[:, None, None] * q[:, :, None] * da[:, None, :] + (beta * a)[:, None, None] * dq)
    L = np.log1p(m)
    ld = np.sqrt(L)
    Jld = np.where((ld > 1e-12)[:, None], dm / (2.0 * (1.0 + m) * np.maximum(ld, 1e-12))[:, None], 0.0)
    return e, J, valid, ld, Jld
