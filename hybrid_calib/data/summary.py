"""Per-scene / per-vehicle summary of a nuScenes-format root.

``summarize_dataset`` walks every frame once (tqdm progress) and returns a ``DatasetSummary``;
``DatasetSummary.to_json()`` is the schema written by ``hybrid-calib inspect``::

    {"root": str, "version": str, "radar_channel": str, "camera_channel": str,
     "n_frames": int, "n_loaded": int, "n_skipped": int,
     "groups": [{"scene": str, "vehicle": str, "log_token": str, "frames": int, "loaded": int,
                 "radar_points_per_sweep": {"mean": float, "min": int, "max": int},  # null: none loaded
                 "radar_points_raw_mean": float, "radar_nonfinite_dropped": int, "lidar_nonfinite_dropped": int,
                 "dt_radar_minus_camera_ms": {"mean": float, "min": float, "max": float},  # null: none loaded
                 "radar_sweeps_between": {"records": int, "on_disk": int, "broken": int}}],
                 # radar_sweeps_between: the non-keyframe radar sweeps between the group's keyframes (the
                 # mount monitor and the Doppler lever arm pair them too where their files are on disk)
     "skipped": [{"index": int | null, "token": str, "path": str | null, "reason": str}]}
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hybrid_calib.data.nuscenes import NuScenesRadarCamera
from hybrid_calib.data.sweeps import sweep_files_between
from hybrid_calib.geometry import transform_points
from hybrid_calib.sensors.radar_velocity import MAX_ROAD_SPEED_MPS

MIN_IN_IMAGE = 0.02  # fewer radar points in the image than this fraction: the tables' calibration cannot be right
# a keyframe's radar record this far in time from its camera's (nuScenes: under 0.1 s; the loader refuses beyond its
# max_sync_offset_s, 0.5 s): said, since a record naming another instant moved the yaw by 2.5 deg silently (probe 29)
SYNC_WARN_MS = 100.0
# a sensor mount farther than this from the vehicle's origin (nuScenes: within 4 m) is said: a translation in
# decimetres (34 m) passed every check below the loader's 50 m bound (probe 29)
MOUNT_WARN_M = 10.0
# a sensor's up axis this far from the vehicle's (nuScenes' cameras and radars: within 1.3 deg; a camera pitched down
# 20 deg on a truck is not said; a 45 deg roll was, by probe 36, missed at 60)
TILT_WARN_DEG = 30.0
MIN_MOUNT_HEIGHT_M = 0.1  # a sensor lower than this over the ego origin (on the ground) is on or under the road
MIN_KEYFRAME_GAP_US = 10_000  # keyframes closer than 10 ms (nuScenes: 500 ms): the timestamps are not microseconds


@dataclass
class GroupSummary:
    scene: str
    vehicle: str
    log_token: str
    frames: int = 0  # frames in the index
    loaded: int = 0  # frames that loaded
    radar_points: list[int] = field(default_factory=list)  # per loaded frame, after filtering
    radar_raw: list[int] = field(default_factory=list)  # per loaded frame, before filtering
    nonfinite: int = 0  # NaN/inf radar points dropped
    lidar_nonfinite: int = 0  # NaN/inf LiDAR points dropped (when LiDAR is loaded)
    dt_ms: list[float] = field(default_factory=list)  # radar minus camera timestamp, milliseconds
    sweeps_between: int = 0  # non-keyframe radar sweep records between the keyframes (data.sweeps)
    sweeps_on_disk: int = 0  # ... whose files are on disk
    sweeps_broken: int = 0  # ... broken (a prev pointer that does not resolve, a file name outside the root)
    sweeps_unreadable: int = 0  # ... on disk, but not readable as a radar PCD (truncated, empty)
    sweep_unreadable: str = ""  # the first of those, and why
    radar_in_image: int = 0  # radar points that project into the image with the tables' extrinsic and intrinsics
    boresight_deg: float = 0.0  # the largest angle between the radar's boresight (x) and the camera's axis (z)
    camera_us: list[int] = field(default_factory=list)  # camera keyframe timestamps (the sanity of their unit)
    # per loaded frame in scene order: (sample token, radar timestamp us, ego position at it (3,) m)
    ego_track: list[tuple[str, int, np.ndarray]] = field(default_factory=list)
    ego_lean: tuple[str, float] = ("", 0.0)  # the keyframe whose ego pose leans most from the world's up; deg
    late: list[tuple[str, float]] = field(default_factory=list)  # (sample, radar - camera ms) beyond SYNC_WARN_MS
    far_mount: tuple[str, float] = ("", 0.0)  # the channel whose mount lies farthest from the ego origin; how far, m
    tilted: tuple[str, float] = ("", 0.0)  # the channel whose "up" (camera -y, radar z) leans most from ego up; deg
    low_mount: tuple[str, float] = ("", np.inf)  # the channel whose mount lies lowest; its height over the origin, m
    # (width, height) of its camera images -> (frames, first sample): one camera's intrinsics fit one image size
    image_sizes: dict[tuple[int, int], list] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        pts = np.asarray(self.radar_points, np.int64)  # none loaded: null counts, not a sweep of 0 points (probe 102)
        dt = self.dt_ms or [None]  # no frame loaded: null (strict JSON; probe 101 read NaN)
        return dict(scene=self.scene, vehicle=self.vehicle, log_token=self.log_token, frames=self.frames,
                    loaded=self.loaded,
                    radar_points_per_sweep=dict(mean=None, min=None, max=None) if not pts.size else dict(
                        mean=float(pts.mean()), min=int(pts.min()), max=int(pts.max())),
                    radar_points_raw_mean=float(np.mean(self.radar_raw)) if self.radar_raw else 0.0,
                    radar_nonfinite_dropped=self.nonfinite, lidar_nonfinite_dropped=self.lidar_nonfinite,
                    dt_radar_minus_camera_ms=dict(mean=None, min=None, max=None) if dt == [None] else dict(
                        mean=float(np.mean(dt)), min=float(np.min(dt)), max=float(np.max(dt))),
                    radar_sweeps_between=dict(records=self.sweeps_between, on_disk=self.sweeps_on_disk,
                                              broken=self.sweeps_broken, unreadable=self.sweeps_unreadable))


@dataclass
class DatasetSummary:
    root: str
    version: str
    radar_channel: str
    camera_channel: str
    groups: list[GroupSummary]
    skipped: list[dict[str, Any]]
    first_loaded: int | None  # index of the first frame that loaded (used for the overlay)
    calibration_splits: dict[str, list[str]] = field(default_factory=dict)  # vehicle -> its names
    calibration_offsets: dict[str, tuple[float, float]] = field(default_factory=dict)  # NAME-calN -> (deg, cm)
    intrinsic_changes: dict[str, str] = field(default_factory=dict)  # log -> sentence (NuScenesRadarCamera)

    @property
    def n_frames(self) -> int:
        return sum(g.frames for g in self.groups)

    @property
    def n_loaded(self) -> int:
        return sum(g.loaded for g in self.groups)

    def to_json(self) -> dict[str, Any]:
        return dict(root=self.root, version=self.version, radar_channel=self.radar_channel,
                    camera_channel=self.camera_channel, n_frames=self.n_frames, n_loaded=self.n_loaded,
                    n_skipped=len(self.skipped), groups=[g.to_json() for g in self.groups], skipped=self.skipped,
                    calibration_splits=self.calibration_splits, calibration_offsets=self.calibration_offsets,
                    intrinsic_changes=self.intrinsic_changes)

    def format(self, listed_in: str | None = None) -> str:
        """A human-readable table: one line per scene/vehicle, then the skipped items grouped by reason (count,
        the first one's reason, a few more of its frames and tokens: a drive with hundreds of bad frames does not
        flood the terminal). ``listed_in``: the file that lists every skipped item, named when some are left out."""
        wv = min(max([12] + [len(g.vehicle) for g in self.groups]), 24)  # a calibration's name (NAME-cal2) whole
        lines = [f"{self.root} [{self.version}] {self.radar_channel} -> {self.camera_channel}: "
                 f"{self.n_loaded}/{self.n_frames} frames loaded, {len(self.skipped)} skipped",
                 f"{'scene':24s} {'vehicle':{wv}s} {'frames':>6s} {'loaded':>6s} {'radar pts/sweep':>18s} "
                 f"{'raw':>6s} {'NaN':>5s} {'dt ms':>7s}"]
        for g in self.groups:
            j = g.to_json()
            p, dt = j["radar_points_per_sweep"], j["dt_radar_minus_camera_ms"]["mean"]
            lines.append(f"{g.scene[:24]:24s} {g.vehicle[:wv]:{wv}s} {g.frames:6d} {g.loaded:6d} "
                         + (f"{p['mean']:7.1f} [{p['min']:3d},{p['max']:4d}]" if p["mean"] is not None else
                            f"{'-':>18s}") + f" {j['radar_points_raw_mean']:6.1f} "
                         f"{g.nonfinite:5d} " + (f"{dt:7.1f}" if dt is not None else f"{'-':>7s}"))  # none loaded
        lines += self._sweep_lines() + self._sanity_lines()
        for vehicle, names in self.calibration_splits.items():
            far = [f"{n}: {d:.2f} deg, {cm:.1f} cm from {vehicle}'s" for n in names[1:]
                   if (off := self.calibration_offsets.get(n)) is not None for d, cm in [off]]
            lines.append(f"vehicle {vehicle}: its frames hold {len(names)} different camera-radar calibrations in the "
                         f"tables, so it is calibrated as {len(names)} vehicles, one per calibration: "
                         f"{', '.join(names)} (the first met keeps the name)" + (f" ({'; '.join(far)})" if far else ""))
        lines += [f"log {log}: {words}" for log, words in self.intrinsic_changes.items()]
        if not self.n_frames:
            lines.append(f"no frames: no sample has both a {self.radar_channel} and a {self.camera_channel} keyframe "
                         "(the skipped items below say why); check --radar/--camera and the tables")
        lines += format_skips(self.skipped, listed_in)
        return "\n".join(lines)

    def _sanity_lines(self) -> list[str]:
        """Warnings on tables that load but cannot be right: a scene whose radar points (almost) never fall into the
        image with the tables' calibration, keyframes milliseconds apart, ego poses that jump, a keyframe's radar
        record more than ``SYNC_WARN_MS`` from its camera's, a mount more than ``MOUNT_WARN_M`` from the vehicle's
        origin (each passed as a clean bill)."""
        out = []
        blind = [g for g in self.groups if sum(g.radar_points) >= 50 and g.radar_in_image < MIN_IN_IMAGE * sum(
            g.radar_points)]  # per scene: one vehicle's wrong mount hid among others' right ones (probe 29)
        if blind:
            pts, inside = sum(sum(g.radar_points) for g in blind), sum(g.radar_in_image for g in blind)
            away = max(g.boresight_deg for g in blind)
            where = ("" if len(blind) == len(self.groups) else f" in {len(blind)} of {len(self.groups)} scenes (" +
                     ", ".join(f"{g.scene} of {g.vehicle}" for g in blind[:4]) + (", ..." if len(blind) > 4 else "")
                     + ")")
            out.append(f"warning: only {inside} of {pts} radar points ({100 * inside / pts:.1f} %) project into the "
                       f"{self.camera_channel} image with the tables' extrinsic and intrinsics{where}: "
                       + (f"the tables' mounts turn the {self.radar_channel} {away:.0f} deg away from the "
                          f"{self.camera_channel}'s axis: " + self._away_words() if away > 60 else
                          "the intrinsics may be for another image size (width/height in sample_data against "
                          "camera_intrinsic's principal point), or the camera-radar extrinsic is far off"))
        for g in self.groups:
            out += pose_track_lines(g.scene, g.ego_track)
            if g.late:
                out.append(late_line(g.scene, g.late, self.radar_channel, self.camera_channel))
            if len(g.image_sizes) > 1:  # a frame of another size read with the drive's intrinsics (probe 29)
                (w, h), (n, _) = max(g.image_sizes.items(), key=lambda kv: kv[1][0])
                odd = [f"{ww} x {hh} ({m} frame(s), first: sample {tok})" for (ww, hh), (m, tok) in
                       g.image_sizes.items() if (ww, hh) != (w, h)]
                out.append(f"warning: scene {g.scene}: its {self.camera_channel} images are not all one size: {n} "
                           f"frames {w} x {h}, and {'; '.join(odd[:3])}: a camera's intrinsics fit one image size, "
                           "so those frames were resized or belong to another camera; replace them or give them "
                           "their own calibrated_sensor record")
            if g.tilted[1] > TILT_WARN_DEG:
                out.append(f"warning: scene {g.scene}: the {g.tilted[0]}'s mount in calibrated_sensor.json turns its "
                           f"up axis {g.tilted[1]:.0f} deg from the vehicle's up (a sensor mounted upside down or on "
                           "its side, or a rotation written wrong: a quaternion in x, y, z, w order, or inverted): "
                           "check the record's rotation" + ("; a camera really mounted so is unlike every frame the "
                                                            "network was trained on" if g.tilted[0] ==
                                                            self.camera_channel else ""))
            if g.ego_lean[1] > TILT_WARN_DEG:
                out.append(f"warning: scene {g.scene}: {lean_words(g.ego_lean[1], g.ego_lean[0])}; the Doppler steps "
                           "and the motion compensation use them: fix the records")
            if g.low_mount[1] < MIN_MOUNT_HEIGHT_M:
                out.append(f"warning: scene {g.scene}: the {g.low_mount[0]}'s mount lies {g.low_mount[1]:+.2f} m over "
                           f"the vehicle's origin in calibrated_sensor.json, under {MIN_MOUNT_HEIGHT_M:g} m (nuScenes' "
                           "ego origin is on the ground: a sensor sits above it): a translation's sign or unit is "
                           "wrong; fix the record")
            if g.far_mount[1] > MOUNT_WARN_M:
                out.append(f"warning: scene {g.scene}: the {g.far_mount[0]}'s mount lies {g.far_mount[1]:.1f} m from "
                           f"the vehicle's origin in calibrated_sensor.json (a sensor on a car sits within a few "
                           "metres of it): a translation in another unit (cm, dm) or another frame's; fix the record")
        if gap := keyframe_gap_warning(g.camera_us for g in self.groups):
            out.append(gap)
        return out

    def _away_words(self) -> str:
        """Why a radar would look away from the camera: another direction (a side or corner radar), or a mount
        rotation written wrong in calibrated_sensor.json; the second first when both channels name the same direction
        (probe 29: a radar quaternion in x, y, z, w order read "RADAR_FRONT looks 180 deg away ... pair it with a
        camera facing its way"). One shared word is no same direction: nuScenes' RADAR_FRONT_LEFT looks 88 deg left
        of CAM_FRONT by its true tables (probe 101 read "both channels are FRONT sensors, so a mount rotation ... is
        wrong")."""
        sides = ("FRONT", "BACK", "LEFT", "RIGHT")

        def direction(channel: str) -> tuple[str, ...]:
            return tuple(w for w in channel.upper().split("_") if w in sides)

        radar, camera = direction(self.radar_channel), direction(self.camera_channel)
        wrong = ("a mount rotation in calibrated_sensor.json is wrong (a quaternion written x, y, z, w instead of "
                 "w, x, y, z, or the inverse rotation: check both channels' records)")
        if radar and radar == camera:
            return (f"both channels are {'_'.join(radar)} sensors, so {wrong}; or the channels' names are not their "
                    "directions")
        mate = "CAM_" + "_".join(radar)
        pair = (f"pair it with the camera facing its way (--camera {mate} if the root has it)" if radar else
                "pair it with a camera facing its way (--radar / --camera)")
        return f"either a side or corner radar sees little of this camera's view: {pair}; or {wrong}"

    def _sweep_lines(self) -> list[str]:
        """What the radar's non-keyframe sweeps give the Doppler steps (mount monitor, lever arm), in words."""
        n, on = sum(g.sweeps_between for g in self.groups), sum(g.sweeps_on_disk for g in self.groups)
        broken = sum(g.sweeps_broken for g in self.groups)
        unread = sum(g.sweeps_unreadable for g in self.groups)
        bad_file = next((g.sweep_unreadable for g in self.groups if g.sweep_unreadable), "")
        tail = (f"; {broken} broken record(s) (a prev pointer that does not resolve, names a record left out for the "
                "schema (said above) or does not go back in time, a file name outside the root): the sweeps behind "
                "them are not paired" if broken else "")
        tail += (f"; {unread} of the files on disk do not read (first: {bad_file[:400]}): those are not paired"
                 if unread else "")
        head = f"{self.radar_channel} sweeps between keyframes: "
        if not n:
            return [head + f"none {'reached' if broken else 'in the tables'}; the mount monitor and the Doppler lever "
                    "arm pair keyframes only" + tail]
        per = n / max(self.n_frames, 1)
        if on == n:
            return [head + f"{n} ({per:.1f} per frame), all on disk; the mount monitor and the Doppler lever arm pair "
                    "them too" + tail]
        if on:
            return [head + f"{n} in the tables ({per:.1f} per frame), {on} on disk ({n - on} missing); the mount "
                    "monitor and the Doppler lever arm pair those on disk too" + tail]
        return [head + f"{n} in the tables ({per:.1f} per frame), none on disk (a keyframe-only copy); the mount "
                f"monitor and the Doppler lever arm pair keyframes only; add the sweeps/ folder for about "
                f"{1 + per:.0f} times as many pairs" + tail]

def keyframe_gap_warning(camera_us: Iterable[Iterable[int]]) -> str:
    """A warning ("" if none) when the camera keyframe timestamps of the scenes (one iterable of microseconds per
    scene) lie milliseconds apart at the median: the unit is not microseconds (inspect, and calibrate: the mount
    monitor, the Doppler pairs and the motion constraint read time from them)."""
    gaps = [d for us in camera_us for d in np.diff(sorted(us))]
    if not gaps:
        return ""
    # whole seconds: most gaps 0 (probe 100: a median of 0 was no warning, its frames "do not advance in time")
    gap, how = (float(np.median(gaps)), "median") if float(np.median(gaps)) > 0 else (float(np.mean(gaps)), "mean")
    if 0 < gap < MIN_KEYFRAME_GAP_US:
        shown = f"{gap / 1000:.3f} ms" if gap >= 1 else f"{gap:.2g} us"  # whole seconds: under a microsecond
        return (f"warning: keyframes are {shown} apart ({how}): the timestamps look like milliseconds or "
                "seconds; nuScenes uses microseconds (keyframes ~500 ms apart)")
    return ""


def timestamp_unit_warning(ds) -> str:
    """``keyframe_gap_warning`` of ``ds``'s camera keyframes, scene by scene ("" if none, or no frame)."""
    by_scene: dict[str, list[int]] = {}
    for ref in getattr(ds, "frames", []):
        if isinstance(ts := ref.camera_sd.get("timestamp"), int) and not isinstance(ts, bool):
            by_scene.setdefault(ref.scene_token, []).append(ts)
    return keyframe_gap_warning(by_scene.values())


EXAMPLES_PER_REASON = 3  # further frames (index and token) shown per kind of skip reason in the terminal
_HEX_TOKEN = re.compile(r"\b[0-9a-f]{32}\b")  # a nuScenes token
_SUFFIX = re.compile(r" \[(file|token) [^\]]*\]$")  # the [file ..., token ...] that DataError appends


def skip_kind(rec: dict[str, Any]) -> str:
    """A skip record's reason with what names the one item taken out (its token and file, other tokens, numbers),
    so that the reasons of frames that failed alike compare equal."""
    text = _SUFFIX.sub("", rec["reason"])
    for name in (rec.get("path"), rec.get("token")):
        if name:
            text = text.replace(str(name), "<>")
    return re.sub(r"\d+", "#", _HEX_TOKEN.sub("<token>", text))


def format_skips(skipped: list[dict[str, Any]], listed_in: str | None = None) -> list[str]:
    """Terminal lines for skip records (``SkipRecord`` dicts): one per kind of reason (``skip_kind``), in order of
    first occurrence, with its count, the first item's full reason and up to ``EXAMPLES_PER_REASON`` more items."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for rec in skipped:
        groups.setdefault(skip_kind(rec), []).append(rec)

    def where(rec: dict[str, Any]) -> str:  # an item of the index (no frame yet) by its token
        return f"frame {rec['index']}" if rec['index'] is not None else f"item {rec.get('token') or '-'}"

    lines = []
    for recs in groups.values():
        first = recs[0]
        if len(recs) == 1:
            lines.append(f"skipped {where(first)}: {first['reason']}")
            continue
        lines.append(f"skipped {len(recs)} items for one reason, e.g. {where(first)}: {first['reason']}")
        more = ", ".join(where(r) if r["index"] is None else f"{where(r)} ({r['token']})"
                         for r in recs[1:1 + EXAMPLES_PER_REASON])
        rest = len(recs) - 1 - EXAMPLES_PER_REASON
        lines.append(f"  also {more}" + (f" and {rest} more" if rest > 0 else ""))
    if any(len(recs) > 1 + EXAMPLES_PER_REASON for recs in groups.values()):
        lines.append(f"every skipped item is listed in {listed_in}" if listed_in else
                     "pass --out DIR to list every skipped item in DIR/inspect_summary.json")
    return lines


# a keyframe's ego position this far from the straight line of its two neighbours' (at its time): a car braking at
# 10 m/s2 or turning at 20 deg/s strays ~1 m at most over the second between them; a 10 m pose error in a
# parking lot (~20 m/s apparent, under MAX_ROAD_SPEED_MPS) passed inspect in silence (probe 11)
MAX_POSE_OFF_PATH_M = 3.0


def ego_track_warnings(ds, most: int = 3) -> list[str]:
    """``pose_track_lines`` of every scene of ``ds`` from its tables alone (each radar keyframe's timestamp and ego
    pose record; no sensor file read), at most ``most`` lines and one more saying how many were left out: what inspect
    warns of, for the commands that calibrate from those poses and times (probe 42: ego poses 5 km apart between two
    keyframes, and a radar keyframe 1 ms before its predecessor, passed calibrate in silence)."""
    records = ds.tables.by_token["ego_pose"] if hasattr(ds, "tables") else {}
    tracks: dict[str, list] = {}
    for ref in getattr(ds, "frames", []):
        rec, ts = records.get(ref.radar_sd.get("ego_pose_token")), ref.radar_sd.get("timestamp")
        try:
            t = np.asarray(rec["translation"], np.float64)
        except (TypeError, KeyError, ValueError):  # no record, or one the reader refuses (said per frame)
            continue
        if isinstance(ts, int) and t.shape == (3,) and np.all(np.isfinite(t)):
            tracks.setdefault(ref.scene_name, []).append((ref.sample_token, ts, t))
    lines = [w for scene, track in tracks.items() for w in pose_track_lines(scene, track)]
    if len(lines) > most:
        lines = lines[:most] + [f"warning: and {len(lines) - most} more such warning(s) (hybrid-calib inspect lists "
                                "them)"]
    return lines


def pose_track_lines(scene: str, track: list[tuple[str, int, np.ndarray]]) -> list[str]:
    """Warnings on a scene's keyframes in their order (``track``: (sample token, radar timestamp us, ego position
    (3,) m) each): radar timestamps that do not advance (the Doppler steps skip such pairs, and the mount monitor's
    words blamed missing sweep files), and ego poses that jump: faster than ``MAX_ROAD_SPEED_MPS`` between two
    keyframes, or a keyframe farther than ``MAX_POSE_OFF_PATH_M`` off the straight line of its neighbours (a pose
    50 m off passed inspect and calibrate in silence: probe 9; 10 m: probe 11)."""
    out = []
    back = [(a[0], b[0], a[1], b[1]) for a, b in zip(track, track[1:]) if b[1] <= a[1]]
    if back:
        a, b, ta, tb = back[0]
        out.append(f"warning: scene {scene}: {len(back)} keyframe(s) do not advance in time (sample {b} at {tb} us, "
                   f"its predecessor {a} at {ta} us): the tables' timestamps are broken; the Doppler steps skip "
                   "those pairs; fix or re-extract sample_data.json / sample.json")
    fast = [(a[0], b[0], float(np.linalg.norm(b[2] - a[2])) / ((b[1] - a[1]) * 1e-6))
            for a, b in zip(track, track[1:]) if b[1] > a[1]]
    fast = [f for f in fast if f[2] > MAX_ROAD_SPEED_MPS]
    off = []  # (sample, metres off the line of its neighbours)
    for a, b, c in zip(track, track[1:], track[2:]):
        if a[1] < b[1] < c[1]:
            w = (b[1] - a[1]) / (c[1] - a[1])
            if (d := float(np.linalg.norm(b[2] - ((1 - w) * a[2] + w * c[2])))) > MAX_POSE_OFF_PATH_M:
                off.append((b[0], d))
    if fast or off:
        worst = max(off, key=lambda o: o[1]) if off else None
        said = [f"{len(fast)} keyframe pair(s) faster than any road vehicle ({MAX_ROAD_SPEED_MPS:.0f} m/s; first: "
                f"sample {fast[0][0]} -> {fast[0][1]}, {fast[0][2]:.0f} m/s)" if fast else "",
                f"{len(off)} keyframe(s) off the path of their neighbours by more than {MAX_POSE_OFF_PATH_M:g} m "
                f"(worst: sample {worst[0]}, {worst[1]:.1f} m)" if off else ""]
        out.append(f"warning: scene {scene}: the ego poses jump: {'; '.join(w for w in said if w)}: an ego_pose "
                   "record is wrong; the Doppler steps skip pairs whose travel contradicts the radar's speed")
    return out


def vehicleless_warning(ds) -> str:
    """The samples ``ds``'s index left out that belong to no vehicle (``NuScenesRadarCamera.vehicleless``: their scene
    or its log is missing from the tables), in one sentence for the commands that calibrate per vehicle, or ""."""
    skips = getattr(ds, "vehicleless", None) or []
    if not skips:
        return ""
    more = f" (and {len(skips) - 1} more: hybrid-calib inspect lists them)" if len(skips) > 1 else ""
    return (f"warning: samples of no vehicle are not calibrated: {skips[0].reason}{more}; fix the tables (scene.json, "
            "log.json, sample.json) to calibrate them")


def late_line(scene: str, late: list[tuple[str, float]], radar_channel: str, camera_channel: str) -> str:
    """The warning on a scene's keyframes whose radar record is more than ``SYNC_WARN_MS`` from its camera's
    (``late``: (sample token, radar - camera ms) each)."""
    worst = max(late, key=lambda x: abs(x[1]))
    return (f"warning: scene {scene}: {len(late)} keyframe(s) whose {radar_channel} record is more than "
            f"{SYNC_WARN_MS:g} ms from its {camera_channel} record (worst: sample {worst[0]}, {worst[1]:+.0f} ms; "
            "nuScenes keyframes are under 0.1 s apart): a timestamp or the instant a record names is wrong, and the "
            "frame's motion compensation uses it; fix or re-extract sample_data.json")


def sync_warnings(ds) -> list[str]:
    """``late_line`` of every scene of ``ds`` from its tables alone (each keyframe's radar and camera timestamps; no
    file read): inspect's warning, for the commands that calibrate (probe 52: a radar clock 50 ms late was warned by
    inspect, and calibrate said nothing)."""
    late: dict[str, list[tuple[str, float]]] = {}
    for ref in getattr(ds, "frames", []):
        tr, tc = ref.radar_sd.get("timestamp"), ref.camera_sd.get("timestamp")
        if isinstance(tr, int) and isinstance(tc, int) and abs(dt := (tr - tc) / 1000.0) > SYNC_WARN_MS:
            late.setdefault(ref.scene_name, []).append((ref.sample_token, dt))
    return [late_line(scene, rows, getattr(ds, "radar_channel", "radar"), getattr(ds, "camera_channel", "camera"))
            for scene, rows in late.items()]


def table_warnings(ds) -> list[str]:
    """What a calibration says of ``ds``'s tables before it reads a frame (oracle and learned alike; inspect says the
    same in its summary): samples of no vehicle (``vehicleless_warning``), ego poses or radar times that jump or go
    back (``ego_track_warnings``) and radar records far from their camera's in time (``sync_warnings``)."""
    lost = vehicleless_warning(ds)
    return ([lost] if lost else []) + ego_track_warnings(ds) + sync_warnings(ds)


