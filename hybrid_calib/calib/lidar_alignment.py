"""The radar's lateral and forward offsets from the LiDAR: radar ranges against the first LiDAR surface in
each beam.

Why. The network does not correct translation (docs/benchmarks.md, "Why translation is not learned")
and its radar-pixel rows are too coarse to (the hybrid's measurement model): the hybrid's camera-x
translation error stayed at the start's level (8 cm from R1 starts, ~40 cm from R2). Where the
vehicle has a LiDAR with a known LiDAR-camera extrinsic (the tables; the same extrinsic the
``lidar-densified`` depth the network sees already rests on), the radar's own detections locate it
in the LiDAR's scene: a 2D radar's detection at range ``r`` and azimuth ``a`` lies on the first
surface the LiDAR sees along that beam, so the offset of the radar's origin in its own x-y plane is
what lines the two up. Only detections of the stationary world are used (``stationary``: the radar's own
Doppler velocity of the frame, ``sensors.radar_velocity.stationary``): moving traffic is displaced between
the LiDAR's and the radar's instants, and on highways it made the forward offset tens of centimetres wrong.

The model (radar frame of the current estimate ``X = T_cam_radar``; per frame ``f`` the time-aware
extrinsic is ``T_f = A_f X`` with ``A_f = T_cam_radar(frame) inv(T_cam_radar_static)`` from the
tables, which cancels the mount). LiDAR points ``p`` (LiDAR frame) go to the radar frame by
``inv(A_f X Exp([0, 0, 0, dx, dy, 0])) T_cam_lidar p``; points near the ground or above the radar's
view are dropped (``ground_m``, ``top_m`` above the road, whose height in the *ego* frame the frame's own LiDAR
gives, ``ground_level``: from the LiDAR's mount alone, so an error of the radar's tilt cannot let the ground into the
band, and wherever a root puts its ego origin; probe 143: 0.5 m under the road, the band held no surface and the
step read "0 radar detections match"). Each radar detection is matched to
the nearest-range LiDAR point within ``+-beam_deg`` of its azimuth (the first surface), kept when
within ``gate`` metres, and gives the residual ``e = r - m - b`` with ``d e / d [dx, dy, b] = [u, -1]``
(``u``: the matched point's unit direction in the radar plane; ``b``: a common range offset, the
depth of the radar's reflections behind the LiDAR's first surface). Gauss-Newton with Huber weights
re-associates at every iteration while the gate shrinks (``gates_m``); the fit is run ``passes`` times, each
from the offset the last one found (one pass from a start 0.5 m off stops short of it: measured on the
validation drives, docs/benchmarks.md).

What it measures and what it does not (docs/benchmarks.md "The radar's lateral offset from the
LiDAR"): the lateral offset ``dy`` to ~2 cm whatever the start (up to 50 cm off). The forward offset
``dx`` is separated from ``b`` only by the spread of the detections' azimuths (``d e / d dx = cos a``,
``d e / d b = -1``), and a reflection depth or a first-surface bias that changes with azimuth (guard rails
seen at grazing angles) reads as ``dx``: measured on validation drives its error is 3-5 cm on urban and
rainy drives and 7-9 cm on highways, with a cluster-robust std of 3-5 cm. So its variance gets a
drive-common term ``systematic_x_m`` set by the worst validation scenario (the highways'), and it is folded only
when its std is below ``max_std_x_m`` and the range offset ``|b|`` inside ``max_range_offset_m``: the
simulator's reflections lie 0-0.23 m behind the LiDAR's surfaces (where dx was validated), the real radar's
of scene-0916 0.53 m, and there dx says the tables' radar is 40 cm off, which no other measurement of that
scene supports (the Doppler's forward offsets there: within 1-2 sigma of the tables). Without ``b`` in the
model a one-sided scene turns the range offset into a lateral one (scene-0916: ``dy`` -19 cm at the tables'
extrinsic without ``b``, -5 +- 4 cm with it). Its covariance is cluster-robust (sandwich over frames: one
frame's residuals share the scene) plus ``systematic_m`` (dy) and ``systematic_x_m`` (dx), fitted on
validation drives, for what is common to a drive. ``dy`` and ``dx`` are fitted at the estimate's rotation:
``coupling`` / ``coupling_x`` (central differences of the whole fit, ``coupling_deg``) say how they move
with that rotation.

``apply_offsets`` folds ``dy`` (and ``dx`` when it is trusted) into an estimate as measurements of
``xi[4] - coupling @ xi[:3]`` and ``xi[3] - coupling_x @ xi[:3]`` of the right perturbation ``xi`` (one
Kalman update of the 6x6 covariance, ``[rotation, translation]`` right tangent, with the fit's 2x2
covariance): the estimate's rotation uncertainty widens them, and correlated axes move with them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from factors.robust import weight
from hybrid_calib.calib.covariance import fold_linear
from hybrid_calib.config import require, require_ranges
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import se3_exp, se3_inverse
from hybrid_calib.metrics import mad_scale
from hybrid_calib.sensors.ground import ground_level
from hybrid_calib.sensors.radar_velocity import RadarVelocityConfig, estimate_velocity, stationary
from hybrid_calib.words import above

DEFAULT_VELOCITY = RadarVelocityConfig()  # the Doppler fit and stationary band when the caller gives none
# what to check when the LiDAR and the loop disagree: the LiDAR-camera extrinsic is T_cam_ego T_ego_lidar, two records
# (probe 52: a camera record 1.28 deg off moved the LiDAR's lateral reading 60 cm, and the words named the LiDAR alone)
CHECK_RECORDS = "check the LiDAR's and the camera's records in calibrated_sensor.json"
RADAR_X, RADAR_Y = 3, 4  # indices of the radar-x / radar-y translation in the right tangent [phi (3), rho (3)]


@dataclass(frozen=True)
class LidarAlignConfig:
    enabled: bool = True  # hybrid: fold the LiDAR's offsets into the final estimate when the frames have LiDAR
    forward: bool = True  # also fold the forward offset dx (when its std is below max_std_x_m); off: dy alone
    stationary: bool = True  # only the detections the frame's Doppler calls stationary (moving traffic is displaced)
    beam_deg: float = 0.5  # half-width of a radar detection's beam in azimuth, deg (the radar's ~0.3 deg noise)
    ground_m: float = 0.3  # LiDAR points lower than this above the road (``ground_level``) are dropped, m
    top_m: float = 3.5  # ... and higher than this, m
    min_forward_m: float = 0.5  # LiDAR points less far ahead of the radar are dropped, m
    gates_m: tuple[float, ...] = (1.5, 1.0, 0.7, 0.5, 0.5, 0.5, 0.5, 0.5)  # match gate per iteration, m
    huber: float = 1.345  # Huber threshold, in robust residual scales
    min_rows: int = 100  # fewer matched detections (all frames): no alignment (a straight road: ~1 per frame)
    min_frames: int = 3  # fewer frames with LiDAR: no alignment
    max_frames: int = 60  # frames used at most (evenly spaced over the drive)
    systematic_m: float = 0.020  # drive-common error of dy, m (benchmarks/lidar_alignment.py; validation drives)
    # drive-common error of dx, m: the worst validation scenario's (highway: 5.6 cm on the 30-frame drives, 9.1 cm
    # on the 200-frame ones; the same benchmark and drives)
    systematic_x_m: float = 0.09
    max_std_m: float = 0.10  # an alignment whose dy is less certain than this is not applied (reported only), m
    max_std_x_m: float = 0.10  # a dx less certain than this is not folded (dy still is), m ...
    # ... unless its std is at most this fraction of the loop's own std on the radar's forward axis: folded, it at
    # least halves the loop's variance there, and its std is honest to conservative where it was validated (NEES
    # 0.45-0.58: docs/benchmarks.md). Probe 53: from R2 starts on urban and rain the loop ended 50-91 cm forward at a
    # ~70 cm std while the LiDAR read within 5 cm of the truth at 10.0-10.9 cm, refused by the 10 cm cap alone; 0: never
    informative_x: float = 1.0
    max_range_offset_m: float = 0.30  # |b| beyond this: dx is not folded (reflections deep behind surfaces), m
    passes: int = 3  # the fit re-run from the offsets the previous pass found
    range_bias: bool = True  # fit a common range offset (reflection depth): a one-sided scene cannot make it dy
    coupling_deg: float = 0.5  # step of the central differences of dy, dx against the rotation, deg (0: none)
    # dy farther from the loop's estimate than this many stds of their difference: not applied (0: never refused,
    # the default). Off because the two cases cannot be told apart: a wrong LiDAR-camera table (the LiDAR wrong)
    # and a radar far off its tables with an over-confident loop (the LiDAR right: a probe's 80 cm table error
    # read 6.2 stds, the real scene up to 3.5); the innovation is recorded and said instead (``describe``)
    max_innovation: float = 0.0
    far_innovation: float = 4.0  # beyond this many stds (dy, or a folded dx) the two disagree: said, that std widened

    def __post_init__(self):
        require(self, {
            "beam_deg > 0": self.beam_deg > 0, "top_m > ground_m": self.top_m > self.ground_m,
            "min_rows >= 3": self.min_rows >= 3, "min_frames >= 1": self.min_frames >= 1,
            "max_frames >= min_frames": self.max_frames >= self.min_frames,
            "gates_m positive": bool(self.gates_m) and min(self.gates_m) > 0, "huber > 0": self.huber > 0,
            "systematic_m >= 0": self.systematic_m >= 0, "max_std_m > 0": self.max_std_m > 0,
            "systematic_x_m >= 0": self.systematic_x_m >= 0, "max_std_x_m > 0": self.max_std_x_m > 0,
            "0 <= informative_x <= 1": 0 <= self.informative_x <= 1,
            "max_range_offset_m > 0": self.max_range_offset_m > 0,
            "passes >= 1": self.passes >= 1, "coupling_deg >= 0": self.coupling_deg >= 0,
            "max_innovation >= 0": self.max_innovation >= 0, "far_innovation > 0": self.far_innovation > 0})
        require_ranges(self, {"beam_deg": "(0, 45]", "ground_m": "[-100, 100]", "top_m": "[-100, 100]",
                              "min_forward_m": "[0, 1000]", "gates_m": "(0, 100]", "huber": "(0, 100]",
                              "min_rows": "[3, 1e9]", "min_frames": "[1, 1e9]", "max_frames": "[1, 1e9]",
                              "systematic_m": "[0, 10]", "systematic_x_m": "[0, 10]", "max_std_m": "(0, 100]",
                              "max_std_x_m": "(0, 100]", "max_range_offset_m": "(0, 100]", "passes": "[1, 100]",
                              "coupling_deg": "[0, 10]", "max_innovation": "[0, 1000]",
                              "far_innovation": "(0, 1000]"})

    def far(self, z: float) -> bool:
        """Whether an innovation ``z`` (stds, either sign) lies beyond ``far_innovation``: the LiDAR and the loop
        disagree, the lateral std is widened to cover both and the line says so."""
        return abs(z) > self.far_innovation


@dataclass(frozen=True)
class LidarFrame:
    """One frame's inputs. lidar: (M, 3) metres, LiDAR frame, ground and tall points already dropped.
    T_cam_lidar: (4, 4). A: (4, 4) ``T_cam_radar(frame) inv(T_cam_radar_static)`` (tables). radar_xy:
    (N, 2) metres, radar frame (moving detections already dropped with ``stationary``). frame_id: the radar
    sample_data token. moving: detections dropped as moving."""

    lidar: np.ndarray
    T_cam_lidar: np.ndarray
    A: np.ndarray
    radar_xy: np.ndarray
    frame_id: str
    moving: int = 0


@dataclass(frozen=True)
class LidarAlignment:
    """delta: (3,) [dx, dy, b] metres: the radar-x / radar-y translation of the right perturbation of the
    estimate it was measured at, and the common range offset ``b`` (0 when not fitted). cov: (3, 3) m^2
    (cluster-robust + ``systematic_x_m^2`` on dx and ``systematic_m^2`` on dy). rows / frames: matched
    detections and frames. scale: the residuals' robust scale, m. iterations: Gauss-Newton steps (all
    passes). coupling / coupling_x: (3,) m/rad, ``d dy / d phi`` and ``d dx / d phi`` for a right rotation
    ``phi`` of the estimate it was measured at (zeros: not computed): ``dy`` measures ``xi[4] - coupling @
    xi[:3]`` and ``dx`` ``xi[3] - coupling_x @ xi[:3]`` of the estimate's error ``xi``. spread / spread_x: (3,)
    m/rad, half the difference of the two one-sided slopes behind each coupling: how far the fit is from linear in
    the rotation (a re-association that jumps on one side); ``apply_offsets`` counts it as noise. moving: detections
    left out as moving."""

    delta: np.ndarray
    cov: np.ndarray
    rows: int
    frames: int
    scale: float
    iterations: int
    coupling: np.ndarray = field(default_factory=lambda: np.zeros(3))
    coupling_x: np.ndarray = field(default_factory=lambda: np.zeros(3))
    moving: int = 0
    spread: np.ndarray = field(default_factory=lambda: np.zeros(3))
    spread_x: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def dy_std(self) -> float:
        return float(np.sqrt(self.cov[1, 1]))

    @property
    def dx_std(self) -> float:
        return float(np.sqrt(self.cov[0, 0]))

    def record(self, applied: bool, why: str = "", forward: bool = False, forward_why: str = "",
               innovation: float | None = None, innovation_x: float | None = None) -> dict:
        """The result's ``lidar`` block (plain JSON): ``applied`` (dy folded in), ``forward_applied`` (dx too),
        and the reasons when not; ``innovation_sigma`` / ``innovation_x_sigma``: dy / dx against the loop's estimate
        in stds (``innovation``)."""
        return {"applied": applied, "dy_m": float(self.delta[1]), "dy_std_m": self.dy_std,
                **({"innovation_sigma": float(innovation)} if innovation is not None else {}),
                **({"innovation_x_sigma": float(innovation_x)} if innovation_x is not None else {}),
                "dx_m": float(self.delta[0]), "dx_std_m": self.dx_std, "forward_applied": bool(applied and forward),
                "range_offset_m": float(self.delta[2]),
                "coupling_m_per_rad": [float(c) for c in self.coupling],
                "coupling_x_m_per_rad": [float(c) for c in self.coupling_x],
                "coupling_spread_m_per_rad": [float(c) for c in self.spread],
                "coupling_x_spread_m_per_rad": [float(c) for c in self.spread_x], "rows": self.rows,
                "frames": self.frames, "moving_dropped": self.moving, "scale_m": self.scale,
                **({"note": why} if why else {}), **({"forward_note": forward_why} if forward_why else {})}


def lidar_frame(frame, conf: LidarAlignConfig = LidarAlignConfig(), velocity: tuple | None = None,
                velocity_conf: RadarVelocityConfig = DEFAULT_VELOCITY) -> LidarFrame | None:
    """The alignment's inputs from a ``RadarCameraFrame`` loaded with its LiDAR, or None when it has no
    LiDAR, no ego mount of the camera or no radar detection. With ``conf.stationary`` the detections the
    frame's Doppler velocity calls moving are dropped; a frame whose velocity cannot be told (no velocity
    fields, too few stationary detections) keeps them all. velocity: the frame's ``(RadarVelocity | None,
    why)`` when the caller has it (the hybrid's motion source), else ``estimate_velocity`` with
    ``velocity_conf`` (whose inlier band also tells the stationary detections)."""
    if frame.lidar_points is None or frame.T_cam_lidar is None or not len(frame.radar_points):
        return None
    T_ego_cam = frame.extras.get("T_ego_cam")
    static = frame.extras.get("T_cam_radar_static")
    if T_ego_cam is None or static is None:
        return None
    L = np.asarray(frame.lidar_points, np.float64)[:, :3]
    T_cam_lidar = np.asarray(frame.T_cam_lidar, np.float64)
    T_ego_lidar = np.asarray(T_ego_cam, np.float64) @ T_cam_lidar
    height = L @ T_ego_lidar[2, :3] + T_ego_lidar[2, 3]
    height = height - ground_level(height, np.hypot(L @ T_ego_lidar[0, :3], L @ T_ego_lidar[1, :3]))
    keep = np.isfinite(L).all(axis=1) & (height > conf.ground_m) & (height < conf.top_m)
    A = np.asarray(frame.T_cam_radar, np.float64) @ se3_inverse(np.asarray(static, np.float64))
    radar = np.asarray(frame.radar_points, np.float64)
    moving = 0
    if conf.stationary:
        v, _ = velocity or estimate_velocity(radar, frame.radar_fields, velocity_conf,
                                              frame.extras.get("radar_sweep_index"))
        if v is not None:
            still = stationary(radar, frame.radar_fields, v.v, velocity_conf)
            moving = int(len(still) - still.sum())
            radar = radar[still]
    return LidarFrame(L[keep], T_cam_lidar, A, radar[:, :2], frame.radar_token, moving)


def _match(f: LidarFrame, T: np.ndarray, gate: float, conf: LidarAlignConfig, b: float = 0.0
           ) -> tuple[np.ndarray, np.ndarray]:
    """(e (K,) m, u (K, 2)) of one frame's matched detections at ``T`` (the frame's T_cam_radar): ``e = r - m``
    (without ``b``), kept when ``|e - b| < gate``; ``u`` the matched point's unit direction (``d e / d [dx, dy]``)."""
    T_radar_lidar = se3_inverse(T) @ f.T_cam_lidar
    Q = f.lidar @ T_radar_lidar[:3, :3].T + T_radar_lidar[:3, 3]
    Q = Q[Q[:, 0] > conf.min_forward_m, :2]
    if not len(Q):
        return np.zeros(0), np.zeros((0, 2))
    az = np.arctan2(Q[:, 1], Q[:, 0])
    order = np.argsort(az)
    az, Q = az[order], Q[order]
    rng = np.hypot(Q[:, 0], Q[:, 1])
    r = np.hypot(f.radar_xy[:, 0], f.radar_xy[:, 1])
    a = np.arctan2(f.radar_xy[:, 1], f.radar_xy[:, 0])
    beam = np.radians(conf.beam_deg)
    lo, hi = np.searchsorted(az, a - beam), np.searchsorted(az, a + beam)
    e, u = [], []
    for k in np.flatnonzero(hi > lo):
        j = lo[k] + int(np.argmin(rng[lo[k]:hi[k]]))
        if abs(r[k] - rng[j] - b) < gate:
            e.append(r[k] - rng[j])
            u.append(Q[j] / rng[j])
    return np.asarray(e, np.float64), np.asarray(u, np.float64).reshape(-1, 2)


