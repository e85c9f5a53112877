"""Multi-Modal Cross-Attention (paper eqs. 4-7 and supplement B).

With f_I, f_R (B, m, c) the flattened feature maps, K_* = Linear(f_*), V_* = Linear(f_*):

    a_IR = K_I K_R^T                       (B, m_I, m_R)   [paper: K_I^T K_R with column vectors]
    m_{I<-R} = Softmax_j(a_IR) V_R,   m_{R<-I} = Softmax_i(a_IR^T) V_I
    O = Theta(F, m) = reshape(FFN(concat[f, m]))   FFN = Linear -> LayerNorm -> GELU -> Linear
    F_hat_I = F_I + O_{I<-R},   F_hat_R = F_R + O_{R<-I}

Optional multi-head split and 1/sqrt(d) scaling (config). The visualisation maps of the supplement
(its eqs. 3-4) are ``I_{I<-R} = max_j Softmax(a_IR)_ij`` and ``I_{R<-I} = max_j Softmax(a_IR^T)_ij``.
"""

from __future__ import annotations

import torch
from torch import nn


class FFN(nn.Module):
    """Theta's feed-forward network: (B, m, 2c) -> (B, m, c)."""

    def __init__(self, c: int):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(2 * c, 2 * c), nn.LayerNorm(2 * c), nn.GELU(), nn.Linear(2 * c, c))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class MultiModalCrossAttention(nn.Module):
    """MCA(F_I, F_R) -> (F_hat_I, F_hat_R, maps).

    F_I: (B, c, h_I, w_I), F_R: (B, c, h_R, w_R) (same c). Returns the updated features of the same
    shapes and a dict with ``attn_I_from_R`` (B, 1, h_I, w_I) and ``attn_R_from_I`` (B, 1, h_R, w_R).
    """

    def __init__(self, c: int, heads: int = 1, scale: bool = True):
        super().__init__()
        self.heads = heads
        self.scale = (c // heads) ** -0.5 if scale else 1.0
        self.key_I, self.key_R = nn.Linear(c, c), nn.Linear(c, c)
        self.value_I, self.value_R = nn.Linear(c, c), nn.Linear(c, c)
        # multi-head outputs are mixed by a Linear (LightGlue); single-head is exactly the paper's m = Softmax V
        self.merge_I = nn.Linear(c, c) if heads > 1 else nn.Identity()
        self.merge_R = nn.Linear(c, c) if heads > 1 else nn.Identity()
        self.theta_I, self.theta_R = FFN(c), FFN(c)

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        B, m, c = x.shape
        return x.reshape(B, m, self.heads, c // self.heads).transpose(1, 2)  # (B, heads, m, d)

    def _join(self, x: torch.Tensor) -> torch.Tensor:
        B, H, m, d = x.shape
        return x.transpose(1, 2).reshape(B, m, H * d)

    def forward(self, F_I: torch.Tensor, F_R: torch.Tensor):
        B, c, hI, wI = F_I.shape
        hR, wR = F_R.shape[-2:]
        f_I = F_I.flatten(2).transpose(1, 2)  # (B, m_I, c)
        f_R = F_R.flatten(2).transpose(1, 2)
        kI, kR = self._split(self.key_I(f_I)), self._split(self.key_R(f_R))
        vI, vR = self._split(self.value_I(f_I)), self._split(self.value_R(f_R))
        a_IR = (kI @ kR.transpose(-1, -2)) * self.scale  # (B, heads, m_I, m_R)
        soft_IR = a_IR.softmax(-1)
        soft_RI = a_IR.transpose(-1, -2).softmax(-1)
        m_I = self.merge_I(self._join(soft_IR @ vR))
        m_R = self.merge_R(self._join(soft_RI @ vI))
        O_I = self.theta_I(torch.cat([f_I, m_I], -1))
        O_R = self.theta_R(torch.cat([f_R, m_R], -1))
        F_hat_I = F_I + O_I.transpose(1, 2).reshape(B, c, hI, wI)
        F_hat_R = F_R + O_R.transpose(1, 2).reshape(B, c, hR, wR)
        maps = {
            "attn_I_from_R": soft_IR.mean(1).amax(-1).reshape(B, 1, hI, wI).detach(),
            "attn_R_from_I": soft_RI.mean(1).amax(-1).reshape(B, 1, hR, wR).detach(),
        }
        return F_hat_I, F_hat_R, maps