def ego_lean_warning(ds) -> str:
    """inspect's warning on ego poses that lean the vehicle over (a quaternion written x, y, z, w), from the tables'
    ego_pose records of ``ds``'s radar keyframes (no frame read), for the commands that calibrate from them; "" when
    none leans more than ``TILT_WARN_DEG`` (probe 40: calibrate said nothing of it, and blamed the radar's mount)."""
    from hybrid_calib.geometry import quat_wxyz_to_matrix

    worst: tuple[str, float] = ("", 0.0)
    records = ds.tables.by_token["ego_pose"] if hasattr(ds, "tables") else {}
    for ref in getattr(ds, "frames", []):
        rec = records.get(ref.radar_sd.get("ego_pose_token"))
        try:
            R = quat_wxyz_to_matrix(np.asarray(rec["rotation"], np.float64))
        except (TypeError, KeyError, ValueError):  # no record, or a rotation the reader refuses (said per frame)
            continue
        if np.all(np.isfinite(R)) and (lean := lean_deg(R, (0.0, 0.0, 1.0))) > worst[1]:
            worst = (ref.sample_token, lean)
    return "" if worst[1] <= TILT_WARN_DEG else f"warning: {lean_words(worst[1], worst[0])}"


def lean_words(lean: float, sample: str) -> str:
    """Ego poses that lean the vehicle ``lean`` deg over (at ``sample``), in words: inspect's and calibrate's."""
    return (f"the ego poses lean the vehicle up to {lean:.0f} deg from the world's up (sample {sample}; a car on a "
            "road leans a few degrees): a rotation in ego_pose.json is written wrong (a quaternion in x, y, z, w "
            "order, or another frame's)")


