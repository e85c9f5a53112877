"""Spinning LiDAR like the nuScenes LIDAR_TOP (Velodyne HDL-32E): 32 beams, -30.67 to +10.67 deg.

LiDAR frame as in nuScenes: x right, y forward, z up. Azimuth here is atan2(y, x) in that frame.
Output rows are (x, y, z, intensity, ring) float32, the nuScenes ``.pcd.bin`` layout; intensity is
0..255, ring is the beam index 0..31 (0 = lowest beam).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hybrid_calib.config import require, require_ranges
from hybrid_calib.sim.raycast import GROUND, Primitives, cast_angular, check_pose


@dataclass(frozen=True)
class LidarConfig:
    """HDL-32E-like spinning LiDAR."""

    n_beams: int = 32  # number of lasers (rings)
    elevation_min_deg: float = -30.67  # lowest beam elevation, degrees
    elevation_max_deg: float = 10.67  # highest beam elevation, degrees
    azimuth_steps: int = 1084  # firings per revolution (nuScenes: ~1084, 0.33 deg)
    min_range_m: float = 1.0  # closer returns (the ego's own body) are dropped, metres
    max_range_m: float = 80.0  # farthest return, metres
    range_noise_m: float = 0.02  # range noise standard deviation, metres
    dropout_probability: float = 0.03  # chance that a return is lost
    intensity_noise: float = 0.05  # relative intensity noise

    def __post_init__(self):
        # azimuth_steps=0 wrote 0-byte LiDAR files without a word
        require(self, {**{f"0 < {n} < inf": 0 < getattr(self, n) < np.inf
                          for n in ("n_beams", "azimuth_steps", "max_range_m")},
                       **{f"0 <= {n} < inf": 0 <= getattr(self, n) < np.inf
                          for n in ("min_range_m", "range_noise_m", "intensity_noise")},
                       "0 <= dropout_probability < 1": 0 <= self.dropout_probability < 1})
        if not self.min_range_m < self.max_range_m:
            raise ValueError(f"min_range_m={self.min_range_m} must be below max_range_m={self.max_range_m}")
        if not (self.elevation_min_deg < self.elevation_max_deg or (self.n_beams == 1 and np.isfinite(
                self.elevation_min_deg) and self.elevation_min_deg == self.elevation_max_deg)):
            raise ValueError(f"elevation_min_deg={self.elevation_min_deg} must be below elevation_max_deg="
                             f"{self.elevation_max_deg}")
        require_ranges(self, {"n_beams": "[1, 512]", "elevation_min_deg": "[-90, 90]", "elevation_max_deg": "[-90, 90]",
                              "azimuth_steps": "[1, 36000]", "min_range_m": "[0, 1000)", "max_range_m": "(0, 1000]",
                              "range_noise_m": "[0, 10]", "dropout_probability": "[0, 1)",
                              "intensity_noise": "[0, 10]"})


def beam_elevations(conf: LidarConfig) -> np.ndarray:
    """(n_beams,) radians, increasing."""
    return np.deg2rad(np.linspace(conf.elevation_min_deg, conf.elevation_max_deg, conf.n_beams))


def simulate_lidar_sweep(prims: Primitives, T_global_lidar: np.ndarray, conf: LidarConfig, rng: np.random.Generator,
                         ground_reflectivity: Callable[[np.ndarray], np.ndarray],
                         lidar_reflectivity: np.ndarray | None = None) -> np.ndarray:
    """One revolution, all firings at one instant.

    prims: the world (global frame) at the sweep time. T_global_lidar: (4, 4) LiDAR -> global.
    ground_reflectivity: global xy (N, 2) -> (N,) reflectivity 0..1 of the ground there.
    lidar_reflectivity: (n_materials,) 0..1 (default ``world.LIDAR_REFLECTIVITY``).
    Returns (N, 5) float32 [x, y, z, intensity, ring] in the LiDAR frame.
    """
    if lidar_reflectivity is None:
        from hybrid_calib.sim.world import LIDAR_REFLECTIVITY as lidar_reflectivity
    T_global_lidar = check_pose(T_global_lidar, "T_global_lidar")
    el = beam_elevations(conf)
    az = np.linspace(-np.pi, np.pi, conf.azimuth_steps, endpoint=False)
    buf, dirs = cast_angular(prims, T_global_lidar, el, az, conf.max_range_m, wrap=True)
    t = buf.t
    ok = np.isfinite(t) & (t >= conf.min_range_m) & (rng.random(t.shape) >= conf.dropout_probability)
    ring = np.broadcast_to(np.arange(conf.n_beams)[:, None], t.shape)[ok]
    d_global = dirs[ok]
    prim = buf.prim[ok]
    r = t[ok]
    cos_inc = np.abs(np.einsum("ij,ij->i", buf.normal[ok].astype(np.float64), d_global))
    refl = np.empty(len(r))
    g = prim == GROUND
    obj = prim >= 0
    if g.any():
        p = T_global_lidar[:3, 3] + r[g, None] * d_global[g]
        refl[g] = ground_reflectivity(p[:, :2])
    refl[obj] = lidar_reflectivity[prims.material[prim[obj]]]
    intensity = 255 * refl * (0.3 + 0.7 * cos_inc) * (1 + conf.intensity_noise * rng.standard_normal(len(r)))
    r_m = r + rng.normal(0, conf.range_noise_m, len(r))
    d_local = d_global @ T_global_lidar[:3, :3]
    xyz = d_local * r_m[:, None]
    return np.column_stack([xyz, np.clip(intensity, 0, 255), ring]).astype(np.float32)
