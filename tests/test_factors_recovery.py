"""Recovery from perturbed starts (R1, R2) with outliers, degenerate geometry statuses, the
synthetic generator, and the robust schedule (all solves through the one stack: ``calib.batch``,
``calib.schedule``, ``calib.covariance``)."""

from __future__ import annotations

import numpy as np
import pytest

from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences
from factors.gtsam_factors import frame_residuals
from factors.synthetic import synthetic_correspondences
from hybrid_calib.calib.batch import BatchConfig, solve_batch
from hybrid_calib.calib.covariance import CovarianceConfig
from hybrid_calib.calib.schedule import ScheduleConfig
from hybrid_calib.geometry import local, perturb_camera_frame, transform_points
from tests.helpers import nominal_T_cam_radar, rng

CHI2_6_999 = 22.458  # chi-square, 6 degrees of freedom, 99.9 %
# The data's own covariance: no prior-pinned inflation of radar z / pitch (the synthetic heights'
# mean is the one the model assumes), so the status and the NEES read what the rows observe.
UNPINNED = dict(reflector_height_mean_std_m=0.0, reflector_tilt_std_deg=0.0)
# A direction is "weak" above 5 deg / 50 cm std (weak_factor 10 x these tolerances): these drives
# of 4 x 60 rows see the vertical translation to ~10 cm, which the default 1 cm tolerance calls weak.
COARSE = CovarianceConfig(rot_tol_deg=0.5, trans_tol_cm=5.0)


def solve(frames, T0, conf: RadarPixelFactorConfig, backend: str = "gtsam", covariance: CovarianceConfig | None = None,
          **schedule):
    """The batch solve of the one stack; ``schedule`` overrides ``ScheduleConfig`` fields."""
    return solve_batch(frames, T0, BatchConfig(backend=backend, factor=conf, schedule=ScheduleConfig(**schedule),
                                               covariance=covariance or CovarianceConfig())).estimate


@pytest.fixture(scope="module")
def drive():
    T = nominal_T_cam_radar()
    g = rng(100)
    frames = [synthetic_correspondences(T, n=60, rng=g, outlier_frac=0.2, frame_id=f"f{i}")[0] for i in range(4)]
    ref = solve(frames, T, RadarPixelFactorConfig(**UNPINNED))
    return T, frames, ref


@pytest.mark.parametrize("rot_deg,trans_m,seed", [(10, 0.25, 1), (10, 0.25, 2), (10, 0.25, 3),
                                                  (20, 1.5, 4), (20, 1.5, 5), (20, 1.5, 6)])
def test_recovery_from_R1_R2_starts(drive, rot_deg, trans_m, seed):
    T, frames, ref = drive
    g = rng(seed)
    T0 = perturb_camera_frame(T, np.deg2rad(g.uniform(-rot_deg, rot_deg, 3)), g.uniform(-trans_m, trans_m, 3))
    res = solve(frames, T0, RadarPixelFactorConfig(**UNPINNED), covariance=COARSE)
    assert res.status == "ok", res.status
    # the same optimum as the solve started at the truth ...
    assert np.abs(local(res.T, ref.T)).max() < 1e-5
    # ... which is consistent with its covariance
    d = local(T, res.T)
    assert d @ np.linalg.solve(res.cov, d) < CHI2_6_999
    assert np.rad2deg(np.linalg.norm(d[:3])) < 0.5


def test_huber_alone_is_biased_redescending_after_convex_start_is_not():
    """With 20 % gross outliers Huber keeps a pull from every outlier; the schedule (Huber, then
    Cauchy, then gated least squares) removes it. Measured over frames: Mahalanobis error of both."""
    T = nominal_T_cam_radar()
    g = rng(12)
    frames = [synthetic_correspondences(T, n=100, rng=g, outlier_frac=0.2, elevation_beam_deg=0.0)[0]
              for _ in range(6)]
    conf0 = dict(elevation_beam_deg=0.0, **UNPINNED)
    hub = solve(frames, T, RadarPixelFactorConfig(kernel="huber", kernel_scale=1.345, **conf0), final_gate=0.0)
    cau = solve(frames, T, RadarPixelFactorConfig(kernel="cauchy", **conf0))
    m_h = local(T, hub.T) @ np.linalg.solve(hub.cov, local(T, hub.T))
    m_c = local(T, cau.T) @ np.linalg.solve(cau.cov, local(T, cau.T))
    assert m_c < CHI2_6_999
    assert m_h > m_c


def test_degenerate_few_points_names_directions_and_never_raises():
    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=2, rng=rng(3), outlier_frac=0.0)
    res = solve([corr], T, RadarPixelFactorConfig(kernel="none", elevation_model="zero"))
    assert res.status.startswith("degenerate: ") and "unobservable" in res.status, res.status
    assert res.regularised and res.weak_directions
    assert np.all(np.isfinite(res.cov)) and np.all(np.linalg.eigvalsh(res.cov) > 0)


def test_degenerate_single_range_and_weak_vertical_are_named():
    """All points at one range with the honest elevation model: the vertical (pitch / y_cam)
    information comes only from the elevation prior; the status names it."""
    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=8, rng=rng(4), outlier_frac=0.0, range_m=(20.0, 20.0))
    res = solve([corr], T, RadarPixelFactorConfig(kernel="none", **UNPINNED), covariance=COARSE)
    assert res.status.startswith(("weak: ", "degenerate: ")), res.status
    # camera y is radar -z (vertical translation), pitch is a rotation about camera x
    assert any("translation along camera y" in n or "rotation about camera x" in n for n in res.weak_directions), \
        res.weak_directions


