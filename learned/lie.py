"""Batched SO(3)/SE(3) operations in torch (same conventions as ``hybrid_calib.geometry``).

Transforms are (..., 4, 4); tangents are ``[omega, v]`` (..., 6), radians then metres; right
perturbation ``T Exp(xi)``. Everything is differentiable and safe at the identity.
"""

from __future__ import annotations

import torch


def skew(w: torch.Tensor) -> torch.Tensor:
    """(..., 3) -> (..., 3, 3) cross-product matrix."""
    z = torch.zeros_like(w[..., 0])
    wx, wy, wz = w.unbind(-1)
    return torch.stack([z, -wz, wy, wz, z, -wx, -wy, wx, z], dim=-1).reshape(*w.shape[:-1], 3, 3)


def so3_exp(w: torch.Tensor) -> torch.Tensor:
    """Rotation vectors (..., 3) radians -> rotation matrices (..., 3, 3) (Rodrigues, Taylor near 0).

    Uses ``1 - cos = 2 sin^2(theta / 2)`` so float32 stays accurate for small angles.
    """
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]
    theta = theta2.clamp_min(1e-20).sqrt()
    small = theta2 < 1e-6
    half_sin = torch.sin(theta / 2)
    a = torch.where(small, 1 - theta2 / 6, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24, 2 * half_sin * half_sin / theta2.clamp_min(1e-20))
    K = skew(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(K)
    return eye + a * K + b * (K @ K)


def so3_log(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) -> rotation vectors (..., 3) radians, angle in [0, pi]. Not for gradients at
    exactly pi. Near pi (sin(theta) < 1e-3 with cos(theta) < 0) the axis comes from the symmetric part
    ``(R + I) / 2 ~ a a^T`` (the antisymmetric one vanishes there): a half-turn had read as the identity, where
    ``hybrid_calib.geometry.so3_log`` reads pi (probe 141), and float32 lost the axis within 1e-5 rad of it."""
    vee = torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    cos = ((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1.0, 1.0)
    sin = 0.5 * vee.norm(dim=-1)
    theta = torch.atan2(sin, cos)
    scale = torch.where(sin < 1e-6, 0.5 + theta * theta / 12, theta / (2 * sin.clamp_min(1e-12)))
    out = vee * scale[..., None]
    near_pi = (sin < 1e-3) & (cos < 0)  # float32's vee is noise there (probe 142: 0.3-3 deg off within 1e-5 rad)
    if bool(near_pi.any()):
        # ((R + R^T) / 2 + I) / 2 = ((1 + cos) / 2) I + ((1 - cos) / 2) a a^T: a a^T to 1e-6 for sin < 1e-3
        B = ((R + R.transpose(-1, -2)) / 2 + torch.eye(3, dtype=R.dtype, device=R.device)) / 2
        k = B.diagonal(dim1=-2, dim2=-1).argmax(-1)  # the column with the largest |a_k|
        col = torch.take_along_dim(B, k[..., None, None].expand(*k.shape, 3, 1), dim=-1)[..., 0]
        axis = col / col.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        sign = torch.where((axis * vee).sum(-1) < 0, -1.0, 1.0).to(R.dtype)  # the side the residual vee points to
        out = torch.where(near_pi[..., None], axis * (sign * theta)[..., None], out)
    return out


def so3_sin_vector(R: torch.Tensor) -> torch.Tensor:
    """vee((R - R^T) / 2) = sin(theta) * axis (..., 3): a smooth, zero-at-identity rotation residual."""
    return 0.5 * torch.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0],
                              R[..., 1, 0] - R[..., 0, 1]], -1)


def make_T(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Rotation (..., 3, 3) and translation (..., 3) -> (..., 4, 4)."""
    T = torch.zeros(*R.shape[:-2], 4, 4, dtype=R.dtype, device=R.device)
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inverse(T: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms (..., 4, 4)."""
    R = T[..., :3, :3].transpose(-1, -2)
    return make_T(R, -(R @ T[..., :3, 3:4])[..., 0])


def transform_points(T: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Apply (B, 4, 4) ``T_a_b`` to (B, N, 3) points in b -> (B, N, 3) in a."""
    return p @ T[..., :3, :3].transpose(-1, -2) + T[..., None, :3, 3]


def _left_jacobian_inv(w: torch.Tensor) -> torch.Tensor:
    """Inverse SO(3) left Jacobian: I - K/2 + c K^2, c = (1 - (theta/2) cot(theta/2)) / theta^2."""
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]
    theta = theta2.clamp_min(1e-20).sqrt()
    small = theta2 < 1e-3
    half = theta / 2
    exact = (1 - half * torch.cos(half) / torch.sin(half).clamp_min(1e-20)) / theta2.clamp_min(1e-20)
    coef = torch.where(small, 1.0 / 12 + theta2 / 720, exact)
    K = skew(w)
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(K)
    return eye - 0.5 * K + coef * (K @ K)


def se3_log(T: torch.Tensor) -> torch.Tensor:
    """(..., 4, 4) -> tangent ``[omega, v]`` (..., 6), identical to ``gtsam.Pose3.Logmap``."""
    w = so3_log(T[..., :3, :3])
    v = (_left_jacobian_inv(w) @ T[..., :3, 3:4])[..., 0]
    return torch.cat([w, v], -1)


def local(T1: torch.Tensor, T2: torch.Tensor) -> torch.Tensor:
    """Right tangent from T1 to T2, ``Log(T1^-1 T2)`` (..., 6)."""
    return se3_log(inverse(T1) @ T2)
