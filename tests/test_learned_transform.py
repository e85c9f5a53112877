"""learned.transform / learned.lie: points land where the geometry says."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hybrid_calib import geometry
from learned import lie
from learned.config import model_config
from learned.transform import (
    bev_intrinsics,
    cell_centres,
    cell_index,
    depth_to_points,
    project_fv,
    pseudo_bev,
    render_radar_maps,
)
from tests.helpers import nominal_T_cam_radar, random_pose, rng

H, W = 64, 128
CFG = model_config("small", {"input_hw": (H, W), "bev_hw": (64, 64), "bev_res_m": 0.5})





def _K(B=1):
    return torch.tensor([[100.0, 0, 63.5], [0, 100.0, 31.5], [0, 0, 1]]).expand(B, 3, 3).clone()


def test_lie_matches_numpy_geometry():
    g = rng(1)
    for _ in range(5):
        T1, T2 = random_pose(g, 0.5), random_pose(g, 0.5)
        t1, t2 = torch.tensor(T1), torch.tensor(T2)
        np.testing.assert_allclose(lie.local(t1, t2).numpy(), geometry.local(T1, T2), atol=1e-9)
        xi = g.normal(size=6) * 0.3
        np.testing.assert_allclose(lie.so3_exp(torch.tensor(xi[:3])).numpy(), geometry.so3_exp(xi[:3]), atol=1e-12)
        np.testing.assert_allclose(lie.inverse(t1).numpy(), geometry.se3_inverse(T1), atol=1e-12)
    assert torch.allclose(lie.so3_exp(torch.zeros(3)), torch.eye(3))


def test_lie_log_of_a_half_turn_matches_numpy_geometry():
    """Probe 141: ``lie.so3_log`` took the small-angle series wherever sin(theta) < 1e-6, at pi too, and read a
    half-turn (and a rotation 1e-5 deg short of it) as the identity; ``geometry.so3_log`` reads pi."""
    from scipy.spatial.transform import Rotation

    for deg in (180.0, 180.0 - 1e-5, 180.0 - 1e-4, 180.0 - 1e-3, 179.0):
        for axis in (np.array([0.0, 0.0, 1.0]), np.array([0.3, -0.8, 0.52]), np.array([-1.0, 0.0, 0.0])):
            R = Rotation.from_rotvec(np.radians(deg) * axis / np.linalg.norm(axis)).as_matrix()
            w = lie.so3_log(torch.from_numpy(R)[None])[0].numpy()
            assert np.linalg.norm(w) == pytest.approx(np.linalg.norm(geometry.so3_log(R)), abs=1e-6), (deg, axis)
            assert np.allclose(geometry.so3_exp(w), R, atol=1e-6), (deg, axis)  # the same rotation, either sign
            w32 = lie.so3_log(torch.from_numpy(R).float()[None])[0].double().numpy()  # the network's dtype
            assert np.degrees(np.linalg.norm(geometry.so3_log(geometry.so3_exp(w32).T @ R))) < 0.01, (deg, axis)


def test_radar_point_projects_to_fv_and_bev():
    T = torch.tensor(nominal_T_cam_radar(), dtype=torch.float32)[None]
    # radar point 20 m ahead, 2 m to the left, on the radar plane -> camera (2 m left = x -2)
    p = torch.tensor([[[20.0, 2.0, 0.0]]])
    r = render_radar_maps(T, p, torch.ones(1, 1, dtype=torch.bool), _K(), CFG)
    pc = r["points_cam"][0, 0]
    np.testing.assert_allclose(pc.numpy(), [-2.0, 1.0, 21.7], atol=1e-5)
    u, v = 63.5 + 100 * (-2.0) / 21.7, 31.5 + 100 * 1.0 / 21.7
    np.testing.assert_allclose(r["fv_pix"][0, 0].numpy(), [u, v], atol=1e-4)
    fv = r["fv"][0, 0]
    col, row = int(np.floor(u + 0.5)), int(np.floor(v + 0.5))
    assert fv[row, col] == pytest.approx(21.7, abs=1e-4)
    assert (fv > 0).sum() == 1
    # BEV: u_b = X / res + W'/2 - 0.5, v_b = (z_max - Z) / res - 0.5 ; value = Y + h_cam
    ub, vb = -2.0 / 0.5 + 32 - 0.5, (32.0 - 21.7) / 0.5 - 0.5
    np.testing.assert_allclose(r["bev_pix"][0, 0].numpy(), [ub, vb], atol=1e-4)
    bev = r["bev"][0, 0]
    assert bev[int(np.floor(vb + 0.5)), int(np.floor(ub + 0.5))] == pytest.approx(1.0 + CFG.camera_height_m, abs=1e-5)
    assert (bev > 0).sum() == 1
    K_bev = bev_intrinsics(CFG)
    np.testing.assert_allclose((K_bev @ torch.tensor([-2.0, 21.7, 1.0]))[:2].numpy(), [ub, vb], atol=1e-4)


def test_fv_keeps_nearest_and_drops_outside():
    T = torch.eye(4)[None]
    pts = torch.tensor([[[0.0, 0.0, 10.0], [0.0, 0.0, 5.0], [0.0, 0.0, -5.0], [100.0, 0.0, 10.0]]])
    r = render_radar_maps(T, pts, torch.ones(1, 4, dtype=torch.bool), _K(), CFG)
    assert r["fv_valid"][0].tolist() == [True, True, False, False]
    assert r["fv"][0, 0, 32, 64] == pytest.approx(5.0)
    masked = render_radar_maps(T, pts, torch.tensor([[True, False, False, False]]), _K(), CFG)
    assert masked["fv"][0, 0, 32, 64] == pytest.approx(10.0)


def test_pseudo_points_invert_projection():
    g = torch.Generator().manual_seed(0)
    depth = torch.rand(2, 1, H, W, generator=g) * 30 + 1
    K = _K(2)
    pts = depth_to_points(depth, K)
    pix, inside = project_fv(pts, K, (H, W), 0.1)
    v, u = torch.meshgrid(torch.arange(H).float(), torch.arange(W).float(), indexing="ij")
    assert inside.all()
    torch.testing.assert_close(pix[0], torch.stack([u, v], -1).reshape(-1, 2), atol=1e-3, rtol=0)
    torch.testing.assert_close(pts[..., 2], depth.reshape(2, -1))


def test_pseudo_bev_of_flat_ground_lands_on_right_rows():
    h_cam = CFG.camera_height_m
    K = _K()
    v = torch.arange(H, dtype=torch.float32)
    z_row = torch.where(v > 31.5 + 1, 100.0 * h_cam / (v - 31.5), torch.zeros_like(v))  # ground: Y = h_cam
    depth = z_row[None, None, :, None].expand(1, 1, H, W).clone()
    bev = pseudo_bev(depth, K, CFG)[0, 0]
    occupied = bev > 0
    assert occupied.any()
    # every occupied cell has value Y + h = 2 h (the ground is h below the camera)
    torch.testing.assert_close(bev[occupied], torch.full_like(bev[occupied], 2 * h_cam))
    # occupied BEV rows are exactly the rows of the ground depths that fall in the map
    zs = z_row[(z_row > CFG.min_depth_m) & (z_row < CFG.pseudo_bev_max_depth_m)]
    vb = torch.floor((32.0 - zs) / 0.5 - 0.5 + 0.5).long()
    want = sorted({int(r) for r in vb if 0 <= r < 64})
    got = sorted(set(torch.nonzero(occupied)[:, 0].tolist()))
    assert got == want
    # the image centre column (X = 0) lands in the BEV centre columns
    assert occupied[:, 31:33].any(1).sum() == len(want)


def test_cell_index_and_centres():
    pix = torch.tensor([[[0.0, 0.0], [7.4, 7.4], [7.6, 0.0], [127.0, 63.0]]])
    valid = torch.tensor([[True, True, True, False]])
    idx = cell_index(pix, valid, (H, W))
    assert idx[0].tolist() == [0, 0, 1, -1]
    c = cell_centres((H, W))
    assert c.shape == (8 * 16, 2)
    assert c[0].tolist() == [3.5, 3.5] and c[17].tolist() == [11.5, 11.5]


def test_lie_float32_small_angles_are_accurate():
    for scale in (1e-7, 1e-5, 1e-3, 3e-2, 0.3):
        xi = np.array([0.3, -0.5, 0.8, 1.0, -2.0, 0.5]) * scale
        T64 = geometry.se3_exp(xi)
        T32 = torch.tensor(T64, dtype=torch.float32)
        got = lie.se3_log(T32).double().numpy()
        assert np.all(np.isfinite(got))
        np.testing.assert_allclose(got, xi, atol=2e-6 + 1e-5 * np.abs(xi).max())
        R = lie.so3_exp(torch.tensor(xi[:3], dtype=torch.float32)).double().numpy()
        np.testing.assert_allclose(R, T64[:3, :3], atol=2e-7)
