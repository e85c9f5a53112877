"""The perturbed starts of the paper, R1 and R2, and our near-truth range R0: the one definition the
calibrator, the network's dataset and the commands share (docs/conventions.md, "Perturbed starts").

R0 is not the paper's: it is the regime of the closed loop once the fused estimate is close (the
refining network of the hybrid's cascade is trained on it, ``hybrid.network.CascadeRunner``).

A start samples roll, pitch, yaw (camera axes) uniformly in +-rot_deg and dx, dy, dz uniformly in
+-trans_m, independently, and applies them with ``geometry.perturb_camera_frame``.
"""

from __future__ import annotations

import numpy as np

from hybrid_calib.errors import HybridCalibError
from hybrid_calib.geometry import check_transform, perturb_camera_frame
from hybrid_calib.seeds import keyed_rng

# name -> (max |angle| degrees, max |offset| metres) per axis
RANGES: dict[str, tuple[float, float]] = {"R0": (2.0, 0.10), "R1": (10.0, 0.25), "R2": (20.0, 1.5)}


def perturbation_bounds(name: str) -> tuple[float, float]:
    """``"R0"``/``"R1"``/``"R2"`` -> (rot_deg, trans_m). Raises ``HybridCalibError`` for anything else."""
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
    T_cam_radar = check_transform(T_cam_radar, "perturbed_start T_cam_radar", 1e-4)  # probe 112: NaN / scaled bases
    xi = sample_perturbation(g, name)  # were perturbed into NaN / non-rigid starts
    return perturb_camera_frame(T_cam_radar, xi[:3], xi[3:])


def vehicle_rng(seed: int, vehicle: str, purpose: str = "start") -> np.random.Generator:
    """A generator fixed by (seed, vehicle, purpose) alone: a vehicle's start does not depend on which
    other vehicles a run holds, their order, or the method (every method sees the same start)."""

    if not (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool) and 0 <= seed < 2**63):
        raise HybridCalibError(f"vehicle_rng: seed {seed!r} is not a whole number in 0..2**63-1 (1.7 was truncated, "
                               "'3' taken as text)")
    return keyed_rng(purpose, int(seed), vehicle)


def vehicle_start(base: np.ndarray, kind: str, seed: int, vehicle: str) -> np.ndarray:
    """(4, 4) the start of one vehicle: ``base`` itself for ``kind="reference"``, else a draw in the
    named range around ``base`` (the truth on simulated roots, the tables on real ones) from
    ``vehicle_rng(seed, vehicle)``."""
    base = np.asarray(base, np.float64)
    if kind == "reference":
        return base.copy()
    return perturbed_start(base, vehicle_rng(seed, vehicle), kind)
