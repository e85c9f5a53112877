"""The radar's own travel against the vehicle's: its sweeps (Doppler velocity, ego pose) and the pairs of them.

One home for what the radar mount monitor (``calib.mount_monitor``) and the lever arm (``calib.lever_arm``)
both measure. Per pair of sweeps a -> b the radar's Doppler gives the direction of its own travel in its own
frame (``sensors.radar_velocity``, the chord of its velocities at a and b) and the ego poses at the two
radar timestamps give the vehicle's displacement ``D`` and rotation ``R_A`` (``ego_measurement``).

Which sweeps. Every radar sweep of the drive: the keyframe's and, where the root has them, the non-keyframe
sweeps between two keyframes (nuScenes' ``sweeps/`` folder: RADAR_FRONT runs at ~13 Hz, 6-7 sweeps per 0.5 s
keyframe interval; the simulator writes ``radar_sweeps_per_frame``, 5 by default; ``data.sweeps``). A
keyframe-only root (a mini copy without ``sweeps/``) gives the keyframes alone, as before.

Which pairs (``partner``). Each sweep b is paired with the latest earlier sweep a at least ``pair_dt_s``
before it (0.4 s by default): on a keyframe-only root that is the previous keyframe (0.5 s); with the
sweeps, 6-7 pairs per keyframe interval, each of about the keyframes' baseline and each sweep in two
pairs. The same baseline keeps the chord model and what the ego poses' errors do to it as they were; only
the Doppler's noise averages down: on 6 unchanged simulated drives (urban, straight) the median of a
keyframe interval's pairs has a heading-residual MAD of 0.07-0.105 deg against 0.16-0.24 deg for the one
keyframe pair (docs/benchmarks.md, "The radar mount monitor"). An entry without a timestamp (an unreadable
keyframe on a dataset that cannot name it) is a barrier: the pair that would reach across it is skipped.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from factors.motion import MotionMeasurement, chord_heading, radar_yaw_change
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import so3_log
from hybrid_calib.sensors.radar_velocity import estimate_velocity


@dataclass(frozen=True)
class EgoSweep:
    """What a pair needs of one sweep: ``timestamp_radar_us`` (None: unknown, an unreadable keyframe),
    ``extras["T_global_ego_radar"]`` (4, 4) and ``radar_token``; ``velocity``: the sweep's Doppler velocity
    (``RadarVelocity``) or None, with ``why`` not. ``position``: the drive position of the keyframe whose
    interval holds it (its own, for a keyframe sweep); ``keyframe``: whether it is the keyframe's sweep."""

    timestamp_radar_us: int | None
    extras: dict
    radar_token: str
    velocity: object = None
    why: str = ""
    position: int = -1
    keyframe: bool = True

MAX_PLAUSIBLE_TURN_DPS = 120.0  # a yaw rate no road vehicle reaches (a tight U-turn: ~40 deg/s), deg/s


def ego_measurement(fa, va, fb, vb, T_ego_radar: np.ndarray, min_speed_mps: float, max_gap_s: float,
                    max_turn_dps: float) -> tuple[MotionMeasurement | None, str]:
    """The pair a -> b as a ``factors.motion`` measurement with the ego in the camera's place, or (None, why it
    was skipped). fa / fb: sweeps or frames (``timestamp_radar_us``, ``extras["T_global_ego_radar"]``,
    ``radar_token``); va / vb: their ``RadarVelocity`` (or None); T_ego_radar: (4, 4) the mount (its rotation
    carries the radar's velocity at b into frame a; its position gives the radar's travel the Doppler speed is
    checked against)."""
    if fa.timestamp_radar_us is None or fb.timestamp_radar_us is None:
        return None, "a sweep without a timestamp (its frame is unreadable)"
    if why := scene_break(fa, fb):
        return None, why
    dt = (fb.timestamp_radar_us - fa.timestamp_radar_us) * 1e-6
    if not 0 < dt <= max_gap_s:
        return None, f"radar sweeps {dt:.2f} s apart (a pair needs 0 < dt <= {max_gap_s:g} s)"
    if va is None or vb is None:
        return None, "no Doppler velocity"
    Ta, Tb = fa.extras.get("T_global_ego_radar"), fb.extras.get("T_global_ego_radar")
    if Ta is None or Tb is None:
        return None, "no ego pose at the radar's timestamp"
    Ta, Tb = np.asarray(Ta, np.float64), np.asarray(Tb, np.float64)
    if not (np.isfinite(Ta).all() and np.isfinite(Tb).all()):
        return None, "an ego pose is not finite"
    R_A = Ta[:3, :3].T @ Tb[:3, :3]
    D = Ta[:3, :3].T @ (Tb[:3, 3] - Ta[:3, 3])
    s = float(np.linalg.norm(D))
    # before the speed: a radar saying 0 m/s while the poses move is not a parked car
    if why := pose_doppler_conflict(sensor_travel(Ta, Tb, T_ego_radar), dt, 0.5 * (va.speed + vb.speed)):
        return None, why
    if min(va.speed, vb.speed) < min_speed_mps:
        return None, f"radar speed {min(va.speed, vb.speed):.1f} m/s (need {min_speed_mps:g})"
    turn = float(np.degrees(np.linalg.norm(so3_log(R_A)))) / dt
    if turn > MAX_PLAUSIBLE_TURN_DPS:  # a heading flipped in the tables read as a "turn"
        return None, (f"the ego poses turn {turn:.0f} deg/s between these sweeps ({dt:.2f} s), which no vehicle "
                      "does: the ego poses (ego_pose.json) are wrong here")
    if turn > max_turn_dps:
        return None, f"turning at {turn:.0f} deg/s (at most {max_turn_dps:g})"
    psi, sig, speed = chord_heading(va.v, va.cov, vb.v, vb.cov, radar_yaw_change(R_A, T_ego_radar[:3, :3]))
    if not np.all(np.isfinite([psi, sig, speed])) or not sig > 0:  # (probe 118: a NaN measurement was made)
        return None, "the radar's Doppler chord is not finite (a sweep's velocity or its covariance holds NaN/inf)"
    if not s > 0:
        return None, "the ego poses do not move between these sweeps"
    return MotionMeasurement(D / s, R_A, s, psi, sig, speed, fa.radar_token, fb.radar_token, 0,
                             min(va.n_inliers, vb.n_inliers)), ""