def test_no_correspondences_is_a_status():
    T = nominal_T_cam_radar()
    empty = Correspondences.empty(synthetic_correspondences(T, n=1, rng=rng(5))[0].K)
    for backend in ("gtsam", "ceres"):
        res = solve([empty], T, RadarPixelFactorConfig(), backend=backend)
        assert res.status.startswith("degenerate: ") and res.regularised, (backend, res.status)
        np.testing.assert_allclose(res.T, T)


def test_synthetic_generator_truth():
    T = nominal_T_cam_radar()
    corr, truth = synthetic_correspondences(T, n=200, rng=rng(5), sigma_px=1e-9, outlier_frac=0.25,
                                            elevation_beam_deg=7.0)
    assert len(corr) == 200 and truth["inlier"].sum() == 150
    np.testing.assert_allclose(corr.points_radar[:, 2], 0.0)
    np.testing.assert_allclose(np.linalg.norm(corr.points_radar, axis=1), np.linalg.norm(truth["points_true"], axis=1))
    P = transform_points(T, truth["points_true"])
    uv = P @ corr.K.T
    uv = uv[:, :2] / uv[:, 2:]
    np.testing.assert_allclose(corr.pixels[truth["inlier"]], uv[truth["inlier"]], atol=1e-6)
    el = np.rad2deg(truth["elevation_rad"])
    assert el.min() < -5 and el.max() > 5 and np.all(np.abs(el) <= 7.0)
    coarse, _ = synthetic_correspondences(T, n=50, rng=rng(6), cell_px=8.0)
    np.testing.assert_allclose((coarse.pixels + 0.5) % 8.0, 4.0)
    assert np.all(coarse.sigma_px > 2.0)


def test_frame_residuals_shapes_and_weights():
    T = nominal_T_cam_radar()
    corr, truth = synthetic_correspondences(T, n=50, rng=rng(7), outlier_frac=0.2)
    e, J, w = frame_residuals(T, corr, RadarPixelFactorConfig())
    assert e.shape == (100,) and J.shape == (100, 6) and w.shape == (50,)
    assert np.median(w[~truth["inlier"]]) < 0.1 < 0.5 < np.median(w[truth["inlier"]])
    with pytest.raises(ValueError, match="4, 4"):
        frame_residuals(np.eye(3), corr, RadarPixelFactorConfig())
    with pytest.raises(ValueError, match="kernel"):
        RadarPixelFactorConfig(kernel="welsch")


def test_points_behind_camera_keep_a_finite_continuous_residual():
    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=10, rng=rng(8), outlier_frac=0.0)
    pts = corr.points_radar.copy()
    pts[0] = [-3.0, 0.0, 0.0]  # behind the radar and the camera
    corr = Correspondences(pts, corr.pixels, corr.sigma_px, corr.confidence, corr.K)
    e, J, w = frame_residuals(T, corr, RadarPixelFactorConfig())
    assert np.all(np.isfinite(e)) and np.all(np.isfinite(J)) and w[0] < 0.01


def test_ceres_degenerate_is_a_status_not_a_pseudo_inverse():
    """Ceres refuses the rank-deficient covariance; the one status vocabulary names it."""
    from factors.ceres_costs import ceres_covariance, solve_ceres_stage

    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=2, rng=rng(3), outlier_frac=0.0)
    conf = RadarPixelFactorConfig(kernel="none", elevation_model="zero")
    assert ceres_covariance(solve_ceres_stage([corr], T, conf)) is None
    res = solve([corr], T, conf, backend="ceres")
    assert res.status.startswith("degenerate: ") and "unobservable" in res.status, res.status
    assert "ceres covariance unavailable" in res.status and res.regularised and res.weak_directions


def test_factor_cost_is_robust_rows_plus_logdet():
    """factor.error == sum rho(|e_i|) + sum ld_i^2/2, built from frame_residuals / frame_logdet_rows."""
    import gtsam

    from factors.gtsam_factors import frame_logdet_rows, radar_pixel_factor
    from factors.robust import rho

    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=30, rng=rng(9))
    T0 = perturb_camera_frame(T, np.deg2rad([1.0, 0.5, -0.5]), [0.05, 0.02, -0.03])
    for model in ("zero", "anisotropic", "height"):
        conf = RadarPixelFactorConfig(elevation_model=model)
        e, _, _ = frame_residuals(T0, corr, conf)
        ld, _ = frame_logdet_rows(T0, corr, conf)
        v = gtsam.Values()
        v.insert(0, gtsam.Pose3(T0))
        want = rho(conf.kernel, np.linalg.norm(e.reshape(-1, 2), axis=1), conf.kernel_scale).sum() + 0.5 * (ld**2).sum()
        np.testing.assert_allclose(radar_pixel_factor(0, corr, conf).error(v), want, rtol=1e-12)
        assert (model == "zero") == bool(np.all(ld == 0))


def test_elevation_study_small_version():
    """The elevation study in seconds: with elevations spread over +-7 deg the anisotropic model's
    covariance is consistent (mean NEES near 6) while the z = 0 model is grossly over-confident."""
    T = nominal_T_cam_radar()
    nees = {"zero": [], "anisotropic": []}
    for seed in range(6):
        g = rng(300 + seed)
        frames = [synthetic_correspondences(T, n=60, rng=g, outlier_frac=0.0)[0] for _ in range(3)]
        for model in nees:
            res = solve(frames, T, RadarPixelFactorConfig(elevation_model=model))
            xi = local(res.T, T)
            nees[model].append(xi @ np.linalg.solve(res.cov, xi))
    assert 1.5 < np.mean(nees["anisotropic"]) < 15, nees
    assert np.mean(nees["zero"]) > 100, nees
