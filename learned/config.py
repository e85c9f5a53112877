"""Configuration of the RC-AutoCalib network (frozen dataclasses, presets ``small`` and ``paper``).

Values the paper fixes are marked "paper"; every value the paper leaves open carries the reason for
the choice. Build one with ``model_config("small", {"feat_dim": 32})`` or
``hybrid_calib.config.merge(ModelConfig, overrides)``; unknown keys raise.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hybrid_calib.config import ConfigError, merge, require_ranges

FUSIONS = ("selective", "add", "concat")
VIEWS = ("both", "fv", "bev")
VARIANTS = ("radar", "lidar")
UNCERTAINTIES = ("learned", "spread")


@dataclass(frozen=True)
class ModelConfig:
    # --- input / data transform -------------------------------------------------------------
    variant: str = "radar"  # "radar" (paper) or "lidar" (supplement's LiDAR-camera variant: no NR matcher)
    input_hw: tuple = (192, 400)  # (H, W) model input, paper: 1600x900 resized to 400x192
    depth_norm_m: float = 50.0  # FV depth values are divided by this (keeps inputs O(1); nuScenes radar mostly < 100 m)
    min_depth_m: float = 0.5  # points closer than this to the camera plane are not rendered (behind / degenerate)
    camera_height_m: float = 1.5  # BEV value offset "camera height" (paper); nuScenes CAM_FRONT is ~1.5 m up
    height_norm_m: float = 3.0  # BEV height values are divided by this (Y + h is ~0..4 m for road scenes)
    bev_hw: tuple = (256, 256)  # (H', W') BEV map: not given in the paper; 1024 BEV tokens at H'/8 like the FV's 1200
    bev_res_m: float = 0.3125  # metres per BEV pixel -> Z in [0, 80] m, X in [-40, 40] m: covers the FV frustum to 80 m
    bev_z_min_m: float = 0.0  # nearest Z of the BEV map (camera plane)
    pseudo_bev_max_depth_m: float = 80.0  # estimated depth beyond this is unreliable and is not splatted to BEV
    # --- feature extraction -----------------------------------------------------------------
    feat_dim: int = 128  # C of F_R, F_I (not given by the paper; ResNet-18's layer2 width, so ImageNet weights load)
    radar_widths: tuple = (64, 64, 128)  # radar ResNet stem/layer1/layer2 widths (ResNet-18's, trained from scratch)
    context_widths: tuple = (64, 64, 128)  # image ResNet-18 stem/layer1/layer2 widths (pretrained loads only at these)
    depth_branch_mid: int = 64  # channels after the first of the two depth/pseudo-BEV convolutions
    # --- multi-modal cross-attention --------------------------------------------------------
    use_mca: bool = True  # ablation "no MCA": F_hat = F
    mca_heads: int = 1  # paper's equations are single-head; LightGlue uses 4
    mca_scale: bool = True  # divide a_IR by sqrt(d): standard dot-product scaling, keeps the softmaxes unsaturated
    # --- residual conv block Phi ------------------------------------------------------------
    phi_channels: int = 64  # channels of the Residual Conv Block convolutions (not given; half of 2C keeps it light)
    phi_pool_fv: tuple = (6, 12)  # Phi flattens after an adaptive pool to this grid, so any input size works
    phi_pool_bev: tuple = (8, 8)  # same for BEV (square map)
    view_dim: int = 512  # MLP output of Phi per view (CalibDepth-like 512-d global descriptor)
    # --- explicit matching supervision ------------------------------------------------------
    use_ems: bool = True  # ablation "no EMS": no matching head, no matching loss
    match_dim: int = 128  # output of the Linear() projections in S = Linear(f_I)^T Linear(f_R)
    # --- noise-resistant matcher (paper values) ---------------------------------------------
    use_nr: bool = True  # ablation "no NR"; forced off in the lidar variant
    nr_tau: int = 3  # paper tau: a radar point is reliable with >= tau LiDAR points in its box B
    nr_delta_s_m: float = 0.5  # paper Delta s: cross-sensor error added to every box side
    nr_delta_m: float = 1.0  # paper delta: allowable height error to the radar plane
    nr_chunk: int = 256  # radar points per chunk of the (chunk x M) LiDAR box test (memory bound)
    # --- fusion ------------------------------------------------------------------------------
    views: str = "both"  # "both", or ablations "fv" / "bev" (single perspective)
    fusion: str = "selective"  # "selective" (paper, SKNet-style), ablations "add" / "concat"
    sk_reduction: int = 4  # SKNet compact feature z has view_dim / sk_reduction channels (SKNet default r=16 on 64+)
    sk_min_dim: int = 32  # lower bound of that size (SKNet's L)
    # --- regression head ---------------------------------------------------------------------
    iterations: int = 3  # paper N = 3
    lstm_hidden: int = 256  # hidden size of the one-layer LSTM cell (CalibDepth's decoder: 2 layers, dropout 0.5)
    uncertainty: str = "learned"  # per-frame SE(3) covariance: "learned" log-variance head, or iteration "spread"
    # --- losses (paper values where marked) --------------------------------------------------
    beta: float = 0.1  # paper: L_total = L_calib + beta L_matching
    lam: float = 0.75  # paper lambda: positive/negative balance of L_M
    iter_gamma: float = 0.8  # weight gamma^(N-n) of iteration n in L_calib (RAFT-style sequence loss; not CalibDepth's)
    calib_rot_weight: float = 1.0  # weight of the rotation term (radians, sin-vector of the residual)
    calib_trans_weight: float = 1.0  # weight of the translation term (metres, smooth-L1)
    calib_point_weight: float = 0.5  # weight of the point-cloud distance term (metres; LCCNet/CalibDepth)
    unc_weight: float = 0.01  # weight of the Gaussian NLL of the learned log-variance head (gradient stops at T)

    def __post_init__(self):
        checks = {
            "variant": (self.variant, VARIANTS), "fusion": (self.fusion, FUSIONS), "views": (self.views, VIEWS),
            "uncertainty": (self.uncertainty, UNCERTAINTIES),
        }
        for name, (value, allowed) in checks.items():
            if value not in allowed:
                raise ConfigError(f"ModelConfig.{name}={value!r}; valid: {allowed}")
        for name in ("input_hw", "bev_hw"):
            hw = getattr(self, name)
            if len(hw) != 2 or any(int(v) % 8 or int(v) <= 0 for v in hw):
                raise ConfigError(f"ModelConfig.{name}={hw}: need two positive multiples of 8 (features are at 1/8)")
        for name in ("radar_widths", "context_widths"):
            if len(getattr(self, name)) != 3:
                raise ConfigError(f"ModelConfig.{name}={getattr(self, name)!r}: need three widths (ResNet stem, "
                                  "layer1, layer2), e.g. [64, 64, 128]")
        if self.radar_widths[-1] <= 0 or self.iterations < 1:
            raise ConfigError("ModelConfig: widths and iterations must be positive")
        sizes = {name: getattr(self, name) for name in (
            "feat_dim", "radar_widths", "context_widths", "depth_branch_mid", "phi_channels", "phi_pool_fv",
            "phi_pool_bev", "view_dim", "match_dim", "sk_reduction", "sk_min_dim", "lstm_hidden", "nr_chunk")}
        for name, value in sizes.items():  # a layer width / pool size <= 0 fails deep inside torch otherwise
            if any(int(v) < 1 for v in (value if isinstance(value, (tuple, list)) else (value,))):
                raise ConfigError(f"ModelConfig.{name}={value!r}: layer sizes must be >= 1")
        for name in ("depth_norm_m", "height_norm_m", "bev_res_m", "pseudo_bev_max_depth_m"):  # divisors, ranges
            if not 0 < getattr(self, name) < float("inf"):
                raise ConfigError(f"ModelConfig.{name}={getattr(self, name)!r}: must be a finite number > 0")
        if self.mca_heads < 1 or self.feat_dim % self.mca_heads:
            raise ConfigError(f"ModelConfig.mca_heads={self.mca_heads} must divide feat_dim={self.feat_dim}")
        require_ranges(self, {
            # 8 px: one feature cell, which the network's normalisation cannot train on (probe 27)
            "input_hw": "[16, 10000]", "depth_norm_m": "[0.1, 1000]", "min_depth_m": "[0, 100]",
            "camera_height_m": "[0, 100]", "height_norm_m": "[0.1, 100]", "bev_hw": "[16, 10000]",
            "bev_res_m": "[0.001, 10]", "bev_z_min_m": "[0, 1000]", "pseudo_bev_max_depth_m": "(0, 1000]",
            "feat_dim": "[1, 4096]", "radar_widths": "[1, 4096]", "context_widths": "[1, 4096]",
            "depth_branch_mid": "[1, 4096]", "mca_heads": "[1, 4096]", "phi_channels": "[1, 4096]",
            "phi_pool_fv": "[1, 1000]", "phi_pool_bev": "[1, 1000]", "view_dim": "[1, 4096]", "match_dim": "[1, 4096]",
            "nr_tau": "[1, 1e6]", "nr_delta_s_m": "[0, 10]", "nr_delta_m": "[0, 10]", "nr_chunk": "[1, 1e6]",
            "sk_reduction": "[1, 4096]", "sk_min_dim": "[1, 4096]", "iterations": "[1, 100]",
            "lstm_hidden": "[1, 4096]", "beta": "[0, 1000]", "lam": "[0, 1]", "iter_gamma": "[0, 1]",
            "calib_rot_weight": "[0, 1000]", "calib_trans_weight": "[0, 1000]", "calib_point_weight": "[0, 1000]",
            "unc_weight": "[0, 1000]"})

    @property
    def nr_active(self) -> bool:
        """The NR matcher runs only for radar (the supplement's LiDAR variant has none)."""
        return self.use_nr and self.variant == "radar"

    @property
    def bev_x_half_m(self) -> float:
        """Half width of the BEV map in metres (X in [-x_half, x_half])."""
        return self.bev_hw[1] * self.bev_res_m / 2.0

    @property
    def bev_z_max_m(self) -> float:
        return self.bev_z_min_m + self.bev_hw[0] * self.bev_res_m


PRESETS: dict[str, dict[str, Any]] = {
    "paper": {},
    # Trains on 2 CPU cores: quarter-area input, half widths, 256 BEV tokens at 0.625 m.
    "small": dict(
        input_hw=(96, 200), bev_hw=(128, 128), bev_res_m=0.625, feat_dim=64, radar_widths=(32, 32, 64),
        context_widths=(32, 32, 64), depth_branch_mid=32, phi_channels=32, phi_pool_fv=(3, 6), phi_pool_bev=(4, 4),
        view_dim=256, match_dim=64, lstm_hidden=128,
    ),
}


def model_config(preset: str | ModelConfig | Mapping = "small", overrides: Mapping[str, Any] | None = None
                 ) -> ModelConfig:
    """A ``ModelConfig`` from a preset name (or a config / mapping) plus overrides."""
    if isinstance(preset, ModelConfig):
        base = dataclasses.asdict(preset)
    elif isinstance(preset, Mapping):
        base = dict(preset)
    else:
        if preset not in PRESETS:
            raise ConfigError(f"unknown model preset {preset!r}; valid: {sorted(PRESETS)}")
        base = dict(PRESETS[preset])
    base.update(overrides or {})
    return merge(ModelConfig, base, "model.")  # errors name the option as --set model.KEY


# The ablation rows of the paper's Table 2 (modules) and Table 3 (fusion) as overrides (FV/BEV/SF/MCA/EMS/NR columns).
ABLATIONS: dict[str, dict[str, Any]] = {
    "fv_only": dict(views="fv", use_mca=False, use_ems=False, use_nr=False),
    "bev_only": dict(views="bev", use_mca=False, use_ems=False, use_nr=False),
    "concat": dict(fusion="concat", use_mca=False, use_ems=False, use_nr=False),
    "add": dict(fusion="add", use_mca=False, use_ems=False, use_nr=False),
    "sf": dict(use_mca=False, use_ems=False, use_nr=False),
    "sf_mca": dict(use_ems=False, use_nr=False),
    "sf_mca_ems": dict(use_nr=False),
    "full": {},
}