def align(frames: list[LidarFrame], X: np.ndarray, conf: LidarAlignConfig = LidarAlignConfig()
          ) -> tuple[LidarAlignment | None, str]:
    """(the alignment of the module doc at the static estimate ``X`` (4, 4), "") or (None, why not)."""
    if len(frames) < conf.min_frames:
        return None, f"{len(frames)} frame(s) with LiDAR (need {conf.min_frames})"
    frames = _evenly(frames, conf.max_frames)
    a, why = _passes(frames, X, conf)
    if a is None or conf.coupling_deg <= 0:
        return a, why
    # How the measured dy and dx move with the estimate's rotation: the same fit, re-associated, at the
    # estimate turned by +-coupling_deg. Started at the estimate itself, from an estimate far off (a 1.4 m R2
    # start) the turned fits start at the edge of the gates and the difference is noise (28 m/rad against
    # 0.1-0.4). So each turned fit starts at the offsets found, in the turned frame: ``X Exp(phi) S`` (S the
    # shift by [dx, dy]); its offsets add to [dx, dy] and are relative to ``X Exp(phi)``, the estimate turned
    # about its own origin, as the Kalman rows need. One pass each: they start at the fit.
    # The two one-sided slopes (against the same one-pass fit at the estimate) should agree; where a re-association
    # jumps on one side they do not (a drive that stood still at a light, its 17 views: 7.7 and 57.2 m/rad in yaw,
    # the central difference 32 m/rad folded as exact made the yaw-lateral NEES 34): half their difference is the
    # coupling's spread, which ``apply_offsets`` counts as noise.
    shift = se3_exp(np.array([0.0, 0.0, 0.0, a.delta[0], a.delta[1], 0.0]))
    c, spread = np.zeros((2, 3)), np.zeros((2, 3))
    eps = np.radians(conf.coupling_deg)
    b, _ = _solve(frames, X @ shift, conf)
    centre = b.delta[:2] if b is not None else np.zeros(2)
    for j in range(3):
        slope = {}
        for sgn in (1.0, -1.0):
            phi = np.zeros(6)
            phi[j] = sgn * eps
            b, _ = _solve(frames, X @ se3_exp(phi) @ shift, conf)
            if b is not None:
                slope[sgn] = sgn * (b.delta[:2] - centre) / eps
        if len(slope) == 2:
            c[:, j] = 0.5 * (slope[1.0] + slope[-1.0])  # the central difference
            spread[:, j] = 0.5 * np.abs(slope[1.0] - slope[-1.0])
        elif slope:  # one side's fit failed: its slope is all there is, and how far from linear is unknown
            c[:, j] = next(iter(slope.values()))
            spread[:, j] = np.abs(c[:, j])
    return dataclasses.replace(a, coupling=c[1], coupling_x=c[0], spread=spread[1], spread_x=spread[0]), ""