def lean_deg(T: np.ndarray, up: tuple[float, float, float]) -> float:
    """How far the axis ``up`` (3,) of a frame posed by ``T`` (4, 4, or its (3, 3) rotation) leans from the parent's z
    (up) axis, deg: a sensor's up in ego axes, or the vehicle's up in the world."""
    return float(np.degrees(np.arccos(np.clip((np.asarray(T, np.float64)[:3, :3] @ up)[2], -1.0, 1.0))))


def summarize_dataset(ds: NuScenesRadarCamera, progress: bool = True) -> DatasetSummary:
    """Load every frame of ``ds`` once and summarise it per scene and vehicle."""
    from tqdm import tqdm

    groups: dict[str, GroupSummary] = {}
    for ref in ds.frames:
        g = groups.setdefault(ref.scene_token, GroupSummary(ref.scene_name, ref.vehicle, ref.log_token))
        g.frames += 1
        records, on_disk, broken, unreadable, why = sweep_files_between(ds.tables, ref.radar_sd)
        g.sweeps_between += records
        g.sweeps_on_disk += on_disk
        g.sweeps_broken += broken
        g.sweeps_unreadable += unreadable
        g.sweep_unreadable = g.sweep_unreadable or why
    first = None
    for f in tqdm(ds, total=len(ds), desc="inspect", unit="frame", disable=not progress):
        g = groups[f.extras["scene_token"]]
        g.loaded += 1
        g.radar_points.append(len(f.radar_points))
        g.radar_raw.append(int(f.extras["radar_points_raw"]))
        g.nonfinite += int(f.extras["radar_nonfinite_dropped"])
        g.lidar_nonfinite += int(f.extras.get("lidar_nonfinite_dropped", 0))
        g.dt_ms.append((f.timestamp_radar_us - f.timestamp_camera_us) / 1000.0)
        if abs(g.dt_ms[-1]) > SYNC_WARN_MS:
            g.late.append((f.sample_token, g.dt_ms[-1]))
        size = g.image_sizes.setdefault((int(f.camera.width), int(f.camera.height)), [0, f.sample_token])
        size[0] += 1
        for channel, key, up in ((ds.radar_channel, "T_ego_radar", (0.0, 0.0, 1.0)),
                                 (ds.camera_channel, "T_ego_cam", (0.0, -1.0, 0.0))):
            if (mount := f.extras.get(key)) is None:
                continue
            if (d := float(np.linalg.norm(mount[:3, 3]))) > g.far_mount[1]:
                g.far_mount = (channel, d)
            # a sensor's up axis (an image's up: camera -y; a radar's z) in ego: a mount rolled ~180 deg still lands the
            # radar's points in the image, so the in-image check passed it (probe 34)
            if (lean := lean_deg(mount, up)) > g.tilted[1]:
                g.tilted = (channel, lean)
            if (z := float(mount[2, 3])) < g.low_mount[1]:
                g.low_mount = (channel, z)
        g.camera_us.append(int(f.timestamp_camera_us))
        pose = f.extras.get("T_global_ego_radar")
        if pose is not None and np.all(np.isfinite(pose)):
            g.ego_track.append((f.sample_token, int(f.timestamp_radar_us), np.asarray(pose)[:3, 3].copy()))
            # the vehicle's up (ego z) against the world's: every pose rolled 40 deg passed in silence (probe 38)
            if (lean := lean_deg(pose, (0.0, 0.0, 1.0))) > g.ego_lean[1]:
                g.ego_lean = (f.sample_token, lean)
        uv, z = f.camera.project(transform_points(f.T_cam_radar, f.radar_points))
        g.radar_in_image += int(((z > 0) & f.camera.in_image(uv)).sum())
        x_cam = np.asarray(f.T_cam_radar, np.float64)[:3, 0]  # the radar's boresight in camera axes
        g.boresight_deg = max(g.boresight_deg, float(np.degrees(np.arccos(np.clip(x_cam[2], -1.0, 1.0)))))
        first = f.index if first is None else first
    return DatasetSummary(str(ds.root), ds.version, ds.radar_channel, ds.camera_channel, list(groups.values()),
                          [dataclasses.asdict(s) for s in ds.skipped], first, dict(ds.calibration_splits),
                          dict(ds.calibration_offsets), ds.intrinsic_changes())


