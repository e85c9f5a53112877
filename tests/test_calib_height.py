"""Honest vertical translation under the ``height`` elevation model: the unobservable mean-height
offset enters the calibrator's covariance (window and batch) and the Cramer-Rao bound; the oracle
draws from the height model when asked."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from factors.config import RadarPixelFactorConfig
from factors.projection import height_elevation_prior
from hybrid_calib.calib.batch import solve_batch
from hybrid_calib.calib.covariance import (
    analyse_information,
    inflate_prior_pinned,
    prior_pinned_std,
    report_std,
)
from hybrid_calib.calib.crb import crb_covariance, elevation_sigma, fisher_information
from hybrid_calib.calib.oracle import OracleConfig, _draw_elevation, synthetic_drive
from hybrid_calib.calib.window import SlidingWindowCalibrator
from hybrid_calib.geometry import local, se3_exp, transform_points
from tests.helpers import nominal_T_cam_radar, rng

HEIGHT = {"elevation_model": "height", "reflector_height_mean_m": 0.5, "reflector_height_std_m": 0.8}


def test_prior_pinned_std_only_for_height_model():
    assert np.all(prior_pinned_std(RadarPixelFactorConfig(elevation_model="anisotropic")) == 0.0)
    std = prior_pinned_std(RadarPixelFactorConfig(elevation_model="height", reflector_height_mean_std_m=0.3,
                                                  reflector_tilt_std_deg=2.0))
    np.testing.assert_allclose(std, [0, np.radians(2.0), 0, 0, 0, 0.3])
    C = inflate_prior_pinned(np.eye(6) * 1e-6, [0, 0.01, 0, 0, 0, 0.2])
    np.testing.assert_allclose(C - np.eye(6) * 1e-6, np.diag([0, 1e-4, 0, 0, 0, 0.04]), atol=1e-15)
    with pytest.raises(ValueError):
        inflate_prior_pinned(np.eye(6), [0, -1, 0, 0, 0, 0])


def test_tilt_of_the_height_plane_is_a_radar_pitch_to_first_order():
    """Heights tilted by beta about radar y (h += beta x) == T Exp([-beta e_y, 0]) p up to O(beta z)."""
    T = nominal_T_cam_radar()
    g = rng(4)
    P = np.stack([g.uniform(5, 60, 50), g.uniform(-20, 20, 50), g.uniform(-1, 3, 50)], 1)
    beta = np.radians(1.0)
    tilted = P + np.stack([np.zeros(50), np.zeros(50), beta * P[:, 0]], 1)
    rotated = transform_points(T @ se3_exp(np.array([0, -beta, 0, 0, 0, 0])), P)
    d = rotated - transform_points(T, tilted)
    assert np.abs(d).max() < 2 * beta * np.abs(P[:, 2]).max() + beta**2 * 60, np.abs(d).max()


def test_analyse_information_inflates_radar_z_and_names_it():
    T = nominal_T_cam_radar()
    info = np.diag([1e8] * 3 + [1e6] * 3)  # everything observed to ~0.006 deg / 0.1 cm
    ok = analyse_information(T, info)
    inf = analyse_information(T, info, pinned_std=[0, 0, 0, 0, 0, 0.25])
    assert ok.status == "ok"
    np.testing.assert_allclose(inf.cov - ok.cov, np.diag([0, 0, 0, 0, 0, 0.0625]), atol=1e-15)
    # radar z (up) is camera -y (down): 25 cm on camera y, and the status says so
    assert abs(inf.std_report[4] - np.hypot(25.0, 0.1)) < 0.05
    assert inf.status.startswith("weak: ") and "translation along camera y" in inf.status, inf.status
    np.testing.assert_allclose(report_std(T, inf.cov), inf.std_report)


def test_batch_and_window_covariance_include_the_offset():
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 3, rng(5), {"n_per_frame": 60, "outlier_frac": 0.0}, height_m=(0.5, 0.8))
    covs = {}
    for s in (0.0, 0.2):
        fac = dict(HEIGHT, reflector_height_mean_std_m=s, reflector_tilt_std_deg=s * 5)
        b = solve_batch(frames, T, {"factor": fac}).estimate
        cal = SlidingWindowCalibrator(T, {"factor": fac, "window": 5})
        for c in frames:
            w = cal.update(c)
        covs[s] = (b.cov, w.cov)
    for k in range(2):
        d = covs[0.2][k] - covs[0.0][k]
        np.testing.assert_allclose([d[1, 1], d[5, 5]], [np.radians(1.0) ** 2, 0.04], rtol=1e-6)
        d[1, 1] = d[5, 5] = 0.0
        assert np.abs(d).max() < 1e-9 * 0.04 + 1e-12, d


def test_crb_per_row_sigma_and_offset():
    T = nominal_T_cam_radar()
    g = rng(8)
    P = np.stack([g.uniform(5, 50, 40), g.uniform(-10, 10, 40), g.uniform(-1, 2, 40)], 1)
    K = np.array([[1266.4, 0, 816.3], [0, 1266.4, 491.5], [0, 0, 1]])
    F1 = fisher_information(T, P, K, 2.0, 0.05)
    np.testing.assert_allclose(fisher_information(T, P, K, 2.0, np.full(40, 0.05)), F1, rtol=1e-12)
    conf = RadarPixelFactorConfig(**HEIGHT)
    sig = elevation_sigma(P, conf)
    np.testing.assert_allclose(sig, height_elevation_prior(np.linalg.norm(P, axis=1), conf)[1])
    F = fisher_information(T, P, K, 2.0, sig)
    # a tighter elevation prior never loses information
    assert np.all(np.linalg.eigvalsh(F - fisher_information(T, P, K, 2.0, sig * 2)) > -1e-6 * np.abs(F).max())
    pinned = prior_pinned_std(conf)
    np.testing.assert_allclose(crb_covariance(F, pinned) - crb_covariance(F), np.diag(pinned**2), atol=1e-12)


def test_oracle_height_draw_matches_the_model():
    conf = OracleConfig(elevation_model="height", reflector_height_mean_m=0.5, reflector_height_std_m=1.5)
    fconf = RadarPixelFactorConfig(elevation_model="height", reflector_height_mean_m=0.5, reflector_height_std_m=1.5)
    g = rng(2)
    for r in (8.0, 40.0):
        rho = np.full(20000, r)
        phi = _draw_elevation(rho, conf, g)
        assert np.all(np.abs(phi) <= np.radians(conf.elevation_beam_deg) + 1e-12)
        h = r * np.sin(phi)
        mean_phi, _ = height_elevation_prior(np.array([r]), fconf)
        assert abs(h.mean() - r * np.sin(mean_phi[0])) < 4 * h.std() / np.sqrt(len(h)) + 1e-3


def test_marginalising_the_pinned_nuisance_from_data_only():
    """Without external priors the marginalisation equals adding the nuisance variances to the
    covariance; a tight external prior still pins the nuisance directions (it is not inflated)."""
    from hybrid_calib.calib.covariance import marginalise_prior_pinned

    g = np.random.default_rng(5)
    A = g.normal(size=(40, 6))
    H_data = A.T @ A * 1e4
    std = np.array([0, 0.02, 0, 0, 0, 0.3])
    H = marginalise_prior_pinned(H_data, std)
    np.testing.assert_allclose(np.linalg.inv(H), np.linalg.inv(H_data) + np.diag(std**2), rtol=1e-8, atol=1e-12)
    H_prior = np.eye(6) * 1e8  # e.g. a very confident external prior on T_cam_radar
    H2 = marginalise_prior_pinned(H_data + H_prior, std, external_info=H_prior)
    assert np.sqrt(np.linalg.inv(H2)[5, 5]) < 2e-4  # pinned by the prior, not 0.3 m
    assert np.sqrt(np.linalg.inv(H2)[1, 1]) < 2e-4


def test_scene_nuisance_is_a_consider_covariance():
    """marginalise_scene_nuisance: covariance = inv(info) + E S E^T (pinned) + A P A^T, A = info^-1 cross;
    a singular information stays singular there (no NaN), and an external prior shrinks the term."""
    from hybrid_calib.calib.covariance import marginalise_scene_nuisance

    g = rng(8)
    M = g.normal(size=(40, 6))
    info = M.T @ M * 1e4
    cross = g.normal(size=(6, 3)) * 50.0
    std = np.array([0.5, 0.0, 2.0])  # a 0 std is off
    pinned = np.array([0, 0.01, 0, 0, 0, 0.3])
    A = np.linalg.solve(info, cross)
    expect = np.linalg.inv(info) + np.diag(pinned**2) + A @ np.diag(std**2) @ A.T
    got = np.linalg.inv(marginalise_scene_nuisance(info, cross, std, pinned))
    np.testing.assert_allclose(got, expect, rtol=1e-6, atol=1e-14)
    np.testing.assert_allclose(marginalise_scene_nuisance(info, None, None, pinned),
                               np.linalg.inv(np.linalg.inv(info) + np.diag(pinned**2)), rtol=1e-6)
    sing = info.copy()
    sing[:, 2] = sing[2, :] = 0.0
    out = marginalise_scene_nuisance(sing, cross, std)
    assert np.all(np.isfinite(out)) and abs(out[2, 2]) < 1e-9
    ext = np.eye(6) * 1e8
    with_ext = np.linalg.inv(marginalise_scene_nuisance(info + ext, cross, std, external_info=ext))
    assert np.all(np.diag(with_ext) < np.diag(np.linalg.inv(marginalise_scene_nuisance(info, cross, std))))
    with pytest.raises(ValueError, match="scene nuisance"):
        marginalise_scene_nuisance(info, cross[:, :2], std)


def _scene_drive(T, conf, g, n_frames=12, n=150):
    """Frames whose reflectors follow the factor's linearised height model plus ONE per-drive scene
    deviation ``c ~ N(0, diag(scene_prior_std^2))`` (``factors.scene.scene_shift``) shared by every
    frame: true point ``p_bar + scene_shift(c) + dp * N(0, sigma_elev^2)``, 2 px pixel noise."""
    from factors.correspondences import Correspondences
    from factors.projection import row_model
    from factors.scene import scene_prior_std, scene_shift
    from hybrid_calib.geometry import project_points

    K = np.array([[1266.0, 0, 816], [0, 1266.0, 491], [0, 0, 1]])
    c = g.normal(size=len(scene_prior_std(conf))) * scene_prior_std(conf)
    frames = []
    for k in range(n_frames):
        r, az = g.uniform(4, 70, n), np.radians(g.uniform(-30, 30, n))
        pts = np.stack([r * np.cos(az), r * np.sin(az), np.zeros(n)], 1)
        corr = Correspondences(pts, np.zeros((n, 2)), np.full(n, 2.0), np.ones(n), K, f"scene-{k}", k)
        rows = row_model(corr, conf)
        sigma = rows.kappa / rows.w  # per-row elevation std (rad)
        true = rows.p_bar + scene_shift(rows, pts, conf, c) + rows.dp * (g.normal(size=n) * sigma)[:, None]
        uv, _ = project_points(K, T, true)
        frames.append(Correspondences(pts, uv + g.normal(scale=2.0, size=(n, 2)), corr.sigma_px, corr.confidence,
                                      K, corr.frame_id, k))
    return frames


def test_scene_nuisance_removes_the_leak_into_the_observable_directions():
    """Recovery: per-drive scene deviations drawn from the nuisance's own prior leak into the four
    observable directions (rotation about radar x and z, translation along x and y) when the
    covariance ignores them; with the scene nuisance (default config) their NEES is ~4."""
    from factors.scene import scene_prior_std
    from hybrid_calib.calib.covariance import analyse_drive_information

    T = nominal_T_cam_radar()
    assert len(scene_prior_std(RadarPixelFactorConfig())) > 0  # on by default
    conf = RadarPixelFactorConfig(kernel="none")  # no outliers here: one least-squares stage (fast)
    obs = [0, 2, 3, 4]
    on, off = [], []
    for s in range(8):
        g = rng(300 + s)
        frames = _scene_drive(T, conf, g)
        est = solve_batch(frames, T @ se3_exp(g.normal(size=6) * 0.01), {"factor": conf}).estimate
        e = local(T, est.T)[obs]
        C_off = analyse_drive_information(est.T, est.info, None, conf).cov  # no scene_cross: today's reading
        on.append(e @ np.linalg.solve(est.cov[np.ix_(obs, obs)], e))
        off.append(e @ np.linalg.solve(C_off[np.ix_(obs, obs)], e))
    assert 1.5 < np.mean(on) < 8.0, (np.mean(on), on)
    assert np.mean(off) > 1.5 * np.mean(on), (np.mean(off), off)


def _tilted_radar_drive(T_cam_level, Q, g, frames=6):
    """Oracle rows of a radar tilted by ``Q`` (4, 4: T_level_radar) against the road: reflector heights above the
    road (N(0.5, 0.8)), each recorded in the tilted radar's plane (range, azimuth; z = 0)."""
    from factors.synthetic import synthetic_correspondences

    out = []
    for k in range(frames):
        c, tr = synthetic_correspondences(T_cam_level, n=80, rng=g, outlier_frac=0.0, height_m=(0.5, 0.8),
                                          elevation_beam_deg=14.0)
        p = tr["points_true"] @ Q[:3, :3]  # the true points in the tilted radar's frame
        r, az = np.linalg.norm(p, axis=1), np.arctan2(p[:, 1], p[:, 0])
        out.append(dataclasses.replace(c, points_radar=np.stack([r * np.cos(az), r * np.sin(az), 0 * r], 1),
                                       frame_id=f"tilted-{k}"))
    return out


