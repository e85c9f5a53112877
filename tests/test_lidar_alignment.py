"""The radar's lateral offset from the LiDAR (calib.lidar_alignment): recovery on a synthetic scene of
poles and on a simulated drive, the Kalman fold into an estimate, and the refusals."""

from __future__ import annotations

import numpy as np
import pytest

from hybrid_calib.calib.lidar_alignment import (
    RADAR_Y,
    LidarAlignConfig,
    LidarAlignment,
    LidarFrame,
    align,
    apply_lateral,
    drive_frames,
)
from hybrid_calib.geometry import local, se3_exp

X_TRUE = np.array([[0.0, -1, 0, 0.1], [0, 0, -1, -0.3], [1, 0, 0, -0.5], [0, 0, 0, 1]])  # radar x fwd -> cam z


def _poles(g: np.random.Generator, n_frames: int = 6, n_poles: int = 25, noise_m: float = 0.05,
           lateral=(-15, 15), range_offset_m: float = 0.0) -> list[LidarFrame]:
    """Frames of poles (radius 0.15 m) seen by a LiDAR mounted at the radar (T_radar_lidar = I): LiDAR rings
    at several heights, radar detections ``range_offset_m`` behind each pole's first surface with range
    noise."""
    frames = []
    for k in range(n_frames):
        c = np.column_stack([g.uniform(6, 40, n_poles), g.uniform(*lateral, n_poles)])
        ang = np.linspace(0, 2 * np.pi, 72, endpoint=False)
        ring = np.column_stack([np.cos(ang), np.sin(ang)]) * 0.15
        lidar = np.concatenate([np.column_stack([cj + ring, np.full(len(ring), h)]) for cj in c
                                for h in (0.2, 0.8, 1.5)])
        r = np.linalg.norm(c, axis=1) - 0.15 + range_offset_m + noise_m * g.standard_normal(n_poles)
        a = np.arctan2(c[:, 1], c[:, 0])
        frames.append(LidarFrame(lidar, X_TRUE.copy(), np.eye(4), np.column_stack([r * np.cos(a), r * np.sin(a)]),
                                 f"f{k}"))
    return frames


def test_recovers_the_lateral_offset_from_a_start_half_a_metre_off():
    frames = _poles(np.random.default_rng(0))
    start = X_TRUE @ se3_exp(np.array([0.0, 0.0, 0.0, 0.3, -0.4, 0.0]))
    a, why = align(frames, start, LidarAlignConfig(systematic_m=0.0, min_rows=30))
    assert a is not None, why
    need = local(start, X_TRUE)
    assert abs(a.delta[1] - need[RADAR_Y]) < 0.01 and abs(a.delta[0] - need[3]) < 0.1 and abs(a.delta[2]) < 0.1
    assert 0 < a.dy_std < 0.01 and a.frames == 6 and a.rows > 100
    # the drive-common term enters the reported variance of dy only
    b, _ = align(frames, start, LidarAlignConfig(systematic_m=0.03, min_rows=30))
    assert np.isclose(b.cov[1, 1], a.cov[1, 1] + 0.03 ** 2) and np.isclose(b.cov[0, 0], a.cov[0, 0])


def test_a_range_offset_on_a_one_sided_scene_does_not_become_a_lateral_offset():
    # every pole on the right, detections 0.3 m behind the surface (a radar's reflection depth)
    frames = _poles(np.random.default_rng(3), n_frames=12, lateral=(-20, -4), range_offset_m=0.3)
    start = X_TRUE @ se3_exp(np.array([0.0, 0.0, 0.0, 0.2, 0.25, 0.0]))
    need = local(start, X_TRUE)[RADAR_Y]
    a, why = align(frames, start, LidarAlignConfig(systematic_m=0.0, coupling_deg=0.0))
    assert a is not None, why
    assert abs(a.delta[1] - need) < 3 * a.dy_std and a.dy_std < 0.05 and abs(a.delta[2] - 0.3) < 0.15
    # without the range offset in the model the same scene reads as a lateral offset, confidently
    b, _ = align(frames, start, LidarAlignConfig(systematic_m=0.0, coupling_deg=0.0, range_bias=False))
    assert abs(b.delta[1] - need) > max(0.1, 5 * b.dy_std)


def test_the_coupling_is_how_dy_moves_with_the_estimates_rotation():
    frames = _poles(np.random.default_rng(4), lateral=(-20, -2))
    a, _ = align(frames, X_TRUE, LidarAlignConfig(systematic_m=0.0, min_rows=30))
    phi = np.radians(0.3)
    b, _ = align(frames, X_TRUE @ se3_exp(np.array([0.0, 0.0, phi, 0.0, 0.0, 0.0])),
                 LidarAlignConfig(systematic_m=0.0, coupling_deg=0.0, min_rows=30))
    assert abs(a.coupling[2]) > 0.1  # a one-sided scene: a turn of the radar reads partly as a lateral offset
    assert abs((b.delta[1] - a.delta[1]) - a.coupling[2] * phi) < 0.3 * abs(a.coupling[2] * phi) + 0.002


