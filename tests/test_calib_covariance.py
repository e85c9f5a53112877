"""Reported std, degeneracy status (named directions, no exception), CRB sanity."""

import numpy as np
import pytest

from factors.projection import elevation_moments
from hybrid_calib.calib.batch import solve_batch
from hybrid_calib.calib.covariance import analyse_information, report_cov, report_std
from hybrid_calib.calib.crb import crb_covariance, fisher_information, pixel_jacobians
from hybrid_calib.calib.oracle import synthetic_drive
from hybrid_calib.calib.window import SlidingWindowCalibrator
from hybrid_calib.geometry import local, retract, se3_exp
from tests.helpers import NO_SCENE, nominal_T_cam_radar, random_pose, rng
from tests.jacobians import check_se3_residual_jacobian


def test_report_std_rotates_into_camera_axes():
    T = nominal_T_cam_radar()
    # variance only along radar z (up) -> camera -y (down): std appears on camera y
    C = np.diag([1e-10, 1e-10, np.radians(0.5) ** 2, 1e-10, 1e-10, 0.03**2])
    s = report_std(T, C)
    assert np.isclose(s[1], 0.5, rtol=1e-6) and np.isclose(s[4], 3.0, rtol=1e-6)
    assert s[0] < 1e-3 and s[2] < 1e-3
    # B C B^T is what a first-order Monte Carlo of the camera-frame quantities gives
    g = rng(0)
    L = np.linalg.cholesky(np.diag([1e-4, 2e-4, 3e-4, 1e-4, 4e-4, 9e-4]))
    xi = g.normal(size=(20000, 6)) @ L.T
    samples = np.array([retract(T, x) for x in xi[:4000]])
    t = samples[:, :3, 3]
    assert np.allclose(np.std(t, axis=0), np.sqrt(np.diag(report_cov(T, L @ L.T))[3:]), rtol=0.06)


@pytest.mark.parametrize("case", ["one_range", "few_points", "one_azimuth"])
def test_degenerate_geometry_named_not_silent(case):
    T = nominal_T_cam_radar()
    g = rng(3)
    if case == "one_range":
        frames, _ = synthetic_drive(T, 2, g, {"outlier_frac": 0.0}, range_m=(20.0, 20.0))
    elif case == "few_points":
        frames, _ = synthetic_drive(T, 1, g, {"outlier_frac": 0.0, "n_per_frame": 2})
    else:
        frames, _ = synthetic_drive(T, 2, g, {"outlier_frac": 0.0}, azimuth_deg=(0.0, 0.0))
    est = solve_batch(frames, T).estimate  # must not raise IndeterminantLinearSystemException
    assert est.status.startswith(("weak:", "degenerate:")), est.status
    assert "translation along camera" in est.status
    assert est.weak_directions
    # never over-confident: the named weak direction carries a large std
    assert est.std[3:].max() > 5.0  # cm
    if case == "few_points":
        assert est.status.startswith("degenerate:") and est.regularised
        assert "unobservable" in est.status and "regularised" in est.status
    if case == "one_azimuth":  # every point straight ahead: depth (camera z) barely constrained
        assert "translation along camera z" in est.status and est.std[5] > 50.0
    w = SlidingWindowCalibrator(T).update(frames[0])  # window path, same guarantee
    assert w.status.startswith(("weak:", "degenerate:"))


def test_singular_information_uses_regularised_prior():
    T = nominal_T_cam_radar()
    info = np.diag([1e6, 1e6, 1e6, 1e6, 1e6, 0.0])  # radar z translation unobservable
    rep = analyse_information(T, info)
    assert rep.regularised and rep.status.startswith("degenerate:")
    assert "vertical offset (translation along camera y) is unobservable" in rep.status  # radar z = camera -y
    assert rep.std_report[4] > 100  # cm: the weak prior's 5 m, not a silent tiny number
    ok = analyse_information(T, np.eye(6) * 1e10)
    assert ok.status == "ok" and not ok.regularised


