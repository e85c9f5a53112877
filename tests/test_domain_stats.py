"""The sim-vs-real statistics (``hybrid_calib.data.domain_stats``) and their figures (``plots.domain``)."""

from __future__ import annotations

import numpy as np
import pytest

from hybrid_calib.data.domain_stats import (
    _unsupported,
    depth_stats,
    image_stats,
    intrinsics_full_res,
    mount_angles,
    split_points,
)
from hybrid_calib.geometry import pose_from_nuscenes
from hybrid_calib.sim.randomise import NUSCENES_FLEET_MOUNTS


def test_image_stats_respond_to_contrast_colour_and_edges():
    grey = np.full((90, 160, 3), 128, np.uint8)
    s = image_stats(grey)
    assert s["luminance"] == pytest.approx(128 / 255, abs=1e-3)
    assert s["contrast"] < 1e-3 and s["saturation"] < 1e-3 and s["sharpness"] < 1e-3
    checker = np.kron((np.indices((9, 16)).sum(0) % 2), np.ones((10, 10)))[..., None] * np.array([255, 40, 40])
    c = image_stats(checker.astype(np.uint8))
    assert c["contrast"] > 0.1 and c["sharpness"] > 0.05 and c["saturation"] > 0.3 and c["mean_r"] > c["mean_b"]


def test_depth_stats_density_and_errors():
    K = np.array([[100.0, 0, 50], [0, 100.0, 25], [0, 0, 1]])
    depth = np.zeros((50, 100), np.float32)
    depth[:, :50] = 10.0
    g = np.random.default_rng(0)
    pts = np.stack([g.uniform(-4.9, -0.1, 200), g.uniform(-2.4, 2.4, 200), np.full(200, 11.5)], 1)
    s = depth_stats(depth, K, pts, truth=np.full((25, 50), 10.0, np.float32))
    assert s["density"] == pytest.approx(0.5)
    assert s["lidar_abs_rel"] == pytest.approx(1.5 / 11.5) and s["lidar_delta1"] == 1.0 and s["lidar_coverage"] == 1.0
    assert s["truth_abs_rel"] == pytest.approx(0.0) and s["truth_coverage"] == pytest.approx(0.5)
    assert np.isnan(depth_stats(depth, K)["lidar_abs_rel"])
    held = split_points(1000, 0.2, 3)
    assert 150 < held.sum() < 250 and np.array_equal(held, split_points(1000, 0.2, 3))


def test_lidar_support_proxy():
    radar = np.array([[10.0, 0.0], [20.0, 5.0], [40.0, -3.0]])
    lidar = np.array([[10.3, 0.2], [40.0, 0.0]])
    assert _unsupported(radar, np.hypot(*radar.T), lidar).tolist() == [False, True, True]
    assert _unsupported(radar, np.hypot(*radar.T), np.zeros((0, 2))).all()


def test_mount_angles_and_intrinsics_of_the_real_fleet():
    row = NUSCENES_FLEET_MOUNTS[0]  # 452 scenes: docs/conventions.md "Fleet mounts"
    a = mount_angles(pose_from_nuscenes(row[2], row[1]), pose_from_nuscenes(row[5], row[4]))
    assert (a["cam_yaw_deg"], a["cam_pitch_deg"], a["cam_roll_deg"]) == pytest.approx((0.58, -0.49, 0.70), abs=0.01)
    assert a["radar_yaw_deg"] == pytest.approx(-0.26, abs=0.01) and a["radar_x_m"] == pytest.approx(3.412)
    K = np.array([[316.6, 0, 203.9], [0, 316.6, 122.6], [0, 0, 1]])
    full = intrinsics_full_res(K, 400, 225)
    assert full["fx"] == pytest.approx(1266.4) and full["cx"] == pytest.approx((203.9 + 0.5) * 4 - 0.5)


def test_domain_figures_are_written_small(tmp_path):
    from hybrid_calib.plots.domain import plot_depth, plot_examples, plot_image, plot_mounts, plot_radar

    g = np.random.default_rng(1)
    group = {"n": g.integers(20, 70, 30), "range_m": g.uniform(1, 200, 500), "azimuth_deg": g.uniform(-60, 60, 500),
             "rcs_dbsm": g.normal(5, 5, 500), "luminance": g.random(30), "contrast": g.random(30),
             "saturation": g.random(30), "sharpness": g.random(30), "mean_r": g.random(30), "mean_g": g.random(30),
             "mean_b": g.random(30), "density": g.random(30), "lidar_abs_rel": g.random(30) * 0.1,
             "truth_abs_rel": np.full(30, np.nan)}
    mounts = {k: g.normal(0, 1, 5) for k in ("cam_yaw_deg", "cam_pitch_deg", "cam_roll_deg", "radar_yaw_deg", "cam_x_m",
                                             "cam_z_m", "cx", "cy")}
    paths = [plot_radar({"a": group, "b": group}, tmp_path / "r.png"), plot_image({"a": group}, tmp_path / "i.png"),
             plot_depth({"a": group}, tmp_path / "d.png"),
             plot_mounts({"a": {**mounts, "weight": np.arange(5)}, "b": mounts}, tmp_path / "m.png"),
             plot_examples({"x": np.zeros((90, 160, 3), np.uint8)}, tmp_path / "e.png")]
    for p in paths:
        assert p.is_file() and 300 < p.stat().st_size < 150_000