@pytest.mark.parametrize("roll_pitch_deg", [(0.0, 3.0), (3.0, 0.0)])
def test_heights_are_measured_from_the_road_as_the_tables_mount_the_radar(roll_pitch_deg):
    """Probe 133: a radar mounted 2-3 deg off level was taken for level (its heights measured from its own plane):
    pitch 2.5 deg off at a 1 deg std, the bias leaking into roll, NEES ~60-90. With the road's normal in the radar
    frame (``height_plane_normal``, which calibrate sets from the tables' mount: ``pipeline.road_normal``) the
    estimate is unbiased and its NEES ~6."""
    from hybrid_calib.calib.pipeline import road_normal
    from hybrid_calib.geometry import make_T, so3_exp

    Q = make_T(so3_exp(np.radians([*roll_pitch_deg, 0.0])), np.zeros(3))
    T_cam_level = nominal_T_cam_radar()
    T = T_cam_level @ Q
    n = road_normal(Q)
    np.testing.assert_allclose(n, Q[:3, :3].T @ [0, 0, 1])
    fac = dict(HEIGHT, elevation_beam_deg=14.0, kernel="none")
    nees, err = {}, {}
    for plane in ("radar", "road"):
        conf = RadarPixelFactorConfig(**fac, height_plane_normal=None if plane == "radar" else tuple(n))
        e_all = []
        for s in range(4):
            g = rng(700 + s)
            est = solve_batch(_tilted_radar_drive(T_cam_level, Q, g), T @ se3_exp(g.normal(size=6) * 0.01),
                              {"factor": conf}).estimate
            e = local(T, est.T)
            e_all.append((np.degrees(np.abs(e[:3])).max(), float(e @ np.linalg.solve(est.cov, e))))
        err[plane], nees[plane] = np.mean([a for a, _ in e_all]), np.mean([b for _, b in e_all])
    assert err["road"] < 0.3 and 1.0 < nees["road"] < 12.0, (err, nees)
    assert err["radar"] > 0.6 and nees["radar"] > 3 * nees["road"], (err, nees)