def scene_break(fa, fb) -> str:
    """Why frames or sweeps ``fa`` and ``fb`` are no pair ("" when they may be): they belong to two scenes
    (``extras["scene_token"]``). A log's scenes are recorded apart, and two logs' ego poses are in two map frames: a
    pair across them measured a motion no vehicle made (probe 45: a scene cut in two, its second log's poses moved
    1000 m, changed the hybrid's yaw by 0.2 deg in silence)."""
    a, b = fa.extras.get("scene_token"), fb.extras.get("scene_token")
    if a and b and a != b:
        return f"the frames are of two scenes ({a}, {b}): a motion is measured within one scene"
    return ""


# the ego poses' speed between two instants and the radar's Doppler speed disagree beyond max(1 m/s, 25 %): on the
# real scene-0916 they differ by at most 0.25 m/s (7 %) over its 40 keyframe pairs, on simulated drives by 0.03 m/s;
# frozen, duplicated or shuffled poses differ by the whole speed
POSE_SPEED_TOL_MPS, POSE_SPEED_TOL_REL = 1.0, 0.25


def sensor_travel(Ta: np.ndarray, Tb: np.ndarray, T_ego_sensor: np.ndarray | None) -> float:
    """How far a sensor mounted at ``T_ego_sensor`` (4, 4; None: at the ego origin) moved between the ego poses
    ``Ta`` and ``Tb`` (4, 4, ego -> global), metres. The radar's, not the ego origin's: in a turn at w rad/s an origin
    d metres beside the radar moves up to w d m/s faster or slower than it (scene-0916 with its origin put 3 m aside:
    1.1 m/s at 21 deg/s, 11 of its pairs refused), and where a root puts its ego origin is its own choice."""
    Ta, Tb = np.asarray(Ta, np.float64), np.asarray(Tb, np.float64)
    t = np.zeros(3) if T_ego_sensor is None else np.asarray(T_ego_sensor, np.float64)[:3, 3]
    return float(np.linalg.norm((Tb[:3, :3] @ t + Tb[:3, 3]) - (Ta[:3, :3] @ t + Ta[:3, 3])))


def pose_doppler_conflict(travel_m: float, dt_s: float, speed_mps: float) -> str:
    """Why the ego poses cannot be trusted over an interval ("" when they can): the radar's travel by them
    ``travel_m`` (``sensor_travel``) over ``dt_s`` against its Doppler speed ``speed_mps``. The motion constraint
    then does without the poses' rotation, and the Doppler steps (mount monitor, lever arm) skip the pair."""
    v = travel_m / dt_s
    if not np.isfinite(speed_mps) or abs(v - speed_mps) <= max(POSE_SPEED_TOL_MPS, POSE_SPEED_TOL_REL * speed_mps):
        return ""  # a Doppler fit without a speed is refused by its own checks, not blamed on the poses
    return (f"the ego poses moved {travel_m:.2f} m in {dt_s:.2f} s ({v:.1f} m/s) while the radar's Doppler measured "
            f"{speed_mps:.1f} m/s: the ego poses (ego_pose.json) or the radar's velocity fields (vx, vy: the raw "
            "Doppler velocity of its files) are wrong for this drive")


def pair_skip(a: EgoSweep, b: EgoSweep) -> str:
    """Why the pair a -> b has no measurement before any geometry is looked at ("" when both have a velocity)."""
    if a.velocity is None or b.velocity is None:
        return f"no Doppler velocity: {(a if a.velocity is None else b).why}"
    return ""


