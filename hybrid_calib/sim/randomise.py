"""Domain randomisation: per-vehicle (and per-frame) draws of what the simulator cannot match to real
data exactly, so that a network trained on simulated drives has seen the real data's variety.

``Randomisation`` (``SimConfig.randomise``) holds the ranges; everything is off unless ``enabled``
(``--set randomise.enabled=true``), and then deterministic by (seed, vehicle[, frame]):

- appearance: exposure, gamma, contrast, saturation, white balance and warmth, per-object albedo tint, ground
  tint, haze and an overcast sky (weather), blur, pixel noise, JPEG quality;
- radar: the RCS floor of the ARS 408 cluster list, sensitivity, detection threshold, returns per
  object, range / azimuth / RCS / velocity noise, clutter and ghost rates, clutter RCS;
- mounts: the camera, radar and LiDAR base mounts and the CAM_FRONT intrinsics drawn from the real
  nuScenes fleet (``NUSCENES_FLEET_MOUNTS``, scene-weighted), plus an intrinsics jitter; the
  ``SimConfig.mounts`` spread still applies around the drawn base mount.

Ranges are (low, high), drawn uniformly. The radar ranges are centred on what the real scene-0916
sweeps show after the devkit filters (almost no RCS under -5 dBsm, ~48 points per sweep; see
docs/sim_vs_real.md), the appearance ranges cover the real CAM_FRONT images' brightness and contrast.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from hybrid_calib.config import require_ranges
from hybrid_calib.geometry import pose_from_nuscenes
from hybrid_calib.sim.radar import RadarConfig
from hybrid_calib.sim.render import ShadingConfig

# The real fleet: (CAM_FRONT, RADAR_FRONT, LIDAR_TOP) mount combinations of the 850 nuScenes
# v1.0-trainval scenes and how many scenes use each, as ``hybrid_calib.data.fleet_mounts.fleet_mounts``
# reads them from ../shared/data/nuscenes-trainval-tables (tests/test_sim_randomise.py checks this copy).
# Rows: scenes, cam translation (m), cam rotation (w, x, y, z), CAM_FRONT K at 1600 x 900 (fx, fy, cx, cy),
# radar translation, radar rotation, LiDAR translation, LiDAR rotation (sensor -> ego, nuScenes records).
NUSCENES_FLEET_MOUNTS: tuple[tuple, ...] = (
    (452, (1.722, 0.0048, 1.4949), (0.5077, -0.4973, 0.4984, -0.4965), (1252.813, 1252.813, 826.588, 469.985),
     (3.412, 0.0, 0.5), (1.0, 0.0, 0.0, -0.0023), (0.9858, 0.0, 1.8402), (0.7067, -0.0153, 0.0174, -0.7071)),
    (349, (1.7008, 0.0159, 1.511), (0.4998, -0.503, 0.4998, -0.4974), (1266.417, 1266.417, 816.267, 491.507),
     (3.412, 0.0, 0.5), (1.0, 0.0, 0.0, 0.0017), (0.9437, 0.0, 1.8402), (0.7078, -0.0065, 0.0106, -0.7063)),
    (34, (1.7008, 0.0159, 1.511), (0.4998, -0.503, 0.4998, -0.4974), (1266.417, 1266.417, 816.267, 491.507),
     (3.412, 0.0, 0.5), (1.0, 0.0, 0.0, -0.0074), (0.9437, 0.0, 1.8402), (0.7078, -0.0065, 0.0106, -0.7063)),
    (15, (1.671, -0.026, 1.536), (0.5008, -0.4968, 0.4963, -0.506), (1262.809, 1262.809, 786.678, 437.989),
     (3.413, 0.0, 0.5), (1.0, 0.0, 0.0, 0.0), (0.8911, 0.0, 1.8429), (0.7044, 0.0025, -0.0013, -0.7098)),
)

APPEARANCE_KEYS = ("exposure", "gamma", "contrast", "saturation", "haze", "blur_sigma_px", "noise_std",
                   "jpeg_quality")


@dataclass(frozen=True)
class Randomisation:
    """Domain randomisation ranges (``SimConfig.randomise``); nothing changes unless ``enabled``."""

    enabled: bool = False  # master switch (--set randomise.enabled=true)
    per_frame: tuple[str, ...] = ("blur_sigma_px", "noise_std", "jpeg_quality")  # appearance keys drawn per frame
    # (the others once per vehicle); any of APPEARANCE_KEYS
    # appearance
    exposure: tuple[float, float] = (0.6, 1.1)  # image brightness gain
    gamma: tuple[float, float] = (0.8, 1.25)  # output gamma (image ** gamma: > 1 darkens the mid-tones)
    contrast: tuple[float, float] = (0.65, 1.05)  # contrast multiplier on top of the scenario's
    saturation: tuple[float, float] = (0.3, 1.0)  # colour saturation multiplier
    white_balance: float = 0.08  # per-channel gain spread (uniform +- this)
    warmth: tuple[float, float] = (-0.02, 0.08)  # colour temperature: red gain x(1 + w), blue gain x(1 - w)
    object_tint: float = 0.25  # per-object, per-channel albedo gain spread (uniform +- this)
    ground_tint: float = 0.15  # per-vehicle, per ground class and channel albedo gain spread (+- this)
    haze: tuple[float, float] = (0.35, 1.5)  # multiplier of the scenario's fog distance (lower = hazier)
    overcast_probability: float = 0.4  # chance that a vehicle drives under a grey sky without sun shadows
    blur_sigma_px: tuple[float, float] = (0.0, 0.6)  # Gaussian blur of the written image, pixels
    noise_std: tuple[float, float] = (0.004, 0.03)  # pixel noise std, fraction of full scale
    jpeg_quality: tuple[int, int] = (55, 95)  # JPEG quality of the written image
    # radar (per vehicle)
    rcs_floor_db: tuple[float, float] = (-7.0, -3.0)  # RadarConfig.rcs_floor_db, dBsm
    snr_ref_db: tuple[float, float] = (96.0, 101.0)  # RadarConfig.snr_ref_db (sensitivity), dB
    detection_threshold_db: tuple[float, float] = (11.0, 15.0)  # RadarConfig.detection_threshold_db, dB
    max_returns_per_object: tuple[int, int] = (5, 8)  # RadarConfig.max_returns_per_object (inclusive)
    azimuth_loss_db: tuple[float, float] = (1.5, 6.0)  # RadarConfig.azimuth_loss_db (edge of the near field), dB
    range_noise_m: tuple[float, float] = (0.08, 0.25)  # RadarConfig.range_noise_m, metres
    azimuth_noise_deg: tuple[float, float] = (0.15, 0.6)  # RadarConfig.azimuth_noise_deg, degrees
    rcs_noise_db: tuple[float, float] = (0.5, 2.5)  # RadarConfig.rcs_noise_db, dB
    velocity_noise_mps: tuple[float, float] = (0.05, 0.25)  # RadarConfig.velocity_noise_mps, m/s
    clutter_scale: tuple[float, float] = (0.5, 2.0)  # multiplier of the scenario's clutter rate
    clutter_rcs_mean_db: tuple[float, float] = (-4.0, 2.0)  # clutter RCS mean (std stays), dBsm
    ghost_scale: tuple[float, float] = (0.4, 2.0)  # multiplier of the scenario's ghost probability
    # mounts and intrinsics (per vehicle)
    real_mounts: bool = True  # base mounts + CAM_FRONT intrinsics drawn from NUSCENES_FLEET_MOUNTS (scene-weighted)
    focal_jitter: float = 0.01  # relative focal-length spread on top (uniform +- this)
    principal_jitter_px: float = 15.0  # principal-point spread on top at 1600 x 900 (uniform +- this), pixels

    def __post_init__(self):
        bad = [k for k in self.per_frame if k not in APPEARANCE_KEYS]
        if bad:
            raise ValueError(f"randomise.per_frame keys {bad} are not appearance keys {list(APPEARANCE_KEYS)}")
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name != "per_frame" and isinstance(v, tuple) and (len(v) != 2 or v[0] > v[1]):
                raise ValueError(f"randomise.{f.name}={list(v)} must be a range [low, high] with low <= high")
        # the radar ranges: as RadarConfig's bounds (a draw outside them would fail mid-drive)
        require_ranges(self, {
            "exposure": "(0, 10]", "gamma": "(0, 10]", "contrast": "(0, 10]", "saturation": "[0, 10]",
            "white_balance": "[0, 1]", "warmth": "[-1, 1]", "object_tint": "[0, 1]", "ground_tint": "[0, 1]",
            "haze": "[0.01, 100]", "overcast_probability": "[0, 1]", "blur_sigma_px": "[0, 100]", "noise_std": "[0, 1]",
            "jpeg_quality": "[1, 100]", "rcs_floor_db": "[-100, 100]", "snr_ref_db": "[0, 300]",
            "detection_threshold_db": "[-100, 200]", "max_returns_per_object": "[1, 1000]",
            "azimuth_loss_db": "[0, 100]", "range_noise_m": "[0, 10]", "azimuth_noise_deg": "[0, 90]",
            "rcs_noise_db": "[0, 50]", "velocity_noise_mps": "[0, 50]", "clutter_scale": "[0, 10]",
            "clutter_rcs_mean_db": "[-100, 100]", "ghost_scale": "[0, 100]", "focal_jitter": "[0, 0.5]",
            "principal_jitter_px": "[0, 500]"})


@dataclass(frozen=True)
class VehicleDraw:
    """One vehicle's randomised values (recorded in sim_vehicle.json as ``randomisation``)."""

    appearance: dict  # APPEARANCE_KEYS -> value (per-frame keys: redrawn each frame)
    white_balance: tuple[float, float, float]  # per-channel gains
    tint_seed: int  # seed of the per-object and ground tints
    overcast: bool  # grey sky, no sun shadows
    radar: dict  # RadarConfig field -> value, applied over the scenario's effective radar
    fleet_mount: int  # row of NUSCENES_FLEET_MOUNTS, -1 = the nominal design mounts
    camera_K_full: tuple[float, float, float, float] | None  # (fx, fy, cx, cy) at 1600 x 900, or None = nominal
    base_T_ego_cam: np.ndarray | None = field(default=None, repr=False)  # (4, 4) base mounts, or None = nominal
    base_T_ego_radar: np.ndarray | None = field(default=None, repr=False)
    base_T_ego_lidar: np.ndarray | None = field(default=None, repr=False)

    def to_json(self) -> dict:
        return {"appearance": self.appearance, "white_balance": list(self.white_balance), "tint_seed": self.tint_seed,
                "overcast": self.overcast,
                "radar": self.radar, "fleet_mount": self.fleet_mount,
                "camera_K_full": list(self.camera_K_full) if self.camera_K_full is not None else None}