def _first_and_more(items: dict) -> tuple:
    """(first key, its value, " and N more" or "") of a non-empty dict, for a note that names one of several."""
    key, value = next(iter(items.items()))
    return key, value, f" and {len(items) - 1} more" if len(items) > 1 else ""


def sim_vehicle_gap_warning(ds, vehicles=None) -> str:
    """A warning ("" if none) when a simulated root's ``sim_vehicle.json`` holds records, but none for the log of some
    vehicle's frames (its tokens renamed, a merged log.json): that vehicle's verdicts then compare with its
    calibrated_sensor records, which in a simulated root are the truth, not its factory calibration (probe 94: a
    drift test flipped from significant to not, in silence). ``vehicles``: the ones the run calibrates."""
    sims = getattr(ds, "sim_vehicles", None)
    if not sims:
        return ""
    lost = {ref.log_token: ref.vehicle for ref in getattr(ds, "frames", []) if ref.log_token not in sims
            and (vehicles is None or ref.vehicle in vehicles)}
    if not lost:
        return ""
    log, vehicle, more = _first_and_more(lost)
    return (f"warning: {ds.tables.vdir / 'sim_vehicle.json'} holds no record of log {log} (vehicle {vehicle}){more}: "
            "its verdicts compare with its calibrated_sensor records, which in a simulated root are the truth, not "
            "the vehicle's factory calibration; fix the log tokens in sim_vehicle.json, or re-run hybrid-calib "
            "simulate")