def test_the_road_plane_is_set_where_the_options_leave_it_and_checked():
    from hybrid_calib.calib.pipeline import CalibrateConfig, on_road_plane, road_normal
    from hybrid_calib.config import merge
    from hybrid_calib.geometry import make_T, so3_exp

    n = road_normal(make_T(so3_exp(np.radians([0.0, 2.0, 0.0])), np.zeros(3)))
    conf = on_road_plane(CalibrateConfig(), n)
    assert conf.window.factor.height_plane_normal == tuple(n) == conf.batch.factor.height_plane_normal
    mine = merge(CalibrateConfig, {"window": {"factor": {"height_plane_normal": [0.0, 0.0, 1.0]}}})
    assert on_road_plane(mine, n).window.factor.height_plane_normal == (0.0, 0.0, 1.0)  # the user's kept
    arc = merge(CalibrateConfig, {"window": {"factor": {"elevation_model": "anisotropic"}}})
    assert on_road_plane(arc, n).window.factor.height_plane_normal is None  # no heights, no plane
    assert on_road_plane(conf, None) is conf
    # a radar mounted on its side (more than 60 deg off level): its own plane
    assert road_normal(make_T(so3_exp(np.radians([90.0, 0.0, 0.0])), np.zeros(3))) is None
    for bad in ([1.0, 0.0, 0.0], [0.0, float("nan"), 1.0], [0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, -1.0]):
        with pytest.raises(ValueError, match="height_plane_normal"):
            RadarPixelFactorConfig(height_plane_normal=tuple(bad))
    # typed by hand (probe 135: a normal typed to 5 decimals was refused): normalised
    np.testing.assert_allclose(RadarPixelFactorConfig(height_plane_normal=(0.0, 0.0, 2.0)).height_plane_normal,
                               (0.0, 0.0, 1.0))
    typed = RadarPixelFactorConfig(height_plane_normal=(-0.04213, 0.00904, 0.99907)).height_plane_normal
    assert abs(np.linalg.norm(typed) - 1) < 1e-12


