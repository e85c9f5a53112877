"""The physical limit: Cramer-Rao bound of ``T_cam_radar`` from the correspondence geometry.

Model of one inlier correspondence i (docs/conventions.md frames):
    pixel_i = pi(K (R p_i + t)) + n_i,   n_i ~ N(0, sigma_i^2 / c_i I_2)
where ``p_i`` (3,) is the *true* reflector in the radar frame. A 2D radar does not measure the
reflector's elevation e_i: it is a nuisance with a prior of std ``sigma_e`` (a uniform elevation
within ``+-beta``, ``RadarPixelFactorConfig.elevation_beam_deg`` being that half-width, has
``sigma_e = beta / sqrt(3)``: ``factors.projection.elevation_moments``). Linearising the arc at the truth,
the elevation adds ``j_e sigma_e^2 j_e^T`` to the pixel covariance, with ``j_e`` (2,) the image of
the arc tangent ``dp/de = rho (-sin e cos a, -sin e sin a, cos e)``. Eliminating the nuisance
(Schur complement of the per-row Fisher information with the elevation prior) gives exactly
    F = sum_i J_i^T (sigma_i^2 / c_i I + sigma_e^2 j_e j_e^T)^-1 J_i ,
with ``J_i`` (2, 6) the Jacobian of the pixel with respect to the right tangent ``[omega, v]`` of
``T_cam_radar`` at the truth. ``CRB = F^-1`` (6, 6), same convention as every covariance here. With
``sigma_e = 0`` it is the known-elevation bound (a floor no 2D-radar method reaches).

Outliers carry no information about the extrinsic: pass inliers only (the oracle knows them).
"""

from __future__ import annotations

import numpy as np

from factors.projection import project_with_jacobian
from hybrid_calib.geometry import skew