def test_what_is_unobservable_does_not_depend_on_the_tolerances():
    """The rank decision is made in the default tolerances' basis: a user's 1e-4 deg rotation tolerance against 1 cm
    called a roll measured to 0.155 deg "unobservable" and regularised it (probe 51: 1e-5 deg; here 1 deg against
    0.5 mm at 1e-4 deg); the tolerances name the weak
    directions only. A tolerance no computation can use is refused (1e-300 ended in an internal LinAlgError)."""
    std = np.array([np.radians(1.0), np.radians(0.015), np.radians(1.0), 0.0005, 0.35, 0.00065])
    info = np.diag(1.0 / std**2)
    default = analyse_information(np.eye(4), info)
    tight = analyse_information(np.eye(4), info, {"rot_tol_deg": 1e-4})
    assert not default.regularised and not tight.regularised, tight.status
    assert "unobservable" not in tight.status and "poorly observed" in tight.status
    np.testing.assert_allclose(tight.cov, default.cov)
    unobservable = np.diag(1.0 / std**2) * np.array([1, 1, 1, 1, 1, 1e-14])  # translation z: no information
    for tol in ({}, {"rot_tol_deg": 1e-4}, {"trans_tol_cm": 10.0}):
        rep = analyse_information(np.eye(4), unobservable, tol)
        assert rep.regularised and "longitudinal offset (translation along camera z) is unobservable" in rep.status
    for bad in ({"rot_tol_deg": 1e-300}, {"trans_tol_cm": 1e-300}):
        with pytest.raises(ValueError, match="tol"):
            analyse_information(np.eye(4), info, bad)


