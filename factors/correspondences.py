"""Radar-point <-> image-pixel correspondences: what the network exports and the factors consume."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Correspondences:
    """The correspondences of one frame.

    points_radar: (N, 3) float64, metres, radar frame, as recorded (z = 0 for a 2D radar: the
        true elevation of each reflector is unknown).
    pixels: (N, 2) float64, pixels (u = column, v = row) in the image described by ``K``.
    sigma_px: (N,) float64, pixels, isotropic 1-sigma noise of each pixel (e.g. 2 for a keypoint,
        ~8/sqrt(12)*... for a network cell; the producer decides).
    confidence: (N,) float64 in [0, 1]; multiplies the information of each row.
    K: (3, 3) float64 camera intrinsics of the image the pixels live in.
    frame_id: free-form identifier (sample token, index) used in logs and errors.
    timestamp_us: camera timestamp, microseconds (0 if unknown).
    """

    points_radar: np.ndarray
    pixels: np.ndarray
    sigma_px: np.ndarray
    confidence: np.ndarray
    K: np.ndarray
    frame_id: str = ""
    timestamp_us: int = 0

    def __post_init__(self):
        n = len(self.points_radar)
        checks = {
            "points_radar": (np.shape(self.points_radar), (n, 3)),
            "pixels": (np.shape(self.pixels), (n, 2)),
            "sigma_px": (np.shape(self.sigma_px), (n,)),
            "confidence": (np.shape(self.confidence), (n,)),
            "K": (np.shape(self.K), (3, 3)),
        }
        for name, (got, want) in checks.items():
            if got != want:
                raise ValueError(f"Correspondences[{self.frame_id}].{name}: shape {got}, expected {want}")
        for name in ("points_radar", "pixels", "sigma_px", "confidence"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"Correspondences[{self.frame_id}].{name} has NaN/inf values; drop those rows")
        if np.any(np.asarray(self.sigma_px) <= 0):
            raise ValueError(f"Correspondences[{self.frame_id}].sigma_px must be > 0")

    def __len__(self) -> int:
        return len(self.points_radar)

    def subset(self, mask: np.ndarray) -> Correspondences:
        """The rows selected by a boolean mask or index array."""
        return Correspondences(
            np.asarray(self.points_radar)[mask], np.asarray(self.pixels)[mask],
            np.asarray(self.sigma_px)[mask], np.asarray(self.confidence)[mask],
            self.K, self.frame_id, self.timestamp_us,
        )

    def to_npz_dict(self) -> dict[str, np.ndarray]:
        """The arrays of a measurement file (``factors.io``) holding only these rows."""
        from factors.io import FrameMeasurements, to_arrays

        return to_arrays(FrameMeasurements(self))

    @classmethod
    def empty(cls, K: np.ndarray, frame_id: str = "", timestamp_us: int = 0) -> Correspondences:
        """A frame with no rows (a producer that found nothing to export)."""
        return cls(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.asarray(K, np.float64),
                   frame_id, timestamp_us)

    @classmethod
    def from_npz_dict(cls, d) -> Correspondences:
        """The rows of a measurement file's arrays (``factors.io.from_arrays``)."""
        from factors.io import from_arrays

        return from_arrays(d).corr
