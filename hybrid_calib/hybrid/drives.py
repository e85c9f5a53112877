"""A vehicle's drive as the learned methods read it: its frames in time order, the start's base and what errors are
against (``Drive``, ``open_drives``), the depth the network reads there, its start, and what the drive itself says
about trust (a vehicle that did not move, the radar's sweep files).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from hybrid_calib.data.views import ViewConfig, repeated_views
from hybrid_calib.errors import DataError
from hybrid_calib.hybrid.network import shipped_checkpoint
from hybrid_calib.perturbation import vehicle_start
from hybrid_calib.words import did_you_mean, n_vehicles, some_of

if TYPE_CHECKING:
    from hybrid_calib.hybrid.loop import HybridConfig


@dataclass
class Drive:
    """One vehicle of a root: its frame indices (time order), the start base and what errors are against."""

    vehicle: str
    indices: list[int]
    base: np.ndarray  # (4, 4) truth (simulated) or tables (real)
    reference: np.ndarray  # (4, 4) the reference the drift test uses
    simulated: bool
    # (4, 4) the radar mount of the vehicle's tables (a simulated vehicle's: its factory calibration) at the first
    # readable frame: the radar mount monitor's reference and lever arm, and the yaw check's
    ego_radar: np.ndarray | None = None
    # (4, 4) simulated roots: the truth at the drive's last frame (differs from base when the mount moved
    # during the drive, e.g. a knocked radar); the final estimate's errors are against it
    end: np.ndarray | None = None
    # the vehicle's samples the index left out (no camera or radar keyframe): frames_skipped with index None
    index_skips: list = field(default_factory=list)
    # dataset index -> its skip record, for each frame that repeats an earlier view (the ego stood still:
    # ``data.views``); every learned method leaves them out
    repeats: dict = field(default_factory=dict)
    # dataset index -> its skip record, for each frame whose camera image is byte for byte an earlier frame's (a frozen
    # camera: ``frozen_images``); every learned method leaves them out, counted against the network's domain
    frozen: dict = field(default_factory=dict)
    # simulated roots: [(drive position, (4, 4))] where the true mount moved along the drive (``calib.result.path_of``
    # over the tables' records, which a simulated root's hold the truth in); [] when it did not
    truth_path: list = field(default_factory=list)
    # what ``reference`` is (``NuScenesRadarCamera.reference_source``): the tables, or an earlier export's mount
    reference_source: dict = field(default_factory=lambda: {"kind": "tables"})
    # how much the ego poses' heading jitters from record to record (``data.pose_jitter.HeadingJitter``; None: not
    # measured): too noisy, the hybrid's motion constraint takes the camera's turn from the images
    heading_jitter: object = None
    # dataset indices of the frames whose camera or radar file is not on disk (a partial download): no view, so not
    # counted among the drive's views (probe 101: the network priors' drive error counted 861 frames for 41)
    absent: list = field(default_factory=list)

    @property
    def errors_against(self) -> str:
        return "truth" if self.simulated else "tables"

    @property
    def poses_jitter(self) -> bool:
        """Whether its ego poses' heading jitters beyond ``data.pose_jitter.MAX_HEADING_JITTER_DEG`` (not measured:
        False)."""
        return bool(getattr(self.heading_jitter, "too_noisy", False))

    @property
    def n_views(self) -> int:
        """The drive's frames that are new views (``repeats`` and frames with no file on disk left out)."""
        return len(self.indices) - len(self.repeats) - len(set(self.absent) - set(self.repeats))

    def positions(self) -> dict[int, int]:
        """dataset index -> the frame's position in this drive (0-based): a learned trajectory's
        ``FrameEstimate.index``, so frames the loop dropped leave gaps instead of shifting later ones."""
        return {i: k for k, i in enumerate(self.indices)}


def resolve_depth(data, version: str, conf: HybridConfig) -> tuple[str, str]:
    """(depth spec, note): ``conf.depth``, or lidar-densified on a real root with LiDAR, or "" (the
    checkpoint's)."""
    from hybrid_calib.data.nuscenes import simulated_root
    from hybrid_calib.data.tables import sensor_channels, version_dir
    from learned.depth import LidarDepth

    if conf.depth:
        return conf.depth, ""
    version_dir(data, version)  # DataError naming a missing version folder
    simulated = simulated_root(data, version)
    if not simulated and "LIDAR_TOP" in sensor_channels(data, version):  # sensor.json alone (a trainval root's
        # tables were loaded twice per run: probe 101)
        return LidarDepth.name, "real root without --depth: using lidar-densified depth (the LiDAR through the tables)"
    return "", ""


