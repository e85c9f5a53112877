"""Cross-checks: our factor against GTSAM's built-in projection factor (elevation known), per-row
robust noise models against the per-row kernels of the vectorised factor, vectorised against one
factor per correspondence, and GTSAM against Ceres (the batch solve of the one stack on both back ends)."""

from __future__ import annotations

import dataclasses
import time

import gtsam
import numpy as np
import pytest

from factors.ceres_costs import ceres_cov_to_ours, quat_xyzw_from_R
from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences
from factors.gtsam_factors import frame_residuals, radar_pixel_factor, radar_pixel_factors_per_row
from factors.synthetic import synthetic_correspondences
from hybrid_calib.calib.batch import BatchConfig, solve_batch
from hybrid_calib.calib.covariance import marginal_covariance
from hybrid_calib.calib.schedule import GaussianPrior, ScheduleConfig, X, build_graph, lm_params
from hybrid_calib.geometry import adjoint, local, perturb_camera_frame, retract, se3_inverse
from tests.helpers import NO_SCENE, nominal_T_cam_radar, rng
from tests.jacobians import quaternion_plus_xyzw

SIGMA = 2.0
TIGHT = ScheduleConfig(max_iterations=100, relative_error_tol=1e-10)  # LM run to convergence for comparisons


def optimize(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
    """Levenberg-Marquardt with the schedule's parameters (``schedule.lm_params``) on any graph."""
    return gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params(TIGHT)).optimize()


def _known_elevation(n, seed, outlier_frac=0.0):
    """Correspondences whose radar points are the TRUE 3D reflectors (elevation known)."""
    T = nominal_T_cam_radar()
    corr, truth = synthetic_correspondences(T, n=n, rng=rng(seed), sigma_px=SIGMA, outlier_frac=outlier_frac)
    return T, Correspondences(truth["points_true"], corr.pixels, corr.sigma_px, corr.confidence, corr.K), truth


def _builtin_graph(corr, key, noise):
    """GTSAM's GenericProjectionFactorCal3_S2 with the camera pose T_radar_cam (GTSAM's camera pose
    is world_T_camera; the 'world' is the radar frame) and the 3D points fixed."""
    K = corr.K
    cal = gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i, (p, uv) in enumerate(zip(corr.points_radar, corr.pixels, strict=True)):
        lk = 1000 + i
        graph.add(gtsam.GenericProjectionFactorCal3_S2(uv, noise, key, lk, cal))
        graph.add(gtsam.NonlinearEqualityPoint3(lk, p))
        values.insert(lk, p)
    return graph, values


def test_residual_matches_builtin_projection_factor():
    T, corr, _ = _known_elevation(40, 1)
    conf = RadarPixelFactorConfig(kernel="none", elevation_model="zero")
    g = rng(2)
    for _ in range(3):
        T0 = retract(T, g.normal(size=6) * 0.02)
        e, _, _ = frame_residuals(T0, corr, conf)
        bg = _builtin_graph(corr, 1, gtsam.noiseModel.Isotropic.Sigma(2, SIGMA))[0]
        builtin = [bg.at(i) for i in range(bg.size()) if isinstance(bg.at(i), gtsam.GenericProjectionFactorCal3_S2)]
        v = gtsam.Values()
        v.insert(1, gtsam.Pose3(se3_inverse(T0)))
        for i in range(len(builtin)):
            v.insert(1000 + i, corr.points_radar[i])
        e_builtin = np.concatenate([f.whitenedError(v) for f in builtin])
        np.testing.assert_allclose(e, e_builtin, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kernel,mest", [
    ("none", None), ("huber", gtsam.noiseModel.mEstimator.Huber), ("cauchy", gtsam.noiseModel.mEstimator.Cauchy),
    ("tukey", gtsam.noiseModel.mEstimator.Tukey), ("geman_mcclure", gtsam.noiseModel.mEstimator.GemanMcClure)])
