"""Sensor mountings: the nominal (fleet design) nuScenes mounts, each vehicle's true perturbed mounts,
and the radar mount moving during a drive (a step at one frame, or a slow drift).

All transforms are ``T_ego_sensor`` (sensor -> ego), (4, 4) float64; see docs/conventions.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.config import require_ranges
from hybrid_calib.geometry import make_T, se3_exp

# Camera axes (x right, y down, z forward) in the ego frame (x forward, y left, z up).
R_EGO_CAM = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# LiDAR axes (x right, y forward, z up) in the ego frame.
R_EGO_LIDAR = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

NOMINAL_T_EGO_CAM = make_T(R_EGO_CAM, np.array([1.70, 0.016, 1.51]))  # nuScenes CAM_FRONT
NOMINAL_T_EGO_RADAR = make_T(np.eye(3), np.array([3.41, 0.0, 0.50]))  # nuScenes RADAR_FRONT
NOMINAL_T_EGO_LIDAR = make_T(R_EGO_LIDAR, np.array([0.94, 0.0, 1.84]))  # nuScenes LIDAR_TOP

EXTRINSIC_CHANGES = ("none", "step", "drift")


@dataclass(frozen=True)
class ExtrinsicChange:
    """How the radar mount moves during each drive (applied on the right: T_ego_radar Exp(alpha xi))."""

    kind: str = "none"  # none | step (at ``frame``) | drift (linear from frame 0 to the last frame)
    frame: int = -1  # frame index of the step; -1 = the middle of the drive
    rotation_deg: tuple[float, float, float] = (0.3, 1.0, 1.5)  # full change about radar x, y, z, degrees
    translation_m: tuple[float, float, float] = (0.02, 0.01, -0.02)  # full change along radar x, y, z, metres

    def __post_init__(self):
        if self.kind not in EXTRINSIC_CHANGES:
            raise ValueError(f"extrinsic change kind {self.kind!r} is not one of {EXTRINSIC_CHANGES}")
        require_ranges(self, {"frame": "[-1, 1e5]", "rotation_deg": "[-180, 180]", "translation_m": "[-10, 10]"})

    def step_frame(self, frames: int) -> int:
        return frames // 2 if self.frame < 0 else self.frame

    def fraction(self, k: int, frames: int) -> float:
        """How much of the change has happened at frame k (0..1)."""
        if self.kind == "step":
            return 1.0 if k >= self.step_frame(frames) else 0.0
        if self.kind == "drift":
            return k / max(frames - 1, 1)
        return 0.0

    @property
    def xi(self) -> np.ndarray:
        """Full change as a tangent vector [omega, v] in the radar frame (rad, m)."""
        return np.concatenate([np.deg2rad(self.rotation_deg), self.translation_m])


@dataclass(frozen=True)
class MountPerturbation:
    """Spread of each vehicle's true mounts around the nominal (fleet design) ones (uniform in +- the
    value), and the error of each vehicle's factory calibration (Gaussian, std per axis).

    Chosen from the real nuScenes mounts (850 trainval scenes, docs/conventions.md "Fleet mounts"):
    RADAR_FRONT sits at one position with one of four yaws (-0.85 .. +0.20 deg); CAM_FRONT has three
    mounts 5 cm apart along x with rotations up to 0.8 deg from the design axes.
    """

    radar_rotation_deg: float = 1.0  # per-axis radar rotation spread, degrees (nuScenes yaws: -0.85 .. +0.20)
    radar_translation_m: float = 0.02  # per-axis radar translation spread, metres (nuScenes: one position)
    camera_rotation_deg: float = 1.0  # per-axis camera rotation spread, degrees (nuScenes: up to 0.8 deg)
    camera_translation_m: float = 0.03  # per-axis camera translation spread, metres (nuScenes: x 1.671 .. 1.722 m)
    lidar_rotation_deg: float = 0.2  # per-axis LiDAR rotation spread, degrees
    lidar_translation_m: float = 0.01  # per-axis LiDAR translation spread, metres
    factory_rotation_std_deg: float = 0.1  # factory (end-of-line) calibration error per axis and sensor, degrees
    factory_translation_std_m: float = 0.005  # factory calibration error per axis and sensor, metres

    def __post_init__(self):
        require_ranges(self, {"radar_rotation_deg": "[0, 90]", "radar_translation_m": "[0, 10]",
                              "camera_rotation_deg": "[0, 90]", "camera_translation_m": "[0, 10]",
                              "lidar_rotation_deg": "[0, 90]", "lidar_translation_m": "[0, 10]",
                              "factory_rotation_std_deg": "[0, 90]", "factory_translation_std_m": "[0, 10]"})


@dataclass(frozen=True)
class VehicleMounts:
    """One vehicle's true mounts at the start of the drive (T_ego_sensor), and its factory calibration
    of them (what its calibration tables hold: the truth plus a small calibration error)."""

    T_ego_cam: np.ndarray
    T_ego_radar: np.ndarray
    T_ego_lidar: np.ndarray
    factory_T_ego_cam: np.ndarray
    factory_T_ego_radar: np.ndarray

    def radar_at(self, change: ExtrinsicChange, k: int, frames: int) -> np.ndarray:
        """T_ego_radar at frame k under ``change``."""
        a = change.fraction(k, frames)
        return self.T_ego_radar if a == 0.0 else self.T_ego_radar @ se3_exp(a * change.xi)


def _perturbed(T: np.ndarray, g: np.random.Generator, rot_deg: float, trans_m: float) -> np.ndarray:
    xi = np.concatenate([np.deg2rad(g.uniform(-rot_deg, rot_deg, 3)), g.uniform(-trans_m, trans_m, 3)])
    return T @ se3_exp(xi)


def _factory(T: np.ndarray, g: np.random.Generator, spread: MountPerturbation) -> np.ndarray:
    xi = np.concatenate([np.deg2rad(g.normal(0.0, spread.factory_rotation_std_deg, 3)),
                         g.normal(0.0, spread.factory_translation_std_m, 3)])
    return T @ se3_exp(xi)


def sample_mounts(g: np.random.Generator, spread: MountPerturbation, g_factory: np.random.Generator,
                  base: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> VehicleMounts:
    """A vehicle's true mounts: the base ones (default: the nominal design mounts; the domain
    randomisation passes a real nuScenes fleet mount) as (T_ego_cam, T_ego_radar, T_ego_lidar),
    perturbed on the right (sensor frame, ``g``); its factory calibration: the true ones perturbed
    again by the calibration error (``g_factory``, a stream of its own so the true mounts do not
    depend on the calibration error's size)."""
    nominal = (NOMINAL_T_EGO_CAM, NOMINAL_T_EGO_RADAR, NOMINAL_T_EGO_LIDAR)
    b_cam, b_radar, b_lidar = base if base is not None else nominal
    cam = _perturbed(b_cam, g, spread.camera_rotation_deg, spread.camera_translation_m)
    radar = _perturbed(b_radar, g, spread.radar_rotation_deg, spread.radar_translation_m)
    lidar = _perturbed(b_lidar, g, spread.lidar_rotation_deg, spread.lidar_translation_m)
    return VehicleMounts(T_ego_cam=cam, T_ego_radar=radar, T_ego_lidar=lidar,
                         factory_T_ego_cam=_factory(cam, g_factory, spread),
                         factory_T_ego_radar=_factory(radar, g_factory, spread))
