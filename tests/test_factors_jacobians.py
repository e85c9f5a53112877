"""Every factor of factors/ through the one Jacobian harness (tests/jacobians.py)."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from factors.ceres_costs import LogDetCost, RadarPixelCost, _PriorCost, quat_xyzw_from_R
from factors.config import ELEVATION_MODELS, KERNELS, RadarPixelFactorConfig
from factors.gtsam_factors import extrinsic_prior_factor, radar_pixel_factor, random_walk_factor
from factors.projection import row_model
from factors.robust import rho, weight
from factors.synthetic import synthetic_correspondences
from hybrid_calib.geometry import perturb_camera_frame, retract
from tests.helpers import NO_SCENE, nominal_T_cam_radar, random_pose, rng
from tests.jacobians import check_ceres_cost_jacobians, check_factor_jacobians, quaternion_plus_xyzw


def _values(**poses):
    v = gtsam.Values()
    for k, T in poses.items():
        v.insert(int(k[1:]), gtsam.Pose3(T))
    return v


@pytest.mark.parametrize("model", ELEVATION_MODELS)
@pytest.mark.parametrize("kernel", KERNELS)
def test_radar_pixel_factor_jacobians(model, kernel):
    T = nominal_T_cam_radar()
    g = rng(11)
    corr, _ = synthetic_correspondences(T, n=30, rng=g, outlier_frac=0.2, cell_px=8.0 if model == "zero" else 0.0)
    corr = corr.subset(np.arange(30))
    conf = RadarPixelFactorConfig(kernel=kernel, elevation_model=model, kernel_scale=2.0)
    f = radar_pixel_factor(7, corr, conf)
    for _ in range(3):  # several seeded random points around the truth (R1-sized)
        T0 = perturb_camera_frame(T, np.deg2rad(g.uniform(-3, 3, 3)), g.uniform(-0.1, 0.1, 3))
        check_factor_jacobians(f, _values(k7=T0), eps=1e-6, rtol=1e-6)


@pytest.mark.parametrize("model", ELEVATION_MODELS)
def test_radar_pixel_factor_jacobians_of_points_behind_the_camera(model):
    """Rows whose point lies behind the camera or nearer than ``min_depth_m`` have their depth clamped: the residual
    stays large and continuous and its depth derivative is zero, which the Jacobian must say too (probe 73: the mask
    dropped from the Jacobian survived, every test's points lying in front of the camera)."""
    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=12, rng=rng(4), outlier_frac=0.0)
    R, t = T[:3, :3], T[:3, 3]
    behind = (np.array([[1.0, 0.5, -5.0], [-2.0, 0.2, -0.5], [0.5, 0.0, 0.02]]) - t) @ R  # camera z -5, -0.5, 0.02 m
    behind[:, 2] = 0.0  # a 2D radar's points
    pts = np.concatenate([corr.points_radar[:9], behind])
    from factors.correspondences import Correspondences

    corr = Correspondences(pts, corr.pixels[:12], corr.sigma_px[:12], corr.confidence[:12], corr.K)
    conf = RadarPixelFactorConfig(kernel="none", elevation_model=model)
    valid = row_model(corr, conf)
    from factors.projection import whitened_residuals

    assert whitened_residuals(T, valid)[2].tolist() == [True] * 9 + [False] * 3
    f = radar_pixel_factor(7, corr, conf)
    for T0 in (T, perturb_camera_frame(T, np.radians([0.3, -0.2, 0.4]), [0.01, 0.0, -0.01])):
        check_factor_jacobians(f, _values(k7=T0), eps=1e-6, rtol=1e-6)


def test_radar_pixel_factor_confidence_and_sigma_scale_rows():
    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=20, rng=rng(2), outlier_frac=0.0)
    conf = RadarPixelFactorConfig(kernel="none", elevation_model="zero")
    T0 = retract(T, rng(3).normal(size=6) * 0.01)
    base = radar_pixel_factor(0, corr, conf).whitenedError(_values(k0=T0)).reshape(-1, 2)
    sig = corr.sigma_px.copy()
    sig[0] *= 4.0
    c = corr.confidence.copy()
    c[1] = 0.25
    from factors.correspondences import Correspondences

    corr2 = Correspondences(corr.points_radar, corr.pixels, sig, c, corr.K)
    e2 = radar_pixel_factor(0, corr2, conf).whitenedError(_values(k0=T0)).reshape(-1, 2)
    np.testing.assert_allclose(e2[0], base[0] / 4.0, rtol=1e-12)
    np.testing.assert_allclose(e2[1], base[1] * 0.5, rtol=1e-12)
    np.testing.assert_allclose(e2[2:], base[2:], rtol=1e-12)


