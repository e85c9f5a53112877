"""One vehicle's drive: its world, ego motion, true mounts, timestamps, and the per-frame simulation
of camera (RGB + ground-truth depth), radar and LiDAR."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from hybrid_calib.config import MAX_SEED, check_fields, freeze_dict_fields, merge, require_ranges, to_dict
from hybrid_calib.data.summary import MIN_MOUNT_HEIGHT_M
from hybrid_calib.seeds import sequence_rng
from hybrid_calib.sensors.camera import PinholeCamera
from hybrid_calib.sim.extrinsics import ExtrinsicChange, MountPerturbation, VehicleMounts, sample_mounts
from hybrid_calib.sim.lidar import LidarConfig, simulate_lidar_sweep
from hybrid_calib.sim.radar import RadarConfig, RadarSweep, simulate_radar_sweep
from hybrid_calib.sim.randomise import (
    Randomisation,
    VehicleDraw,
    draw_vehicle,
    frame_appearance,
    randomised_radar,
    randomised_shading,
)
from hybrid_calib.sim.raycast import cast_pinhole
from hybrid_calib.sim.render import ShadingConfig, shade
from hybrid_calib.sim.scenarios import ScenarioConfig, build_world, scenario
from hybrid_calib.sim.trajectory import EGO_START_S, EgoMotion, EgoStops
from hybrid_calib.sim.world import GROUND_LIDAR_REFLECTIVITY, World

# nuScenes CAM_FRONT intrinsics at full resolution (1600 x 900).
NUSCENES_CAM_FRONT_K = np.array([[1266.417203046554, 0.0, 816.2670197447984],
                                 [0.0, 1266.417203046554, 491.50706579294757], [0.0, 0.0, 1.0]])
BASE_TIMESTAMP_US = 1_600_000_000_000_000  # first camera timestamp of vehicle 0, microseconds


MAX_FRAME_INTERVAL_S = 10.0  # keyframes further apart: a drive of a few frames spans kilometres of world


RADAR_LAGS = ("either", "after", "before")


@dataclass(frozen=True)
class SimConfig:
    """A simulated fleet: ``vehicles`` drives of ``frames`` keyframes each in one scenario."""

    scenario: str = "urban"  # preset name (urban, highway, rain, straight)
    vehicles: int = 1  # number of vehicles (one log and one scene each)
    frames: int = 200  # keyframes per vehicle
    seed: int = 0  # master seed; every vehicle / frame derives its own
    frame_interval_s: float = 0.5  # time between keyframes (nuScenes keyframes: 2 Hz)
    radar_offset_ms: tuple[float, float] = (30.0, 50.0)  # |t_radar - t_cam| range, ms (sign: radar_lag)
    # which side of the camera's the radar keyframe lies: "either" (a random sign per frame), "after" (as on
    # nuScenes' scene-0916: the radar 34 ms after the camera on average), "before"
    radar_lag: str = "either"
    # non-keyframe radar sweeps before each keyframe sweep (0..5): nuScenes' RADAR_FRONT runs at ~13 Hz, 6-7 sweeps
    # per 0.5 s keyframe interval; the mount monitor and the lever arm pair them (calib.ego_doppler)
    radar_sweeps_per_frame: int = 5
    radar_sweep_period_ms: float = 1000.0 / 13.0  # radar cycle time (ARS 408: ~13 Hz), ms
    lidar_offset_ms: float = 5.0  # |t_lidar - t_cam| at most, ms
    image_scale: float = 0.5  # camera = nuScenes CAM_FRONT (1600x900) scaled by this
    jpeg_quality: int = 92  # JPEG quality of the camera images
    camera_max_range_m: float = 500.0  # farthest rendered surface (depth 0 beyond), metres
    extrinsic_change: ExtrinsicChange = ExtrinsicChange()  # radar mount movement during each drive
    mounts: MountPerturbation = MountPerturbation()  # spread of the true mounts around the nominal
    radar: RadarConfig = RadarConfig()  # radar model (the scenario sets its weather fields)
    lidar: LidarConfig = LidarConfig()  # LiDAR model
    randomise: Randomisation = Randomisation()  # domain randomisation (off unless randomise.enabled=true)
    stops: EgoStops = EgoStops()  # the ego's stops during each drive, as at a red light (none unless stops.count > 0)
    # ScenarioConfig fields over the preset's, e.g. {"ego_speed": 5.0, "parked_per_100m": 8.0}: --set world.ego_speed=5
    world: dict = field(default_factory=dict)

    def __post_init__(self):
        check_fields(self)  # the types first: SimConfig(frames="20") was a bare TypeError below (probe 51)
        freeze_dict_fields(self)  # world: read-only as the rest
        scenario(self.scenario)  # validates the name
        _ = self.scenario_config  # ConfigError naming a bad world.KEY
        # first (the sweeps' message below blamed them for a 0 s interval); 1e6 s built a world growing ~110 MB/s
        if not 0.05 <= self.frame_interval_s <= MAX_FRAME_INTERVAL_S:
            raise ValueError(f"frame_interval_s={self.frame_interval_s} is outside 0.05..{MAX_FRAME_INTERVAL_S:g} s "
                             "(nuScenes keyframes are 0.5 s apart; the world is built for the whole drive)")
        if self.vehicles < 1 or self.frames < 1:
            raise ValueError(f"need at least one vehicle and one frame, got vehicles={self.vehicles} "
                             f"frames={self.frames}")
        self.stops.windows(self.frames * self.frame_interval_s)  # ValueError naming the options when they do not fit
        # 0.01: a 16x9 image, the smallest that renders; 2: 3200x1800, about 16 s a frame (4 was accepted at 65 s a
        # frame: the default demo would have run for hours, probe 71)
        if not 0.01 <= self.image_scale <= 2.0:
            raise ValueError(f"image_scale={self.image_scale} is outside 0.01..2 (the camera is nuScenes CAM_FRONT, "
                             "1600x900, scaled by it; e.g. 0.125 for a quick test)")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality={self.jpeg_quality}; valid: 1..100")
        if not 0 <= self.seed < MAX_SEED:  # numpy's generators take non-negative seeds only; the bound is --seed's
            raise ValueError(f"seed={self.seed}; must be in 0..2**63-1 (--seed / --set seed)")
        # frames: the world is built for the whole drive (~1.5 s and ~2 MB per km of urban road); radar_sweep_period_ms:
        # sweeps are jittered by +-1 ms, so shorter periods reorder them; camera_max_range_m: the depth PNGs hold
        # uint16 centimetres (farther depths were clipped to 655.35 m without a word)
        require_ranges(self, {"vehicles": "[1, 1e4]", "frames": "[1, 1e5]", "frame_interval_s": "[0.05, 10]",
                              "radar_offset_ms": "[0, 1000]", "radar_sweeps_per_frame": "[0, 1000]",
                              "radar_sweep_period_ms": "[2, 1000]", "lidar_offset_ms": "[0, 1000]",
                              "image_scale": "[0.01, 2]", "jpeg_quality": "[1, 100]",
                              "camera_max_range_m": "(0, 655]"})
        if self.radar_lag not in RADAR_LAGS:
            raise ValueError(f"radar_lag={self.radar_lag!r}; valid: {', '.join(RADAR_LAGS)}")
        if not self.radar_offset_ms[0] <= self.radar_offset_ms[1]:  # an internal error in the draw (probe 79)
            raise ValueError(f"radar_offset_ms={list(self.radar_offset_ms)}: a range [low, high] with low <= high, ms")
        span_ms = self.radar_sweeps_per_frame * (self.radar_sweep_period_ms + 1.0) + 2 * self.radar_offset_ms[1]
        if self.radar_sweeps_per_frame < 0 or span_ms >= 1000 * self.frame_interval_s:
            raise ValueError(f"radar_sweeps_per_frame={self.radar_sweeps_per_frame} sweeps of "
                             f"{self.radar_sweep_period_ms:.1f} ms do not fit between keyframes "
                             f"{self.frame_interval_s} s apart; use fewer")
        try:  # radar with the scenario's weather (its extra loss added) and the most randomised clutter must be valid
            r = self.effective_radar
            if self.randomise.enabled:
                dataclasses.replace(r, clutter_per_sweep=r.clutter_per_sweep * self.randomise.clutter_scale[1])
        except ValueError as e:
            extra = " and the largest randomise.clutter_scale" if self.randomise.enabled else ""
            raise ValueError(f"radar with the {self.scenario} scenario's weather{extra}: {e}") from None

    @cached_property
    def scenario_config(self) -> ScenarioConfig:
        """The preset ``scenario`` with ``world`` over it (probe 48: nothing of a preset could be set from the command
        line, and ``--set scenario.ego_speed=5`` beside ``--scenario urban`` rendered the preset's 9 m/s)."""
        preset = scenario(self.scenario)
        if not self.world:
            return preset
        if "name" in self.world:  # the preset is --scenario's; a name of its own was accepted and did nothing
            raise ValueError("world.name: the preset is chosen with --scenario (or --set scenario=NAME); world.KEY "
                             "sets its other fields")
        return merge(ScenarioConfig, {**to_dict(preset), **self.world}, "world.")

    @property
    def effective_radar(self) -> RadarConfig:
        """The radar config with the scenario's weather applied: its extra loss is added, and its clutter
        rate and ghost probability are used unless ``radar`` sets them away from the defaults."""
        s, default = self.scenario_config, RadarConfig()

        def pick(name: str, scenario_value: float) -> float:
            own = getattr(self.radar, name)
            return own if own != getattr(default, name) else scenario_value

        return dataclasses.replace(self.radar, extra_loss_db=self.radar.extra_loss_db + s.radar_extra_loss_db,
                                   clutter_per_sweep=pick("clutter_per_sweep", s.radar_clutter_per_sweep),
                                   ghost_probability=pick("ghost_probability", s.radar_ghost_probability))

    @property
    def camera(self) -> PinholeCamera:
        return PinholeCamera.from_K(NUSCENES_CAM_FRONT_K, 1600, 900).scaled(self.image_scale)


def vehicle_mounts(conf: SimConfig, vehicle: int) -> tuple[VehicleDraw | None, tuple | None, VehicleMounts]:
    """Vehicle ``vehicle``'s randomisation draws (None when off), base mounts (T_ego_cam, T_ego_radar,
    T_ego_lidar) drawn from the real fleet (None: the nominal ones) and true + factory mounts; cheap
    (no world is built), so mount statistics of many vehicles need no rendering.

    The randomisation has its own streams (7: per vehicle, 8: per frame), so turning it off leaves every
    other draw as it was."""
    c = conf
    draw = (draw_vehicle(c.randomise, c.effective_radar, sequence_rng(c.seed, vehicle, 7)) if c.randomise.enabled
            else None)
    base = (draw.base_T_ego_cam, draw.base_T_ego_radar, draw.base_T_ego_lidar) if (
        draw is not None and draw.base_T_ego_cam is not None) else None
    return draw, base, sample_mounts(sequence_rng(c.seed, vehicle, 2), c.mounts, sequence_rng(c.seed, vehicle, 5), base)


# where a sensor can sit on a car, ego axes (x forward from the rear axle, y left, z up from the ground), metres: the
# nominal mounts lie well inside (radar x 3.4, camera 1.7 / z 1.5, LiDAR z 1.8)
CAR_BOX_M = ((-2.0, 6.0), (-1.5, 1.5), (MIN_MOUNT_HEIGHT_M, 4.0))


def check_mounts(conf: SimConfig) -> None:
    """``ConfigError`` naming the vehicle, the sensor and the option when a drawn mount (or the radar at the end of
    ``extrinsic_change``) lies outside ``CAR_BOX_M``: under the road the ray caster still saw a scene and the root was
    written as if valid (probe 34: ``mounts.radar_translation_m=5``, radar 3.6 m below), beside the car it floated
    (probe 36: 2.8 m to the side on the default seed)."""
    from hybrid_calib.config import ConfigError

    for v in range(conf.vehicles):
        m = vehicle_mounts(conf, v)[2]
        end = m.radar_at(conf.extrinsic_change, conf.frames - 1, conf.frames)
        for name, T, option in (("camera", m.T_ego_cam, "mounts.camera_translation_m"),
                                ("radar", m.T_ego_radar, "mounts.radar_translation_m"),
                                ("LiDAR", m.T_ego_lidar, "mounts.lidar_translation_m"),
                                ("radar at the drive's last frame", end, "extrinsic_change.translation_m")):
            t = np.asarray(T, np.float64)[:3, 3]
            out = [f"{'xyz'[i]} {t[i]:+.2f} m (allowed {lo:g} .. {hi:g})" for i, (lo, hi) in enumerate(CAR_BOX_M)
                   if not lo <= t[i] <= hi]
            if out:
                raise ConfigError(f"vehicle {v}'s {name} would sit outside a car ({'; '.join(out)}, ego axes: x "
                                  "forward from the rear axle, z up from the road) with "
                                  f"{option} as given; give a smaller {option}" + (
                                      " (a change in the radar's own axes: z is up)" if option.startswith("extrinsic")
                                      else " (the spread is per axis, the vertical one included)"))


def vehicle_camera(conf: SimConfig, draw: VehicleDraw | None) -> PinholeCamera:
    """A vehicle's camera: ``SimConfig.camera``, or with randomised real mounts the drawn CAM_FRONT
    intrinsics (1600 x 900 scaled by ``image_scale``)."""
    if draw is None or draw.camera_K_full is None:
        return conf.camera
    fx, fy, cx, cy = draw.camera_K_full
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    return PinholeCamera.from_K(K, 1600, 900).scaled(conf.image_scale)


@dataclass
class FrameTimes:
    """Timestamps of frame k, microseconds, and the same in seconds since the drive's start."""

    camera_us: int
    radar_us: int
    lidar_us: int
    radar_sweeps_us: tuple[int, ...] = ()  # earlier non-keyframe radar sweeps, oldest first

    def seconds(self, base_us: int) -> tuple[float, float, float]:
        return tuple((x - base_us) * 1e-6 for x in (self.camera_us, self.radar_us, self.lidar_us))


@dataclass
class FrameSim:
    """Everything simulated for one keyframe (see ``VehicleDrive.simulate_frame``)."""

    index: int
    times: FrameTimes
    image: np.ndarray  # (H, W, 3) uint8 RGB
    depth: np.ndarray  # (H, W) float32 metres, camera z (0 = no surface)
    radar: RadarSweep  # radar frame at t_radar
    lidar: np.ndarray  # (N, 5) float32, LiDAR frame at t_lidar
    T_global_ego_cam: np.ndarray  # ego pose at t_cam
    T_global_ego_radar: np.ndarray  # ego pose at t_radar
    T_global_ego_lidar: np.ndarray  # ego pose at t_lidar
    T_ego_radar: np.ndarray  # the radar mount at this frame
    radar_sweeps: list[tuple[int, RadarSweep, np.ndarray]] = field(default_factory=list)
    # earlier non-keyframe sweeps: (timestamp us, sweep, T_global_ego at that time), oldest first


@dataclass
class VehicleDrive:
    """Vehicle ``vehicle`` of a fleet simulation: deterministic for (conf.seed, vehicle)."""

    conf: SimConfig
    vehicle: int
    world: World = field(init=False)
    ego: EgoMotion = field(init=False)
    mounts: VehicleMounts = field(init=False)

    def __post_init__(self):
        c, s = self.conf, self.conf.scenario_config
        duration = c.frames * c.frame_interval_s + 1.0
        drive_len = s.ego_speed * (1 + s.ego_speed_variation) * duration
        self.world = build_world(s, int(sequence_rng(c.seed, self.vehicle, 1).integers(2**31)),
                                 EGO_START_S + drive_len + 400.0)
        lane = self.world.layout.lane_centre(self.world.layout.lanes_per_direction - 1)
        self.ego = EgoMotion(self.world.path, lane, s.ego_speed, s.ego_speed_variation,
                             stops=c.stops.windows(c.frames * c.frame_interval_s))
        self.draw, self.base_mounts, self.mounts = vehicle_mounts(c, self.vehicle)
        self.base_us = BASE_TIMESTAMP_US + self.vehicle * 10_000_000_000

    @cached_property
    def name(self) -> str:
        return f"sim-veh-{self.vehicle:03d}"

    def times(self, k: int) -> FrameTimes:
        c = self.conf
        g = sequence_rng(c.seed, self.vehicle, 3, k)
        cam = self.base_us + int(round(k * c.frame_interval_s * 1e6))
        drawn = g.choice([-1, 1])  # whatever the lag: the later draws stay those of "either"
        sign = {"either": drawn, "after": 1, "before": -1}[c.radar_lag]
        radar = cam + int(round(sign * g.uniform(*c.radar_offset_ms) * 1e3))
        lidar = cam + int(round(g.uniform(-c.lidar_offset_ms, c.lidar_offset_ms) * 1e3))
        n = c.radar_sweeps_per_frame
        period_us = c.radar_sweep_period_ms * 1e3
        sweeps = tuple(radar - int(round(j * period_us + g.uniform(-1000, 1000))) for j in range(n, 0, -1))
        return FrameTimes(cam, radar, lidar, sweeps)

    def T_ego_radar(self, k: int) -> np.ndarray:
        return self.mounts.radar_at(self.conf.extrinsic_change, k, self.conf.frames)

    @cached_property
    def camera(self) -> PinholeCamera:
        """This vehicle's camera (``vehicle_camera``)."""
        return vehicle_camera(self.conf, self.draw)

    @cached_property
    def radar_config(self) -> RadarConfig:
        """This vehicle's radar: the scenario's effective radar, randomised when enabled."""
        r = self.conf.effective_radar
        return r if self.draw is None else randomised_radar(r, self.draw)

    def appearance(self, k: int) -> dict | None:
        """Frame k's randomised appearance (``randomise.APPEARANCE_KEYS``), None when randomisation is off."""
        if self.draw is None:
            return None
        return frame_appearance(self.conf.randomise, self.draw, sequence_rng(self.conf.seed, self.vehicle, 8, k))

    def jpeg_quality(self, k: int) -> int:
        a = self.appearance(k)
        return self.conf.jpeg_quality if a is None else a["jpeg_quality"]

    def shading(self, k: int = 0) -> ShadingConfig:
        s = self.conf.scenario_config
        base = ShadingConfig(contrast=s.image_contrast, fog_distance=s.fog_distance, rain=s.rain)
        a = self.appearance(k)
        return base if a is None else randomised_shading(base, self.conf.randomise, self.draw, a)

    def simulate_frame(self, k: int, radar: RadarConfig | None = None) -> FrameSim:
        """Render and simulate keyframe k (all sensors)."""
        c = self.conf
        g = sequence_rng(c.seed, self.vehicle, 4, k)
        times = self.times(k)
        t_cam, t_radar, t_lidar = times.seconds(self.base_us)
        Tge_cam, Tge_radar, Tge_lidar = (self.ego.T_global_ego(t) for t in (t_cam, t_radar, t_lidar))
        image, depth = self.render_camera(Tge_cam @ self.mounts.T_ego_cam, t_cam, g, self.shading(k))
        T_ego_radar = self.T_ego_radar(k)
        radar = radar or self.radar_config
        sweep = self.simulate_radar(Tge_radar, T_ego_radar, t_radar, radar, g)
        lidar = self.simulate_lidar(Tge_lidar @ self.mounts.T_ego_lidar, t_lidar, g)
        extra = []
        for us in times.radar_sweeps_us:
            t = (us - self.base_us) * 1e-6
            Tge = self.ego.T_global_ego(t)
            extra.append((us, self.simulate_radar(Tge, T_ego_radar, t, radar, g), Tge))
        return FrameSim(k, times, image, depth, sweep, lidar, Tge_cam, Tge_radar, Tge_lidar, T_ego_radar, extra)

    def simulate_radar(self, T_global_ego: np.ndarray, T_ego_radar: np.ndarray, t: float, radar: RadarConfig,
                       g: np.random.Generator) -> RadarSweep:
        """One radar sweep at time t with the ego at ``T_global_ego`` and the radar mounted at ``T_ego_radar``."""
        v_radar = self.ego.point_velocity(t, T_ego_radar[:3, 3])
        T_global_radar = T_global_ego @ T_ego_radar
        prims = self.world.primitives_at(t, T_global_radar[:3, 3], radar.far_range_m)
        return simulate_radar_sweep(prims, T_global_radar, v_radar, radar, g)

    def render_camera(self, T_global_cam: np.ndarray, t: float, g: np.random.Generator,
                      shading: ShadingConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
        """RGB (H, W, 3) uint8 and depth (H, W) float32 metres (camera z, 0 = none) at time t
        (``shading``: default ``self.shading()``)."""
        cam = self.camera
        rays = _camera_rays(cam)
        prims = self.world.primitives_at(t, T_global_cam[:3, 3], self.conf.camera_max_range_m)
        buf, dirs = cast_pinhole(prims, T_global_cam, rays, cam.K, self.conf.camera_max_range_m)
        image = shade(self.world, prims, buf, dirs, T_global_cam[:3, 3], shading or self.shading(), g)
        depth = np.where(np.isfinite(buf.t), buf.t * rays[..., 2], 0.0).astype(np.float32)
        return image, depth

    def simulate_lidar(self, T_global_lidar: np.ndarray, t: float, g: np.random.Generator) -> np.ndarray:
        def ground_refl(xy):
            return GROUND_LIDAR_REFLECTIVITY[self.world.ground_class(xy)[0]]

        prims = self.world.primitives_at(t, T_global_lidar[:3, 3], self.conf.lidar.max_range_m)
        return simulate_lidar_sweep(prims, T_global_lidar, self.conf.lidar, g, ground_refl)


_RAYS: dict[PinholeCamera, np.ndarray] = {}


def _camera_rays(cam: PinholeCamera) -> np.ndarray:
    if cam not in _RAYS:
        _RAYS[cam] = cam.rays()
    return _RAYS[cam]
