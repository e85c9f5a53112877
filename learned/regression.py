"""Iterative LSTM regression head (paper Sec. 3.5, CalibDepth's sequence decoder).

At iteration n the fused descriptor x_n (B, D) drives one LSTM step whose hidden state carries over
the iterations; linear heads give a rotation vector (radians) and a translation (metres) of the
correction T_pred^n = [Exp(omega), t; 0, 1], and 6 log-variances of the right-tangent error of the
updated estimate (used by ``learned.export``; that head reads the hidden state detached, so its loss
trains only itself). The model composes T_init <- T_init . T_pred^n.
"""

from __future__ import annotations

import torch
from torch import nn

from learned import lie


class LSTMRegressionHead(nn.Module):
    """x: (B, D), state: (h, c) or None -> dict(rot (B, 3), trans (B, 3), log_var (B, 6), T_delta (B, 4, 4)), state."""

    def __init__(self, in_dim: int, hidden: int):
        super().__init__()
        self.inp = nn.Sequential(nn.Linear(in_dim, hidden), nn.LeakyReLU(0.1, inplace=True))
        self.cell = nn.LSTMCell(hidden, hidden)
        self.rot = nn.Sequential(nn.Linear(hidden, hidden // 2), nn.LeakyReLU(0.1, inplace=True),
                                 nn.Linear(hidden // 2, 3))
        self.trans = nn.Sequential(nn.Linear(hidden, hidden // 2), nn.LeakyReLU(0.1, inplace=True),
                                   nn.Linear(hidden // 2, 3))
        # variance head reads a detached hidden state: its NLL never shapes the calibration features
        self.log_var = nn.Sequential(nn.Linear(hidden, hidden // 2), nn.LeakyReLU(0.1, inplace=True),
                                     nn.Linear(hidden // 2, 6))
        for head in (self.rot[-1], self.trans[-1]):  # start near the identity correction
            nn.init.normal_(head.weight, std=1e-3)
            nn.init.zeros_(head.bias)
        nn.init.zeros_(self.log_var[-1].weight)
        nn.init.constant_(self.log_var[-1].bias, -4.0)  # ~ (0.14 rad, 0.14 m) 1-sigma before training

    def forward(self, x: torch.Tensor, state=None):
        h, c = self.cell(self.inp(x), state)
        rot, trans = self.rot(h), self.trans(h)
        out = dict(rot=rot, trans=trans, log_var=self.log_var(h.detach()), T_delta=lie.make_T(lie.so3_exp(rot), trans))
        return out, (h, c)