def test_prior_and_random_walk_jacobians():
    g = rng(5)
    for _ in range(3):
        A = g.normal(size=(6, 6))
        cov = A @ A.T * 1e-3 + np.eye(6) * 1e-4
        Tp, T1, T2 = random_pose(g), random_pose(g), random_pose(g)
        check_factor_jacobians(extrinsic_prior_factor(3, Tp, cov), _values(k3=retract(Tp, g.normal(size=6) * 0.3)))
        T1b = retract(T1, g.normal(size=6) * 0.2)
        check_factor_jacobians(random_walk_factor(1, 2, cov, 0.5), _values(k1=T1, k2=T1b))
        check_factor_jacobians(random_walk_factor(1, 2, cov, 2.0), _values(k1=T1, k2=T2))


def test_random_walk_covariance_scales_with_dt():
    cov = np.diag([1e-6, 2e-6, 3e-6, 1e-4, 2e-4, 3e-4])
    v = _values(k1=np.eye(4), k2=retract(np.eye(4), np.array([1e-3, 0, 0, 0.01, 0, 0])))
    e1 = random_walk_factor(1, 2, cov, 1.0).error(v)
    e4 = random_walk_factor(1, 2, cov, 4.0).error(v)
    np.testing.assert_allclose(e4, e1 / 4.0, rtol=1e-9)
    with pytest.raises(ValueError, match="dt_s"):
        random_walk_factor(1, 2, cov, 0.0)
    with pytest.raises(ValueError, match="positive definite"):
        extrinsic_prior_factor(1, np.eye(4), np.zeros((6, 6)))
    # an orthonormal block with det -1 (a reflection) is no rotation: only the determinant test sees it
    with pytest.raises(ValueError, match="not a proper rotation"):
        extrinsic_prior_factor(1, np.diag([1.0, 1.0, -1.0, 1.0]), np.eye(6))


def test_builtin_factors_pass_the_harness_too():
    """The harness itself against factors whose Jacobians GTSAM guarantees."""
    g = rng(8)
    K = gtsam.Cal3_S2(1000.0, 1000.0, 0.0, 640.0, 360.0)
    f = gtsam.GenericProjectionFactorCal3_S2(np.array([600.0, 300.0]), gtsam.noiseModel.Isotropic.Sigma(2, 2.0),
                                             1, 2, K)
    v = gtsam.Values()
    v.insert(1, gtsam.Pose3())
    v.insert(2, np.array([0.3, -0.2, 8.0]))
    check_factor_jacobians(f, v)
    # and the harness must FAIL on a factor with a wrong Jacobian
    def bad(this, values, H):
        x = values.atPose3(1).translation()
        if H is not None:
            H[0] = np.hstack([np.zeros((3, 3)), 2.0 * np.eye(3)])
        return x

    v2 = _values(k1=random_pose(g))
    with pytest.raises(AssertionError):
        check_factor_jacobians(gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(3), [1], bad), v2)


@pytest.mark.parametrize("model", ELEVATION_MODELS)
def test_ceres_cost_jacobians(model):
    T = nominal_T_cam_radar()
    g = rng(21)
    corr, _ = synthetic_correspondences(T, n=6, rng=g, outlier_frac=0.0)
    rows = row_model(corr, RadarPixelFactorConfig(elevation_model=model))
    for i in range(len(rows)):
        T0 = perturb_camera_frame(T, np.deg2rad(g.uniform(-5, 5, 3)), g.uniform(-0.2, 0.2, 3))
        q, t = quat_xyzw_from_R(T0[:3, :3]), T0[:3, 3].copy()
        for cost in (RadarPixelCost(rows.rows(slice(i, i + 1))), LogDetCost(rows.rows(slice(i, i + 1)))):
            check_ceres_cost_jacobians(cost, [q, t], [quaternion_plus_xyzw, lambda x, d: x + d])
    A = g.normal(size=(6, 6))
    prior = _PriorCost(T, A @ A.T * 1e-3 + 1e-4 * np.eye(6))
    T0 = retract(T, g.normal(size=6) * 0.2)
    check_ceres_cost_jacobians(prior, [quat_xyzw_from_R(T0[:3, :3]), T0[:3, 3].copy()],
                               [quaternion_plus_xyzw, lambda x, d: x + d])