def _u(g: np.random.Generator, r: tuple) -> float:
    return float(g.uniform(r[0], r[1]))


def _appearance(conf: Randomisation, g: np.random.Generator) -> dict:
    out = {}
    for k in APPEARANCE_KEYS:
        r = getattr(conf, k)
        out[k] = int(g.integers(r[0], r[1] + 1)) if k == "jpeg_quality" else _u(g, r)
    return out


def draw_vehicle(conf: Randomisation, scenario_radar: RadarConfig, g: np.random.Generator) -> VehicleDraw:
    """The per-vehicle draws from the generator ``g`` (one stream per vehicle). ``scenario_radar``: the
    scenario's effective radar (its clutter / ghost rates are scaled)."""
    appearance = _appearance(conf, g)
    w = _u(g, conf.warmth)
    wb = tuple(float(x) for x in (1 + g.uniform(-conf.white_balance, conf.white_balance, 3)) * (1 + w, 1.0, 1 - w))
    tint_seed = int(g.integers(1, 2**31))
    overcast = bool(g.random() < conf.overcast_probability)
    lo, hi = conf.max_returns_per_object
    radar = {
        "rcs_floor_db": _u(g, conf.rcs_floor_db), "snr_ref_db": _u(g, conf.snr_ref_db),
        "detection_threshold_db": _u(g, conf.detection_threshold_db),
        "max_returns_per_object": int(g.integers(lo, hi + 1)), "azimuth_loss_db": _u(g, conf.azimuth_loss_db),
        "range_noise_m": _u(g, conf.range_noise_m), "azimuth_noise_deg": _u(g, conf.azimuth_noise_deg),
        "rcs_noise_db": _u(g, conf.rcs_noise_db), "velocity_noise_mps": _u(g, conf.velocity_noise_mps),
        "clutter_per_sweep": scenario_radar.clutter_per_sweep * _u(g, conf.clutter_scale),
        "clutter_rcs_db": (_u(g, conf.clutter_rcs_mean_db), scenario_radar.clutter_rcs_db[1]),
        "ghost_probability": min(1.0, scenario_radar.ghost_probability * _u(g, conf.ghost_scale)),
    }
    if not conf.real_mounts:
        return VehicleDraw(appearance, wb, tint_seed, overcast, radar, -1, None)
    w = np.array([row[0] for row in NUSCENES_FLEET_MOUNTS], float)
    i = int(g.choice(len(w), p=w / w.sum()))
    _, ct, cr, (fx, fy, cx, cy), rt, rr, lt, lr = NUSCENES_FLEET_MOUNTS[i]
    f = 1 + g.uniform(-conf.focal_jitter, conf.focal_jitter)
    dc = g.uniform(-conf.principal_jitter_px, conf.principal_jitter_px, 2)
    K = (fx * f, fy * f, cx + dc[0], cy + dc[1])
    return VehicleDraw(appearance, wb, tint_seed, overcast, radar, i, tuple(float(x) for x in K),
                       pose_from_nuscenes(cr, ct), pose_from_nuscenes(rr, rt), pose_from_nuscenes(lr, lt))