@pytest.mark.parametrize("skew_px", [0.0, 3.5])
def test_pixel_jacobian_matches_finite_differences(skew_px):
    """The Cramer-Rao bound's pose Jacobian through the one harness, with a skewed K too (it once ignored K[0, 1])."""
    g = rng(5)
    T = nominal_T_cam_radar() @ se3_exp(g.normal(size=6) * 0.05)
    P = np.column_stack([g.uniform(5, 40, 8), g.uniform(-5, 5, 8), g.uniform(-1, 1, 8)])
    K = np.array([[1266.0, skew_px, 816], [0, 1266.0, 491], [0, 0, 1]])

    def pixels(TT):
        q = P @ TT[:3, :3].T + TT[:3, 3]
        uv = np.stack([K[0, 0] * q[:, 0] / q[:, 2] + K[0, 1] * q[:, 1] / q[:, 2] + K[0, 2],
                       K[1, 1] * q[:, 1] / q[:, 2] + K[1, 2]], axis=1)
        return uv.reshape(-1), pixel_jacobians(TT, P, K)[0].reshape(-1, 6)

    check_se3_residual_jacobian(pixels, T, rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize("beam", [0.0, 7.0])
def test_crb_matches_monte_carlo_for_gaussian_data(beam):
    """No outliers: the estimator's error distribution matches the bound (E[e^T F e] ~ 6) and the
    reported covariance is close to the CRB."""
    T = nominal_T_cam_radar()
    sig_e = elevation_moments(beam, 0.0)[2]
    stats, ratios = [], []
    for r in range(25):
        g = rng(200 + r)
        frames, truth = synthetic_drive(T, 2, g, {"outlier_frac": 0.0}, elevation_beam_deg=beam)
        # the data's elevations are uniform in the beam: the factor uses that (anisotropic) model
        est = solve_batch(frames, T, {"factor": {"elevation_model": "anisotropic", **NO_SCENE,
                                                 "elevation_beam_deg": max(beam, 1e-9)}}).estimate
        F = sum(fisher_information(T, tr.points_true[tr.inlier], frames[0].K, 2.0, sig_e) for tr in truth)
        e = local(T, est.T)
        stats.append(e @ F @ e)
        ratios.append(np.sqrt(np.diag(est.cov) / np.diag(crb_covariance(F))))
    assert 3.5 < np.mean(stats) < 9.0, np.mean(stats)
    assert np.all(np.abs(np.median(ratios, axis=0) - 1) < 0.25), np.median(ratios, axis=0)


def test_crb_of_random_pose_is_symmetric_positive():
    g = rng(9)
    T = random_pose(g, 0.01) @ nominal_T_cam_radar()
    P = np.column_stack([g.uniform(5, 40, 30), g.uniform(-10, 10, 30), g.uniform(-1, 1, 30)])
    F = fisher_information(T, P, np.array([[1000.0, 0, 800], [0, 1000, 450], [0, 0, 1]]), 2.0, 0.05)
    assert np.allclose(F, F.T) and np.linalg.eigvalsh(F).min() > 0
    with pytest.raises(ValueError, match="behind the camera"):
        fisher_information(T, -P, np.eye(3), 1.0)


def test_straight_scenario_names_the_weak_direction(tmp_path):
    """The simulator's ``straight`` drive: few, similar frames; the status must name what is
    poorly observed (with its std) instead of reporting a silently tight covariance."""
    from hybrid_calib.calib.oracle import OracleConfig, oracle_from_frame
    from hybrid_calib.config import merge
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.sim import simulate as sim
    from hybrid_calib.sim.drive import SimConfig

    sim.simulate(merge(SimConfig, {"scenario": "straight", "frames": 3, "image_scale": 0.125}), tmp_path,
                 overwrite=False, workers=1)
    ds = NuScenesRadarCamera(tmp_path, "v1.0-sim", conf={"check_images": False})
    g = rng(0)
    frames = [oracle_from_frame(f, OracleConfig(), g)[0] for f in ds]
    est = solve_batch(frames, ds[0].extras["reference_T_cam_radar"]).estimate
    assert est.status.startswith(("weak:", "degenerate:")), est.status
    assert "camera" in est.status and "std" in est.status
    assert "all reflectors lie along the road" in est.status, est.status  # straight-specific words
    assert est.std[:3].max() > 1.0 or est.std[3:].max() > 10.0  # deg / cm: large where it says so


@pytest.mark.parametrize("times, weak", [(15.0, True), (9.0, False)])
def test_a_direction_is_named_weak_above_weak_factor_times_its_tolerance(times, weak):
    """``weak_factor`` (10): a rotation std of 15x ``rot_tol_deg`` is named, one of 9x is not (the other axes at half
    their tolerance). A mutation probe found the boundary unpinned."""
    conf = {"rot_tol_deg": 0.1, "trans_tol_cm": 1.0, "weak_factor": 10.0}
    std = np.array([np.radians(0.05)] * 3 + [0.005] * 3)
    std[0] = np.radians(0.1 * times)  # rotation about radar x = camera x at the identity
    rep = analyse_information(np.eye(4), np.diag(1.0 / std**2), conf)
    if weak:
        assert rep.status.startswith("weak:") and "pitch (rotation about camera x)" in rep.status, rep.status
        assert f"std {0.1 * times:.3g} deg" in rep.status
    else:
        assert rep.status == "ok", rep.status


def test_elevation_moments_of_the_uniform_beam():
    """E[cos phi], E[sin phi] and std(phi) of phi uniform in [mean - beam, mean + beam] against quadrature (the
    Jacobian checks are self-consistent and cannot see a wrong moment)."""
    from scipy.integrate import quad

    for beam, mean in ((5.0, 2.0), (7.0, 0.0), (0.5, -1.0)):
        b, m = np.radians(beam), np.radians(mean)
        c, s, sd = elevation_moments(beam, mean)
        assert c == pytest.approx(quad(np.cos, m - b, m + b)[0] / (2 * b), rel=1e-9)
        assert s == pytest.approx(quad(np.sin, m - b, m + b)[0] / (2 * b), rel=1e-9, abs=1e-12)
        var = quad(lambda p, m=m: (p - m) ** 2, m - b, m + b)[0] / (2 * b)
        assert sd == pytest.approx(np.sqrt(var), rel=1e-9)


def test_a_weak_direction_of_one_axis_is_said_with_that_axis_std():
    """The status gave the weak eigen-direction's std ("pitch ... (std 1.03 deg)") beside the axis' own 1.04 deg in the
    result and the verdict (probe 24); a direction mixing axes says its std is along it."""
    conf = {"rot_tol_deg": 0.1, "trans_tol_cm": 1.0, "weak_factor": 10.0}
    std = np.array([np.radians(0.05)] * 3 + [0.005] * 3)
    std[0], std[4] = np.radians(2.0), 0.05
    cov = np.diag(std**2)
    cov[0, 4] = cov[4, 0] = 0.3 * std[0] * std[4]  # pitch leans a little on the vertical offset
    rep = analyse_information(np.eye(4), np.linalg.inv(cov), conf)
    axis = float(np.degrees(np.sqrt(report_cov(np.eye(4), rep.cov)[0, 0])))
    assert f"pitch (rotation about camera x) is poorly observed (std {axis:.3g} deg)" in rep.status, rep.status
    mixed = np.diag([np.radians(0.05) ** 2] * 3 + [0.005**2] * 3)
    mixed[np.ix_([0, 1], [0, 1])] = np.radians(2.0) ** 2 * np.array([[1.0, 0.999], [0.999, 1.0]])
    rep = analyse_information(np.eye(4), np.linalg.inv(mixed), conf)
    assert "deg along that direction" in rep.status, rep.status


def test_an_indefinite_information_is_read_as_unobservable_not_inverted():
    """Probe 36: an information matrix with a negative eigenvalue (a rear radar paired with the front camera, rows that
    fit nothing) was inverted into a covariance with a negative variance, and the run ended in "internal error". Its
    negative directions are unobservable now (regularised, "degenerate"); a solver's marginal that is not a
    covariance is not used either."""
    T = nominal_T_cam_radar()
    V = np.linalg.qr(rng(8).normal(size=(6, 6)))[0]
    info = V @ np.diag([1e6, 1e6, 1e6, 1e6, 1e6, -3e4]) @ V.T
    rep = analyse_information(T, info)
    assert rep.regularised and rep.status.startswith("degenerate")
    assert np.linalg.eigvalsh(rep.cov)[0] > 0 and np.all(np.isfinite(rep.std_report))
    good = V @ np.diag([1e6] * 6) @ V.T
    bad_hint = np.linalg.inv(good) - 1e-3 * np.outer(V[:, 0], V[:, 0])  # a negative variance along V[:, 0]
    rep = analyse_information(T, good, cov_hint=bad_hint)
    np.testing.assert_allclose(rep.cov, np.linalg.inv(good), rtol=1e-9, atol=1e-15)


def test_a_covariance_below_what_any_calibration_measures_is_not_ok():
    """An information of 1e300 * I (rows of sigma_px 1e-12 px, a producer's covariance of 1e-30) read "ok" with stds of
    1e-148 deg: a covariance that promises what no radar-camera pair can measure is "weak", and says why."""
    from hybrid_calib.calib.covariance import MIN_PLAUSIBLE_STD, analyse_information

    T = nominal_T_cam_radar()
    for scale in (1e300, 1e12):
        rep = analyse_information(T, np.eye(6) * scale)
        assert rep.status.startswith("weak: the covariance claims a pitch std of") and "check their units" in \
            rep.status, rep.status
    rep = analyse_information(T, np.eye(6) * 1e8)  # stds 0.006 deg, 0.01 cm: a long drive's, plausible
    assert rep.status == "ok" and np.all(rep.std_report[:3] > MIN_PLAUSIBLE_STD[0])
