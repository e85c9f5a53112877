"""The radar's lateral offset from the LiDAR: radar ranges against the first LiDAR surface in each beam.

Why. The network does not correct translation (docs/benchmarks.md, "Why translation is not learned")
and its radar-pixel rows are too coarse to (the hybrid's measurement model): the hybrid's camera-x
translation error stayed at the start's level (8 cm from R1 starts, ~40 cm from R2). Where the
vehicle has a LiDAR with a known LiDAR-camera extrinsic (the tables; the same extrinsic the
``lidar-densified`` depth the network sees already rests on), the radar's own detections locate it
in the LiDAR's scene: a 2D radar's detection at range ``r`` and azimuth ``a`` lies on the first
surface the LiDAR sees along that beam, so the offset of the radar's origin in its own x-y plane is
what lines the two up.

The model (radar frame of the current estimate ``X = T_cam_radar``; per frame ``f`` the time-aware
extrinsic is ``T_f = A_f X`` with ``A_f = T_cam_radar(frame) inv(T_cam_radar_static)`` from the
tables, which cancels the mount). LiDAR points ``p`` (LiDAR frame) go to the radar frame by
``inv(A_f X Exp([0, 0, 0, dx, dy, 0])) T_cam_lidar p``; points near the ground or above the radar's
view in the *ego* frame (``ground_m``, ``top_m``: from the LiDAR's mount alone, so an error of the
radar's tilt cannot let the ground into the band) are dropped. Each radar detection is matched to
the nearest-range LiDAR point within ``+-beam_deg`` of its azimuth (the first surface), kept when
within ``gate`` metres, and gives the residual ``e = r - m - b`` with ``d e / d [dx, dy, b] = [u, -1]``
(``u``: the matched point's unit direction in the radar plane; ``b``: a common range offset, the
depth of the radar's reflections behind the LiDAR's first surface). Gauss-Newton with Huber weights
re-associates at every iteration while the gate shrinks (``gates_m``).

What it measures and what it does not (docs/benchmarks.md "The radar's lateral offset from the
LiDAR"): the lateral offset ``dy`` to ~2 cm whatever the start (up to 50 cm off). ``dx`` is nearly
collinear with ``b`` (``cos a ~ 1``) and is not used. Without ``b`` in the model a one-sided scene
turns the range offset into a lateral one (scene-0916: ``dy`` -19 cm at the tables' extrinsic
without ``b``, -5 +- 4 cm with it). Its covariance is cluster-robust (sandwich over frames: one
frame's residuals share the scene) plus ``systematic_m`` (fitted on validation drives) for what is
common to a drive. ``dy`` is fitted at the estimate's rotation: ``coupling`` (central differences of
the whole fit, ``coupling_deg``) says how it moves with that rotation.

``apply_lateral`` folds ``dy`` into an estimate as a measurement of ``xi[4] - coupling @ xi[:3]`` of
the right perturbation ``xi`` (Kalman update of the 6x6 covariance, ``[rotation, translation]``
right tangent): the estimate's rotation uncertainty widens it, and correlated axes move with it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from hybrid_calib.calib.covariance import fold_scalar
from hybrid_calib.config import require
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import se3_exp, se3_inverse

RADAR_Y = 4  # index of the radar-y translation in the right tangent [phi (3), rho (3)]


@dataclass(frozen=True)
class LidarAlignConfig:
    enabled: bool = True  # hybrid: fold the LiDAR's lateral offset into the final estimate when the frames have LiDAR
    beam_deg: float = 0.5  # half-width of a radar detection's beam in azimuth, deg (the radar's ~0.3 deg noise)
    ground_m: float = 0.3  # LiDAR points lower than this above the ego frame's ground plane are dropped, m
    top_m: float = 3.5  # ... and higher than this, m
    min_forward_m: float = 0.5  # LiDAR points less far ahead of the radar are dropped, m
    gates_m: tuple[float, ...] = (1.5, 1.0, 0.7, 0.5, 0.5, 0.5, 0.5, 0.5)  # match gate per iteration, m
    huber: float = 1.345  # Huber threshold, in robust residual scales
    min_rows: int = 100  # fewer matched detections (all frames): no alignment (a straight road: ~1 per frame)
    min_frames: int = 3  # fewer frames with LiDAR: no alignment
    max_frames: int = 60  # frames used at most (evenly spaced over the drive)
    systematic_m: float = 0.020  # drive-common error of dy, m (benchmarks/lidar_alignment.py; validation drives)
    max_std_m: float = 0.10  # an alignment less certain than this is not applied (reported only), m
    range_bias: bool = True  # fit a common range offset (reflection depth): a one-sided scene cannot make it dy
    coupling_deg: float = 0.5  # step of the central differences of dy against the estimate's rotation, deg (0: none)

    def __post_init__(self):
        require(self, {
            "beam_deg > 0": self.beam_deg > 0, "top_m > ground_m": self.top_m > self.ground_m,
            "min_rows >= 3": self.min_rows >= 3, "min_frames >= 1": self.min_frames >= 1,
            "max_frames >= min_frames": self.max_frames >= self.min_frames,
            "gates_m positive": bool(self.gates_m) and min(self.gates_m) > 0, "huber > 0": self.huber > 0,
            "systematic_m >= 0": self.systematic_m >= 0, "max_std_m > 0": self.max_std_m > 0,
            "coupling_deg >= 0": self.coupling_deg >= 0})


@dataclass(frozen=True)
class LidarFrame:
    """One frame's inputs. lidar: (M, 3) metres, LiDAR frame, ground and tall points already dropped.
    T_cam_lidar: (4, 4). A: (4, 4) ``T_cam_radar(frame) inv(T_cam_radar_static)`` (tables). radar_xy:
    (N, 2) metres, radar frame. frame_id: the radar sample_data token."""

    lidar: np.ndarray
    T_cam_lidar: np.ndarray
    A: np.ndarray
    radar_xy: np.ndarray
    frame_id: str


@dataclass(frozen=True)
class LidarAlignment:
    """delta: (3,) [dx, dy, b] metres: the radar-x / radar-y translation of the right perturbation of the
    estimate it was measured at, and the common range offset ``b`` (0 when not fitted). cov: (3, 3) m^2
    (cluster-robust + ``systematic_m^2`` on dy). rows / frames: matched detections and frames. scale:
    the residuals' robust scale, m. iterations: Gauss-Newton steps. coupling: (3,) m/rad, ``d dy / d
    phi`` for a right rotation ``phi`` of the estimate it was measured at (zeros: not computed):
    ``dy`` measures ``xi[4] - coupling @ xi[:3]`` of the estimate's error ``xi``."""

    delta: np.ndarray
    cov: np.ndarray
    rows: int
    frames: int
    scale: float
    iterations: int
    coupling: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def dy_std(self) -> float:
        return float(np.sqrt(self.cov[1, 1]))

    def record(self, applied: bool, why: str = "") -> dict:
        """The result's ``lidar`` block (plain JSON)."""
        return {"applied": applied, "dy_m": float(self.delta[1]), "dy_std_m": self.dy_std,
                "dx_m_unused": float(self.delta[0]), "range_offset_m": float(self.delta[2]),
                "coupling_m_per_rad": [float(c) for c in self.coupling], "rows": self.rows, "frames": self.frames,
                "scale_m": self.scale, **({"note": why} if why else {})}


