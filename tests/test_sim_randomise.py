"""Domain randomisation (``SimConfig.randomise``): off changes nothing, on changes the named quantities
deterministically by seed, and the written nuScenes root stays valid and consistent."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hybrid_calib.config import ConfigError, merge
from hybrid_calib.geometry import pose_from_nuscenes
from hybrid_calib.sim.drive import SimConfig, VehicleDrive
from hybrid_calib.sim.extrinsics import NOMINAL_T_EGO_CAM
from hybrid_calib.sim.radar import RadarConfig, simulate_radar_sweep
from hybrid_calib.sim.randomise import NUSCENES_FLEET_MOUNTS, Randomisation, draw_vehicle
from hybrid_calib.sim.render import ShadingConfig

TABLES = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "nuscenes-trainval-tables" / "v1.0-trainval"
ON = {"randomise": {"enabled": True}}


def conf(seed: int = 0, **over) -> SimConfig:
    return merge(SimConfig, {"frames": 3, "seed": seed, "image_scale": 0.125, **over})


def test_off_by_default_changes_nothing():
    d = VehicleDrive(conf(), 0)
    assert d.draw is None and d.base_mounts is None
    assert d.radar_config == d.conf.effective_radar
    assert d.camera == d.conf.camera
    assert d.shading(2) == ShadingConfig()
    assert d.jpeg_quality(1) == d.conf.jpeg_quality
    # the randomisation's streams are its own: the true mounts of a randomised vehicle differ only
    # through the drawn base mount (same perturbation draws on top)
    r = VehicleDrive(conf(**ON), 0)
    assert not np.allclose(r.mounts.T_ego_cam, d.mounts.T_ego_cam)
    assert np.allclose(np.linalg.inv(r.base_mounts[0]) @ r.mounts.T_ego_cam,
                       np.linalg.inv(NOMINAL_T_EGO_CAM) @ d.mounts.T_ego_cam, atol=1e-12)


def test_draws_change_the_named_quantities_deterministically():
    a0, a0_again, a1, b0 = (VehicleDrive(conf(**ON), 0), VehicleDrive(conf(**ON), 0), VehicleDrive(conf(**ON), 1),
                            VehicleDrive(conf(seed=7, **ON), 0))
    assert a0.draw.to_json() == a0_again.draw.to_json()
    assert a0.draw.to_json() != a1.draw.to_json() and a0.draw.to_json() != b0.draw.to_json()
    base = a0.conf.effective_radar
    rc = a0.radar_config
    r = a0.conf.randomise
    for name in ("rcs_floor_db", "snr_ref_db", "detection_threshold_db", "range_noise_m", "azimuth_noise_deg",
                 "rcs_noise_db", "velocity_noise_mps", "clutter_per_sweep", "ghost_probability", "azimuth_loss_db"):
        assert getattr(rc, name) != getattr(base, name), name
    assert r.rcs_floor_db[0] <= rc.rcs_floor_db <= r.rcs_floor_db[1]
    assert r.clutter_scale[0] <= rc.clutter_per_sweep / base.clutter_per_sweep <= r.clutter_scale[1]
    # appearance: the per-vehicle keys stay, the per-frame keys change from frame to frame
    s1, s2 = a0.shading(1), a0.shading(2)
    assert (s1.exposure, s1.gamma, s1.saturation, s1.contrast, s1.fog_distance) == (
        s2.exposure, s2.gamma, s2.saturation, s2.contrast, s2.fog_distance)
    assert s1.exposure != 1.0 and s1.white_balance != (1.0, 1.0, 1.0) and s1.object_tint > 0
    assert s1.noise_std != s2.noise_std and s1.blur_sigma_px != s2.blur_sigma_px
    assert {a0.jpeg_quality(k) for k in range(6)} != {a0.jpeg_quality(0)}
    assert all(r.jpeg_quality[0] <= a0.jpeg_quality(k) <= r.jpeg_quality[1] for k in range(6))
    # mounts and intrinsics from the real fleet (scene-weighted), with the intrinsics jitter on top
    row = NUSCENES_FLEET_MOUNTS[a0.draw.fleet_mount]
    assert np.allclose(a0.base_mounts[1], pose_from_nuscenes(row[5], row[4]))
    fx, fy, cx, cy = a0.draw.camera_K_full
    assert abs(fx / row[3][0] - 1) <= r.focal_jitter and abs(cx - row[3][2]) <= r.principal_jitter_px
    assert a0.camera.fx == pytest.approx(fx * 0.125) and a0.camera.width == 200
    draws = [draw_vehicle(Randomisation(enabled=True), base, np.random.default_rng(i)) for i in range(300)]
    picks = [d.fleet_mount for d in draws]
    assert set(picks) == set(range(len(NUSCENES_FLEET_MOUNTS))) and picks.count(0) > 5 * picks.count(3)
    assert 0.3 < np.mean([d.overcast for d in draws]) < 0.5  # overcast_probability 0.4


def test_rendered_frame_is_randomised_and_reproducible():
    plain = VehicleDrive(conf(), 0).simulate_frame(1)
    f = VehicleDrive(conf(**ON), 0).simulate_frame(1)
    again = VehicleDrive(conf(**ON), 0).simulate_frame(1)
    assert np.array_equal(f.image, again.image) and np.array_equal(f.radar.points, again.radar.points)
    assert f.image.shape == plain.image.shape
    assert np.abs(f.image.astype(float) - plain.image.astype(float)).mean() > 3.0


def test_rcs_floor_removes_weak_points():
    d = VehicleDrive(conf(), 0)
    t = (d.times(1).radar_us - d.base_us) * 1e-6
    T = d.ego.T_global_ego(t) @ d.T_ego_radar(1)
    prims = d.world.primitives_at(t, T[:3, 3], 250.0)
    rc = merge(RadarConfig, {"rcs_noise_db": 0.0})
    weak = simulate_radar_sweep(prims, T, np.zeros(3), rc, np.random.default_rng(0))
    rc_floor = merge(RadarConfig, {"rcs_noise_db": 0.0, "rcs_floor_db": -5.0})
    floored = simulate_radar_sweep(prims, T, np.zeros(3), rc_floor, np.random.default_rng(0))
    assert (weak.points["rcs"] < -10).sum() >= 3
    assert (floored.points["rcs"] < -10).sum() == 0 and len(floored) > 0


def test_bad_options_fail_clearly():
    with pytest.raises(ConfigError, match="per_frame"):
        merge(SimConfig, {"randomise": {"per_frame": ["colour"]}})
    with pytest.raises(ConfigError, match="exposure"):
        merge(SimConfig, {"randomise": {"exposure": [1.2, 0.8]}})


def test_randomised_root_is_a_valid_nuscenes_root(tmp_path):
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.sim.simulate import simulate

    c = merge(SimConfig, {"vehicles": 2, "frames": 2, "seed": 3, "image_scale": 0.125, **ON})
    root = simulate(c, tmp_path / "sim", progress=False)
    ds = NuScenesRadarCamera(root, "v1.0-sim", conf={"load_lidar": True})
    assert len(ds) == 4 and not ds.skipped
    truth = json.loads((root / "v1.0-sim" / "sim_vehicle.json").read_text())
    for v, rec in enumerate(truth):
        drive = VehicleDrive(c, v)
        assert rec["randomisation"] == json.loads(json.dumps(drive.draw.to_json()))
        assert rec["radar_config"]["rcs_floor_db"] == drive.radar_config.rcs_floor_db
    for f in ds:
        d = VehicleDrive(c, int(f.vehicle.split("-")[-1]))
        assert np.allclose(f.K, d.camera.K)
        img = f.load_image()
        assert img.shape == (d.camera.height, d.camera.width, 3)
        assert np.allclose(f.extras["T_ego_cam"], d.mounts.T_ego_cam, atol=1e-9)
        assert f.lidar_points is not None and len(f.lidar_points) > 100


@pytest.mark.skipif(not (TABLES / "calibrated_sensor.json").is_file(), reason="trainval tables not present")
def test_fleet_mounts_copy_matches_the_trainval_tables():
    from hybrid_calib.data.fleet_mounts import fleet_mounts

    found = fleet_mounts(TABLES)
    assert sum(m.scenes for m in found) == 850
    assert len(found) == len(NUSCENES_FLEET_MOUNTS)
    for m, row in zip(found, NUSCENES_FLEET_MOUNTS):
        K = np.asarray(m.camera_K)
        assert (m.scenes, m.cam_translation, m.cam_rotation, m.radar_translation, m.radar_rotation,
                m.lidar_translation, m.lidar_rotation) == (row[0], row[1], row[2], row[4], row[5], row[6], row[7])
        assert np.allclose((K[0, 0], K[1, 1], K[0, 2], K[1, 2]), row[3], atol=1e-3)