def test_optimum_and_covariance_match_builtin(kernel, mest):
    """Elevation known: same cost as per-row built-in factors (robust noise model per row), same
    optimum; with no kernel also the same covariance (mapped from T_radar_cam to T_cam_radar)."""
    T, corr, _ = _known_elevation(60, 3, outlier_frac=0.0 if kernel == "none" else 0.2)
    conf = RadarPixelFactorConfig(kernel=kernel, elevation_model="zero", kernel_scale=2.5)
    noise = gtsam.noiseModel.Isotropic.Sigma(2, SIGMA)
    if mest is not None:
        noise = gtsam.noiseModel.Robust.Create(mest.Create(2.5), noise)
    T0 = perturb_camera_frame(T, np.deg2rad([1.0, -1.0, 0.5]), [0.05, -0.05, 0.05])
    # cost equality at an arbitrary pose
    bg, bv = _builtin_graph(corr, 1, noise)
    bv.insert(1, gtsam.Pose3(se3_inverse(T0)))
    v = gtsam.Values()
    v.insert(0, gtsam.Pose3(T0))
    ours = gtsam.NonlinearFactorGraph()
    ours.add(radar_pixel_factor(0, corr, conf))
    np.testing.assert_allclose(ours.error(v), bg.error(bv), rtol=1e-10)
    # optimum: start both from the truth's basin
    start = perturb_camera_frame(T, np.deg2rad([0.2, -0.2, 0.1]), [0.01, -0.01, 0.01])
    v.update(0, gtsam.Pose3(start))
    bv.update(1, gtsam.Pose3(se3_inverse(start)))
    out = optimize(ours, v)
    bout = optimize(bg, bv)
    T_ours, T_builtin = out.atPose3(0).matrix(), se3_inverse(bout.atPose3(1).matrix())
    # The robust costs are flat near the optimum (Huber with 20 % outliers most of all): the two LMs
    # stop within 1e-4 of each other, at costs equal to 1e-11 relative.
    assert np.abs(local(T_ours, T_builtin)).max() < 1e-4
    bv2 = gtsam.Values(bout)
    bv2.update(1, gtsam.Pose3(se3_inverse(T_ours)))
    np.testing.assert_allclose(bg.error(bv2), bg.error(bout), rtol=1e-11)
    if kernel == "none":
        cov, why = marginal_covariance(ours, out, 0)
        assert why == "", why
        cov_b = np.asarray(gtsam.Marginals(bg, bout).marginalCovariance(1))  # of T_radar_cam
        # inv(T Exp(xi)) = T^-1 Exp(-Ad_T xi): C_inv = Ad_T C Ad_T^T
        Ad = adjoint(T_ours)
        np.testing.assert_allclose(Ad @ cov @ Ad.T, cov_b, rtol=1e-6, atol=1e-14)


def test_vectorised_equals_per_row_factors_and_is_faster():
    T = nominal_T_cam_radar()
    g = rng(4)
    frames = [synthetic_correspondences(T, n=100, rng=g)[0] for _ in range(3)]
    conf = RadarPixelFactorConfig()
    T0 = perturb_camera_frame(T, np.deg2rad([2.0, -2.0, 1.0]), [0.1, -0.1, 0.1])
    vec, per = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
    for c in frames:
        vec.add(radar_pixel_factor(0, c, conf))
        for f in radar_pixel_factors_per_row(0, c, conf):
            per.add(f)
    v = gtsam.Values()
    v.insert(0, gtsam.Pose3(T0))
    results, times = [], []
    for graph in (vec, per):
        t0 = time.perf_counter()
        out = optimize(graph, v)
        times.append(time.perf_counter() - t0)
        cov, _ = marginal_covariance(graph, out, 0)
        results.append((out.atPose3(0).matrix(), cov))
    assert np.abs(local(results[0][0], results[1][0])).max() < 1e-9
    np.testing.assert_allclose(results[0][1], results[1][1], rtol=1e-8)
    print(f"\nvectorised {times[0] * 1e3:.1f} ms, per-row {times[1] * 1e3:.1f} ms, ratio {times[1] / times[0]:.1f}x")
    assert times[1] > 2.0 * times[0]


