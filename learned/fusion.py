"""Dual-perspective fusion (paper Sec. 3.4): SKNet-style selective fusion, plus add / concat ablations.

Selective fusion of F_FV, F_BEV (B, D):

    z = F_fc(F_BEV + F_FV)            F_fc = Linear -> BatchNorm1d -> LeakyReLU     (B, d)
    (a training batch of one sample normalises with the running statistics instead of failing)
    a_v = Linear_v(z), v in {FV, BEV};   [w_FV, w_BEV] = Softmax over views, per channel
    F_select = w_FV * F_FV + w_BEV * F_BEV                                         (B, D)
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class SelectiveFusion(nn.Module):
    """SKNet-style selection between the two view descriptors. Returns (fused (B, D), weights (B, 2, D))."""

    def __init__(self, dim: int, reduction: int = 4, min_dim: int = 32):
        super().__init__()
        d = max(dim // reduction, min_dim)
        self.fc_lin, self.fc_bn, self.fc_act = nn.Linear(dim, d), nn.BatchNorm1d(d), nn.LeakyReLU(0.1)
        self.select = nn.Linear(d, 2 * dim)
        self.out_dim = dim

    def forward(self, f_fv: torch.Tensor, f_bev: torch.Tensor):
        y = self.fc_lin(f_fv + f_bev)
        if self.training and y.shape[0] == 1:  # BatchNorm cannot estimate batch statistics from one sample
            y = F.batch_norm(y, self.fc_bn.running_mean, self.fc_bn.running_var, self.fc_bn.weight, self.fc_bn.bias,
                             False, 0.0, self.fc_bn.eps)
        else:
            y = self.fc_bn(y)
        z = self.fc_act(y)
        w = self.select(z).view(-1, 2, f_fv.shape[1]).softmax(1)
        return w[:, 0] * f_fv + w[:, 1] * f_bev, w


class AddFusion(nn.Module):
    """Ablation: F_FV + F_BEV."""

    def __init__(self, dim: int):
        super().__init__()
        self.out_dim = dim

    def forward(self, f_fv: torch.Tensor, f_bev: torch.Tensor):
        return f_fv + f_bev, None


class ConcatFusion(nn.Module):
    """Ablation: concat[F_FV, F_BEV] (B, 2D); the regression head takes the wider input."""

    def __init__(self, dim: int):
        super().__init__()
        self.out_dim = 2 * dim

    def forward(self, f_fv: torch.Tensor, f_bev: torch.Tensor):
        return torch.cat([f_fv, f_bev], 1), None


class SingleView(nn.Module):
    """Ablation: one perspective only (FV only / BEV only); the other input is None."""

    def __init__(self, dim: int):
        super().__init__()
        self.out_dim = dim

    def forward(self, f_fv: torch.Tensor | None, f_bev: torch.Tensor | None):
        return (f_fv if f_fv is not None else f_bev), None


def make_fusion(kind: str, views: str, dim: int, reduction: int = 4, min_dim: int = 32) -> nn.Module:
    if views != "both":
        return SingleView(dim)
    if kind == "selective":
        return SelectiveFusion(dim, reduction, min_dim)
    if kind == "add":
        return AddFusion(dim)
    if kind == "concat":
        return ConcatFusion(dim)
    raise ValueError(f"unknown fusion {kind!r}; valid: selective, add, concat")