def overlap_note(ds) -> str:
    """The scenes ``ds``'s index left out for being recorded while another scene of the same vehicle was
    (``NuScenesRadarCamera.overlapping``), in one note, or "" (probe 96: only inspect and result.json said them)."""
    left = getattr(ds, "overlapping", None) or {}
    if not left:
        return ""
    scene, other, more = _first_and_more(left)
    return (f"note: scene {scene}{more} left out: recorded while scene {other} of the same vehicle was (one vehicle "
            "records one scene at a time: the tables list one recording twice, or give two vehicles one name; "
            "hybrid-calib inspect lists its samples)")


def not_on_disk_note(ds, vehicles=None) -> str:
    """The scenes ``ds``'s index left out because none of their sensor files is on disk
    (``NuScenesRadarCamera.not_on_disk``: a partial download), of ``vehicles`` (None: all), in one note, or ""."""
    owner = getattr(ds, "not_on_disk_vehicle", {})
    left = {scene: path for scene, path in (getattr(ds, "not_on_disk", None) or {}).items()
            if vehicles is None or owner.get(scene) in vehicles}
    if not left:
        return ""
    scene, path, more = _first_and_more(left)
    gone = [v for v in (ds.not_on_disk_vehicles() if hasattr(ds, "not_on_disk_vehicles") else [])
            if vehicles is None or v in vehicles]
    return (f"note: scene {scene}{more} left out: their sensor files are not on disk ({path} is absent: a partial "
            "download); the scenes whose files are there are calibrated (--set 'data.scenes=[...]' names them; "
            "hybrid-calib inspect lists the scenes left out)" +
            (f"; vehicle(s) {', '.join(gone[:5])}{' and more' if len(gone) > 5 else ''} have no scene on disk: they "
             "cannot be calibrated" if gone else ""))