def test_ceres_covariance_conversion_is_our_right_tangent():
    """Ceres tangent [d, dt] (left, half-angle) -> ours: perturb through Ceres's plus, read back
    with our local(), compare with B = blockdiag(2 R^T, R^T)."""
    g = rng(6)
    T = nominal_T_cam_radar()
    R = T[:3, :3]
    q = quat_xyzw_from_R(R)
    from factors.ceres_costs import R_from_quat_xyzw
    from hybrid_calib.geometry import make_T

    eps = 1e-7
    B = np.zeros((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        T1 = make_T(R_from_quat_xyzw(quaternion_plus_xyzw(q, d[:3])), T[:3, 3] + d[3:])
        B[:, i] = local(T, T1) / eps
    C = np.cov(g.normal(size=(6, 50)))
    np.testing.assert_allclose(ceres_cov_to_ours(C, R), B @ C @ B.T, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("model", ["anisotropic", "height"])
@pytest.mark.parametrize("kernel", ["none", "cauchy"])
def test_gtsam_and_ceres_agree(kernel, model):
    """The batch solve on both back ends (same ``ScheduleConfig``: Huber start, then the kernel; no
    gated stage here, so the robust covariances are compared): same optimum (within 1e-3 standard
    deviations per axis) and covariance: exactly (1e-6 relative) without a kernel; within 25 % per
    standard deviation with Cauchy (GTSAM's factor uses the exact Gauss-Newton Hessian of the
    square-rooted robust rows, Ceres the IRLS one, sqrt(rho') scaling). No prior-pinned inflation,
    so each covariance is its back end's own marginal."""
    T = nominal_T_cam_radar()
    g = rng(7)
    out_frac = 0.0 if kernel == "none" else 0.2
    frames = [synthetic_correspondences(T, n=40, rng=g, outlier_frac=out_frac)[0] for _ in range(2)]
    conf = RadarPixelFactorConfig(kernel=kernel, elevation_model=model, reflector_height_mean_std_m=0.0,
                                  reflector_tilt_std_deg=0.0, **NO_SCENE)
    T0 = perturb_camera_frame(T, np.deg2rad([3.0, -3.0, 2.0]), [0.1, -0.1, 0.1])
    sched = ScheduleConfig(max_iterations=100, relative_error_tol=1e-10, final_gate=0.0)
    a, b = (solve_batch(frames, T0, BatchConfig(backend=be, factor=conf, schedule=sched)) for be in ("gtsam", "ceres"))
    a, b = a.estimate, b.estimate
    assert not a.regularised and not b.regularised, (a.status, b.status)
    assert "unavailable" not in b.status and "failed" not in a.status, (a.status, b.status)
    assert np.all(np.abs(local(a.T, b.T)) < 1e-3 * np.sqrt(np.diag(a.cov)))
    if kernel == "none":
        np.testing.assert_allclose(b.cov, a.cov, rtol=1e-6, atol=1e-14)
        # the scene nuisance (factors.scene, the default) reads the same rows on both back ends
        scene = dataclasses.replace(conf, **{k: v for k, v in RadarPixelFactorConfig().__dict__.items()
                                             if k in NO_SCENE})
        a2, b2 = (solve_batch(frames, T0, BatchConfig(backend=be, factor=scene, schedule=sched)).estimate
                  for be in ("gtsam", "ceres"))
        assert np.all(np.linalg.eigvalsh(a2.cov - a.cov) > -1e-12 * np.abs(a.cov).max())  # it only adds
        np.testing.assert_allclose(b2.cov, a2.cov, rtol=1e-4, atol=1e-6 * np.abs(a2.cov).max())
    else:
        ratio = np.sqrt(np.diag(b.cov) / np.diag(a.cov))
        assert np.all(np.abs(ratio - 1) < 0.25), ratio


def test_build_graph_prior_pulls_towards_prior():
    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=20, rng=rng(9))
    T_prior = retract(T, np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.3]))
    graph = build_graph([corr], RadarPixelFactorConfig(), [GaussianPrior(T_prior, np.eye(6) * 1e-10)])
    v = gtsam.Values()
    v.insert(X, gtsam.Pose3(T))
    out = optimize(graph, v)
    assert np.abs(local(out.atPose3(X).matrix(), T_prior)).max() < 1e-4
