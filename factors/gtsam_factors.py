"""GTSAM factors on the extrinsic ``T_cam_radar`` (a ``gtsam.Pose3`` = the (4, 4) matrix of
docs/conventions.md; GTSAM's right tangent ``[omega, v]`` is ours).

- ``radar_pixel_factor``: ONE vectorised ``CustomFactor`` per frame (2N rows), robust kernel applied
  per correspondence row inside the error function (``factors.robust``), analytic Jacobians.
- ``extrinsic_prior_factor``: prior with a full 6x6 covariance (e.g. the network's estimate).
- ``random_walk_factor``: identity between successive extrinsic states, covariance growing with dt.
- ``frame_residuals``: the same rows as arrays, for Cramer-Rao bounds and diagnostics.
"""

from __future__ import annotations

import gtsam
import numpy as np

from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences
from factors.projection import RowModel, row_model, whitened_residuals, whitened_rows
from factors.robust import robustify


def _check_cov(cov: np.ndarray, name: str) -> np.ndarray:
    from hybrid_calib.geometry import check_covariance

    return check_covariance(cov, name)


def _check_T(T: np.ndarray, name: str) -> np.ndarray:
    from hybrid_calib.geometry import check_transform

    return check_transform(T, name)


def robust_rows(T_cam_radar: np.ndarray, rows: RowModel, conf: RadarPixelFactorConfig):
    """Robust (square-rooted) rows: ``r`` (N, 2), ``Jr`` (N, 2, 6), IRLS weights (N,), valid (N,)."""
    e, J, valid = whitened_residuals(T_cam_radar, rows)
    r, Jr, w = robustify(e, J, conf.kernel, conf.kernel_scale)
    return r, Jr, w, valid


def frame_residuals(T_cam_radar: np.ndarray, corr: Correspondences,
                    conf: RadarPixelFactorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened residuals of a frame under ``conf.elevation_model``, before the robust kernel.

    Returns ``e`` (2N,) float64 (row i at [2i, 2i+1], unit covariance under the model),
    ``J`` (2N, 6) float64 = d e / d xi (right tangent ``[omega, v]`` of ``T_cam_radar``, radians and
    metres), and ``w`` (N,) the per-correspondence IRLS weights ``rho'(|e_i|)/|e_i|`` of
    ``conf.kernel`` (1 for ``none``; 0 for a point behind the camera). The Fisher information of
    the inliers is ``J^T J``; the IRLS information ``J^T diag(repeat(w, 2)) J``.
    """
    rows = row_model(corr, conf)
    e, J, valid = whitened_residuals(_check_T(T_cam_radar, "frame_residuals.T_cam_radar"), rows)
    _, _, w = robustify(e, J, conf.kernel, conf.kernel_scale)
    w = np.where(valid, w, 0.0)
    return e.reshape(-1), J.reshape(-1, 6), w


def frame_logdet_rows(T_cam_radar: np.ndarray, corr: Correspondences,
                      conf: RadarPixelFactorConfig) -> tuple[np.ndarray, np.ndarray]:
    """The log-determinant rows the anisotropic factor adds to ``frame_residuals``' rows.

    Returns ``ld`` (N,) and ``Jld`` (N, 6) (right tangent): the factor's cost is
    ``sum rho(|e_i|) + sum ld_i^2 / 2`` with ``ld_i^2 = log(1 + |q_i|^2)``, so its gradient is
    ``J^T W e + Jld^T ld``. Zeros for the isotropic elevation models.
    """
    rows = row_model(corr, conf)
    _, _, _, ld, Jld = whitened_rows(_check_T(T_cam_radar, "frame_logdet_rows.T_cam_radar"), rows)
    return ld, Jld


def radar_pixel_factor(key: int, corr: Correspondences, conf: RadarPixelFactorConfig) -> gtsam.NonlinearFactor:
    """One ``gtsam.CustomFactor`` for all N correspondences of a frame on the Pose3 ``key``.

    Dimension 2N (3N for the anisotropic model), unit noise model: each row is whitened by its
    ``sigma_px`` and ``confidence`` (and the elevation model), then robustified on its own, so
    ``factor.error(values)`` is ``sum_i rho(|e_i|)`` (+ ``sum_i log(1 + |q_i|^2) / 2``, the
    log-determinant of the anisotropic pixel covariance, as N more rows; see
    ``projection.whitened_rows``). Raises ValueError for an empty frame.
    """
    if len(corr) == 0:
        raise ValueError(f"radar_pixel_factor: frame {corr.frame_id!r} has no correspondences")
    rows = row_model(corr, conf)
    return _custom_factor(key, rows, conf)


def radar_pixel_factors_per_row(key: int, corr: Correspondences, conf: RadarPixelFactorConfig) -> list:
    """The same rows as N separate 2-dimensional factors (reference for the vectorised factor)."""
    rows = row_model(corr, conf)
    return [_custom_factor(key, rows.rows(slice(i, i + 1)), conf) for i in range(len(rows))]


def _custom_factor(key: int, rows: RowModel, conf: RadarPixelFactorConfig) -> gtsam.CustomFactor:
    kernel, scale = conf.kernel, conf.kernel_scale
    logdet = bool(np.any(rows.kappa > 0))
    n = len(rows)

    def error(this, values, H):
        T = values.atPose3(this.keys()[0]).matrix()
        e, J, _, ld, Jld = whitened_rows(T, rows)
        r, Jr, _ = robustify(e, J, kernel, scale)
        if logdet:
            if H is not None:
                H[0] = np.concatenate([Jr.reshape(-1, 6), Jld])
            return np.concatenate([r.reshape(-1), ld])
        if H is not None:
            H[0] = Jr.reshape(-1, 6)
        return r.reshape(-1)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create((3 if logdet else 2) * n), [key], error)


def extrinsic_prior_factor(key: int, T_prior: np.ndarray, cov: np.ndarray) -> gtsam.NonlinearFactor:
    """Prior ``Log(T_prior^-1 T)`` ~ N(0, cov) on ``key``; cov (6, 6) in our right tangent
    ``[rotation rad, translation m]`` (the network's estimate comes in through this)."""
    T_prior = _check_T(T_prior, "extrinsic_prior_factor.T_prior")
    cov = _check_cov(cov, "extrinsic_prior_factor.cov")
    return gtsam.PriorFactorPose3(key, gtsam.Pose3(T_prior), gtsam.noiseModel.Gaussian.Covariance(cov))


def random_walk_factor(key1: int, key2: int, cov_per_second: np.ndarray, dt_s: float) -> gtsam.NonlinearFactor:
    """Random walk of a slowly drifting mount: ``Log(T1^-1 T2)`` ~ N(0, cov_per_second * dt_s).

    cov_per_second: (6, 6) rad^2/s and m^2/s in our right tangent; dt_s > 0 seconds.
    """
    if not dt_s > 0 or not np.isfinite(dt_s):
        raise ValueError(f"random_walk_factor: dt_s must be a positive number of seconds, got {dt_s}")
    cov = _check_cov(np.asarray(cov_per_second, np.float64) * dt_s, "random_walk_factor.cov_per_second")
    return gtsam.BetweenFactorPose3(key1, key2, gtsam.Pose3(), gtsam.noiseModel.Gaussian.Covariance(cov))