def frame_appearance(conf: Randomisation, draw: VehicleDraw, g: np.random.Generator) -> dict:
    """The appearance of one frame: the vehicle's draws with the ``per_frame`` keys redrawn from ``g``."""
    if not conf.per_frame:
        return dict(draw.appearance)
    fresh = _appearance(conf, g)
    return {k: (fresh[k] if k in conf.per_frame else v) for k, v in draw.appearance.items()}


def randomised_radar(radar: RadarConfig, draw: VehicleDraw) -> RadarConfig:
    return dataclasses.replace(radar, **draw.radar)


def randomised_shading(base: ShadingConfig, conf: Randomisation, draw: VehicleDraw, appearance: dict) -> ShadingConfig:
    """The scenario's shading with a frame's randomised appearance."""
    a = appearance
    return dataclasses.replace(
        base, contrast=base.contrast * a["contrast"], fog_distance=base.fog_distance * a["haze"],
        noise_std=a["noise_std"], exposure=a["exposure"], gamma=a["gamma"], saturation=a["saturation"],
        white_balance=draw.white_balance, blur_sigma_px=a["blur_sigma_px"], object_tint=conf.object_tint,
        ground_tint=conf.ground_tint, tint_seed=draw.tint_seed, overcast=base.overcast or draw.overcast)