def pixel_jacobians(T_cam_radar: np.ndarray, points_radar: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel Jacobians at the given points.

    Returns (J_pose (N, 2, 6) w.r.t. the right tangent [omega, v] of T_cam_radar,
    J_point (N, 2, 3) w.r.t. the point in the radar frame). Points must be in front of the camera.
    """
    T = np.asarray(T_cam_radar, np.float64)
    P = np.asarray(points_radar, np.float64).reshape(-1, 3)
    R, t = T[:3, :3], T[:3, 3]
    q = P @ R.T + t
    if np.any(q[:, 2] <= 1e-6):
        raise ValueError("crb: a point lies behind the camera; pass only points that project")
    _, Jpi = project_with_jacobian(np.asarray(K, np.float64), q)
    J_point = Jpi @ R  # d pixel / d p
    # T Exp([w, v]) p = R (p + w x p + v) + t  ->  dq/dw = -R [p]x, dq/dv = R
    J_pose = np.zeros((len(P), 2, 6))
    for i in range(len(P)):
        J_pose[i, :, :3] = -J_point[i] @ skew(P[i])
    J_pose[:, :, 3:] = J_point
    return J_pose, J_point


def arc_tangent(points_radar: np.ndarray) -> np.ndarray:
    """d p / d elevation (N, 3), metres per radian, on the constant-range arc through each point."""
    P = np.asarray(points_radar, np.float64).reshape(-1, 3)
    rho = np.linalg.norm(P, axis=1)
    a = np.arctan2(P[:, 1], P[:, 0])
    e = np.arcsin(np.clip(P[:, 2] / np.maximum(rho, 1e-12), -1, 1))
    return rho[:, None] * np.stack([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)], axis=1)


def fisher_information(
    T_cam_radar: np.ndarray, points_true_radar: np.ndarray, K: np.ndarray, sigma_px,
    elevation_sigma_rad=0.0, confidence=None,
) -> np.ndarray:
    """Fisher information (6, 6) of one frame's inliers (right tangent, [rad, m] units).

    points_true_radar: (N, 3) metres, radar frame, true reflector positions (with elevation).
    sigma_px: scalar or (N,) pixel noise std. confidence: optional (N,) in (0, 1], multiplies the
    information of each row (as the factors do). elevation_sigma_rad: scalar or (N,) prior std of
    the unknown elevation (0 = elevation known; per row for the ``height`` model, see
    ``elevation_sigma``).
    """
    P = np.asarray(points_true_radar, np.float64).reshape(-1, 3)
    n = len(P)
    if n == 0:
        return np.zeros((6, 6))
    sig = np.broadcast_to(np.asarray(sigma_px, np.float64), (n,))
    conf = np.ones(n) if confidence is None else np.broadcast_to(np.asarray(confidence, np.float64), (n,))
    J_pose, J_point = pixel_jacobians(T_cam_radar, P, np.asarray(K, np.float64))
    cov = (sig**2 / np.maximum(conf, 1e-12))[:, None, None] * np.eye(2)[None]
    sig_e = np.broadcast_to(np.asarray(elevation_sigma_rad, np.float64), (n,))
    if np.any(sig_e < 0) or not np.all(np.isfinite(sig_e)):
        raise ValueError("crb: elevation_sigma_rad must be finite and >= 0")
    if np.any(sig_e > 0):
        je = np.einsum("nij,nj->ni", J_point, arc_tangent(P))  # (N, 2)
        cov = cov + (sig_e**2)[:, None, None] * je[:, :, None] * je[:, None, :]
    W = np.linalg.inv(cov)
    return np.einsum("nai,nab,nbj->ij", J_pose, W, J_pose)


def elevation_sigma(points_true_radar: np.ndarray, factor_conf) -> np.ndarray:
    """(N,) elevation prior std (rad) that ``factor_conf`` (a ``RadarPixelFactorConfig``) assumes
    for reflectors at these true positions: the beam's ``beam / sqrt(3)`` for ``anisotropic`` (and
    ``mean_arc``, whose residual ignores it but whose data have it), the range-dependent
    ``projection.height_elevation_prior`` for ``height``, 0 for ``zero``."""
    from factors.projection import elevation_moments, height_elevation_prior

    P = np.asarray(points_true_radar, np.float64).reshape(-1, 3)
    if factor_conf.elevation_model == "zero":
        return np.zeros(len(P))
    if factor_conf.elevation_model == "height":
        return height_elevation_prior(np.linalg.norm(P, axis=1), factor_conf, xy=P[:, :2])[1]
    return np.full(len(P), elevation_moments(factor_conf.elevation_beam_deg, factor_conf.elevation_mean_deg)[2])


def crb_covariance(information: np.ndarray, pinned_std: np.ndarray | None = None,
                   scene_cross: np.ndarray | None = None, scene_std: np.ndarray | None = None) -> np.ndarray:
    """CRB (6, 6) = inverse Fisher information (pseudo-inverse if singular: infinite directions
    then show as huge variances rather than an exception).

    pinned_std: optional (6,) std (rad, m) of the directions only the elevation prior pins under
    the ``height`` model (``covariance.prior_pinned_std``: a common reflector-height offset is
    exactly a radar-z translation, a tilt of the height reference plane about a radar-y rotation).
    The correspondences cannot see them, so the bound adds those variances
    (``covariance.inflate_prior_pinned``): the physical limit of any method that does not know the
    world's height distribution better.

    scene_cross: optional (6, K) cross information of the rows at the truth with the per-drive scene
    nuisance (``calib.schedule.frame_scene_cross``) and scene_std (K,) its prior std
    (``factors.scene.scene_prior_std``): the bound of an estimator that holds the scene nuisance at
    its prior mean (as the factor does) adds ``A P A^T``, ``A = F^-1 cross``
    (``covariance.marginalise_scene_nuisance``).
    """
    from hybrid_calib.calib.covariance import inflate_prior_pinned, marginalise_scene_nuisance

    F = 0.5 * (np.asarray(information, np.float64) + np.asarray(information, np.float64).T)
    if scene_cross is not None and scene_std is not None and np.any(np.asarray(scene_std) > 0):
        return np.linalg.inv(marginalise_scene_nuisance(F, scene_cross, scene_std, pinned_std))
    try:
        C = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        C = np.linalg.pinv(F, hermitian=True) + np.eye(6) * 1e12 * (np.linalg.matrix_rank(F) < 6)
    return inflate_prior_pinned(C, pinned_std)


def oracle_crb(T_cam_radar: np.ndarray, frames, truths, sigma_px, factor_conf) -> np.ndarray:
    """CRB (6, 6) of the model ``factor_conf`` uses, for oracle frames with known inliers.

    frames: list of ``Correspondences``; truths: matching ``calib.oracle.OracleTruth`` (true reflector
    points and inlier masks); frames whose truth has no inlier or another ``T_cam_radar`` are skipped.
    Fisher information of the true points with the model's per-row elevation prior
    (``elevation_sigma``), plus the prior-pinned directions (``covariance.prior_pinned_std``) and the
    per-drive scene nuisance at the truth (``calib.schedule.frame_scene_cross`` of the inlier rows), with the
    stds that hold for these frames' rows (``covariance.scene_config_for``, as the covariance takes them).
    """
    import dataclasses

    from factors.scene import scene_prior_std
    from hybrid_calib.calib.covariance import prior_pinned_std, scene_config_for
    from hybrid_calib.calib.degeneracy import RowGeometry
    from hybrid_calib.calib.schedule import frame_scene_cross

    T = np.asarray(T_cam_radar, np.float64)
    used = [(c, t) for c, t in zip(frames, truths) if t.inlier.any() and np.allclose(t.T_cam_radar, T)]
    F = sum((fisher_information(T, t.points_true[t.inlier], c.K, sigma_px,
                                elevation_sigma(t.points_true[t.inlier], factor_conf)) for c, t in used),
            np.zeros((6, 6)))
    factor_conf = scene_config_for(factor_conf, RowGeometry.from_frames(frames))  # as the covariance's
    std = scene_prior_std(factor_conf)
    plain = dataclasses.replace(factor_conf, kernel="none")
    cross = sum((frame_scene_cross(T, c.subset(t.inlier), plain) for c, t in used), np.zeros((6, len(std))))
    return crb_covariance(F, prior_pinned_std(factor_conf), cross, std)