def _passes(frames: list[LidarFrame], X: np.ndarray, conf: LidarAlignConfig) -> tuple[LidarAlignment | None, str]:
    """``_solve`` run ``conf.passes`` times, each from the offsets the earlier ones found: the offsets add up
    (translations along the radar's own x and y), the covariance and counts are the last pass's. A pass whose
    residuals' robust scale is wider than the one before is not taken, and ends the passes: on the simulated
    drives each taken pass matched more detections more tightly, while on the real scene-0916 (one-sided,
    reflections deep behind the LiDAR's surfaces) later passes walked 20 cm away, matching fewer, more loosely."""
    a, why = _solve(frames, X, conf)
    if a is None:
        return a, why
    total, its = a.delta.copy(), a.iterations
    for _ in range(conf.passes - 1):
        b, _ = _solve(frames, X @ se3_exp(np.array([0.0, 0.0, 0.0, total[0], total[1], 0.0])), conf)
        if b is None or b.scale > a.scale:  # a pass whose residuals spread wider has walked off: keep the last
            break
        total[:2] += b.delta[:2]
        total[2] = b.delta[2]
        its += b.iterations
        a = b
    return dataclasses.replace(a, delta=total, iterations=its), ""


def _solve(frames: list[LidarFrame], X: np.ndarray, conf: LidarAlignConfig) -> tuple[LidarAlignment | None, str]:
    """The Gauss-Newton fit of ``[dx, dy, b]`` at ``X`` with its cluster-robust covariance."""
    p = 3 if conf.range_bias else 2
    d = np.zeros(3)
    for gate in conf.gates_m:
        D = se3_exp(np.array([0.0, 0.0, 0.0, d[0], d[1], 0.0]))
        parts = [_match(f, f.A @ X @ D, gate, conf, d[2]) for f in frames]
        e = np.concatenate([q[0] for q in parts])
        if len(e) < conf.min_rows:
            return None, f"{len(e)} radar detections match a LiDAR surface (need {conf.min_rows})"
        J = np.concatenate([q[1] for q in parts])
        if p == 3:  # d e / d b = -1; the residual at the current range offset: r - m - b
            J = np.column_stack([J, np.full(len(J), -1.0)])
            e = e - d[2]
        fid = np.concatenate([np.full(len(q[0]), k) for k, q in enumerate(parts)])
        scale = mad_scale(e, 0.02)
        w = weight("huber", np.abs(e), conf.huber * scale)
        H = (J * w[:, None]).T @ J
        if np.linalg.cond(H[:2, :2]) > 1e8 or np.linalg.cond(H) > 1e10:
            return None, "the matched detections do not span the radar plane (one direction only)"
        d[:p] = d[:p] - np.linalg.solve(H, (J * w[:, None]).T @ e)
    Hi = np.linalg.inv(H)
    g = np.zeros((fid.max() + 1, p))
    np.add.at(g, fid, J * (w * e)[:, None])  # per-frame score: the frames' residuals are not independent
    n = len(np.unique(fid))
    cov = np.zeros((3, 3))
    cov[:p, :p] = Hi @ (g.T @ g) @ Hi * n / max(n - 1, 1)
    cov[0, 0] += conf.systematic_x_m ** 2
    cov[1, 1] += conf.systematic_m ** 2
    moving = sum(f.moving for f in frames)
    return LidarAlignment(d, cov, int(len(e)), n, scale, len(conf.gates_m), moving=moving), ""


