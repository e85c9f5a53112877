"""LiDAR model: format, beam geometry, and consistency with the ground-truth depth image."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hybrid_calib.data.frame import read_depth_png
from hybrid_calib.data.pcd import read_lidar_bin
from hybrid_calib.geometry import se3_inverse, transform_points
from hybrid_calib.sim.drive import SimConfig, VehicleDrive
from hybrid_calib.sim.lidar import LidarConfig, beam_elevations, simulate_lidar_sweep
from hybrid_calib.sim.raycast import BOX, Primitives
from hybrid_calib.sim.simulate import depth_file, frame_record, write_frame


@pytest.fixture(scope="module")
def drive_root(tmp_path_factory):
    conf = SimConfig(scenario="urban", frames=3, seed=5, image_scale=0.25)
    drive = VehicleDrive(conf, 0)
    root = tmp_path_factory.mktemp("lidar_sim")
    recs = [frame_record(drive, k, "lidar-test") for k in range(conf.frames)]
    for r in recs:
        write_frame(root, drive, r)
    return drive, root, recs


def test_format_and_beams(drive_root):
    drive, root, recs = drive_root
    conf = drive.conf.lidar
    for r in recs:
        pts = read_lidar_bin(root / r.lidar_file)
        assert pts.dtype == np.float32 and pts.shape[1] == 5
        assert 10_000 < len(pts) <= conf.n_beams * conf.azimuth_steps
        ring = pts[:, 4]
        assert np.all(ring == np.round(ring)) and ring.min() >= 0 and ring.max() <= conf.n_beams - 1
        rng_ = np.linalg.norm(pts[:, :3], axis=1)
        assert rng_.min() >= conf.min_range_m - 0.1 and rng_.max() <= conf.max_range_m + 0.1
        el = np.arcsin(pts[:, 2] / rng_)
        # each point lies on its beam's cone (up to range noise and the LiDAR's own mounting tilt)
        err = np.abs(el - beam_elevations(conf)[ring.astype(int)])
        assert np.median(err) < np.deg2rad(0.2), np.rad2deg(np.median(err))
        assert np.all((pts[:, 3] >= 0) & (pts[:, 3] <= 255))


def test_points_agree_with_the_depth_image(drive_root):
    drive, root, recs = drive_root
    cam = drive.conf.camera
    errs = []
    for r in recs:
        pts = read_lidar_bin(root / r.lidar_file)[:, :3].astype(np.float64)
        T_cam_lidar = (se3_inverse(drive.mounts.T_ego_cam) @ se3_inverse(r.T_global_ego_cam)
                       @ r.T_global_ego_lidar @ drive.mounts.T_ego_lidar)
        uv, z = cam.project(transform_points(T_cam_lidar, pts))
        ok = cam.in_image(uv, margin=1.0) & (z > 1.0)
        px = np.round(uv[ok]).astype(int)
        depth = read_depth_png(depth_file(root, r.camera_file))
        errs.append(np.abs(depth[px[:, 1], px[:, 0]] - z[ok]))
    errs = np.concatenate(errs)
    assert len(errs) > 2000
    # different viewpoints: some LiDAR points are hidden from the camera; most agree to noise
    assert np.median(errs) < 0.05, np.median(errs)
    assert np.mean(errs < 0.3) > 0.85, np.mean(errs < 0.3)


def test_single_wall_ranges_and_intensity():
    # a wall 10 m ahead along the LiDAR's y axis (forward); the ground below
    wall = Primitives(kind=np.array([BOX], np.int8), center=np.array([[0.0, 10.5, 2.0]]),
                      half=np.array([[20.0, 0.5, 2.0]]), yaw=np.zeros(1), colour=np.ones((1, 3), np.float32),
                      material=np.zeros(1, np.int16), object_id=np.zeros(1, np.int32), velocity=np.zeros((1, 3)))
    T = np.eye(4)
    T[2, 3] = 1.8
    conf = LidarConfig(range_noise_m=0.0, dropout_probability=0.0, intensity_noise=0.0)
    pts = simulate_lidar_sweep(wall, T, conf, np.random.default_rng(0), lambda xy: np.full(len(xy), 0.1))
    on_wall = np.abs(pts[:, 1] - 10.0) < 1e-3
    assert on_wall.sum() > 100
    ground = np.abs(pts[:, 2] + 1.8) < 1e-3
    assert ground.sum() > 1000
    assert on_wall.sum() + ground.sum() == len(pts)
    assert pts[on_wall, 3].mean() > pts[ground, 3].mean()


def test_deterministic(drive_root):
    drive, root, recs = drive_root
    again = VehicleDrive(drive.conf, 0).simulate_frame(0).lidar
    assert np.array_equal(again, read_lidar_bin(root / recs[0].lidar_file))
    assert Path(root / recs[0].lidar_file).stat().st_size == again.nbytes