def checked_depth(data, version: str, conf: HybridConfig, option: str = "--depth") -> tuple[str, str, str]:
    """(``resolve_depth``'s spec and note, the spec the run computes: that or the checkpoint's) of a learned run on the
    root, after checking that the root has the tables and what that depth reads: ``DataError`` naming a missing table,
    ``OptionError`` (``--depth``: ``learned.depth.check_depth_source``). Said once before any frame is read (probes 23
    and 71), by calibrate once per run and by fleet once per root (probe 124: once per vehicle, each job indexing the
    whole root first). ``option``: how the command takes a depth (``--depth``; fleet's ``--set depth``)."""
    from hybrid_calib.data.tables import require_tables
    from learned.depth import check_depth_source

    require_tables(data, version)
    depth, note = resolve_depth(data, version, conf)
    effective = depth or trained_depth(conf.checkpoint or shipped_checkpoint(conf.start))
    # probe 101: the real root's default read "the --depth given"
    check_depth_source(effective, data, given=bool(conf.depth) or (
        f"chosen for a real root whose tables list a LIDAR_TOP, when no {option} is given" if depth else False),
        option=option)
    return depth, note, effective


def effective_depth(data, version: str, conf: HybridConfig) -> str:
    """The depth estimator a learned run uses: ``--depth``, the real root's lidar-densified, or the checkpoint's."""
    return resolve_depth(data, version, conf)[0] or trained_depth(conf.checkpoint or shipped_checkpoint(conf.start))


def trained_depth(checkpoint) -> str:
    """The depth spec a checkpoint (path) was trained with (``learned.depth.trained_with``)."""
    from learned.checkpoint import read_checkpoint_meta
    from learned.depth import trained_with

    path, meta = read_checkpoint_meta(checkpoint)
    return trained_with(meta.get("train_config"), path)