def refusal(a: LidarAlignment, conf: LidarAlignConfig = LidarAlignConfig(), cov: np.ndarray | None = None) -> str:
    """Why an alignment is reported but not applied ("" when it is applied): its dy is too uncertain, or, with
    the loop's covariance ``cov`` (6, 6) of the estimate it was measured at, farther from that estimate than
    ``max_innovation`` stds of their difference (``innovation``)."""
    if a.dy_std > conf.max_std_m:
        return f"std {above(a.dy_std, conf.max_std_m)} cm > max_std_m {conf.max_std_m * 100:g} cm"
    z = innovation(a, cov) if cov is not None else 0.0
    if conf.max_innovation and abs(z) > conf.max_innovation:
        return (f"{a.delta[1] * 100:+.1f} cm from the loop's estimate is {abs(z):.1f} stds of what either can be off "
                f"by (max_innovation {conf.max_innovation:g}): the tables' LiDAR-camera extrinsic or the loop's "
                f"estimate is wrong, and which cannot be told; {CHECK_RECORDS}")
    return ""


def innovation(a: LidarAlignment, cov: np.ndarray, axis: int = RADAR_Y) -> float:
    """dy (``axis`` ``RADAR_Y``) or dx (``RADAR_X``) against the loop's estimate in stds of their difference:
    ``d / sqrt(h C h + var(d))`` with ``h`` the Kalman row of the offset (``apply_offsets``) and ``C`` (6, 6) the
    loop's covariance of the estimate."""
    forward = axis == RADAR_X
    h = np.zeros(6)
    h[axis], h[:3] = 1.0, -np.asarray(a.coupling_x if forward else a.coupling, np.float64)
    cov = np.asarray(cov, np.float64)
    k = 0 if forward else 1
    return float(a.delta[k] / np.sqrt(h @ cov @ h + a.cov[k, k] + spread_var(a.spread_x if forward else a.spread,
                                                                          cov)))


