"""Ground-truth match matrices and the Noise-Resistant matcher (paper Sec. 3.3, eqs. 12-14, supplement C).

Ground truth ``M`` (B, m_I, m_R) in {0, 1}: a radar point p links the radar-map cell j where the
*current* estimate T_init puts it (that is where its feature lives) to the image-map cell i where the
*true* T_gt puts it (where the image shows it). ``M`` is made one-to-one (each radar cell keeps its most
supported image cell, then each image cell its most supported radar cell), so that
``N_I = 1 - sum_j M`` and ``N_R = 1 - sum_i M`` (paper eq. 19) are in {0, 1}.

Noise-resistant matcher (FV only, radar only): with the radar point in the camera frame by T_gt,
``d = P_r^c - o`` its offset from the radar origin ``o = t_gt`` (camera frame), the range
``R = |(d_x, d_z)|`` and azimuth ``theta = atan2(d_x, d_z)``:

    cos(phi) = sqrt(1 - (delta / R)^2)                     (clamped to 0 when R <= delta)
    dx = R sin(theta) (1 - cos phi) = d_x (1 - cos phi),   dz = R cos(theta) (1 - cos phi) = d_z (1 - cos phi)
    h_B = 2 (delta + Delta_s),  w_B = |dx| + 2 Delta_s,  d_B = |dz| + 2 Delta_s
    centre = (X - dx / 2, Y, Z - dz / 2)

(the paper writes w_B = dx + 2 Delta_s; we take |dx| so boxes left of the radar have a positive width,
and keep the signed shift so the centre moves toward the radar, where a raised reflector at the same
range lies). A radar point is reliable when at least ``tau`` LiDAR points (camera frame) fall inside its
axis-aligned box; unreliable points are removed from ``M``. The paper's ``tau`` counts the points of the
whole sweep: where a sample keeps a random fraction ``f`` of the sweep's in-image points (training's
``max_lidar_points``), a box needs ``tau * f`` of the kept ones (the same expected density), so subsampling
does not tighten the matcher.
"""

from __future__ import annotations

import torch

from learned import lie
from learned.transform import bev_intrinsics, cell_index, project_bev, project_fv