def open_drives(data, version: str, conf: HybridConfig, lidar: bool, unreadable: dict | None = None,
                said: list | None = None):
    """(frames, {vehicle: Drive}) of a root, restricted to ``conf.vehicles``, the frames of
    ``conf.split`` (``learned.dataset.split_indices`` with ``conf.split_options``) and ``conf.max_frames``.
    A vehicle none of whose frames reads is a ``DataError`` (naming the first bad file), or, when
    ``unreadable`` is a dict, recorded there (vehicle -> reason) and left out."""
    from hybrid_calib.data.summary import calibration_notes
    from learned.dataset import open_frames, split_indices

    frames = open_frames(data, version, lidar=lidar,
                         options={**conf.data, **({"reference": conf.reference} if conf.reference else {})})
    for line in calibration_notes(frames, conf.vehicles):
        print(line, file=sys.stderr)
        if said is not None:  # the result keeps them (CalibrationRun.notes)
            said.append(line)
    simulated = bool(getattr(frames, "simulated", False))
    keep = None if conf.split == "all" else set(split_indices(frames, conf.split, conf.split_options))
    drives, outside_split = {}, []
    by_vehicle = frames.frames_by_vehicle()
    for vehicle, idx in sorted(by_vehicle.items()):
        if conf.vehicles is not None and vehicle not in conf.vehicles:
            continue
        if keep is not None:
            idx = [i for i in idx if i in keep]
            if not idx:
                outside_split.append(vehicle)
                continue
        n_all, idx = len(idx), (idx[: conf.max_frames] if conf.max_frames > 0 else idx)
        f, first_error = None, None
        for i in idx:  # the first readable frame gives the extrinsics
            try:
                f = frames[i]
                break
            except DataError as e:
                first_error = first_error or e
                continue
        if f is None:
            cut = (f"; only the first {len(idx)} of its {n_all} frames were tried (max_frames={conf.max_frames}): "
                   "raise max_frames, or fix these files" if len(idx) < n_all else "")  # probe 108: read as none at all
            reason = (f"vehicle {vehicle}: no readable frame ({len(idx)} frame(s) tried; first: "
                      f"{first_error if first_error is not None else '-'}){cut}")
            if unreadable is None:
                raise DataError(reason, path=str(data))
            unreadable[vehicle] = reason
            continue
        static = np.asarray(f.extras.get("T_cam_radar_static", f.T_cam_radar), np.float64)
        ref = np.asarray(f.extras.get("reference_T_cam_radar", static), np.float64)
        ego_radar = f.extras.get("reference_T_ego_radar", f.extras.get("T_ego_radar"))
        drives[vehicle] = Drive(vehicle, list(idx), static, ref, simulated,
                                None if ego_radar is None else np.asarray(ego_radar, np.float64),
                                _end_truth(frames, idx, static) if simulated else None,
                                [{"index": None, "token": s.token, "reason": s.reason}
                                 for s in getattr(frames, "lacking_keyframes", {}).get(vehicle, [])],
                                (repeats := view_repeats(frames, idx, conf.views)),
                                frozen_images(frames, idx, repeats), _truth_path(frames, idx) if simulated else [],
                                frames.reference_source(vehicle) if hasattr(frames, "reference_source") else
                                {"kind": "tables"},
                                frames.heading_jitter(idx) if hasattr(frames, "heading_jitter") else None,
                                frames.absent_files(idx) if hasattr(frames, "absent_files") else [])
    frameless = frames.frameless_vehicles(conf.vehicles) if hasattr(frames, "frameless_vehicles") else {}
    for vehicle, reason in frameless.items():  # a vehicle of no frame at all
        if vehicle in by_vehicle or vehicle in drives:
            continue
        if unreadable is None:
            raise DataError(reason, path=str(data))
        unreadable[vehicle] = reason
    if outside_split and not drives and not unreadable and conf.vehicles is None:  # "no vehicle to calibrate (check
        # --set vehicles=...)"; with a vehicle filter, the wanted vehicles' own message below
        opts = f", split options {conf.split_options}" if conf.split_options else ""
        raise DataError(f"no frame of vehicle(s) {outside_split} is in split {conf.split!r}{opts} ({len(frames)} "
                        "frames in the data; split by scene, the scenes of a small root can all go to train); pass "
                        "--split all, or --split-by time, or other --val-fraction / --test-fraction", path=str(data))
    # a wanted vehicle none of whose frames reads is in ``unreadable`` with its reason, not "not in the data"
    if conf.vehicles is not None and (missing := sorted(set(conf.vehicles) - set(drives) - set(unreadable or {}))):
        present = sorted(by_vehicle)
        if in_data := [v for v in missing if v in present]:  # present, but no frame of the split
            opts = f" (split options {conf.split_options})" if conf.split_options else ""
            raise DataError(f"vehicle(s) {in_data} have no frame in split {conf.split!r}{opts}; pass --split all or "
                            "other split options", path=str(data))
        close, mean = did_you_mean(missing[0], present)
        raise DataError(f"vehicle(s) {missing} not in the data{mean} (its {n_vehicles(len(present))}: "
                        f"{some_of(present, close)}; hybrid-calib inspect lists them)", path=str(data))
    return frames, drives


def _truth_path(frames, idx: list[int]) -> list:
    """Where a simulated drive's true mount moved (``calib.result.path_of``), from the tables' records of its frames
    (no sensor file read); a record that does not resolve is no truth there."""
    from hybrid_calib.calib.result import path_of
    from hybrid_calib.data.nuscenes import tables_extrinsic

    refs, tables = getattr(frames, "frames", None), getattr(frames, "tables", None)
    if refs is None or tables is None:
        return []
    return path_of(range(len(idx)), [tables_extrinsic(tables, refs[i].camera_sd, refs[i].radar_sd) for i in idx])


def _end_truth(frames, idx: list[int], static: np.ndarray) -> np.ndarray:
    """The static truth at the last readable frame of a simulated drive (``static`` when none reads)."""
    for i in reversed(idx):
        try:
            f = frames[i]
        except DataError:
            continue
        return np.asarray(f.extras.get("T_cam_radar_static", f.T_cam_radar), np.float64)
    return static


