"""Data transform of RC-AutoCalib (paper Sec. 3.1): front-view and bird's-eye-view maps, batched in torch.

Frames and units (docs/conventions.md): camera x right, y down, z forward; metres; pixels (u = column,
v = row) with pixel centres at integers, so a continuous pixel ``u`` is rasterised to column
``floor(u + 0.5)``.

- FV radar map ``I_R^FV``: (B, 1, H, W), pixel value Z (metres) of the nearest point in the pixel,
  0 = empty; pixel = K [X/Z, Y/Z, 1].
- BEV map via K' (paper eq. 2): ``[u_b, v_b, 1] = K' [X, Z, 1]`` with row 0 the far edge:
  ``u_b = X / res + (W'/2 - 0.5)``, ``v_b = -Z / res + (z_max / res - 0.5)``. Value = ``Y + h_cam``
  (paper: camera height offset), mean over the points of the cell, clamped to >= 1 mm so an occupied
  cell never reads as empty (0).
- Pseudo point cloud (paper eq. 3): ``P = depth(u, v) K^-1 [u, v, 1]``; pseudo-BEV = the same BEV
  rendering of those points. Differentiable with respect to the depth values.
"""

from __future__ import annotations

import torch

from learned import lie
from learned.config import ModelConfig

STRIDE = 8  # feature maps are at 1/8 of their input map (paper: H/8 x W/8)
MIN_BEV_VALUE = 1e-3  # metres; an occupied BEV cell is at least this


def bev_intrinsics(cfg: ModelConfig, dtype=torch.float32, device=None) -> torch.Tensor:
    """K' (3, 3): maps ``[X, Z, 1]`` (camera frame, metres) to BEV pixel ``[u_b, v_b, 1]``."""
    hb, wb = cfg.bev_hw
    res = cfg.bev_res_m
    return torch.tensor([[1.0 / res, 0.0, wb / 2.0 - 0.5],
                         [0.0, -1.0 / res, cfg.bev_z_max_m / res - 0.5],
                         [0.0, 0.0, 1.0]], dtype=dtype, device=device)