def spread_var(spread: np.ndarray, cov: np.ndarray) -> float:
    """The variance, m^2, an offset gets from its coupling's spread (``LidarAlignment.spread``, (3,) m/rad) with the
    estimate's rotation uncertainty (``cov`` (6, 6)): ``sum_j spread_j^2 var(phi_j)``."""
    return float(np.sum(np.asarray(spread, np.float64) ** 2 * np.clip(np.diag(cov)[:3], 0.0, None)))


def forward_refusal(a: LidarAlignment, conf: LidarAlignConfig = LidarAlignConfig(),
                    loop_std_x: float | None = None) -> str:
    """Why the alignment's dx is not folded with its dy ("" when it is): switched off, or too uncertain: its std
    above ``max_std_x_m`` and, with the loop's own std on the radar's forward axis ``loop_std_x`` (m), above
    ``informative_x`` of it."""
    if not conf.forward:
        return "forward offset off (lidar.forward=false)"
    informative = loop_std_x is not None and a.dx_std <= conf.informative_x * loop_std_x
    if a.dx_std > conf.max_std_x_m and not informative:
        loop = (f", nor under informative_x {conf.informative_x:g} of the loop's own {loop_std_x * 100:.1f} cm"
                if loop_std_x is not None and conf.informative_x else "")
        return (f"forward offset std {above(a.dx_std, conf.max_std_x_m)} cm > max_std_x_m {conf.max_std_x_m * 100:g} "
                f"cm{loop} (the detections' azimuths do not separate it from the radar's reflection depth)")
    if abs(a.delta[2]) > conf.max_range_offset_m:
        return (f"the radar's reflections lie {a.delta[2] * 100:+.0f} cm from the LiDAR's surfaces (beyond "
                f"max_range_offset_m {conf.max_range_offset_m * 100:g} cm): a depth that deep varies with what the "
                "radar sees, and the forward offset cannot be told from it")
    return ""