def test_a_frame_with_no_lidar_ahead_of_the_radar_is_left_out_not_a_crash():
    frames = _poles(np.random.default_rng(5))
    f = frames[0]
    behind = LidarFrame(f.lidar * [-1, 1, 1], f.T_cam_lidar, f.A, f.radar_xy, "behind")  # every point behind
    a, why = align([behind, *frames], X_TRUE, LidarAlignConfig(min_rows=30))
    assert a is not None, why
    assert a.frames == len(frames)


def test_refuses_too_few_frames_rows_or_one_direction():
    frames = _poles(np.random.default_rng(1), n_frames=2)
    a, why = align(frames, X_TRUE, LidarAlignConfig())
    assert a is None and "2 frame(s) with LiDAR (need 3)" in why
    few = _poles(np.random.default_rng(1), n_frames=3, n_poles=3)
    a, why = align(few, X_TRUE, LidarAlignConfig())
    assert a is None and "need 100" in why
    # one pole per frame straight ahead: every matched beam points along radar x, dy is not observed
    ahead = []
    for k, f in enumerate(_poles(np.random.default_rng(2), n_poles=1)):
        x = 8.0 + 3 * k
        ring = f.lidar - np.r_[f.lidar[:, :2].mean(axis=0), 0.0] + [x, 0.0, 0.0]
        ahead.append(LidarFrame(ring, X_TRUE, np.eye(4), np.column_stack([np.full(5, x - 0.15), np.zeros(5)]),
                                f.frame_id))
    a, why = align(ahead, X_TRUE, LidarAlignConfig(min_rows=3))
    assert a is None and "one direction" in why


def test_apply_lateral_is_a_kalman_update_along_radar_y():
    cov = np.diag(np.square([0.01, 0.01, 0.005, 0.1, 0.3, 0.1]))
    cov[2, RADAR_Y] = cov[RADAR_Y, 2] = 0.5 * 0.005 * 0.3  # yaw and lateral offset correlated
    a = LidarAlignment(np.array([0.05, 0.2, 0.1]), np.diag([0.01, 0.03 ** 2, 0.01]), 100, 10, 0.2, 8)
    T, cov2 = apply_lateral(X_TRUE, cov, a)
    xi = local(X_TRUE, T)
    gain = 0.3 ** 2 / (0.3 ** 2 + 0.03 ** 2)
    assert np.isclose(xi[RADAR_Y], gain * 0.2, rtol=1e-6) and abs(xi[3]) < 1e-9  # dx is not used
    assert np.isclose(xi[2], cov[2, RADAR_Y] / (0.3 ** 2 + 0.03 ** 2) * 0.2, rtol=1e-6)  # the correlated yaw moves
    assert np.isclose(cov2[RADAR_Y, RADAR_Y], 0.3 ** 2 * 0.03 ** 2 / (0.3 ** 2 + 0.03 ** 2))
    assert np.isclose(cov2[3, 3], cov[3, 3]) and np.linalg.eigvalsh(cov2).min() > 0
    # with a coupling, dy measures xi[4] - c * xi[2]: its innovation variance carries the yaw's
    c = LidarAlignment(a.delta, a.cov, 100, 10, 0.2, 8, coupling=np.array([0.0, 0.0, 4.0]))
    T3, cov3 = apply_lateral(X_TRUE, cov, c)
    h = np.array([0, 0, -4.0, 0, 1, 0])
    s = h @ cov @ h + 0.03 ** 2
    np.testing.assert_allclose(local(X_TRUE, T3), cov @ h / s * 0.2, rtol=1e-6, atol=1e-12)
    assert np.isclose(h @ cov3 @ h, (h @ cov @ h) * 0.03 ** 2 / s)


@pytest.fixture(scope="module")
def sim_root(tmp_path_factory):
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    return simulate(SimConfig(vehicles=1, frames=8, image_scale=0.05, seed=12), tmp_path_factory.mktemp("sim"),
                    progress=False)


def test_on_a_simulated_drive(sim_root):
    from learned.dataset import open_frames

    frames = open_frames(sim_root, "v1.0-sim", lidar=True)
    idx = list(range(len(frames)))
    lfs = drive_frames(frames, idx)
    assert len(lfs) == len(idx) and all(len(f.lidar) for f in lfs)
    truth = np.asarray(frames[0].extras["T_cam_radar_static"])
    start = truth @ se3_exp(np.array([0.0, 0.0, 0.004, -0.2, 0.35, 0.0]))
    a, why = align(lfs, start)
    assert a is not None, why
    err = a.delta[1] - local(start, truth)[RADAR_Y]
    assert abs(err) < 3 * a.dy_std and a.dy_std < 0.06
    # without LiDAR there is nothing to align with
    assert drive_frames(open_frames(sim_root, "v1.0-sim", lidar=False), idx) == []