def calibration_notes(ds, vehicles=None) -> list[str]:
    """What a calibration says of ``ds``'s root before it reads a frame, the learned methods' and the oracle's alike
    (probe 94: the oracle had said only the reference and ``table_warnings``): the reference's notes, a vehicle whose
    tables hold several calibrations, a camera intrinsic that changes within a log, samples read once as another's
    copy, keyframes far apart in time, ``table_warnings`` and ego poses that lean the vehicle over. ``vehicles``: the
    ones the run calibrates (None: all)."""
    out = list(ds.reference_notes(vehicles)) if hasattr(ds, "reference_notes") else []
    if line := sim_vehicle_gap_warning(ds, vehicles):
        out.append(line)
    for vehicle, names in getattr(ds, "calibration_splits", {}).items():  # said where the names appear
        left = [n for n in names if vehicles is not None and n not in vehicles]
        out.append(f"vehicle {vehicle}: its frames hold {len(names)} camera-radar calibrations in the tables, "
                   f"calibrated as {', '.join(names)}" + (f" ({', '.join(left)} not among the vehicles asked for)"
                                                          if left else ""))
    out += [f"log {log}: {words}"
            for log, words in (ds.intrinsic_changes() if hasattr(ds, "intrinsic_changes") else {}).items()]
    out += [line for line in (overlap_note(ds), not_on_disk_note(ds, vehicles)) if line]
    if dup := getattr(ds, "duplicates", None):  # the index read them once (data.nuscenes._once_per_file)
        first = next(iter(dup.items()))
        out.append(f"note: {len(dup)} sample(s) read the same sensor files as earlier samples (first: {first[0]}, as "
                   f"{first[1]}): the tables list one recording twice; each frame is read once (hybrid-calib inspect "
                   "lists them)")
    for vehicle, skips in sorted(getattr(ds, "no_keyframe", {}).items()):  # inspect listed them; a calibration had
        # taken the next frames in their place in silence (probe 108)
        if vehicles is None or vehicle in vehicles:
            more = f" and {len(skips) - 1} more" if len(skips) > 1 else ""
            out.append(f"vehicle {vehicle}: {len(skips)} sample(s) left out, with no usable keyframe record ("
                       f"{skips[0].reason}{more}); the result's frames_skipped lists them")
    if wrong := getattr(ds, "misnamed", None):  # the index kept the frame its file belongs to (_once_per_file)
        more = f" and {len(wrong) - 1} more" if len(wrong) > 1 else ""
        out.append(f"warning: {len(wrong)} sample(s) left out, a sample_data record naming another sample's file "
                   f"({wrong[0].reason}{more})")
    if gap := timestamp_unit_warning(ds):  # inspect said it; a calibration read time from them silently
        out.append(f"{gap}: the radar mount monitor, its Doppler pairs and the motion constraint read time from them; "
                   "fix the tables before trusting this calibration")
    out += table_warnings(ds)  # inspect said them; the monitor, the Doppler and the motion read the poses
    if lean := ego_lean_warning(ds):  # inspect said it; a calibration read the poses silently (probe 40)
        out.append(f"{lean}: the radar mount monitor, its Doppler pairs and the motion compensation read the poses; "
                   "fix the tables before trusting this calibration")
    return out