def nr_boxes(points_cam: torch.Tensor, radar_origin_cam: torch.Tensor, delta: float, delta_s: float
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Boxes B of the NR matcher.

    points_cam: (B, N, 3) radar points in the camera frame (metres, by T_gt). radar_origin_cam: (B, 3).
    Returns centre (B, N, 3) and size (B, N, 3) = (w_B, h_B, d_B) along camera (X, Y, Z), metres.
    """
    d = points_cam - radar_origin_cam[:, None, :]
    R = torch.sqrt(d[..., 0] ** 2 + d[..., 2] ** 2)
    cos_phi = torch.sqrt((1 - (delta / R.clamp_min(1e-6)) ** 2).clamp_min(0.0))
    dx = d[..., 0] * (1 - cos_phi)
    dz = d[..., 2] * (1 - cos_phi)
    centre = torch.stack([points_cam[..., 0] - dx / 2, points_cam[..., 1], points_cam[..., 2] - dz / 2], -1)
    size = torch.stack([dx.abs() + 2 * delta_s, torch.full_like(dx, 2 * (delta + delta_s)), dz.abs() + 2 * delta_s], -1)
    return centre, size


@torch.no_grad()
def nr_reliable(points_cam: torch.Tensor, radar_mask: torch.Tensor, radar_origin_cam: torch.Tensor,
                lidar_cam: torch.Tensor, lidar_mask: torch.Tensor, tau: int = 3, delta: float = 1.0,
                delta_s: float = 0.5, chunk: int = 256, lidar_fraction: torch.Tensor | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Which radar points the NR matcher keeps.

    points_cam: (B, N, 3) radar points in the camera frame by T_gt; radar_mask: (B, N) bool;
    radar_origin_cam: (B, 3); lidar_cam: (B, M, 3) LiDAR points, camera frame; lidar_mask: (B, M) bool;
    lidar_fraction: optional (B,) fraction in (0, 1] of the sweep's points ``lidar_cam`` keeps (default 1).
    Returns keep (B, N) bool (valid and >= tau x lidar_fraction LiDAR points in the box) and counts (B, N) long.
    """
    centre, size = nr_boxes(points_cam, radar_origin_cam, delta, delta_s)
    half = size / 2
    counts = torch.zeros(points_cam.shape[:2], dtype=torch.long, device=points_cam.device)
    for s in range(0, points_cam.shape[1], chunk):
        c, h = centre[:, s:s + chunk, None, :], half[:, s:s + chunk, None, :]
        inside = ((lidar_cam[:, None, :, :] - c).abs() <= h).all(-1) & lidar_mask[:, None, :]
        counts[:, s:s + chunk] = inside.sum(-1)
    if lidar_fraction is None:
        return radar_mask & (counts >= tau), counts
    f = torch.as_tensor(lidar_fraction, dtype=torch.float64, device=counts.device).reshape(-1, 1).clamp(1e-9, 1.0)
    return radar_mask & (counts.double() >= tau * f), counts


def match_matrix(cell_I: torch.Tensor, cell_R: torch.Tensor, m_I: int, m_R: int
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """One-to-one ground-truth matches from per-point cell pairs.

    cell_I, cell_R: (B, N) long flat cell indices, -1 where the point gives no pair.
    Returns M (B, m_I, m_R) float {0, 1}, N_I (B, m_I), N_R (B, m_R) (paper eq. 19).
    """
    B = cell_I.shape[0]
    ok = (cell_I >= 0) & (cell_R >= 0)
    flat = torch.where(ok, cell_I * m_R + cell_R, torch.zeros_like(cell_I))
    counts = torch.zeros(B, m_I * m_R, device=cell_I.device).scatter_add(1, flat, ok.float()).view(B, m_I, m_R)
    # each radar cell j keeps its most supported image cell
    best_i = counts.argmax(1, keepdim=True)
    keep = torch.zeros_like(counts).scatter(1, best_i, 1.0) * (counts > 0)
    # then each image cell i keeps its most supported radar cell
    c2 = counts * keep
    best_j = c2.argmax(2, keepdim=True)
    M = torch.zeros_like(counts).scatter(2, best_j, 1.0) * (c2 > 0)
    return M, 1 - M.sum(2), 1 - M.sum(1)


def match_ground_truth(points: torch.Tensor, mask: torch.Tensor, T_cur: torch.Tensor, T_gt: torch.Tensor,
                       K: torch.Tensor, cfg, view: str, keep: torch.Tensor | None = None, stride: int = 8,
                       hw: tuple | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``M``, ``N_I``, ``N_R`` of one view ("fv" or "bev") for one iteration.

    points: (B, N, 3) radar frame; mask: (B, N); T_cur: (B, 4, 4) the estimate the radar map was rendered
    with; T_gt: (B, 4, 4); K: (B, 3, 3) at the FV size ``hw`` (default ``cfg.input_hw``); keep: optional
    (B, N) NR-matcher mask (applied as given).
    """
    p_cur = lie.transform_points(T_cur, points)
    p_gt = lie.transform_points(T_gt, points)
    if view == "fv":
        hw = tuple(hw or cfg.input_hw)
        pix_R, in_R = project_fv(p_cur, K, hw, cfg.min_depth_m)
        pix_I, in_I = project_fv(p_gt, K, hw, cfg.min_depth_m)
    elif view == "bev":
        hw = cfg.bev_hw
        K_bev = bev_intrinsics(cfg, points.dtype, points.device)
        pix_R, in_R = project_bev(p_cur, K_bev, hw)
        pix_I, in_I = project_bev(p_gt, K_bev, hw)
    else:
        raise ValueError(f"view must be 'fv' or 'bev', got {view!r}")
    valid = mask if keep is None else mask & keep
    cell_R = cell_index(pix_R, in_R & valid, hw, stride)
    cell_I = cell_index(pix_I, in_I & valid, hw, stride)
    m_I = m_R = (hw[0] // stride) * (hw[1] // stride)
    return match_matrix(cell_I, cell_R, m_I, m_R)