def partner(history: Sequence[EgoSweep], b: EgoSweep, pair_dt_s: float) -> EgoSweep | None:
    """The latest sweep of ``history`` (time order, all before ``b``) at least ``pair_dt_s`` before ``b``; an
    entry without a timestamp on the way back is returned itself (a barrier: the pair is skipped); None when
    ``history`` holds none (the drive's first pair)."""
    if b.timestamp_radar_us is None:
        return history[-1] if history else None
    for a in reversed(history):
        if a.timestamp_radar_us is None or (b.timestamp_radar_us - a.timestamp_radar_us) * 1e-6 >= pair_dt_s:
            return a
    return None


def sweep_pairs(sweeps: Sequence[EgoSweep], pair_dt_s: float) -> list[tuple[EgoSweep, EgoSweep]]:
    """Every pair (a, b) of a drive's sweeps (time order), b's ``partner`` for each b that has one."""
    out = []
    for j, b in enumerate(sweeps):
        a = partner(sweeps[:j], b, pair_dt_s)
        if a is not None:
            out.append((a, b))
    return out


def frame_sweeps(frames, index: int, position: int, velocity: Callable[[int], tuple] | None = None,
                 between: bool = True, cache: dict | None = None) -> tuple[list[EgoSweep], np.ndarray | None]:
    """(the sweeps of the keyframe interval ending at dataset ``index``, oldest first, the keyframe sweep last;
    the tables' ``T_ego_cam`` (4, 4) of the frame, or None when it is unreadable or has none). ``between``:
    include the non-keyframe sweeps when ``frames`` offers them (``radar_sweeps_between``, the nuScenes
    dataset's). velocity: dataset index -> (``RadarVelocity`` | None, why) for the keyframe (the hybrid passes
    its motion source's); default ``estimate_velocity`` of the frame; the non-keyframe sweeps always get their
    own. cache: a dict kept across calls (the hybrid's motion source's), so that the mount monitor and the lever
    arm read and fit each sweep once."""
    key = (index, between)
    if cache is not None and key in cache:
        sweeps, T_ego_cam = cache[key]
        return [s if s.position == position else dataclasses.replace(s, position=position) for s in sweeps], T_ego_cam
    sweeps, T_ego_cam = _read_frame_sweeps(frames, index, position, velocity, between)
    if cache is not None:
        cache[key] = (sweeps, T_ego_cam)
    return list(sweeps), T_ego_cam


def _read_frame_sweeps(frames, index: int, position: int, velocity, between: bool
                       ) -> tuple[list[EgoSweep], np.ndarray | None]:
    out = []
    ref = getattr(frames, "frames", None)
    ref = ref[index] if isinstance(ref, list) and index < len(ref) else None
    scene = {"scene_token": ref.scene_token} if getattr(ref, "scene_token", "") else {}  # its sweeps' (scene_break)
    if between and hasattr(frames, "radar_sweeps_between"):
        for s in frames.radar_sweeps_between(index):
            v, why = (None, s.why) if s.why else estimate_velocity(s.points, s.fields)
            out.append(EgoSweep(s.timestamp_us, {"T_global_ego_radar": s.T_global_ego, **scene}, s.token, v, why,
                                position, keyframe=False))
    try:
        f = frames[index]
        v, why = velocity(index) if velocity is not None else estimate_velocity(
            f.radar_points, f.radar_fields, sweep_index=f.extras.get("radar_sweep_index"))
    except DataError as e:
        ts = ref.radar_sd.get("timestamp") if ref is not None else None
        out.append(EgoSweep(None if ts is None else int(ts), {}, "", None, f"frame unreadable: {e}", position))
        return out, None
    pose = f.extras.get("T_global_ego_radar")
    scene = {"scene_token": f.extras["scene_token"]} if f.extras.get("scene_token") else scene
    out.append(EgoSweep(int(f.timestamp_radar_us), {"T_global_ego_radar": pose, **scene}, f.radar_token,
                        v if pose is not None else None, why if pose is not None else "no ego pose", position))
    T_ego_cam = f.extras.get("T_ego_cam")
    return out, None if T_ego_cam is None else np.asarray(T_ego_cam, np.float64)


def drive_sweeps(frames, indices, velocity: Callable[[int], tuple] | None = None, between: bool = True,
                 cache: dict | None = None) -> tuple[list[EgoSweep], np.ndarray | None]:
    """(the sweeps of dataset ``indices`` in drive order (``frame_sweeps`` of each), the tables' ``T_ego_cam``
    (4, 4) of the first readable frame or None)."""
    sweeps, T_ego_cam = [], None
    for k, i in enumerate(indices):
        got, T = frame_sweeps(frames, i, k, velocity, between, cache)
        sweeps += got
        T_ego_cam = T if T_ego_cam is None else T_ego_cam
    return sweeps, T_ego_cam