def test_the_oracle_s_model_draw_keeps_the_radar_s_own_plane():
    """Probe 135 (HIGH): oracle.elevation=model draws heights above the radar's own plane, but calibrate fitted them
    from the road plane (a tilted mount: pitch 2.3 deg off, NEES 29.6)."""
    import unittest.mock as mock

    from hybrid_calib.calib import pipeline
    from hybrid_calib.calib.oracle import synthetic_drive as drive
    from hybrid_calib.calib.pipeline import CalibrateConfig, VehicleInput, calibrate_vehicle
    from hybrid_calib.calib.result import VehicleResult
    from hybrid_calib.config import merge
    from hybrid_calib.geometry import make_T, so3_exp

    T = nominal_T_cam_radar()
    frames, truths = drive(T, 4, rng(11), {"n_per_frame": 40})
    seen = []
    real = pipeline.on_road_plane
    n = pipeline.road_normal(make_T(so3_exp(np.radians([0.0, 3.0, 0.0])), np.zeros(3)))
    for elevation, planed in (("model", False), ("world", True)):
        seen.clear()
        conf = merge(CalibrateConfig, {"mode": "batch", "oracle": {"elevation": elevation}})
        vi = VehicleInput("v", frames, reference=T, truth=[T] * 4, oracle_truths=truths, road_normal=n)
        with mock.patch.object(pipeline, "on_road_plane", lambda c, nn: seen.append(nn) or real(c, nn)):
            res = calibrate_vehicle(vi, conf, progress=False, T_start=T)
        assert bool(seen) is planed, (elevation, seen)
        # the result says which plane it fitted with (it did not: session 50's known item)
        said = VehicleResult.from_dict(json.loads(json.dumps(res.to_dict()))).height_plane
        assert said["plane"] == ("road" if planed else "radar"), said
        if planed:
            np.testing.assert_allclose(said["normal_radar"], n, atol=1e-8)
        else:
            assert said["normal_radar"] is None and "model draw" in said["words"], said
    old = {k: v for k, v in res.to_dict().items() if k != "height_plane"}  # a result written before it
    assert VehicleResult.from_dict(old).height_plane is None
    with pytest.raises(TypeError, match="height_plane"):
        VehicleResult.from_dict({**old, "height_plane": [1, 2]})