@pytest.mark.parametrize("kernel", KERNELS)
def test_kernel_weight_is_rho_derivative_over_s(kernel):
    s = np.linspace(0.01, 10.0, 200)
    h = 1e-6
    d = (rho(kernel, s + h, 2.0) - rho(kernel, s - h, 2.0)) / (2 * h)
    np.testing.assert_allclose(weight(kernel, s, 2.0), d / s, rtol=1e-5, atol=1e-7)
    assert np.all(np.diff(rho(kernel, s, 2.0)) >= 0)


SCENE_ALL = {"scene_height_std_m": 0.5, "scene_lateral_slope_std": 0.01, "scene_height_sq_std_m2": 1.0}


@pytest.mark.parametrize("model", ["height", "anisotropic", "mean_arc"])
def test_scene_nuisance_jacobians(model):
    """The per-drive scene nuisance (factors.scene) as a gtsam Vector variable next to the extrinsic:
    residuals with the rows' points moved by ``scene_shift(c)``, Jacobians ``[J, scene_jacobian]``."""
    from factors.projection import row_model, whitened_residuals
    from factors.scene import scene_jacobian, scene_prior_std, scene_shift

    T = nominal_T_cam_radar()
    g = rng(21)
    corr, _ = synthetic_correspondences(T, n=25, rng=g, outlier_frac=0.0)
    conf = RadarPixelFactorConfig(kernel="none", elevation_model=model, **SCENE_ALL)
    rows = row_model(corr, conf)
    k = len(scene_prior_std(conf))
    assert k == 2 * len(conf.scene_knots_m) + 1

    def error(this, values, H):
        Tv = values.atPose3(this.keys()[0]).matrix()
        c = values.atVector(this.keys()[1])
        moved = dataclasses.replace(rows, p_bar=rows.p_bar + scene_shift(rows, corr.points_radar, conf, c))
        e, J, _ = whitened_residuals(Tv, moved)
        if H is not None:
            H[0] = J.reshape(-1, 6)
            H[1] = scene_jacobian(Tv, moved, corr.points_radar, conf).reshape(-1, k)
        return e.reshape(-1)

    f = gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(2 * len(corr)), [0, 1], error)
    for _ in range(3):
        v = _values(k0=perturb_camera_frame(T, np.deg2rad(g.uniform(-3, 3, 3)), g.uniform(-0.1, 0.1, 3)))
        v.insert(1, g.normal(size=k) * scene_prior_std(conf))
        check_factor_jacobians(f, v, eps=1e-6, rtol=1e-6)


def test_scene_nuisance_off_and_zero_model():
    from factors.projection import row_model
    from factors.scene import range_hats, scene_jacobian, scene_prior_std

    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=10, rng=rng(5), outlier_frac=0.0)
    assert scene_prior_std(RadarPixelFactorConfig(**NO_SCENE)).size == 0
    assert len(scene_prior_std(RadarPixelFactorConfig())) == 2 * len(RadarPixelFactorConfig().scene_knots_m) + 1
    conf = RadarPixelFactorConfig(elevation_model="zero", **{**NO_SCENE, "scene_height_std_m": 0.5})
    G = scene_jacobian(T, row_model(corr, conf), corr.points_radar, conf)
    assert G.shape == (10, 2, len(conf.scene_knots_m)) and not np.any(G)  # no elevation arc: no height
    B = range_hats(np.array([0.0, 5.0, 10.0, 250.0]), (0.0, 10.0, 20.0))
    np.testing.assert_allclose(B, [[1, 0, 0], [0.5, 0.5, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(ValueError, match="scene_knots_m"):
        RadarPixelFactorConfig(scene_knots_m=(0.0, 10.0, 5.0))
    with pytest.raises(ValueError, match="scene_height_std_m"):
        RadarPixelFactorConfig(scene_height_sq_std_m2=-1.0)