def project_fv(points_cam: torch.Tensor, K: torch.Tensor, hw: tuple, min_depth: float
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Pinhole projection.

    points_cam: (B, N, 3) metres, camera frame. K: (B, 3, 3). hw: (H, W).
    Returns pixels (B, N, 2) float (u, v) and in_image (B, N) bool (Z > min_depth and the rasterised
    pixel inside the image).
    """
    z = points_cam[..., 2]
    zs = z.clamp_min(1e-6)[..., None]
    uvw = points_cam @ K.transpose(-1, -2)
    pix = uvw[..., :2] / zs
    col, row = torch.floor(pix[..., 0] + 0.5), torch.floor(pix[..., 1] + 0.5)
    inside = (z > min_depth) & (col >= 0) & (col < hw[1]) & (row >= 0) & (row < hw[0])
    return pix, inside


def project_bev(points_cam: torch.Tensor, K_bev: torch.Tensor, bev_hw: tuple
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """BEV projection (paper eq. 2, right). points_cam: (B, N, 3). K_bev: (3, 3).

    Returns BEV pixels (B, N, 2) float (u_b, v_b) and in_map (B, N) bool.
    """
    xz1 = torch.stack([points_cam[..., 0], points_cam[..., 2], torch.ones_like(points_cam[..., 0])], -1)
    pix = (xz1 @ K_bev.T)[..., :2]
    col, row = torch.floor(pix[..., 0] + 0.5), torch.floor(pix[..., 1] + 0.5)
    inside = (col >= 0) & (col < bev_hw[1]) & (row >= 0) & (row < bev_hw[0])
    return pix, inside


def _flat_index(pix: torch.Tensor, width: int) -> torch.Tensor:
    col = torch.floor(pix[..., 0] + 0.5).long()
    row = torch.floor(pix[..., 1] + 0.5).long()
    return row * width + col


def splat_min(pix: torch.Tensor, values: torch.Tensor, valid: torch.Tensor, hw: tuple) -> torch.Tensor:
    """Rasterise: per pixel the minimum value of the valid points in it, 0 where none. -> (B, 1, H, W)."""
    B = pix.shape[0]
    n_pix = hw[0] * hw[1]
    idx = torch.where(valid, _flat_index(pix, hw[1]), torch.full_like(valid, n_pix, dtype=torch.long))
    big = torch.finfo(values.dtype).max
    out = torch.full((B, n_pix + 1), big, dtype=values.dtype, device=values.device)
    out = out.scatter_reduce(1, idx, torch.where(valid, values, torch.full_like(values, big)), "amin")
    out = torch.where(out == big, torch.zeros_like(out), out)
    return out[:, :n_pix].reshape(B, 1, *hw)


def splat_mean(pix: torch.Tensor, values: torch.Tensor, valid: torch.Tensor, hw: tuple) -> torch.Tensor:
    """Rasterise: per pixel the mean value of the valid points in it, 0 where none. -> (B, 1, H, W)."""
    B = pix.shape[0]
    n_pix = hw[0] * hw[1]
    idx = torch.where(valid, _flat_index(pix, hw[1]), torch.full_like(valid, n_pix, dtype=torch.long))
    w = valid.to(values.dtype)
    s = torch.zeros(B, n_pix + 1, dtype=values.dtype, device=values.device).scatter_add(1, idx, values * w)
    c = torch.zeros(B, n_pix + 1, dtype=values.dtype, device=values.device).scatter_add(1, idx, w)
    out = torch.where(c > 0, s / c.clamp_min(1.0), torch.zeros_like(s))
    return out[:, :n_pix].reshape(B, 1, *hw)


def bev_value(points_cam: torch.Tensor, camera_height: float) -> torch.Tensor:
    """BEV pixel value ``Y + h_cam`` (metres), clamped to >= MIN_BEV_VALUE. (B, N) -> (B, N)."""
    return (points_cam[..., 1] + camera_height).clamp_min(MIN_BEV_VALUE)


def render_radar_maps(T: torch.Tensor, points: torch.Tensor, mask: torch.Tensor, K: torch.Tensor,
                      cfg: ModelConfig, hw: tuple | None = None) -> dict[str, torch.Tensor]:
    """Mis-calibrated radar FV depth map and BEV map for the current extrinsic estimate.

    T: (B, 4, 4) T_cam_radar estimate. points: (B, N, 3) metres, radar frame. mask: (B, N) bool.
    K: (B, 3, 3) at the FV size ``hw`` (default ``cfg.input_hw``).
    Returns dict: ``fv`` (B, 1, H, W) Z metres (0 empty), ``bev`` (B, 1, H', W') Y + h metres (0 empty),
    ``points_cam`` (B, N, 3), ``fv_pix`` (B, N, 2), ``fv_valid`` (B, N), ``bev_pix`` (B, N, 2),
    ``bev_valid`` (B, N).
    """
    hw = tuple(hw or cfg.input_hw)
    pc = lie.transform_points(T, points)
    fv_pix, fv_in = project_fv(pc, K, hw, cfg.min_depth_m)
    fv_valid = fv_in & mask
    K_bev = bev_intrinsics(cfg, pc.dtype, pc.device)
    bev_pix, bev_in = project_bev(pc, K_bev, cfg.bev_hw)
    bev_valid = bev_in & mask
    return dict(
        fv=splat_min(fv_pix, pc[..., 2], fv_valid, hw),
        bev=splat_mean(bev_pix, bev_value(pc, cfg.camera_height_m), bev_valid, cfg.bev_hw),
        points_cam=pc, fv_pix=fv_pix, fv_valid=fv_valid, bev_pix=bev_pix, bev_valid=bev_valid,
    )


def depth_to_points(depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Pseudo point cloud (paper eq. 3). depth: (B, 1, H, W) metres (0 = unknown); K: (B, 3, 3).

    Returns (B, H*W, 3) metres in the camera frame (rows of unknown depth are at the origin).
    """
    B, _, H, W = depth.shape
    v, u = torch.meshgrid(torch.arange(H, dtype=depth.dtype, device=depth.device),
                          torch.arange(W, dtype=depth.dtype, device=depth.device), indexing="ij")
    rays = torch.stack([u, v, torch.ones_like(u)], -1).reshape(1, H * W, 3)
    rays = rays @ torch.linalg.inv(K).transpose(-1, -2)  # (B, HW, 3), z = 1
    return rays * depth.reshape(B, H * W, 1)


def pseudo_bev(depth: torch.Tensor, K: torch.Tensor, cfg: ModelConfig) -> torch.Tensor:
    """Camera pseudo-BEV image ``I_I^BEV`` (B, 1, H', W'), value Y + h metres, 0 = empty."""
    pts = depth_to_points(depth, K)
    z = pts[..., 2]
    valid = (z > cfg.min_depth_m) & (z < cfg.pseudo_bev_max_depth_m)
    pix, inside = project_bev(pts, bev_intrinsics(cfg, pts.dtype, pts.device), cfg.bev_hw)
    return splat_mean(pix, bev_value(pts, cfg.camera_height_m), valid & inside, cfg.bev_hw)


def cell_index(pix: torch.Tensor, valid: torch.Tensor, hw: tuple, stride: int = STRIDE) -> torch.Tensor:
    """Flat index of the 1/stride feature cell holding each (rasterised) pixel; -1 where not valid.

    pix: (B, N, 2) pixels of a map of size hw; valid: (B, N). Returns (B, N) long in [0, (H/s)(W/s)).
    """
    col = torch.floor(pix[..., 0] + 0.5).long().clamp(0, hw[1] - 1) // stride
    row = torch.floor(pix[..., 1] + 0.5).long().clamp(0, hw[0] - 1) // stride
    idx = row * (hw[1] // stride) + col
    return torch.where(valid, idx, torch.full_like(idx, -1))


def cell_centres(hw: tuple, stride: int = STRIDE, dtype=torch.float32, device=None) -> torch.Tensor:
    """Pixel coordinates (u, v) of the centres of the 1/stride cells of a map, (m, 2), row-major."""
    h, w = hw[0] // stride, hw[1] // stride
    r, c = torch.meshgrid(torch.arange(h, dtype=dtype, device=device), torch.arange(w, dtype=dtype, device=device),
                          indexing="ij")
    off = (stride - 1) / 2.0
    return torch.stack([c * stride + off, r * stride + off], -1).reshape(-1, 2)
