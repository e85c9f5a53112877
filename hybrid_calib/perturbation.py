"""The perturbed starts of the paper, R1 and R2: the one definition the calibrator, the network's
dataset and the commands share (docs/conventions.md, "Perturbed starts").

A start samples roll, pitch, yaw (camera axes) uniformly in +-rot_deg and dx, dy, dz uniformly in
+-trans_m, independently, and applies them with ``geometry.perturb_camera_frame``.
"""

from __future__ import annotations

import numpy as np

from hybrid_calib.errors import HybridCalibError
from hybrid_calib.geometry import perturb_camera_frame

# name -> (max |angle| degrees, max |offset| metres) per axis
RANGES: dict[str, tuple[float, float]] = {"R1": (10.0, 0.25), "R2": (20.0, 1.5)}


def perturbation_bounds(name: str) -> tuple[float, float]:
    """``"R1"``/``"R2"`` -> (rot_deg, trans_m). Raises ``HybridCalibError`` for anything else."""
    if name not in RANGES:
        raise HybridCalibError(f"unknown perturbation range {name!r}; use one of {sorted(RANGES)}")
    return RANGES[name]


def sample_perturbation(g: np.random.Generator, name: str) -> np.ndarray:
    """(6,) float64: roll, pitch, yaw (rad) and dx, dy, dz (m), uniform within the named range
    (three angle draws from ``g``, then three offset draws)."""
    rot_deg, trans_m = perturbation_bounds(name)
    rpy = np.radians(g.uniform(-rot_deg, rot_deg, size=3))
    dt = g.uniform(-trans_m, trans_m, size=3)
    return np.concatenate([rpy, dt])


def perturbed_start(T_cam_radar: np.ndarray, g: np.random.Generator, name: str) -> np.ndarray:
    """(4, 4) a start drawn in the named range around ``T_cam_radar`` (``sample_perturbation``)."""
    xi = sample_perturbation(g, name)
    return perturb_camera_frame(T_cam_radar, xi[:3], xi[3:])
