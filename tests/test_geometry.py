import gtsam
import numpy as np
import pytest

from hybrid_calib import geometry as G
from hybrid_calib.metrics import extrinsic_error, signed_errors
from tests.helpers import assert_close, nominal_T_cam_radar, random_pose, rng


@pytest.mark.parametrize("seed", range(5))
def test_se3_exp_log_match_gtsam(seed):
    g = rng(seed)
    xi = g.normal(size=6) * [0.8, 0.8, 0.8, 2, 2, 2]
    assert_close(G.se3_exp(xi), gtsam.Pose3.Expmap(xi).matrix())
    T = random_pose(g)
    assert_close(G.se3_log(T), gtsam.Pose3.Logmap(gtsam.Pose3(T)), scale=100)


@pytest.mark.parametrize("seed", range(3))
def test_retract_local_match_gtsam(seed):
    g = rng(seed)
    T1, T2 = random_pose(g), random_pose(g)
    xi = g.normal(size=6) * 0.3
    assert_close(G.retract(T1, xi), gtsam.Pose3(T1).retract(xi).matrix(), scale=100)
    assert_close(G.local(T1, T2), gtsam.Pose3(T1).localCoordinates(gtsam.Pose3(T2)), scale=1000)


def test_local_many_is_local_of_each():
    """The batched right tangent (averaging a long drive's estimates at once; probe 57) is ``local`` of each, at
    large angles, near zero and near pi, and GTSAM's localCoordinates."""
    g = rng(11)
    T1 = random_pose(g)
    Ts = [T1 @ G.se3_exp(g.normal(size=6) * s) for s in [1.0] * 10 + [1e-9] * 3 + [0.0]]
    Ts.append(T1 @ G.se3_exp(np.r_[np.pi - 1e-4, 0, 0, 0.3, -0.2, 0.1]))
    got = G.local_many(T1, np.stack(Ts))
    assert got.shape == (len(Ts), 6)
    for T, xi in zip(Ts, got):
        assert_close(xi, G.local(T1, T), scale=1000)
        assert_close(xi, gtsam.Pose3(T1).localCoordinates(gtsam.Pose3(T)), scale=1e5)


def test_adjoint_matches_gtsam_and_definition():
    g = rng(7)
    T = random_pose(g)
    xi = g.normal(size=6) * 0.1
    assert_close(G.adjoint(T), gtsam.Pose3(T).AdjointMap(), scale=10)
    assert_close(T @ G.se3_exp(xi), G.se3_exp(G.adjoint(T) @ xi) @ T, scale=100)


def test_quaternion_roundtrip_nuscenes_order():
    # 90 deg about z: w = cos(45), z = sin(45)
    q = np.array([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    R = G.quat_wxyz_to_matrix(q)
    assert_close(R @ [1, 0, 0], [0, 1, 0], scale=10)
    assert_close(G.matrix_to_quat_wxyz(R), q, scale=10)
    with pytest.raises(ValueError, match="invalid quaternion"):
        G.quat_wxyz_to_matrix([0, 0, 0, 0])


def test_axis_permutation_maps_radar_forward_to_camera_forward():
    R = G.R_AXES_CAM_FROM_RADAR
    assert_close(R @ [1, 0, 0], [0, 0, 1])  # forward
    assert_close(R @ [0, 1, 0], [-1, 0, 0])  # left -> -x (camera x is right)
    assert_close(R @ [0, 0, 1], [0, -1, 0])  # up -> -y (camera y is down)
    assert np.isclose(np.linalg.det(R), 1.0)


def test_camera_euler_axes():
    # A pure rotation about the optical axis (camera z) is roll.
    rpy = G.camera_euler_from_rotation(G.so3_exp([0, 0, 0.1]))
    assert_close(rpy, [0.1, 0, 0], scale=1e3)
    rpy = G.camera_euler_from_rotation(G.so3_exp([0.1, 0, 0]))
    assert_close(rpy, [0, 0.1, 0], scale=1e3)
    rpy = G.camera_euler_from_rotation(G.so3_exp([0, 0.1, 0]))
    assert_close(rpy, [0, 0, 0.1], scale=1e3)


def test_camera_euler_order_is_intrinsic_y_x_z():
    """docs/conventions.md: ``R = Ry(yaw) Rx(pitch) Rz(roll)``, built here from elementary matrices. Single-axis
    rotations and round trips cannot tell the order (another order used both ways passes them; probe 28): a
    composed rotation of three large angles can."""
    roll, pitch, yaw = np.radians([15.0, -12.0, 18.0])
    c, s = np.cos, np.sin
    Rx = np.array([[1, 0, 0], [0, c(pitch), -s(pitch)], [0, s(pitch), c(pitch)]])
    Ry = np.array([[c(yaw), 0, s(yaw)], [0, 1, 0], [-s(yaw), 0, c(yaw)]])
    Rz = np.array([[c(roll), -s(roll), 0], [s(roll), c(roll), 0], [0, 0, 1]])
    R = Ry @ Rx @ Rz
    assert_close(G.camera_euler_from_rotation(R), [roll, pitch, yaw], scale=1e3)
    assert_close(G.rotation_from_camera_euler([roll, pitch, yaw]), R, scale=1e3)
    assert np.abs(G.camera_euler_from_rotation(Rz @ Rx @ Ry) - [roll, pitch, yaw]).max() > np.radians(1)


@pytest.mark.parametrize("seed", range(5))
def test_perturbation_reads_back_through_metrics(seed):
    g = rng(seed)
    T = nominal_T_cam_radar()
    rpy = g.uniform(-1, 1, 3) * np.radians(20)
    dt = g.uniform(-1.5, 1.5, 3)
    Tp = G.perturb_camera_frame(T, rpy, dt)
    assert_close(signed_errors(Tp, T), np.concatenate([rpy, dt]), scale=1e3)
    e = extrinsic_error(Tp, T)
    assert np.isclose(e.rot_mean_deg, np.degrees(np.abs(rpy)).mean())
    assert np.isclose(e.trans_mean_cm, np.abs(dt).mean() * 100)
    assert np.isclose(e.trans_norm_cm, np.linalg.norm(dt) * 100)


def test_metrics_zero_at_truth():
    T = nominal_T_cam_radar()
    e = extrinsic_error(T, T)
    assert max(e.as_dict().values()) < 1e-9


def test_nearest_rigid_makes_a_float32_rotation_exact():
    from hybrid_calib.geometry import is_rigid, nearest_rigid, se3_exp

    T = se3_exp(np.array([0.3, -0.2, 1.1, 0.5, -1.0, 2.0]))
    noisy = T.astype(np.float32).astype(np.float64) + 1e-7
    noisy[3] = [0, 0, 0, 1]
    fixed = nearest_rigid(noisy)
    assert is_rigid(fixed, 1e-12) and np.abs(fixed - T).max() < 1e-6
    np.testing.assert_array_equal(fixed[:3, 3], noisy[:3, 3])