def test_the_result_names_the_height_plane_the_options_set_or_none_for_other_models():
    from hybrid_calib.calib.pipeline import height_plane_record

    road = RadarPixelFactorConfig(height_plane_normal=(0.0, 0.05, 1.0))
    mine = height_plane_record(road, road)
    assert mine["plane"] == "option" and "options" in mine["words"]
    np.testing.assert_allclose(mine["normal_radar"], np.array([0.0, 0.05, 1.0]) / np.hypot(0.05, 1.0), atol=1e-8)
    assert height_plane_record(RadarPixelFactorConfig(), RadarPixelFactorConfig(), "why")["words"].endswith("(why)")
    arc = RadarPixelFactorConfig(elevation_model="mean_arc")
    assert height_plane_record(arc, arc) is None


def test_a_plane_normal_typed_as_text_is_shown_as_numbers():
    """Probe 135 (LOW): the hint for a float triple typed as text showed a list of quoted strings."""
    from hybrid_calib.calib.pipeline import CalibrateConfig
    from hybrid_calib.config import ConfigError, merge

    with pytest.raises(ConfigError, match=r"a list is JSON: --set 'window.factor.height_plane_normal=\[0, 0, 1\]'"):
        merge(CalibrateConfig, {"window": {"factor": {"height_plane_normal": "0,0,1"}}})
    with pytest.raises(ConfigError, match="a list is JSON with quoted strings"):
        merge(CalibrateConfig, {"vehicles": "a,b"})