def start_of(drive: Drive, conf: HybridConfig) -> np.ndarray:
    return vehicle_start(drive.reference if conf.start == "reference" else drive.base, conf.start, conf.seed,
                         drive.vehicle)


def sweep_files_record(frames, indices) -> dict:
    """The mount block's words on the radar's sweep files between keyframes over dataset ``indices`` (those the
    monitor read): ``sweeps_absent`` when the tables list sweeps and none is on disk (a keyframe-only copy), else
    ``sweeps_missing`` {"n", "of", "first"} when some are missing, and ``sweeps_unreadable`` {"n", "of", "first": why}
    when some are on disk and do not read (probe 42: all of a drive's sweep files zero-byte left the monitor on its
    keyframes with a count of skipped pairs and no file named)."""
    seen = [getattr(frames, "sweep_files", {}).get(i) for i in indices]
    listed = sum(s[0] for s in seen if s)
    missing = [p for s in seen if s for p in s[1]]
    unread = [w for s in seen if s for w in s[2]]
    if listed and len(missing) == listed:
        return {"sweeps_absent": True}
    return {"sweeps_absent": False, **({"sweeps_missing": {"n": len(missing), "of": listed, "first": missing[0]}}
                                       if missing else {}),
            **({"sweeps_unreadable": {"n": len(unread), "of": listed, "first": unread[0]}} if unread else {})}


STANDSTILL_M = 1.0  # a drive whose ego poses travel less than this, metres: its frames are one view


def view_repeats(frames, idx: list[int], conf: ViewConfig) -> dict:
    """Dataset index -> skip record (``index``: its position in the drive) of each frame of ``idx`` that repeats an
    earlier view (``data.views``; none where the frames have no ego poses)."""
    poses = frames.camera_poses(idx) if conf.enabled and hasattr(frames, "camera_poses") else []
    return {idx[k]: r.record(k, frames.frames[idx[k]].camera_sd.get("token"), conf)
            for k, r in repeated_views(poses, conf).items()}


def frozen_images(frames, idx: list[int], repeats: dict) -> dict:
    """Dataset index -> skip record (``index``: its position in the drive; ``frozen``: the position of the frame it
    copies) of each frame of ``idx`` whose camera image file is byte for byte an earlier frame's. A camera's views of
    two moments differ at least by their sensor noise; the same bytes are a frozen camera or a file copied over
    another (probe 89: a repeated frame scored in domain and was fused as a view of its own). Frames that repeat a
    view (``repeats``: the ego stood still, a simulated stop renders the same image) are not compared; frames whose
    file does not read are left to the run, which says why."""
    import hashlib

    files = frames.camera_files(idx) if hasattr(frames, "camera_files") else []
    seen: dict[str, int] = {}
    out = {}
    for k, path in enumerate(files):
        if path is None or idx[k] in repeats:
            continue
        try:
            digest = hashlib.sha1(path.read_bytes()).hexdigest()
        except OSError:
            continue
        if digest in seen:
            out[idx[k]] = {"index": k, "token": frames.frames[idx[k]].camera_sd.get("token"), "frozen": seen[digest],
                           "reason": f"the camera image is byte for byte frame {seen[digest]}'s ({path.name}): a "
                                     "frozen camera, or a file copied over another; not a view of its own moment"}
        else:
            seen[digest] = k
    return out


def standstill_reason(frames, drive: Drive) -> str:
    """Why a learned result of a drive that did not move cannot be trusted, or "": its frames repeat one view, so the
    network's passes on them share their errors, yet each entered as an independent frame (a stand-still drive's
    1-sigma shrank from 1 frame to 10 with the same estimate, NEES 13.7 -> 23.3 on real data: probe 7)."""
    travel = getattr(frames, "ego_travel_m", lambda idx: None)(drive.indices) if len(drive.indices) > 1 else None
    if travel is None or travel >= STANDSTILL_M:
        return ""
    return (f"the vehicle did not move (its ego poses travel {travel:.2f} m over {len(drive.indices)} frames): the "
            "frames show one view (its repeats are left out), and one view cannot tell the network's error on it "
            "from the extrinsic, however many frames show it; calibrate on a drive")