def apply_offsets(T: np.ndarray, cov: np.ndarray, a: LidarAlignment, forward: bool = True
                  ) -> tuple[np.ndarray, np.ndarray]:
    """(T', cov') with the alignment's ``dy`` (and with ``forward`` its ``dx``) folded in as measurements of
    ``xi[4] - coupling @ xi[:3]`` (and ``xi[3] - coupling_x @ xi[:3]``) of the right perturbation ``xi`` at
    ``T`` (4, 4), ``cov`` (6, 6) [rotation, translation]: one Kalman update with the fit's covariance."""
    rows = [RADAR_X, RADAR_Y] if forward else [RADAR_Y]
    H = np.zeros((len(rows), 6))
    for k, axis in enumerate(rows):
        H[k, axis] = 1.0
        # measured at T, each also carries T's rotation error (LidarAlignment.coupling / coupling_x)
        H[k, :3] = -(a.coupling_x if axis == RADAR_X else a.coupling)
    idx = [axis - RADAR_X for axis in rows]
    R = np.asarray(a.cov, np.float64)[np.ix_(idx, idx)].copy()
    for k, axis in enumerate(rows):  # the coupling's spread with the estimate's rotation uncertainty, as noise
        R[k, k] += spread_var(a.spread_x if axis == RADAR_X else a.spread, cov)
    return fold_linear(T, cov, H, np.asarray(a.delta, np.float64)[idx], R)


