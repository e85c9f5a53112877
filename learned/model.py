"""RC-AutoCalib (CVPR 2025): the whole network, its iterative loop and its loss.

Batch (all float32 unless said; B samples; the model input size H x W must be multiples of 8):

    image:       (B, 3, H, W) RGB in [0, 1]
    depth:       (B, 1, H, W) metres, estimated camera depth (0 = unknown)
    K:           (B, 3, 3) intrinsics of the H x W image
    radar:       (B, N, 3) metres, sensor frame as recorded (LiDAR points for ``variant="lidar"``)
    radar_mask:  (B, N) bool
    T_init:      (B, 4, 4) initial T_cam_radar (T_cam_lidar for the lidar variant)
    training / evaluation only:
    T_gt:        (B, 4, 4)
    lidar_cam:   (B, M, 3) LiDAR points in the camera frame (for the NR matcher), lidar_mask (B, M) bool,
                 optional lidar_fraction (B,) the share of each sweep's in-image points kept (default 1)

Output of ``forward`` (lists have one entry per iteration n = 0..N-1):

    T_iters:   N x (B, 4, 4) estimate after iteration n (final = T_iters[-1])
    T_deltas:  N x (B, 4, 4) correction T_pred^n, with T_iters[n] = T_inputs[n] . T_deltas[n]
    T_inputs:  N x (B, 4, 4) estimate the radar maps of iteration n were rendered with (detached)
    log_var:   N x (B, 6) predicted log-variances of Log(T_iters[n]^-1 T_gt) ([rot rad^2, trans m^2])
    match:     N x {"fv": MatchingHead dict, "bev": ...} (views present and use_ems only)
    attention: N x {"fv": {"attn_I_from_R", "attn_R_from_I"}, ...} (use_mca only)
    render:    N x {"fv_pix" (B, N, 2), "fv_valid" (B, N), "bev_pix", "bev_valid", "fv" map, "bev" map}
    fusion_weights: N x (B, 2, D) selective-fusion weights (or None)
    fused:     N x (B, D') the fused global descriptor the regression head reads (``learned.ood``)
    image_hw:  (H, W); pseudo_bev: (B, 1, H', W') metres
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import torch
from torch import nn

from learned import transform
from learned.attention import MultiModalCrossAttention
from learned.backbone import ImageFVEncoder, ResNetStem3, TwoConvBranch, load_resnet18_weights
from learned.config import ModelConfig, model_config
from learned.fusion import make_fusion
from learned.losses import calib_loss, matching_loss, variance_nll
from learned.matching import MatchingHead, ResidualConvBlock
from learned.nr_matcher import match_ground_truth, nr_reliable
from learned.regression import LSTMRegressionHead

REQUIRED = ("image", "depth", "K", "radar", "radar_mask", "T_init")


class RadarEncoder(nn.Module):
    """Radar map (B, 1, h, w) -> (B, C, h/8, w/8): first three ResNet blocks from scratch (+1x1 to C)."""

    def __init__(self, widths: tuple, feat_dim: int):
        super().__init__()
        self.resnet = ResNetStem3(1, widths)
        self.proj = nn.Identity() if widths[-1] == feat_dim else nn.Conv2d(widths[-1], feat_dim, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(self.resnet(x))


class ViewBranch(nn.Module):
    """One perspective's matching block: MCA, matching head, Residual Conv Block Phi."""

    def __init__(self, cfg: ModelConfig, pool_hw: tuple):
        super().__init__()
        c = cfg.feat_dim
        self.mca = MultiModalCrossAttention(c, cfg.mca_heads, cfg.mca_scale) if cfg.use_mca else None
        self.match = MatchingHead(c, cfg.match_dim) if cfg.use_ems else None
        self.phi = ResidualConvBlock(c, cfg.phi_channels, pool_hw, cfg.view_dim)

    def forward(self, F_I: torch.Tensor, F_R: torch.Tensor):
        maps = None
        if self.mca is not None:
            F_I, F_R, maps = self.mca(F_I, F_R)
        match = self.match(F_I, F_R) if self.match is not None else None
        return self.phi(F_I, F_R), match, maps


