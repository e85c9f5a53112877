"""Losses (paper Sec. 3.6): L_total = L_calib + beta L_matching (+ a small NLL for the variance head).

- ``calib_loss``: the paper's L_calib is CalibDepth's (per-step supervision of each iteration's correction,
  plus terms on the final pose); ours is a RAFT-style sequence loss over the N iterations instead (a
  deviation, README "Where the network differs from the paper"), weight gamma^(N-1-n) for iteration n
  (the last weighs 1), each a sum of
  rotation  SmoothL1(sin-vector of R_gt^T R_n) (radians),
  translation  SmoothL1(t_n - t_gt) (metres, camera frame),
  point distance  SmoothL1(T_n p - T_gt p) averaged over the valid input points (metres).
  It is exactly 0 when every T_n equals T_gt.
- ``matching_loss``: paper eqs. 16-19 for one view and one iteration,
  L_M = -(lambda / sum M * sum_ij log P_ij M_ij + (1 - lambda) / (sum N_I + sum N_R) *
  (sum_i log(1 - sigma_I,i) N_I,i + sum_j log(1 - sigma_R,j) N_R,j)), per sample, then batch mean.
- ``variance_nll``: Gaussian NLL of the right-tangent error Log(T_n^-1 T_gt) (detached) under the
  head's diagonal log-variances; trains only the variance head.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from learned import lie

SMOOTH_L1_BETA = 0.02  # quadratic below ~1 deg / 2 cm: smooth at the optimum, L1 (robust) above


def _sl1(x: torch.Tensor) -> torch.Tensor:
    return F.smooth_l1_loss(x, torch.zeros_like(x), reduction="none", beta=SMOOTH_L1_BETA)


def calib_loss(T_iters: list[torch.Tensor], T_gt: torch.Tensor, points: torch.Tensor, mask: torch.Tensor,
               gamma: float = 0.8, w_rot: float = 1.0, w_trans: float = 1.0, w_point: float = 0.5
               ) -> torch.Tensor:
    """T_iters: N x (B, 4, 4); T_gt: (B, 4, 4); points: (B, P, 3) sensor frame; mask: (B, P) bool. -> scalar."""
    n_it = len(T_iters)
    R_gt, t_gt = T_gt[:, :3, :3], T_gt[:, :3, 3]
    w = mask.to(points.dtype)
    p_gt = lie.transform_points(T_gt, points)
    total = points.new_zeros(())
    for n, T in enumerate(T_iters):
        rot = _sl1(lie.so3_sin_vector(R_gt.transpose(1, 2) @ T[:, :3, :3])).sum(-1)
        trans = _sl1(T[:, :3, 3] - t_gt).sum(-1)
        pt = (_sl1(lie.transform_points(T, points) - p_gt).sum(-1) * w).sum(-1) / w.sum(-1).clamp_min(1.0)
        per_sample = w_rot * rot + w_trans * trans + w_point * pt
        total = total + gamma ** (n_it - 1 - n) * per_sample.mean()
    return total


def matching_loss(match: dict, M: torch.Tensor, N_I: torch.Tensor, N_R: torch.Tensor, lam: float = 0.75
                  ) -> torch.Tensor:
    """One view, one iteration. match: ``MatchingHead`` output (log_P (B, m_I, m_R), logit_I, logit_R);
    M: (B, m_I, m_R), N_I: (B, m_I), N_R: (B, m_R) ground truth. -> scalar (>= 0)."""
    pos = (match["log_P"] * M).sum((1, 2))
    neg = (F.logsigmoid(-match["logit_I"]) * N_I).sum(1) + (F.logsigmoid(-match["logit_R"]) * N_R).sum(1)
    n_pos = M.sum((1, 2)).clamp_min(1.0)
    n_neg = (N_I.sum(1) + N_R.sum(1)).clamp_min(1.0)
    return -(lam * pos / n_pos + (1 - lam) * neg / n_neg).mean()


def variance_nll(log_vars: list[torch.Tensor], T_iters: list[torch.Tensor], T_gt: torch.Tensor) -> torch.Tensor:
    """Mean over iterations of 0.5 * sum(xi^2 exp(-s) + s), xi = Log(T_n^-1 T_gt) detached, s: (B, 6)."""
    total = T_gt.new_zeros(())
    for s, T in zip(log_vars, T_iters):
        xi = lie.local(T.detach(), T_gt).detach()
        total = total + (0.5 * (xi * xi * torch.exp(-s) + s).sum(-1)).mean()
    return total / max(len(log_vars), 1)