def lidar_frame(frame, conf: LidarAlignConfig = LidarAlignConfig()) -> LidarFrame | None:
    """The alignment's inputs from a ``RadarCameraFrame`` loaded with its LiDAR, or None when it has no
    LiDAR, no ego mount of the camera or no radar detection."""
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
    keep = np.isfinite(L).all(axis=1) & (height > conf.ground_m) & (height < conf.top_m)
    A = np.asarray(frame.T_cam_radar, np.float64) @ se3_inverse(np.asarray(static, np.float64))
    return LidarFrame(L[keep], T_cam_lidar, A, np.asarray(frame.radar_points, np.float64)[:, :2], frame.radar_token)


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
    a, why = _solve(frames, X, conf)
    if a is None or conf.coupling_deg <= 0:
        return a, why
    # How the measured dy moves with the estimate's rotation: the same fit, re-associated, at the estimate
    # turned by +-coupling_deg. Turned about the radar origin moved to the fitted dy: from an estimate far off
    # (a 1.4 m R2 start) the turned fits start at the edge of the gates and the difference is noise (28 m/rad
    # against 0.1-0.4), while moving the origin along radar y leaves d dy / d phi unchanged to first order
    # (phi x dy e_y has no y component).
    Xc = X @ se3_exp(np.array([0.0, 0.0, 0.0, 0.0, a.delta[1], 0.0]))
    c = np.zeros(3)
    eps = np.radians(conf.coupling_deg)
    centre = None
    for j in range(3):
        side = {}
        for sgn in (1.0, -1.0):
            phi = np.zeros(6)
            phi[j] = sgn * eps
            b, _ = _solve(frames, Xc @ se3_exp(phi), conf)
            if b is not None:
                side[sgn] = b.delta[1]
        if len(side) == 2:
            c[j] = (side[1.0] - side[-1.0]) / (2 * eps)
        elif side:
            if centre is None:
                b, _ = _solve(frames, Xc, conf)
                centre = b.delta[1] if b is not None else 0.0
            (sgn, y), = side.items()
            c[j] = sgn * (y - centre) / eps
    return dataclasses.replace(a, coupling=c), ""


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
        scale = max(1.4826 * float(np.median(np.abs(e - np.median(e)))), 0.02)
        w = np.minimum(1.0, conf.huber * scale / np.maximum(np.abs(e), 1e-12))
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
    cov[1, 1] += conf.systematic_m ** 2
    return LidarAlignment(d, cov, int(len(e)), n, scale, len(conf.gates_m)), ""