class RCAutoCalib(nn.Module):
    """The RC-AutoCalib network. ``RCAutoCalib("small", {"fusion": "add"})`` or ``RCAutoCalib(ModelConfig())``."""

    def __init__(self, config: str | ModelConfig | Mapping = "small", overrides: Mapping | None = None):
        super().__init__()
        cfg = model_config(config, overrides)
        self.cfg = cfg
        c = cfg.feat_dim
        self.use_fv = cfg.views in ("both", "fv")
        self.use_bev = cfg.views in ("both", "bev")
        if self.use_fv:
            self.image_fv = ImageFVEncoder(c, cfg.context_widths, cfg.depth_branch_mid)
            self.radar_fv = RadarEncoder(cfg.radar_widths, c)
            self.view_fv = ViewBranch(cfg, cfg.phi_pool_fv)
        if self.use_bev:
            self.image_bev = TwoConvBranch(c, cfg.depth_branch_mid)
            self.radar_bev = RadarEncoder(cfg.radar_widths, c)
            self.view_bev = ViewBranch(cfg, cfg.phi_pool_bev)
        self.fusion = make_fusion(cfg.fusion, cfg.views, cfg.view_dim, cfg.sk_reduction, cfg.sk_min_dim)
        self.head = LSTMRegressionHead(self.fusion.out_dim, cfg.lstm_hidden)

    # ------------------------------------------------------------------------------------------
    def load_context_weights(self, path: str | Path) -> list[str]:
        """Load ImageNet ResNet-18 weights (local file) into the image context network."""
        if not self.use_fv:
            raise ValueError("this model has no FV image context network (views='bev')")
        return load_resnet18_weights(self.image_fv.context, path)

    @staticmethod
    def check_batch(batch: Mapping) -> tuple[int, int]:
        missing = [k for k in REQUIRED if k not in batch]
        if missing:
            raise KeyError(f"batch is missing {missing}; required keys: {list(REQUIRED)}")
        B, ch, H, W = batch["image"].shape
        want = {"image": (B, 3, H, W), "depth": (B, 1, H, W), "K": (B, 3, 3), "T_init": (B, 4, 4)}
        for key, shape in want.items():
            if tuple(batch[key].shape) != shape:
                raise ValueError(f"batch[{key!r}] has shape {tuple(batch[key].shape)}, expected {shape}")
        pts, m = batch["radar"], batch["radar_mask"]
        if pts.ndim != 3 or pts.shape[0] != B or pts.shape[2] != 3 or tuple(m.shape) != tuple(pts.shape[:2]):
            raise ValueError(f"batch['radar'] {tuple(pts.shape)} / radar_mask {tuple(m.shape)}: "
                             "expected (B, N, 3) / (B, N)")
        if H % 8 or W % 8:
            raise ValueError(f"image size {H}x{W} must be multiples of 8 (features are at 1/8)")
        return H, W

    def forward(self, batch: Mapping, iterations: int | None = None) -> dict:
        cfg = self.cfg
        H, W = self.check_batch(batch)
        image, depth, K = batch["image"], batch["depth"], batch["K"]
        points, mask = batch["radar"], batch["radar_mask"].bool()
        F_I_fv = self.image_fv(image, depth / cfg.depth_norm_m) if self.use_fv else None
        pbev = transform.pseudo_bev(depth, K, cfg) if self.use_bev else None
        F_I_bev = self.image_bev(pbev / cfg.height_norm_m) if self.use_bev else None

        T = batch["T_init"]
        state = None
        out = {k: [] for k in ("T_iters", "T_deltas", "T_inputs", "log_var", "match", "attention", "render",
                               "fusion_weights", "fused")}
        for _ in range(iterations or cfg.iterations):
            T_in = T.detach()
            r = transform.render_radar_maps(T_in, points, mask, K, cfg, (H, W))
            f_fv = f_bev = None
            match, attn = {}, {}
            if self.use_fv:
                F_R = self.radar_fv(r["fv"] / cfg.depth_norm_m)
                f_fv, match["fv"], attn["fv"] = self.view_fv(F_I_fv, F_R)
            if self.use_bev:
                F_R = self.radar_bev(r["bev"] / cfg.height_norm_m)
                f_bev, match["bev"], attn["bev"] = self.view_bev(F_I_bev, F_R)
            fused, weights = self.fusion(f_fv, f_bev)
            reg, state = self.head(fused, state)
            T = T_in @ reg["T_delta"]
            out["T_iters"].append(T)
            out["T_deltas"].append(reg["T_delta"])
            out["T_inputs"].append(T_in)
            out["log_var"].append(reg["log_var"])
            out["match"].append({k: v for k, v in match.items() if v is not None})
            out["attention"].append({k: v for k, v in attn.items() if v is not None})
            out["render"].append({k: r[k] for k in ("fv", "bev", "fv_pix", "fv_valid", "bev_pix", "bev_valid")})
            out["fusion_weights"].append(weights)
            out["fused"].append(fused.detach())
        out["image_hw"] = (H, W)
        out["pseudo_bev"] = pbev
        return out

    # ------------------------------------------------------------------------------------------
    def match_targets(self, out: dict, batch: Mapping) -> list[dict]:
        """Ground-truth (M, N_I, N_R) per iteration and view; FV uses the NR matcher when active."""
        cfg = self.cfg
        points, mask = batch["radar"], batch["radar_mask"].bool()
        keep = None
        if cfg.nr_active and self.use_fv:
            if "lidar_cam" not in batch or "lidar_mask" not in batch:
                raise KeyError("the noise-resistant matcher needs batch['lidar_cam'] and batch['lidar_mask'] "
                               "(LiDAR points in the camera frame); provide them or set use_nr=False")
            T_gt = batch["T_gt"]
            p_gt = transform.lie.transform_points(T_gt, points)
            keep, _ = nr_reliable(p_gt, mask, T_gt[:, :3, 3], batch["lidar_cam"], batch["lidar_mask"].bool(),
                                  cfg.nr_tau, cfg.nr_delta_m, cfg.nr_delta_s_m, cfg.nr_chunk,
                                  lidar_fraction=batch.get("lidar_fraction"))
        targets = []
        for n, T_in in enumerate(out["T_inputs"]):
            t = {}
            for view in out["match"][n]:
                t[view] = match_ground_truth(points, mask, T_in, batch["T_gt"], batch["K"], cfg, view,
                                             keep if view == "fv" else None, hw=out["image_hw"])
            targets.append(t)
        return targets

    def loss(self, out: dict, batch: Mapping) -> dict[str, torch.Tensor]:
        """dict of scalars: total = calib + beta * matching + unc_weight * uncertainty."""
        cfg = self.cfg
        if "T_gt" not in batch:
            raise KeyError("loss needs batch['T_gt']")
        calib = calib_loss(out["T_iters"], batch["T_gt"], batch["radar"], batch["radar_mask"].bool(),
                           cfg.iter_gamma, cfg.calib_rot_weight, cfg.calib_trans_weight, cfg.calib_point_weight)
        matching = calib.new_zeros(())
        if cfg.use_ems:
            with torch.no_grad():
                targets = self.match_targets(out, batch)
            for n, per_view in enumerate(targets):
                for view, (M, N_I, N_R) in per_view.items():
                    matching = matching + matching_loss(out["match"][n][view], M, N_I, N_R, cfg.lam)
        unc = variance_nll(out["log_var"], out["T_iters"], batch["T_gt"])
        total = calib + cfg.beta * matching + cfg.unc_weight * unc
        return dict(total=total, calib=calib, matching=matching, uncertainty=unc)
