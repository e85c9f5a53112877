"""Automotive radar like the Continental ARS 408-21 (nuScenes RADAR_*): a 2D scanning radar.

Measurement model (radar frame: x forward, y left, z up):
- the radar measures slant range r, azimuth az, RCS (dBsm) and radial velocity of each reflector;
- it cannot measure elevation: it writes every point as (r cos az, r sin az, 0), so a reflector at
  elevation phi lies on the vertical arc (r cos(phi) cos(az), r cos(phi) sin(az), r sin(phi)) within
  the elevation beam. This exact arc model is what the factors use.

Simulation: a grid of rays (elevation x azimuth) is cast into the world; every ray hit carries a
radar cross-section share (material reflectivity x projected area x incidence x elevation-beam gain x
Swerling-1 speckle). Hits are pooled into resolution cells per object (range x azimuth); each cell
is one candidate detection at the position of its strongest ray (that is the true reflector). Its
SNR follows the radar equation (RCS - 40 log10 r), a sigmoid gives the detection probability, the
near / far fields of view and range limits apply, each object keeps its strongest few cells, then
clutter and multipath ghosts are added, an optional soft RCS floor (``rcs_floor_db``: the real ARS 408
cluster lists hold almost nothing under -5 dBsm) thins weak points, and the sweep is capped at ``max_points``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.config import finite, require, require_ranges
from hybrid_calib.data.pcd import empty_radar_points
from hybrid_calib.sim.raycast import Primitives, cast_angular, check_pose

REAL, CLUTTER, GHOST = 0, 1, 2  # RadarSweep.kind


@dataclass(frozen=True)
class RadarConfig:
    """ARS 408-21-like radar parameters (nuScenes RADAR_FRONT defaults)."""

    near_fov_deg: float = 60.0  # near-range scan half-angle, degrees
    near_range_m: float = 70.0  # near-range scan maximum range, metres
    far_fov_deg: float = 9.0  # far-range scan half-angle, degrees
    far_range_m: float = 250.0  # far-range scan maximum range, metres
    min_range_m: float = 0.5  # closest detectable range, metres
    elevation_fov_deg: float = 14.0  # full elevation extent that can return energy, degrees
    elevation_beamwidth_deg: float = 8.0  # -3 dB full elevation beamwidth (two-way gain pattern), degrees
    ray_azimuth_step_deg: float = 0.25  # simulation ray spacing in azimuth, degrees
    ray_elevation_step_deg: float = 0.5  # simulation ray spacing in elevation, degrees
    range_cell_m: float = 0.8  # range resolution cell, metres
    azimuth_cell_deg: float = 2.5  # azimuth resolution cell, degrees
    max_returns_per_object: int = 3  # strongest cells kept per object
    max_points: int = 125  # cap on points per sweep (ARS 408 cluster list)
    range_noise_m: float = 0.12  # range noise standard deviation, metres
    azimuth_noise_deg: float = 0.3  # azimuth noise standard deviation, degrees
    position_quantisation_m: float = 0.2  # x / y written in steps of this, metres
    velocity_noise_mps: float = 0.1  # radial velocity noise standard deviation, m/s
    velocity_quantisation_mps: float = 0.25  # vx / vy written in steps of this, m/s
    rcs_noise_db: float = 1.0  # RCS noise standard deviation, dB
    rcs_quantisation_db: float = 0.5  # RCS written in steps of this, dB
    snr_ref_db: float = 92.0  # SNR of a 0 dBsm target at 1 m (radar-equation constant), dB
    detection_threshold_db: float = 13.0  # SNR at which the detection probability is half its maximum, dB
    detection_slope_db: float = 2.0  # width of the detection-probability sigmoid, dB
    max_detection_probability: float = 0.97  # detection probability of a very strong cell
    azimuth_loss_db: float = 6.0  # antenna loss at the edge of the near field of view, dB
    extra_loss_db: float = 0.0  # extra two-way propagation loss (rain), dB
    clutter_per_sweep: float = 4.0  # mean number of clutter false alarms per sweep (Poisson)
    clutter_rcs_db: tuple[float, float] = (-12.0, 3.0)  # clutter RCS mean and std, dBsm
    ghost_probability: float = 0.05  # chance a return above ghost_min_rcs_db spawns a double-bounce ghost
    ghost_min_rcs_db: float = 5.0  # minimum RCS of a return that can spawn a ghost, dBsm
    ghost_loss_db: float = 12.0  # a ghost is this much weaker than its parent, dB
    rcs_floor_db: float | None = None  # None: no floor; else points whose RCS is below it are rarely reported
    # (the ARS 408 cluster list of nuScenes holds almost nothing under -5 dBsm), dBsm
    rcs_floor_width_db: float = 1.0  # width of the soft RCS floor's sigmoid, dB

    def __post_init__(self):
        # a value no radar has (clutter_per_sweep=-3 failed every frame with numpy's "lam < 0", and the run ended
        # "wrote ... x 2 frames"): refused here, named, as a ConfigError of --set radar.KEY
        positive = ("near_fov_deg", "near_range_m", "far_fov_deg", "far_range_m", "elevation_fov_deg",
                    "elevation_beamwidth_deg", "ray_azimuth_step_deg", "ray_elevation_step_deg", "range_cell_m",
                    "azimuth_cell_deg", "max_returns_per_object", "max_points", "detection_slope_db",
                    "rcs_floor_width_db")
        nonnegative = ("min_range_m", "range_noise_m", "azimuth_noise_deg", "position_quantisation_m",
                       "velocity_noise_mps", "velocity_quantisation_mps", "rcs_noise_db", "rcs_quantisation_db",
                       "azimuth_loss_db", "extra_loss_db", "clutter_per_sweep", "ghost_loss_db")
        require(self, {**{f"0 < {n} < inf": 0 < getattr(self, n) < np.inf for n in positive},
                       **{f"0 <= {n} < inf": 0 <= getattr(self, n) < np.inf for n in nonnegative},
                       **{f"0 <= {n} <= 1": 0 <= getattr(self, n) <= 1
                          for n in ("max_detection_probability", "ghost_probability")}})
        if not self.min_range_m < min(self.near_range_m, self.far_range_m):
            raise ValueError(f"min_range_m={self.min_range_m} must be below near_range_m and far_range_m")
        if len(self.clutter_rcs_db) != 2 or not finite(*self.clutter_rcs_db) or self.clutter_rcs_db[1] < 0:
            raise ValueError(f"clutter_rcs_db={list(self.clutter_rcs_db)}: need [mean, std >= 0] in dBsm")
        # range_cell_m / azimuth_cell_deg: a resolution cell's key holds 4096 range and 512 azimuth cells (finer ones
        # merged the returns of other cells and objects)
        require_ranges(self, {
            "near_fov_deg": "(0, 180]", "near_range_m": "(0, 1000]", "far_fov_deg": "(0, 180]",
            "far_range_m": "(0, 1000]", "min_range_m": "[0, 1000)", "elevation_fov_deg": "(0, 180]",
            "elevation_beamwidth_deg": "(0, 180]", "ray_azimuth_step_deg": "[0.05, 90]",
            "ray_elevation_step_deg": "[0.05, 90]", "range_cell_m": "[0.25, 100]", "azimuth_cell_deg": "[0.75, 180]",
            "max_returns_per_object": "[1, 1000]", "max_points": "[1, 10000]",
            "range_noise_m": "[0, 10]", "azimuth_noise_deg": "[0, 90]", "position_quantisation_m": "[0.001, 10]",
            "velocity_noise_mps": "[0, 50]", "velocity_quantisation_mps": "[0.001, 10]", "rcs_noise_db": "[0, 50]",
            "rcs_quantisation_db": "[0.001, 10]", "snr_ref_db": "[0, 300]", "detection_threshold_db": "[-100, 200]",
            "detection_slope_db": "[0.01, 100]", "max_detection_probability": "[0, 1]", "azimuth_loss_db": "[0, 100]",
            "extra_loss_db": "[0, 200]", "clutter_per_sweep": "[0, 1e4]", "clutter_rcs_db": "[-100, 100]",
            "ghost_probability": "[0, 1]", "ghost_min_rcs_db": "[-100, 100]", "ghost_loss_db": "[0, 100]",
            **({"rcs_floor_db": "[-100, 100]"} if self.rcs_floor_db is not None else {}),
            "rcs_floor_width_db": "[0.01, 100]"})


@dataclass
class RadarSweep:
    """One radar sweep with its ground truth, row-aligned.

    points: (N,) ``RADAR_DTYPE`` as written to the PCD (x, y quantised, z = 0; radar frame).
    true_xyz: (N, 3) float64 true reflector positions, metres, radar frame at the sweep time
      (for a ghost: the real reflector that caused it; for clutter: the radar-plane point).
    kind: (N,) int8 REAL / CLUTTER / GHOST. object_id: (N,) int32, -1 for clutter.
    elevation: (N,) float64 radians, true elevation of the reflector seen from the radar.
    object_speed: (N,) float64 m/s, the object's ground speed (0 for static objects and clutter).
    snr_db: (N,) float64.
    """

    points: np.ndarray
    true_xyz: np.ndarray
    kind: np.ndarray
    object_id: np.ndarray
    elevation: np.ndarray
    object_speed: np.ndarray
    snr_db: np.ndarray

    def __len__(self) -> int:
        return len(self.points)


def ray_grid(conf: RadarConfig) -> tuple[np.ndarray, np.ndarray]:
    """Simulation rays: elevations (E,) and azimuths (A,) radians in the radar frame."""
    half_el = np.deg2rad(conf.elevation_fov_deg / 2)
    half_az = np.deg2rad(conf.near_fov_deg)
    el = np.arange(-half_el, half_el + 1e-9, np.deg2rad(conf.ray_elevation_step_deg))
    az = np.arange(-half_az, half_az + 1e-9, np.deg2rad(conf.ray_azimuth_step_deg))
    return el, az


def snr_db(conf: RadarConfig, rcs_db: np.ndarray, r: np.ndarray, az: np.ndarray) -> np.ndarray:
    """Radar-equation SNR (dB) of targets with RCS ``rcs_db`` (dBsm) at range r (m), azimuth az (rad)."""
    az_loss = conf.azimuth_loss_db * (az / np.deg2rad(conf.near_fov_deg)) ** 2
    return rcs_db + conf.snr_ref_db - 40 * np.log10(np.maximum(r, 0.1)) - conf.extra_loss_db - az_loss


def in_field_of_view(conf: RadarConfig, r: np.ndarray, az: np.ndarray) -> np.ndarray:
    a = np.abs(az)
    near = (r <= conf.near_range_m) & (a <= np.deg2rad(conf.near_fov_deg))
    far = (r <= conf.far_range_m) & (a <= np.deg2rad(conf.far_fov_deg))
    return (near | far) & (r >= conf.min_range_m)


def detection_probability(conf: RadarConfig, snr: np.ndarray) -> np.ndarray:
    return conf.max_detection_probability / (1 + np.exp(-(snr - conf.detection_threshold_db) / conf.detection_slope_db))


def simulate_radar_sweep(prims: Primitives, T_global_radar: np.ndarray, radar_velocity: np.ndarray,
                         conf: RadarConfig, rng: np.random.Generator,
                         radar_reflectivity: np.ndarray | None = None) -> RadarSweep:
    """Simulate one sweep.

    prims: the world at the sweep time (global frame). T_global_radar: (4, 4) radar -> global at the
    sweep time. radar_velocity: (3,) m/s, global velocity of the radar's phase centre.
    radar_reflectivity: (n_materials,) m^2/m^2 per material (default: ``world.RADAR_REFLECTIVITY``).
    """
    if radar_reflectivity is None:
        from hybrid_calib.sim.world import RADAR_REFLECTIVITY as radar_reflectivity
    T_global_radar = check_pose(T_global_radar, "T_global_radar")
    radar_velocity = np.asarray(radar_velocity, dtype=np.float64)
    if radar_velocity.shape != (3,) or not np.all(np.isfinite(radar_velocity)):
        raise ValueError(f"radar_velocity must be a finite (3,) vector in m/s, got {radar_velocity!r}")
    el_grid, az_grid = ray_grid(conf)
    reach = ((conf.near_range_m, np.deg2rad(conf.near_fov_deg)), (conf.far_range_m, np.deg2rad(conf.far_fov_deg)))
    buf, dirs = cast_angular(prims, T_global_radar, el_grid, az_grid, conf.far_range_m, reach=reach)
    R = T_global_radar[:3, :3]
    E, A = buf.t.shape
    EL = np.broadcast_to(el_grid[:, None], (E, A))
    AZ = np.broadcast_to(az_grid[None, :], (E, A))
    hit = buf.prim >= 0
    if hit.any():
        j = buf.prim[hit]
        refl = radar_reflectivity[prims.material[j]]
        r = buf.t[hit]
        az, el = AZ[hit], EL[hit]
        ok = (refl > 0) & in_field_of_view(conf, r, az)
        j, refl, r, az, el = j[ok], refl[ok], r[ok], az[ok], el[ok]
        d = dirs[hit][ok]
        n = buf.normal[hit][ok].astype(np.float64)
    else:
        j = np.zeros(0, int)
    real = _real_returns(conf, prims, j, refl if len(j) else None, r if len(j) else None, az if len(j) else None,
                         el if len(j) else None, d if len(j) else None, n if len(j) else None, rng)
    cols = {k: [v] for k, v in real.items()}
    if len(real["r"]):
        ghosts = _ghosts(conf, real, rng)
        for k, v in ghosts.items():
            cols[k].append(v)
    clutter = _clutter(conf, rng)
    for k, v in clutter.items():
        cols[k].append(v)
    c = {k: np.concatenate(v) for k, v in cols.items()}
    if conf.rcs_floor_db is not None and len(c["r"]):
        p_keep = 1 / (1 + np.exp(-(c["rcs"] - conf.rcs_floor_db) / max(conf.rcs_floor_width_db, 1e-6)))
        keep = rng.random(len(c["r"])) < p_keep
        c = {k: v[keep] for k, v in c.items()}
    if len(c["r"]) > conf.max_points:
        keep = np.argsort(-c["snr"], kind="stable")[: conf.max_points]
        c = {k: v[keep] for k, v in c.items()}
    order = np.argsort(c["r"], kind="stable")
    c = {k: v[order] for k, v in c.items()}
    return _to_sweep(conf, c, R, np.asarray(radar_velocity, float), rng)


def _real_returns(conf, prims, j, refl, r, az, el, d, n, rng) -> dict[str, np.ndarray]:
    empty = dict(r=np.zeros(0), az=np.zeros(0), el=np.zeros(0), rcs=np.zeros(0), snr=np.zeros(0),
                 kind=np.zeros(0, np.int8), obj=np.zeros(0, np.int32), v_obj=np.zeros((0, 3)))
    if len(j) == 0:
        return empty
    daz = np.deg2rad(conf.ray_azimuth_step_deg)
    delv = np.deg2rad(conf.ray_elevation_step_deg)
    cos_inc = np.abs(np.einsum("ij,ij->i", n, d))
    half_bw = np.deg2rad(conf.elevation_beamwidth_deg / 2)
    gain = 10 ** (-0.3 * (el / half_bw) ** 2)  # -3 dB at the beam edge
    w = refl * (r * r * daz * delv) * np.maximum(cos_inc, 0.05) ** 2 * gain * rng.exponential(1.0, len(j))
    obj = prims.object_id[j].astype(np.int64)
    cell = (obj * 4096 + np.floor(r / conf.range_cell_m).astype(np.int64)) * 512 + np.floor(
        (az + np.pi) / np.deg2rad(conf.azimuth_cell_deg)).astype(np.int64)
    order = np.lexsort((-w, cell))
    cell_s = cell[order]
    first = np.concatenate([[True], cell_s[1:] != cell_s[:-1]])
    starts = np.flatnonzero(first)
    sums = np.add.reduceat(w[order], starts)
    best = order[starts]  # strongest ray of each cell: the reflector
    rcs = 10 * np.log10(np.maximum(sums, 1e-6))
    snr = snr_db(conf, rcs, r[best], az[best])
    det = rng.random(len(best)) < detection_probability(conf, snr)
    best, rcs, snr = best[det], rcs[det], snr[det]
    # keep the strongest few cells of each object
    ob = obj[best]
    o2 = np.lexsort((-snr, ob))
    rank = np.arange(len(o2)) - np.searchsorted(ob[o2], ob[o2], "left")
    keep = np.sort(o2[rank < conf.max_returns_per_object])
    best, rcs, snr = best[keep], rcs[keep], snr[keep]
    return dict(r=r[best], az=az[best], el=el[best], rcs=rcs, snr=snr, kind=np.zeros(len(best), np.int8),
                obj=obj[best].astype(np.int32), v_obj=prims.velocity[j[best]])


def _ghosts(conf, real, rng) -> dict[str, np.ndarray]:
    """Double-bounce multipath: radar -> target -> ego -> target -> radar at twice the range."""
    m = (real["rcs"] >= conf.ghost_min_rcs_db) & (rng.random(len(real["r"])) < conf.ghost_probability)
    g = {k: v[m].copy() for k, v in real.items()}
    g["r"] = 2 * g["r"]
    g["rcs"] = g["rcs"] - conf.ghost_loss_db
    g["snr"] = snr_db(conf, g["rcs"], g["r"], g["az"])
    g["kind"] = np.full(len(g["r"]), 2, np.int8)
    ok = in_field_of_view(conf, g["r"], g["az"]) & (rng.random(len(g["r"])) < detection_probability(conf, g["snr"]))
    return {k: v[ok] for k, v in g.items()}


def _clutter(conf, rng) -> dict[str, np.ndarray]:
    """False alarms: stationary low-RCS points spread over the near field of view, in the radar plane."""
    k = rng.poisson(conf.clutter_per_sweep)
    r = conf.min_range_m + (conf.near_range_m - conf.min_range_m) * np.sqrt(rng.random(k))
    az = rng.uniform(-1, 1, k) * np.deg2rad(conf.near_fov_deg)
    rcs = rng.normal(conf.clutter_rcs_db[0], conf.clutter_rcs_db[1], k)
    return dict(r=r, az=az, el=np.zeros(k), rcs=rcs, snr=snr_db(conf, rcs, r, az), kind=np.ones(k, np.int8),
                obj=np.full(k, -1, np.int32), v_obj=np.zeros((k, 3)))


def _to_sweep(conf: RadarConfig, c: dict, R_global_radar: np.ndarray, v_radar: np.ndarray,
              rng: np.random.Generator) -> RadarSweep:
    n = len(c["r"])
    r, az, el = c["r"], c["az"], c["el"]
    ghost = c["kind"] == 2
    true_r = np.where(ghost, r / 2, r)
    true_xyz = np.stack([true_r * np.cos(el) * np.cos(az), true_r * np.cos(el) * np.sin(az), true_r * np.sin(el)], 1)
    # radial velocities along the true line of sight (global), absolute and relative to the radar
    u = true_xyz / np.maximum(np.linalg.norm(true_xyz, axis=1, keepdims=True), 1e-9) @ R_global_radar.T
    vr_abs = np.einsum("ij,ij->i", c["v_obj"], u)
    vr_rel = np.einsum("ij,ij->i", c["v_obj"] - v_radar, u)
    vr_abs = np.where(ghost, 2 * vr_abs, vr_abs)
    vr_rel = np.where(ghost, 2 * vr_rel, vr_rel)
    # measurement noise and quantisation
    r_m = r + rng.normal(0, conf.range_noise_m, n)
    az_m = az + rng.normal(0, np.deg2rad(conf.azimuth_noise_deg), n)
    q = conf.position_quantisation_m
    pts = empty_radar_points(n)
    pts["x"] = np.round(r_m * np.cos(az_m) / q) * q
    pts["y"] = np.round(r_m * np.sin(az_m) / q) * q
    pts["z"] = 0.0
    vq = conf.velocity_quantisation_mps
    vr_rel_m = vr_rel + rng.normal(0, conf.velocity_noise_mps, n)
    vr_abs_m = vr_abs + rng.normal(0, conf.velocity_noise_mps, n)
    pts["vx"] = np.round(vr_rel_m * np.cos(az_m) / vq) * vq
    pts["vy"] = np.round(vr_rel_m * np.sin(az_m) / vq) * vq
    pts["vx_comp"] = vr_abs_m * np.cos(az_m)
    pts["vy_comp"] = vr_abs_m * np.sin(az_m)
    rq = conf.rcs_quantisation_db
    pts["rcs"] = np.round((c["rcs"] + rng.normal(0, conf.rcs_noise_db, n)) / rq) * rq
    speed = np.linalg.norm(c["v_obj"][:, :2], axis=1)
    dyn = np.where(speed < 0.5, 1, np.where(vr_abs < 0, 2, 0))  # stationary / oncoming / moving
    dyn = np.where(c["kind"] == 1, rng.choice([1, 3], n), dyn)  # clutter: stationary (candidate)
    pts["dyn_prop"] = dyn
    pts["id"] = np.arange(n)
    pts["is_quality_valid"] = 1
    pts["ambig_state"] = 3
    pts["invalid_state"] = 0
    pts["x_rms"] = np.clip(np.round(18 + r / 60), 0, 31)
    pts["y_rms"] = np.clip(np.round(18 + r * np.deg2rad(conf.azimuth_noise_deg) * 4), 0, 31)
    pts["vx_rms"] = 17
    pts["vy_rms"] = 3
    pts["pdh0"] = np.where(c["kind"] == 0, 1, np.where(c["kind"] == 2, 2, rng.integers(3, 5, n)))
    return RadarSweep(points=pts, true_xyz=true_xyz, kind=c["kind"].astype(np.int8),
                      object_id=c["obj"].astype(np.int32), elevation=el.astype(np.float64),
                      object_speed=speed, snr_db=c["snr"])