def refusal(a: LidarAlignment, conf: LidarAlignConfig = LidarAlignConfig()) -> str:
    """Why an alignment is reported but not applied ("" when it is applied): too uncertain."""
    if a.dy_std > conf.max_std_m:
        return f"std {a.dy_std * 100:.1f} cm > max_std_m {conf.max_std_m * 100:g} cm"
    return ""


def apply_lateral(T: np.ndarray, cov: np.ndarray, a: LidarAlignment) -> tuple[np.ndarray, np.ndarray]:
    """(T', cov') with the alignment's ``dy`` folded in as a measurement of ``xi[4] - coupling @ xi[:3]`` of the
    right perturbation ``xi`` at ``T`` (4, 4), ``cov`` (6, 6) [rotation, translation] (Kalman update)."""
    h = np.zeros(6)
    h[RADAR_Y] = 1.0
    h[:3] = -a.coupling  # dy measured at T also carries T's rotation error (LidarAlignment.coupling)
    return fold_scalar(T, cov, h, float(a.delta[1]), float(a.cov[1, 1]))


def describe(block: dict) -> str:
    """A result's ``lidar`` block (``LidarAlignment.record``, or ``{"applied": False, "note"}`` when it did not
    run) in one line of words: what was measured and whether it was applied, or why not."""
    if "dy_m" not in block:
        return f"not run: {block.get('note', '')}"
    words = (f"radar lateral offset {block['dy_m'] * 100:+.1f} +- {block['dy_std_m'] * 100:.1f} cm from the loop's "
             f"estimate ({block['rows']} detections on {block['frames']} frames)")
    return words + ("; applied" if block["applied"] else f"; not applied: {block.get('note', '')}")


def _evenly(items: list, n: int) -> list:
    """At most ``n`` of ``items``, evenly spaced (first and last kept)."""
    if len(items) <= n:
        return list(items)
    return [items[int(k)] for k in np.linspace(0, len(items) - 1, n).round()]


def drive_frames(frames, indices, conf: LidarAlignConfig = LidarAlignConfig()) -> list[LidarFrame]:
    """The alignment inputs of dataset ``indices``, at most ``conf.max_frames`` of them evenly spaced (the
    frames ``align`` would keep: the others are not read), unreadable frames and frames without LiDAR left out."""
    out = []
    for i in _evenly(list(indices), conf.max_frames):
        try:
            lf = lidar_frame(frames[i], conf)
        except DataError:
            continue
        if lf is not None:
            out.append(lf)
    return out
