"""Residual Conv Block Phi (paper eq. 8) and the explicit matching head (paper eqs. 9-11).

Matching head, with f_I (B, m_I, c), f_R (B, m_R, c) the flattened F_hat maps:

    S = Linear(f_I) Linear(f_R)^T / sqrt(d)                 (B, m_I, m_R)
    sigma_* = Sigmoid(Linear(f_*))                          (B, m_*)
    P_ij = sigma_I,i sigma_R,j Softmax_i(S)_ij Softmax_j(S)_ij   (LightGlue's double softmax, eq. 9)

``P`` is kept in the log domain (``log_P``) for a stable loss; ``log(1 - sigma)`` likewise.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def conv_lrelu(cin: int, cout: int, stride: int) -> nn.Sequential:
    """'conv' of the paper: a convolution followed by LeakyReLU."""
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1), nn.LeakyReLU(0.1, inplace=True))


class ResidualConvBlock(nn.Module):
    """F_view = Phi(conv(x) + conv(conv(x))), x = concat(F_hat_I, F_hat_R).

    Phi = LeakyReLU -> adaptive average pool to ``pool_hw`` -> flatten -> MLP (Linear, LeakyReLU,
    Linear). The pool is our addition so the flattened size does not depend on the input size.
    F_hat_I, F_hat_R: (B, c, h, w) (same grid). Returns (B, out_dim).
    """

    def __init__(self, c: int, mid: int, pool_hw: tuple, out_dim: int):
        super().__init__()
        self.short = conv_lrelu(2 * c, mid, 2)
        self.long = nn.Sequential(conv_lrelu(2 * c, mid, 2), conv_lrelu(mid, mid, 1))
        self.pool = nn.AdaptiveAvgPool2d(tuple(pool_hw))
        flat = mid * pool_hw[0] * pool_hw[1]
        self.mlp = nn.Sequential(nn.Linear(flat, out_dim), nn.LeakyReLU(0.1, inplace=True), nn.Linear(out_dim, out_dim))

    def forward(self, F_hat_I: torch.Tensor, F_hat_R: torch.Tensor) -> torch.Tensor:
        x = torch.cat([F_hat_I, F_hat_R], 1)
        y = F.leaky_relu(self.short(x) + self.long(x), 0.1)
        return self.mlp(self.pool(y).flatten(1))


class MatchingHead(nn.Module):
    """Explicit feature matching: similarity S, matchability sigma, assignment P (log domain).

    F_hat_I: (B, c, h_I, w_I), F_hat_R: (B, c, h_R, w_R). Returns dict:
    ``S`` (B, m_I, m_R), ``log_P`` (B, m_I, m_R), ``logit_I`` (B, m_I), ``logit_R`` (B, m_R)
    (sigma = sigmoid(logit)), and ``grid_I`` / ``grid_R`` = (h, w) of the cell grids.
    """

    def __init__(self, c: int, dim: int):
        super().__init__()
        self.proj_I, self.proj_R = nn.Linear(c, dim), nn.Linear(c, dim)
        self.match_I, self.match_R = nn.Linear(c, 1), nn.Linear(c, 1)
        self.scale = dim ** -0.5

    def forward(self, F_hat_I: torch.Tensor, F_hat_R: torch.Tensor) -> dict:
        f_I = F_hat_I.flatten(2).transpose(1, 2)
        f_R = F_hat_R.flatten(2).transpose(1, 2)
        S = (self.proj_I(f_I) @ self.proj_R(f_R).transpose(1, 2)) * self.scale
        logit_I = self.match_I(f_I)[..., 0]
        logit_R = self.match_R(f_R)[..., 0]
        log_P = (S.log_softmax(1) + S.log_softmax(2) + F.logsigmoid(logit_I)[:, :, None]
                 + F.logsigmoid(logit_R)[:, None, :])
        return dict(S=S, log_P=log_P, logit_I=logit_I, logit_R=logit_R,
                    grid_I=tuple(F_hat_I.shape[-2:]), grid_R=tuple(F_hat_R.shape[-2:]))