def describe(block: dict) -> str:
    """A result's ``lidar`` block (``LidarAlignment.record``, or ``{"applied": False, "note"}`` when it did not
    run) in one line of words: what was measured and whether it was applied, or why not."""
    if "dy_m" not in block:
        return f"not run: {block.get('note', '')}"
    words = (f"radar lateral offset {block['dy_m'] * 100:+.1f} +- {block['dy_std_m'] * 100:.1f} cm from the loop's "
             f"estimate ({block['rows']} detections on {block['frames']} frames)")
    if "dx_std_m" in block:  # results before the forward offset hold "dx_m_unused" only
        words += f", forward {block['dx_m'] * 100:+.1f} +- {block['dx_std_m'] * 100:.1f} cm"
    if not block["applied"]:
        return words + f"; not applied: {block.get('note', '')}"
    inherits = (" (through the tables' LiDAR-camera extrinsic, the LiDAR's and the camera's calibrated_sensor "
                "records: an error in either is carried into the result)")
    z, z_x = block.get("innovation_sigma"), block.get("innovation_x_sigma") if block.get("forward_applied") else None
    if isinstance(z, (int, float)) and LidarAlignConfig().far(z):
        inherits += (f"; it lies {abs(z):.1f} stds from the loop's estimate: the radar is far off its tables, or the "
                     f"LiDAR's or the camera's record is ({CHECK_RECORDS} before recalibrating the radar)")
    if isinstance(z_x, (int, float)) and LidarAlignConfig().far(z_x):
        inherits += (f"; its forward offset lies {abs(z_x):.1f} stds from the loop's estimate: the radar is far off "
                     f"its tables, or the LiDAR's or the camera's record is ({CHECK_RECORDS} before recalibrating the "
                     "radar)")
    if block.get("forward_applied"):
        return words + "; both applied" + inherits
    note = block.get("forward_note")
    return words + "; lateral applied" + (f", forward not: {note}" if note else "") + inherits


def _evenly(items: list, n: int) -> list:
    """At most ``n`` of ``items``, evenly spaced (first and last kept)."""
    if len(items) <= n:
        return list(items)
    return [items[int(k)] for k in np.linspace(0, len(items) - 1, n).round()]


def drive_frames(frames, indices, conf: LidarAlignConfig = LidarAlignConfig(),
                 velocity: Callable[[int], tuple] | None = None,
                 velocity_conf: RadarVelocityConfig = DEFAULT_VELOCITY) -> list[LidarFrame]:
    """The alignment inputs of dataset ``indices``, at most ``conf.max_frames`` of them evenly spaced (the
    frames ``align`` would keep: the others are not read), unreadable frames and frames without LiDAR left out.
    velocity: dataset index -> (``RadarVelocity`` | None, why) (the hybrid passes its motion source's, which fitted
    each frame's Doppler once already; default ``estimate_velocity`` with ``velocity_conf``)."""
    out = []
    for i in _evenly(list(indices), conf.max_frames):
        try:
            lf = lidar_frame(frames[i], conf, None if velocity is None else velocity(i), velocity_conf)
        except DataError:
            continue
        if lf is not None:
            out.append(lf)
    return out
