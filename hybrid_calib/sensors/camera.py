"""Pinhole camera with optional Brown-Conrady distortion (OpenCV's k1, k2, p1, p2, k3)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics and image size.

    fx, fy, cx, cy: pixels. width, height: pixels. dist: (k1, k2, p1, p2, k3), zeros = none.
    Camera frame: x right, y down, z forward (optical axis); pixel (u, v) = (column, row),
    pixel centres at integer coordinates.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    dist: tuple[float, float, float, float, float] = field(default=(0.0, 0.0, 0.0, 0.0, 0.0))

    @classmethod
    def from_K(cls, K: np.ndarray, width: int, height: int, dist=None) -> PinholeCamera:
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"camera intrinsic must be 3x3, got shape {K.shape}")
        return cls(
            float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height),
            tuple(float(d) for d in dist) if dist is not None else (0.0,) * 5,
        )

    @property
    def K(self) -> np.ndarray:
        """(3, 3) intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def has_distortion(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    def scaled(self, sx: float, sy: float | None = None) -> PinholeCamera:
        """The same camera for an image resized by (sx, sy); pixel centres stay consistent."""
        sy = sx if sy is None else sy
        return PinholeCamera(
            self.fx * sx, self.fy * sy, (self.cx + 0.5) * sx - 0.5, (self.cy + 0.5) * sy - 0.5,
            int(round(self.width * sx)), int(round(self.height * sy)), self.dist,
        )

    def project(self, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) camera-frame points (metres) -> pixels (N, 2) and depth z (N,).

        Points with z <= 0 get NaN pixels. Distortion is applied when set.
        """
        P = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        z = P[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(z > 0, P[:, 0] / z, np.nan)
            y = np.where(z > 0, P[:, 1] / z, np.nan)
        if self.has_distortion:
            x, y = self._distort(x, y)
        uv = np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=1)
        return uv, z

    def _distort(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k1, k2, p1, p2, k3 = self.dist
        r2 = x * x + y * y
        radial = 1 + k1 * r2 + k2 * r2**2 + k3 * r2**3
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N, 2) pixels -> (N,) bool, inside [-0.5, W-0.5) x [-0.5, H-0.5) shrunk by margin."""
        u, v = uv[:, 0], uv[:, 1]
        return (
            np.isfinite(u) & np.isfinite(v)
            & (u >= -0.5 + margin) & (u < self.width - 0.5 - margin)
            & (v >= -0.5 + margin) & (v < self.height - 0.5 - margin)
        )

    def rays(self) -> np.ndarray:
        """Unit ray directions (H, W, 3) in the camera frame for every pixel centre (no distortion)."""
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        d = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u, float)], -1)
        return d / np.linalg.norm(d, axis=-1, keepdims=True)


def size_invariants(K: np.ndarray) -> np.ndarray:
    """(2,) ``fx / (cx + 0.5)`` and ``fy / (cy + 0.5)`` of a (3, 3) intrinsic matrix: unchanged by resizing the
    image (``PinholeCamera.scaled``, pixel centres kept), so two matrices of one camera at any sizes agree on them."""
    K = np.asarray(K, np.float64)
    return np.array([K[0, 0] / (K[0, 2] + 0.5), K[1, 1] / (K[1, 2] + 0.5)])


def other_camera(K: np.ndarray, K_camera: np.ndarray, tol: float = 0.02) -> str:
    """Why ``K`` (3, 3) is not the intrinsics of the camera ``K_camera`` at any image size ("" when it may be): its
    ``size_invariants`` differ by more than ``tol`` (relative)."""
    a, b = size_invariants(K), size_invariants(K_camera)
    if np.all(np.isfinite(a)) and np.all(np.abs(a / b - 1.0) <= tol):
        return ""
    return (f"its intrinsics K (fx / (cx + 0.5) {a[0]:.4g}, fy / (cy + 0.5) {a[1]:.4g}) are not the camera's at any "
            f"image size ({b[0]:.4g}, {b[1]:.4g}; more than {100 * tol:g} % apart)")
