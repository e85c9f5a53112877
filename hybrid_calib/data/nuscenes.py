"""Synchronised radar-camera frames from any nuScenes-format root (real v1.0-* or simulated v1.0-sim).

One frame per sample (keyframe) that has both channels: the camera keyframe image and the radar
keyframe sweep of the same sample (plus, optionally, earlier radar sweeps and the LiDAR keyframe).
A frame's projection of radar points into its image is ego-motion compensated (docs/conventions.md):
``frame.T_cam_radar = inv(T_ego_cam) inv(T_global_ego(t_cam)) T_global_ego(t_radar) T_ego_radar``; the
calibrated quantity, and the truth errors are scored against, is the mount ``inv(T_ego_cam) T_ego_radar``
(``extras["T_cam_radar_static"]``).

Bad input policy:
- Root, version folder, tables, channel names and subsets are checked when the dataset is built;
  problems raise ``DataError`` naming the file / token and what to do.
- Per-frame problems (corrupt PCD, missing or non-image or truncated JPEG, unresolved token, a sweep
  whose points are all NaN, an empty sweep after filtering, a radar or LiDAR keyframe whose timestamp is more
  than ``DataConfig.max_sync_offset_s`` from the camera's) raise ``DataError`` from ``dataset[i]``;
  iteration records a ``SkipRecord`` in ``dataset.skipped`` and goes on
  (``on_error="skip"``) or re-raises (``on_error="raise"``).
- Points with NaN/inf coordinates (or beyond ``filters.MAX_RANGE_M``, 400 m) are dropped and counted
  (``extras["radar_nonfinite_dropped"]``);
  a sweep in which every point is NaN is rejected.
- Images are checked eagerly but cheaply (signature, size and end marker, no decode; see
  ``image_header``); ``RadarCameraFrame.load_image`` decodes lazily and rejects an image whose
  decoder reports corrupt data (``decode_images=True`` does that in ``dataset[i]``, as ``inspect`` does).
- Tables: a duplicate token, or an ego-pose / calibration quaternion whose norm is off 1 by more
  than ``tables.QUAT_NORM_TOL`` (renormalised within it), is a ``DataError``; a ``sample`` table
  without samples too.

``frame.extras`` keys (all (4, 4) float64 transforms follow docs/conventions.md):
  T_ego_cam, T_ego_radar: calibrated_sensor extrinsics; T_global_ego_cam, T_global_ego_radar: ego
  poses at the two timestamps; T_cam_radar_static: inv(T_ego_cam) T_ego_radar (no ego motion);
  reference_T_cam_radar: the reference a drift detector compares against (the simulated vehicle's
  factory calibration for v1.0-sim roots with sim_vehicle.json, else T_cam_radar_static; with
  ``DataConfig.reference``, an earlier export's mount for the vehicles it wrote: ``data.reference``);
  radar_rows: (N,) int64 rows of the newest PCD kept after NaN removal and filtering (single sweep);
  radar_truth_path: simulator per-point truth (.npz, rows aligned with the unfiltered PCD; single
  sweep); radar_sweep_index (N,) int16 and radar_sweep_dt_s (N,) float32; radar_points_raw,
  radar_nonfinite_dropped, radar_sweeps_used, radar_sweeps_missing: counts; lidar_token,
  lidar_nonfinite_dropped when LiDAR is loaded.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import re
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hybrid_calib.config import merge
from hybrid_calib.data.filters import MAX_RANGE_M, RadarFilterConfig
from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.data.image_header import decode_image, image_header
from hybrid_calib.data.mounts import SAME_CALIBRATION, mount_offset, same_calibration
from hybrid_calib.data.pcd import read_lidar_bin
from hybrid_calib.data.reference import load_export_reference
from hybrid_calib.data.sweeps import InterSweep, accumulate_radar, sweeps_between_keyframes
from hybrid_calib.data.tables import (
    MAX_EGO_TURN_DPS,
    MAX_MOUNT_TRANSLATION_M,
    POSE_PAIR_MARGIN_DEG,
    POSE_PAIR_MARGIN_M,
    QUAT_NORM_TOL,
    NuScenesTables,
    _is_number_list,
    short_repr,
    vector_or_reason,
)
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import is_rigid, pose_from_nuscenes, se3_inverse, so3_log
from hybrid_calib.sensors.camera import PinholeCamera
from hybrid_calib.sensors.radar_velocity import MAX_ROAD_SPEED_MPS


@dataclass(frozen=True)
class DataConfig:
    radar_filter: RadarFilterConfig = RadarFilterConfig()  # point filters (devkit defaults)
    nsweeps: int = 1  # radar sweeps per frame (1 = keyframe only; earlier sweeps need their files)
    load_lidar: bool | None = False  # also load the LiDAR keyframe points and T_cam_lidar (None: when the root has it)
    lidar_channel: str = "LIDAR_TOP"  # LiDAR channel used when load_lidar is set
    scenes: tuple[str, ...] | None = None  # scene names or tokens to keep; None = all
    vehicles: tuple[str, ...] | None = None  # log vehicle names to keep; None = all
    on_error: str = "skip"  # iteration: "skip" records bad frames in .skipped and goes on, "raise" stops
    skip_empty_radar: bool = True  # a frame with zero radar points after filtering is an error (skipped)
    check_images: bool = True  # eager image header check (signature, size, end marker; no decode)
    decode_images: bool = False  # also decode each image in dataset[i] and reject corrupt pixel data (slower)
    # |t_radar - t_camera| (and |t_lidar - t_camera| with load_lidar) above this, seconds, makes the frame a skip:
    # one of the timestamps is corrupt (real nuScenes keyframes are under 0.1 s apart, simulated ones under 0.06 s)
    max_sync_offset_s: float = 0.5
    # an earlier export (``hybrid-calib export``'s --out folder or its export.json) whose exported mounts are the
    # reference of the vehicles it names (``data.reference``); None: every vehicle's tables
    reference: str | None = None

    def __post_init__(self):
        if self.on_error not in ("skip", "raise"):
            raise ValueError(f"DataConfig.on_error must be 'skip' or 'raise', got {self.on_error!r}")
        if not 1 <= int(self.nsweeps) <= 1000:
            raise ValueError(f"DataConfig.nsweeps (--nsweeps) must be in 1..1000, got {self.nsweeps}")
        if not 0 < float(self.max_sync_offset_s) < float("inf"):
            raise ValueError(f"DataConfig.max_sync_offset_s must be a positive number of seconds, got "
                             f"{self.max_sync_offset_s}")


@dataclass(frozen=True)
class SkipRecord:
    """A frame (or, with index None, a table record found while indexing) that could not be used."""

    index: int | None  # dataset index, None for problems found while building the index
    token: str  # sample / sample_data / scene token concerned
    path: str | None  # file concerned, if any
    reason: str  # what is wrong and what to do


def tables_extrinsic(tables, camera_sd: dict, radar_sd: dict) -> np.ndarray | None:
    """(4, 4) the static T_cam_radar the calibrated_sensor records of two keyframes give (no sensor file read), None
    where a record does not read (the frame says why when it is read)."""
    try:
        return se3_inverse(tables.T_ego_sensor(camera_sd)) @ tables.T_ego_sensor(radar_sd)
    except (DataError, KeyError, TypeError, ValueError):
        return None


# a principal point farther than this fraction of the image's width or height from its centre: an intrinsic for
# another image size (nuScenes' CAM_FRONT: 51 % / 55 %; the simulator's: 51 % / 54 %)
MAX_PP_OFF_CENTRE = 0.15
_CAL_SUFFIX = re.compile(r"-cal\d+$")  # NAME-cal2: the second calibration of vehicle NAME (_one_mount_per_vehicle)


@dataclass(frozen=True)
class FrameRef:
    """What the index knows about a frame before loading it."""

    sample_token: str
    scene_name: str
    scene_token: str
    log_token: str
    vehicle: str
    camera_sd: dict = field(repr=False)
    radar_sd: dict = field(repr=False)


class MissingSweepWarning(UserWarning):
    """Earlier radar sweeps were requested but their files are absent (keyframe-only release)."""


class RadarElevationWarning(UserWarning):
    """The radar's points carry elevation (a 4D radar): they are read as a 2D radar's, z set to 0."""


# a keyframe point's |z| above this (m) is an elevation the radar measured: a 2D radar writes z = 0 (earlier sweeps
# carried into the keyframe's radar frame get a few cm from the ego's pitch)
RADAR_Z_M = 0.05


class NuScenesRadarCamera:
    """Radar-camera frames of one nuScenes version folder.

    Args:
      root: the folder holding ``VERSION/*.json`` and ``samples/`` (and ``sweeps/`` if any).
      version: a folder name under root, e.g. ``v1.0-mini``, ``v1.0-trainval``, ``v1.0-sim``.
      radar_channel, camera_channel: sensor channels (``sensor.json``).
      conf: ``DataConfig`` or a mapping of overrides (unknown keys raise).
    """

    def __init__(self, root: str | Path, version: str, radar_channel: str = "RADAR_FRONT",
                 camera_channel: str = "CAM_FRONT", conf: DataConfig | dict | None = None):
        self.conf = merge(DataConfig, conf)
        for name, value in (("version", version), ("radar_channel", radar_channel), ("camera_channel", camera_channel)):
            if not isinstance(value, str) or not value:  # probe 67: None was "unsupported operand type(s) for /"
                raise TypeError(f"NuScenesRadarCamera: {name} must be a non-empty str (e.g. 'v1.0-mini'), got "
                                f"{value!r}")
        self.root = Path(root)
        self.version = version
        self.radar_channel = radar_channel
        self.camera_channel = camera_channel
        self.tables = NuScenesTables(root, version)
        channels = self.tables.channels()
        if self.conf.load_lidar is None:  # "when the root has one", resolved on the tables read once here
            self.conf = dataclasses.replace(self.conf, load_lidar=self.conf.lidar_channel in channels)
        wanted = [radar_channel, camera_channel] + ([self.conf.lidar_channel] if self.conf.load_lidar else [])
        for ch in wanted:
            if ch not in channels:
                kind = "radar" if ch == radar_channel else "camera" if ch == camera_channel else "lidar"
                same = [c for c in channels if self.tables.modality(c) == kind]
                # renaming channels in sensor.json (the old advice) left every sample_data file named for its own
                # channel, and each frame was refused (probe 34)
                how = ("; inspect reads another with --radar / --camera; calibrate, fleet, compare, train and evaluate "
                       "work on RADAR_FRONT -> CAM_FRONT only (nuScenes' front radar and camera, the pair the network "
                       "was trained on): another pair is not supported by them" if kind != "lidar" else
                       "; the LiDAR is read for lidar-densified depth and the hybrid's LiDAR alignment: pass another "
                       "--depth, or --set lidar.enabled=false")
                raise DataError(f"channel {ch!r} is not in sensor.json; {kind} channels present: {same or 'none'}"
                                f"{how}", path=str(self.tables.path("sensor")))
        # (inspect's options: the other commands read RADAR_FRONT and CAM_FRONT; probe 108 met "(--radar)" in calibrate)
        for ch, modality, option in ((radar_channel, "radar", "the radar channel: inspect's --radar"),
                                     (camera_channel, "camera", "the camera channel: inspect's --camera"),
                                     (self.conf.lidar_channel, "lidar", "lidar_channel")):
            found = self.tables.modality(ch)
            if ch in wanted and "/" in found:  # a second record of the channel read as "a camera, not a radar"
                raise DataError(f"channel {ch!r} ({option}) is named by several sensor records in sensor.json, of "
                                f"modalities {found.replace('/', ' and ')}: one channel is one sensor; remove the "
                                "record that is not its sensor (and the calibrated_sensor records that name it)",
                                path=str(self.tables.path("sensor")))
            if ch in wanted and found != modality:
                same = [c for c in channels if self.tables.modality(c) == modality]
                raise DataError(f"channel {ch!r} ({option}) is a {found or 'unknown'} sensor in sensor.json, not a "
                                f"{modality}; {modality} channels present: {same}",
                                path=str(self.tables.path("sensor")))
        self.sim_vehicles: dict[str, dict] = load_sim_vehicles(self.tables.vdir)
        # written by the simulator: its vehicles' factory calibrations (sim_vehicle.json), not a folder's name (probe
        # 137: a real root in a folder named v1.0-sim, the commands' default, was never split); a root simulated
        # before the file, or whose file does not read (said), is read as a real one
        self.simulated = bool(self.sim_vehicles)
        self.export_reference = load_export_reference(self.conf.reference) if self.conf.reference else None
        self._index_skips: list[SkipRecord] = [
            SkipRecord(None, tok, str(self.tables.path("sample_data")), reason)
            for tok, reason in self.tables.index_problems]
        self._iter_skips: dict[int, SkipRecord] = {}
        # log vehicle -> its samples the index left out for lacking a camera or radar keyframe: a vehicle of the
        # root with no frame at all (its car has no RADAR_FRONT) is said, not silently absent from the result
        self.lacking_keyframes: dict[str, list[SkipRecord]] = {}
        # those of them with no usable camera or radar keyframe record (a calibration says them: probe 108)
        self.no_keyframe: dict[str, list[SkipRecord]] = {}
        # samples the index left out that belong to no vehicle (their scene is not in scene.json, or its log is not
        # in log.json): a calibration lists no vehicle for them, so it says them (probe 42: a vehicle vanished, rc 0)
        self.vehicleless: list[SkipRecord] = []
        self._warned_missing_sweeps = False
        self._warned_elevation = False
        self.radar_sweeps_missing = 0  # non-keyframe sweep files absent on disk (radar_sweeps_between)
        # frame -> (sweeps listed, files missing, why the unreadable ones did not read) so far
        self.sweep_files: dict[int, tuple[int, list[str], list[str]]] = {}
        self.calibration_splits: dict[str, list[str]] = {}  # vehicle -> its calibrations' names, when more than 1
        self.calibration_offsets: dict[str, tuple[float, float]] = {}  # NAME-calN -> (deg, cm) from NAME's
        self.misnamed: list[SkipRecord] = []  # samples left out: a record of theirs names another sample's file
        self.duplicates: dict[str, str] = {}  # sample read once: a sensor file of it is the named earlier sample's
        self.overlapping: dict[str, str] = {}  # scene left out -> the scene of its vehicle recorded at the same time
        self.not_on_disk: dict[str, str] = {}  # scene left out -> a sensor file of it that is absent (partial download)
        self.not_on_disk_vehicle: dict[str, str] = {}  # the same scenes -> their vehicle
        self.frames: list[FrameRef] = self._build_index()
        if not self.frames and self._index_skips:  # nothing to read, and the reason is known: say it now
            first = self._index_skips[0]
            raise DataError(f"no frame in this version folder: {len(self._index_skips)} problem(s) found while "
                            f"indexing its tables; first: {first.reason}; fix the tables or re-extract the metadata",
                            path=first.path, token=first.token)

    # ---------------------------------------------------------------- index
    def _build_index(self) -> list[FrameRef]:
        t = self.tables
        scenes = t.records["scene"]
        if self.conf.scenes is not None:
            names = {s["name"] for s in scenes} | {s["token"] for s in scenes}
            unknown = sorted(set(self.conf.scenes) - names)
            if unknown:
                raise DataError(f"scene(s) {unknown} not found; scenes present: {sorted(s['name'] for s in scenes)}",
                                path=str(t.path("scene")))
            scenes = [s for s in scenes if s["name"] in self.conf.scenes or s["token"] in self.conf.scenes]
        wanted = None  # the logs' vehicle names of conf.vehicles (a calibration's name NAME-calN is NAME's)
        if self.conf.vehicles is not None:
            present = sorted({lg["vehicle"] for lg in t.records["log"]})
            wanted = {_CAL_SUFFIX.sub("", v) for v in self.conf.vehicles}
            unknown = sorted(wanted - set(present))
            if unknown:
                raise DataError(f"vehicle(s) {unknown} not found; vehicles present: {present}",
                                path=str(t.path("log")))
        frames: list[FrameRef] = []
        orphans: dict[str, list] = {}  # scene token not in scene.json -> its samples' tokens (never indexed)
        for sample in t.records["sample"]:
            if sample["scene_token"] not in t.by_token["scene"]:
                orphans.setdefault(sample["scene_token"], []).append(sample.get("token"))
        for token, samples in orphans.items():  # the samples named too: they are the records to fix (probe 47)
            self._index_skips.append(SkipRecord(
                None, token, str(t.path("scene")),
                f"{len(samples)} sample(s) reference scene {token}, which is not in scene.json (sample "
                f"{samples[0]}{f' and {len(samples) - 1} more' if len(samples) > 1 else ''}); they are skipped (the "
                "tables are inconsistent: re-extract the metadata, or fix those samples' scene_token)"))
            self.vehicleless.append(self._index_skips[-1])
        if lost := self._keyframes_of_no_sample():  # no scene, so no vehicle (probe 94: calibrate said nothing)
            self.vehicleless.append(lost)
        empty = [sc for sc in scenes if not t.scene_samples(sc)]
        if empty:  # a partial metadata copy, or scene.json of a larger release: said once, not silently dropped
            names = [sc["name"] for sc in empty]
            self._index_skips.append(SkipRecord(
                None, empty[0]["token"], str(t.path("sample")),
                f"{len(empty)} of the {len(scenes)} scene(s) of scene.json have no sample in sample.json "
                f"({', '.join(names[:5])}{', ...' if len(names) > 5 else ''}; e.g. {names[0]}'s first_sample_token "
                f"{empty[0].get('first_sample_token')!r} does not resolve): they hold no frame (tables of another "
                "release or a partial copy: use the version folder that holds their samples)"))
        for scene in scenes:
            log = t.by_token["log"].get(scene["log_token"])
            if log is None:
                self._index_skips.append(SkipRecord(
                    None, scene["token"], str(t.path("log")),
                    f"scene {scene['name']} references log {scene['log_token']}, which is not in log.json; "
                    f"its {len(t.scene_samples(scene))} sample(s) are skipped (the log names the vehicle)"))
                self.vehicleless.append(self._index_skips[-1])
                continue
            if wanted is not None and log["vehicle"] not in wanted:
                continue
            for sample in t.scene_samples(scene):
                cam = t.keyframe(sample["token"], self.camera_channel)
                rad = t.keyframe(sample["token"], self.radar_channel)
                if cam is None or rad is None:
                    lacking = [ch for ch, sd in ((self.camera_channel, cam), (self.radar_channel, rad)) if sd is None]
                    own, lost = t.unplaced_keyframes.get(sample["token"]), t.unplaced_keyframes.get("")
                    left = t.left_out_of_sample.get(sample["token"])
                    hint = (f" (its sample_data record {left[0][0]} was left out: {left[0][1]})" if left else
                            f" (its keyframe sample_data {', '.join(own)} names no sensor: its calibrated_sensor does "
                            "not resolve)" if own else f" ({len(lost)} keyframe sample_data record(s) name a sample "
                            f"not in sample.json, e.g. {lost[0]}: one may be its keyframe)" if lost else "")
                    two = [t.ambiguous_keyframes[(sample["token"], ch)] for ch in lacking
                           if (sample["token"], ch) in t.ambiguous_keyframes]
                    # probe 45: two camera keyframes read "has no keyframe for ['CAM_FRONT']"
                    skip = SkipRecord(None, sample["token"], str(t.path("sample_data")),
                                      f"{'; '.join(two)}; not a frame" if two else
                                      f"sample {sample['token']} has no keyframe for {lacking}{hint}; not a frame")
                    if not two:  # (two keyframes are among the index's problems already: said once)
                        self._index_skips.append(skip)
                    self.lacking_keyframes.setdefault(log["vehicle"], []).append(skip)
                    self.no_keyframe.setdefault(log["vehicle"], []).append(skip)
                    continue
                frames.append(FrameRef(sample["token"], scene["name"], scene["token"], log["token"],
                                       log["vehicle"], cam, rad))
        frames = self._once_per_file(frames)
        frames = self._one_mount_per_vehicle(frames)  # before: a calibration's name must not depend on the download
        frames = self._on_disk(frames)
        frames = self._one_scene_at_a_time(frames)
        if self.conf.vehicles is not None:
            names = sorted({f.vehicle for f in frames})
            if unknown := sorted(set(self.conf.vehicles) - set(names)):
                raise DataError(f"vehicle(s) {unknown} not found; vehicles present: {names} (a vehicle whose logs "
                                "are calibrated differently is one vehicle per calibration: NAME, NAME-cal2, ...)",
                                path=str(t.path("calibrated_sensor")))
            frames = [f for f in frames if f.vehicle in self.conf.vehicles]
        return frames

    def _once_per_file(self, frames: list[FrameRef]) -> list[FrameRef]:
        """``frames`` without those whose camera or radar keyframe is a file an earlier frame reads already (each
        said in the index's skips): tables that list one recording twice (a scene copied under new scene and log
        tokens, pointing at the same files) were fused as one drive of twice the frames, the duplicates counted as
        independent measurements (probe 9: a smaller 1-sigma, a lever arm over its turning-frames gate). Of two
        frames reading one file, the one whose record's timestamp the file's name carries (nuScenes names a file
        ``..__CHANNEL__<timestamp>.ext``) is kept: a record pointed at the next frame's image had kept the wrong
        pairing (the camera 400 ms after its radar) and left the right one out (probe 108)."""
        first: dict[str, FrameRef] = {}
        out: dict[str, FrameRef] = {}  # sample token -> frame, in the tables' order
        for ref in frames:
            files = [f for f in (sd.get("filename") for sd in (ref.camera_sd, ref.radar_sd)) if f]
            shared = {f for f in files if f in first}
            dup = next((first[f] for f in files if f in first), None)
            if dup is not None and _names_its_file(ref, shared) and not _names_its_file(dup, shared):
                del out[dup.sample_token]  # the earlier frame points at this one's file: it is the one left out
                first = {f: r for f, r in first.items() if r is not dup}
                wrong = next(sd for sd in (dup.camera_sd, dup.radar_sd) if sd.get("filename") in files)
                self._left_out(dup, f"sample {dup.sample_token} (scene {dup.scene_name}): its sample_data record "
                                    f"{wrong.get('token')} names the file {wrong.get('filename')}, whose name "
                                    f"carries the timestamp of sample {ref.sample_token}'s record, not its own "
                                    f"({wrong.get('timestamp')}): fix that record's filename in sample_data.json")
                self.misnamed.append(self._index_skips[-1])  # not a recording listed twice (probe 110)
            elif dup is not None:  # a vehicle all of whose samples are another's is named (probe 94: it vanished)
                self._left_out(ref, f"sample {ref.sample_token} (scene {ref.scene_name}) reads the same sensor file "
                                    f"as sample {dup.sample_token} (scene {dup.scene_name}): the tables list one "
                                    "recording twice; its frame is read once")
                self.duplicates[ref.sample_token] = dup.sample_token
                continue
            first.update({f: ref for f in files})
            out[ref.sample_token] = ref
        return list(out.values())

    def _keyframes_of_no_sample(self) -> SkipRecord | None:
        """The run's camera and radar keyframes whose sample is not in sample.json, as one record (None if none)."""
        t = self.tables

        def channel(sd: dict) -> str:
            try:
                return t.channel_of(sd)
            except DataError:
                return ""  # no sensor: the index's problems say it

        lost = [sd for tok in t.unplaced_keyframes.get("", []) if channel(sd := t.by_token["sample_data"][tok])
                in (self.camera_channel, self.radar_channel)]
        return None if not lost else SkipRecord(None, lost[0]["token"], str(t.path("sample")), (
            f"{len(lost)} {self.camera_channel} / {self.radar_channel} keyframe sample_data record(s) reference "
            f"samples not in sample.json (first: {lost[0]['token']}, {lost[0].get('filename')}, sample "
            f"{lost[0]['sample_token']}): no scene names their vehicle; the tables are inconsistent or a partial copy: "
            "re-extract the metadata, or restore those samples"))

    def _left_out(self, ref: FrameRef, reason: str) -> None:
        """Say that the index leaves ``ref``'s sample out, once among the index's skips and once among its
        vehicle's samples that hold no frame (``lacking_keyframes``: listed in the vehicle's result, and a vehicle
        left with no frame at all is named, not silently absent; probe 94)."""
        skip = SkipRecord(None, ref.sample_token, str(self.tables.path("sample_data")), reason)
        self._index_skips.append(skip)
        self.lacking_keyframes.setdefault(ref.vehicle, []).append(skip)

    def _on_disk(self, frames: list[FrameRef]) -> list[FrameRef]:
        """``frames`` without the scenes none of whose frames has both its camera and its radar keyframe file on disk,
        when some other scene has (a partial download: trainval's tables with a few of its blobs), each scene said
        once (``_left_out`` of its first sample, ``not_on_disk``). Read as frames, such scenes were one unread frame
        each in their vehicle's drive: a drive of 41 readable frames in 861 inflated its network priors by the 861
        and ended "a radar knocked, blocked or failed there" (probe 101), with a line per absent file. A root with
        no file at all keeps its per-frame words (samples/ not beside the version folder, and so on)."""
        def present(sd: dict) -> bool:  # anything there (a folder, a dangling link) is the frame's read to name
            name = sd.get("filename")  # (not a path: the frame's read names the record)
            return not isinstance(name, str) or not name or os.path.lexists(self.root / name)

        scenes: dict[str, list[FrameRef]] = {}
        for ref in frames:
            scenes.setdefault(ref.scene_token, []).append(ref)
        absent: dict[str, str] = {}  # scene token -> its first absent file
        for token, refs in scenes.items():
            first = None
            for ref in refs:
                missing = [sd["filename"] for sd in (ref.camera_sd, ref.radar_sd) if not present(sd)]
                if not missing:
                    break
                first = first or missing[0]
            else:
                absent[token] = first
        if not absent or len(absent) == len(scenes):
            return frames
        out = []
        for ref in frames:
            if ref.scene_token not in absent:
                out.append(ref)
            elif ref.scene_name not in self.not_on_disk:
                n = len(scenes[ref.scene_token])
                self.not_on_disk[ref.scene_name] = absent[ref.scene_token]
                self.not_on_disk_vehicle[ref.scene_name] = ref.vehicle
                self._left_out(ref, (
                    f"scene {ref.scene_name}: none of its {n} frame(s) has its camera and radar keyframe files on disk "
                    f"(e.g. {absent[ref.scene_token]} is absent under {self.root}): a partial download; the scene is "
                    "left out (download its sensor files, or name the scenes you have with --set "
                    "'data.scenes=[\"scene-...\"]')"))
        return out

    def not_on_disk_vehicles(self) -> list[str]:
        """The vehicles of the tables none of whose scenes is on disk (``_on_disk``): named in the root's note, and
        failed calibrations (``frameless_vehicles``) like any vehicle with no frame."""
        have = {f.vehicle for f in self.frames}
        scenes = list(self.not_on_disk_vehicle.values())  # one record each among its vehicle's lacking_keyframes
        return sorted(v for v in set(scenes) - have if len(self.lacking_keyframes.get(v, ())) == scenes.count(v))

    def _one_scene_at_a_time(self, frames: list[FrameRef]) -> list[FrameRef]:
        """``frames`` without the scenes recorded while an earlier-starting scene of the same vehicle was (their
        camera keyframes' time spans overlap), each of their samples said (``_left_out``). One vehicle records one
        scene at a time, so such tables list one recording twice under new files, or give two vehicles one name:
        fused as one drive, the hybrid paired each frame with the other scene's copy of the instant before, refused
        every such pair as crossing scenes, and ran without its motion and lever arm (probe 94: the same 12 frames
        kept, the yaw 1.4 deg apart)."""
        spans: dict[tuple[str, str], list[int]] = {}  # (vehicle, scene token) -> its camera keyframes' times (us)
        for ref in frames:
            if isinstance(ts := ref.camera_sd.get("timestamp"), int) and not isinstance(ts, bool):
                spans.setdefault((ref.vehicle, ref.scene_token), []).append(ts)
        names = {ref.scene_token: ref.scene_name for ref in frames}
        kept: dict[str, list[tuple[str, int, int]]] = {}  # vehicle -> [(scene token, first, last)] kept
        dropped: dict[str, tuple[str, int, int, str, int, int]] = {}  # scene token -> the overlap, for the words
        for (vehicle, scene), ts in sorted(spans.items(), key=lambda kv: (kv[0][0], min(kv[1]), max(kv[1]))):
            lo, hi = min(ts), max(ts)
            other = next((o for o in kept.get(vehicle, []) if lo <= o[2] and o[1] <= hi), None)
            if other is None:
                kept.setdefault(vehicle, []).append((scene, lo, hi))
            else:
                dropped[scene] = (vehicle, lo, hi, *other)
        if not dropped:
            return frames
        self.overlapping = {names.get(s, s): names.get(d[3], d[3]) for s, d in dropped.items()}
        out = []
        for ref in frames:
            if ref.scene_token not in dropped:
                out.append(ref)
                continue
            vehicle, lo, hi, other, o_lo, o_hi = dropped[ref.scene_token]
            self._left_out(ref, (
                f"sample {ref.sample_token}: its scene {ref.scene_name} (camera keyframes {lo}-{hi} us) was recorded "
                f"while scene {names.get(other, other)} of the same vehicle {vehicle} was ({o_lo}-{o_hi} us): "
                "one vehicle records one scene at a time, so the tables list one recording twice (a copy with its own "
                f"files) or give two vehicles one name; scene {ref.scene_name} is left out (fix the log's vehicle "
                "name, or remove the copy)"))
        return out

    def _one_mount_per_vehicle(self, frames: list[FrameRef]) -> list[FrameRef]:
        """``frames`` with each vehicle whose tables hold more than one camera-radar calibration split into one
        vehicle per calibration: ``NAME`` for the first one met, ``NAME-cal2``, ``NAME-cal3``, ... for the next.

        A vehicle's logs can be calibrated differently (nuScenes: n015's radar is yawed -0.85 deg in 34 scenes and
        +0.20 deg in 349), and a table can re-mount a sensor within a log; fused as one drive they would be one
        extrinsic for two mounts, reported against the first one's tables. A calibration is a frame's camera-radar
        extrinsic from its calibrated_sensor records (not the tokens: every log has its own records, most of them
        equal), the same within ``SAME_CALIBRATION`` (float noise of tables rewritten by other tools), named over
        every scene of the vehicle (whatever ``scenes`` asks for) in the order the tables list them. A simulated
        root (``simulated``) is never split: its tables hold the true mount, which moves where the simulation says
        so (one log per vehicle; the step detectors are what finds such a change). The split is noted in
        ``calibration_splits`` (vehicle -> its names) and ``calibration_offsets`` (name -> how far, deg and cm, from
        the vehicle's first)."""
        if self.simulated:
            return frames
        t = self.tables

        seen: dict[str, list[tuple[str, np.ndarray]]] = {}  # vehicle -> [(name, extrinsic)]

        def name_of(vehicle: str, T: np.ndarray | None) -> str:
            known = seen.setdefault(vehicle, [])
            name = next((n for n, T0 in known if T is None or T0 is None or same_calibration(T, T0)), None)
            if name is None:
                name = vehicle if not known else f"{vehicle}-cal{len(known) + 1}"
                known.append((name, T))
            return name

        if self.conf.scenes is not None:  # named over every scene of the vehicle, not only those asked for (probe
            # 137: with data.scenes a log's calibration was NAME in one run and NAME-cal2 in another, and export wrote
            # its estimate into the other calibration's radar record)
            vehicles = {ref.vehicle for ref in frames}
            for scene in t.records["scene"]:
                log = t.by_token["log"].get(scene["log_token"])
                if log is None or log["vehicle"] not in vehicles:
                    continue
                for sample in t.scene_samples(scene):
                    cam, rad = t.keyframe(sample["token"], self.camera_channel), t.keyframe(sample["token"],
                                                                                            self.radar_channel)
                    if cam is not None and rad is not None and (T := tables_extrinsic(t, cam, rad)) is not None:
                        name_of(log["vehicle"], T)
        out = []
        for ref in frames:
            name = name_of(ref.vehicle, tables_extrinsic(t, ref.camera_sd, ref.radar_sd))
            out.append(ref if name == ref.vehicle else dataclasses.replace(ref, vehicle=name))
        self.calibration_splits = {v: [n for n, _ in k] for v, k in seen.items() if len(k) > 1}
        self.calibration_offsets = {n: mount_offset(T, k[0][1]) for k in seen.values() if len(k) > 1 for n, T in k[1:]
                                    if T is not None and k[0][1] is not None}
        return out

    def intrinsic_changes(self) -> dict[str, str]:
        """Log name (or token) -> a sentence, for each log whose camera intrinsic changes from frame to frame
        (entries more than 0.1 % apart). One camera in one log has one calibration; 41 intrinsics for CAM_FRONT
        in one log (fx x0.95 / x1.05 alternating) mean broken tables, and were accepted without a word (each frame
        is still read with its own). Between logs a camera may be recalibrated: not named."""
        by_log: dict[str, list[np.ndarray]] = {}
        for ref in self.frames:
            try:
                K = self.tables.camera_intrinsic(ref.camera_sd)
            except (DataError, KeyError, TypeError):
                continue  # a broken record: the frame says so when it is read
            Ks = by_log.setdefault(ref.log_token, [])
            if not any(np.allclose(K, K0, rtol=1e-3, atol=1e-6) for K0 in Ks):
                Ks.append(K)
        out = {}
        for log, Ks in by_log.items():
            if len(Ks) > 1:
                rec = self.tables.by_token["log"].get(log) or {}
                fx = [float(K[0, 0]) for K in Ks]
                out[str(rec.get("logfile") or log)] = (
                    f"{self.camera_channel}'s intrinsic changes within the log ({len(Ks)} different ones; fx "
                    f"{min(fx):.0f}..{max(fx):.0f} px): one camera in one drive has one calibration, so the tables "
                    "are likely broken; each frame is read with its own")
        for log, words in self._off_centre().items():
            out[log] = f"{out[log]}; and {words}" if log in out else words
        return out

    def _off_centre(self) -> dict[str, str]:
        """Log name -> a sentence, for each log whose camera principal point (the first frame's intrinsic) lies more
        than ``MAX_PP_OFF_CENTRE`` of the image's width or height from its centre, the size read from the image
        file's header (the tables' width / height when it does not read). Images resized without their intrinsic
        (or an intrinsic for another size) passed every check and showed up only as a network "out of its domain"
        (probe 7: 1600 x 900 images with the 800 x 450 intrinsic; the hybrid ended 21 deg off)."""
        from hybrid_calib.data.image_header import image_header

        out, seen = {}, set()
        for ref in self.frames:
            if ref.log_token in seen:
                continue
            seen.add(ref.log_token)
            try:
                K = self.tables.camera_intrinsic(ref.camera_sd)
            except (DataError, KeyError, TypeError):
                continue  # a broken record: the frame says so when it is read
            try:
                w, h = image_header(self.tables.file(ref.camera_sd), ref.camera_sd.get("token"))
            except (DataError, OSError):
                w, h = ref.camera_sd.get("width"), ref.camera_sd.get("height")
            if not (isinstance(w, int) and isinstance(h, int) and w > 0 and h > 0) or max(
                    abs(K[0, 2] / w - 0.5), abs(K[1, 2] / h - 0.5)) <= MAX_PP_OFF_CENTRE:
                continue
            rec = self.tables.by_token["log"].get(ref.log_token) or {}
            out[str(rec.get("logfile") or ref.log_token)] = (
                f"{self.camera_channel}'s principal point ({K[0, 2]:.0f}, {K[1, 2]:.0f}) px lies at "
                f"{100 * K[0, 2] / w:.0f} % / {100 * K[1, 2] / h:.0f} % of its {w} x {h} image (a camera's is near "
                f"the centre): camera_intrinsic is likely for another image size (about {2 * K[0, 2]:.0f} x "
                f"{2 * K[1, 2]:.0f}), or the images were resized without it; radar points project to the wrong "
                "pixels and the network sees another camera: fix camera_intrinsic or the images (a cropped image of "
                "a right intrinsic is read correctly, but the networks were trained on centred ones: a learned result "
                "whose roll or pitch then leaves the tables is not trusted)")
        return out

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def skipped(self) -> list[SkipRecord]:
        """Index-time problems followed by the frames skipped so far while iterating (by index)."""
        return self._index_skips + [self._iter_skips[i] for i in sorted(self._iter_skips)]

    def ego_poses(self, indices: list[int]) -> list[np.ndarray | None]:
        """(4, 4) ego -> global of each frame of ``indices`` at its camera keyframe (tables only), None where it does
        not read (the frame says why when it is read)."""
        return self._each(indices, lambda f: self.tables.T_global_ego(f.camera_sd))

    def camera_poses(self, indices: list[int]) -> list[np.ndarray | None]:
        """(4, 4) camera -> global of each frame of ``indices`` at its camera keyframe (tables only: the ego pose and
        the camera's mount), None where it does not read. Unlike the ego pose it does not depend on where a root puts
        its ego frame's origin (nuScenes: the rear axle; another fleet's: anywhere), so what the camera's views are
        judged by (how far apart, whether one repeats the last) is the same on any root of the same drive."""
        return self._each(indices, lambda f: self.tables.T_global_ego(f.camera_sd) @ self.tables.T_ego_sensor(
            f.camera_sd))

    def heading_jitter(self, indices: list[int]):
        """``data.pose_jitter.HeadingJitter`` of the radar channel's pose records over the frames ``indices`` (time
        order; keyframes and the records between them, tables only) and of the camera's keyframes against their
        path, the larger; None where neither is measured (too few or too sparse records)."""
        from hybrid_calib.data.pose_jitter import drive_heading_jitter

        return drive_heading_jitter(self.tables, [self.frames[i].radar_sd for i in indices],
                                    [self.frames[i].camera_sd for i in indices])

    def camera_files(self, indices: list[int]) -> list[Path | None]:
        """The camera image file of each frame of ``indices`` (tables only), None where its record does not name one
        under the root (the frame says why when it is read)."""
        return self._each(indices, lambda f: self.tables.file(f.camera_sd))

    def absent_files(self, indices: list[int]) -> list[int]:
        """The frames of ``indices`` whose camera or radar keyframe file the tables name is not on disk (tables only:
        a partial download; a record that names no file is the frame's to say when it is read)."""
        def absent(f: FrameRef) -> bool:
            return any(not p.is_file() for p in (self.tables.file(f.camera_sd), self.tables.file(f.radar_sd)))

        return [i for i, gone in zip(indices, self._each(indices, absent)) if gone]

    def _each(self, indices: list[int], read) -> list:
        """``read(frame record)`` of each frame of ``indices``, None where its tables do not read."""
        out = []
        for i in indices:
            try:
                out.append(read(self.frames[i]))
            except (DataError, KeyError, TypeError, ValueError):
                out.append(None)
        return out

    def ego_travel_m(self, indices: list[int]) -> float | None:
        """How far the ego vehicle moved over the frames ``indices`` (time order), metres: the sum of the distances
        between consecutive camera keyframes' ego poses (tables only). None when a pose does not read (the frame
        says why when it is read)."""
        poses = self.ego_poses(indices)
        if any(T is None for T in poses):
            return None
        p = [T[:3, 3] for T in poses]
        return float(sum(np.linalg.norm(b - a) for a, b in zip(p, p[1:])))

    def frameless_vehicles(self, vehicles=None) -> dict[str, str]:
        """Vehicle -> why it has no frame, for each vehicle of the tables the index left with none (every sample of it
        in ``lacking_keyframes``: no camera or radar keyframe, another sample's copy, a scene overlapping another, a
        scene with no file on disk), among ``vehicles`` (None: all): a calibration names them, not silently absent
        from its result."""
        have = {f.vehicle for f in self.frames}
        absent = set(self.not_on_disk_vehicles())

        def why(v: str, skips: list[SkipRecord]) -> str:
            if v in absent:  # one record per scene (``_on_disk``)
                return (f"vehicle {v}: no frame: none of its {len(skips)} scene(s) has its sensor files on disk "
                        f"(first: {skips[0].reason})")
            return (f"vehicle {v}: no frame: none of its {len(skips)} sample(s) holds a frame the run reads (first: "
                    f"{skips[0].reason}); hybrid-calib inspect lists them")

        return {v: why(v, skips) for v, skips in sorted(self.lacking_keyframes.items())
                if v not in have and (vehicles is None or v in vehicles)}

    def frames_by_vehicle(self) -> dict[str, list[int]]:
        """Vehicle name -> dataset indices of its frames, in time order (the camera keyframes' timestamps: a
        vehicle's scenes need not be listed in scene.json in the order they were driven)."""
        out: dict[str, list[int]] = {}
        for i, f in enumerate(self.frames):
            out.setdefault(f.vehicle, []).append(i)

        def when(i: int):
            t = self.frames[i].camera_sd.get("timestamp")
            return t if isinstance(t, int) and not isinstance(t, bool) else None

        def ordered(idx: list[int]) -> list[int]:  # a timestamp that is not a number: the tables' order kept
            ts = [when(i) for i in idx]
            return idx if None in ts else [i for _, i in sorted(zip(ts, idx))]

        return {v: ordered(idx) for v, idx in out.items()}

    def scenes(self) -> list[dict[str, Any]]:
        """One dict per scene with frames: name, token, vehicle, log_token, indices."""
        out: dict[str, dict[str, Any]] = {}
        for i, f in enumerate(self.frames):
            rec = out.setdefault(f.scene_token, dict(name=f.scene_name, token=f.scene_token, vehicle=f.vehicle,
                                                     log_token=f.log_token, indices=[]))
            rec["indices"].append(i)
        return list(out.values())

    # ---------------------------------------------------------------- frames
    def __iter__(self) -> Iterator[RadarCameraFrame]:
        """Every loadable frame in order; bad ones are recorded in ``skipped`` (or raise, see on_error)."""
        for i in range(len(self)):
            try:
                frame = self[i]
            except DataError as e:
                if self.conf.on_error == "raise":
                    raise
                self._iter_skips[i] = SkipRecord(i, e.token or self.frames[i].sample_token, e.path, str(e))
                continue
            self._iter_skips.pop(i, None)
            yield frame

    def __getitem__(self, i: int) -> RadarCameraFrame:
        """Load frame ``i``; ``DataError`` naming the file / token if anything is wrong."""
        if isinstance(i, bool) or not isinstance(i, (int, np.integer)):
            raise TypeError(f"frame index must be an integer, got {type(i).__name__} {i!r}")
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame index {i} out of range for {n} frames")
        i = i % n
        ref = self.frames[i]
        t = self.tables
        cam, rad = ref.camera_sd, ref.radar_sd
        for sd, channel in ((cam, self.camera_channel), (rad, self.radar_channel)):
            _check_channel_file(sd, channel, t.path("sample_data"), t.root)
        _check_sync(cam, rad, "radar", self.conf.max_sync_offset_s, t.path("sample_data"))
        image_path = t.file(cam)
        width, height = _image_size_field(cam, t.path("sample_data"))
        if self.conf.check_images or not (width and height):
            w_file, h_file = image_header(image_path, cam["token"])
            if width and height and (w_file, h_file) != (width, height):
                raise DataError(f"camera image is {w_file}x{h_file} but sample_data says {width}x{height}; the "
                                "file does not belong to this record or was resized", path=str(image_path),
                                token=cam["token"])
            width, height = w_file, h_file
        if self.conf.decode_images:
            decode_image(image_path, cam["token"])
        camera = PinholeCamera.from_K(t.camera_intrinsic(cam, (width, height) if width and height else None), width,
                                     height)

        T_ego_cam, T_ego_radar = t.T_ego_sensor(cam), t.T_ego_sensor(rad)
        T_ge_cam, T_ge_radar = t.T_global_ego(cam), t.T_global_ego(rad)
        _check_pose_pair(cam, T_ge_cam, rad, T_ge_radar, "radar", t.path("ego_pose"))
        T_cam_global = se3_inverse(T_ego_cam) @ se3_inverse(T_ge_cam)
        T_cam_radar = T_cam_global @ T_ge_radar @ T_ego_radar
        T_cam_radar_static = se3_inverse(T_ego_cam) @ T_ego_radar

        sweeps = accumulate_radar(t, rad, int(self.conf.nsweeps), self.conf.radar_filter)
        if sweeps.missing_paths and not self._warned_missing_sweeps:
            self._warned_missing_sweeps = True
            warnings.warn(
                f"{self.radar_channel}: earlier radar sweep files are absent (first: {sweeps.missing_paths[0]}); "
                f"accumulating only the sweeps on disk (nsweeps={self.conf.nsweeps}). Keyframe-only releases have "
                "no sweeps/ folder; set nsweeps=1 to silence this.", MissingSweepWarning, stacklevel=2)
        pts = sweeps.points
        if len(pts) == 0 and self.conf.skip_empty_radar:
            rf = self.conf.radar_filter
            empty = [k for k in ("invalid_states", "dynprop_states", "ambig_states")
                     if rf.enabled and getattr(rf, k) is not None and not len(getattr(rf, k))]
            # train and evaluate take no such option (probe 55: their skip line advised one they refuse)
            how = ("set skip_empty_radar=false to keep empty frames (inspect: --set KEY=VALUE; the network methods "
                   "of calibrate, fleet and compare: --set data.KEY=VALUE; train and evaluate always skip them: a "
                   "frame without radar points has nothing to match)")
            if not sweeps.n_raw:  # nothing to filter: the file itself holds no point (loosening cannot help)
                raise DataError(f"radar file holds no points (its header says 0); a sweep of a moving car always has "
                                f"some: the file was written or copied empty; re-extract it, or {how}",
                                path=str(self.root / rad["filename"]), token=rad["token"])
            raise DataError(f"radar sweep has 0 points after filtering ({sweeps.n_raw} read, "
                            f"{sweeps.n_nonfinite} NaN or beyond {MAX_RANGE_M:g} m)"
                            + (f"; radar_filter.{' and '.join(empty)}=[] keeps no value (the lists hold the values "
                               "kept; null keeps any)" if empty else "") + f"; loosen radar_filter or {how}",
                            path=str(self.root / rad["filename"]),
                            token=rad["token"])
        radar_points = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
        radar_fields = {name: pts[name].copy() for name in pts.dtype.names or ()}
        # a radar that records elevation (a 4D radar): read as the 2D radar the networks and the elevation model were
        # made for, its points in the radar's plane (probe 122: z passed to the network, trained on z = 0, read the
        # roll 3.7 deg off, 4.7 sigma, under a "weak" status that still said "a 2D radar has no elevation")
        own = radar_points[sweeps.sweep_index == 0, 2]
        elevation = float(np.max(np.abs(own))) if len(own) else 0.0
        if elevation > RADAR_Z_M:
            radar_points[:, 2] = 0.0
            if not self._warned_elevation:
                self._warned_elevation = True
                warnings.warn(f"{self.radar_channel}'s points carry elevation (z up to {elevation:.2f} m in "
                              f"sample_data {rad['token']}): a radar that measures it (4D); they are read as a 2D "
                              "radar's, z set to 0, as the networks and the elevation model were made for: its "
                              "elevation is not used", RadarElevationWarning, stacklevel=2)

        extras: dict[str, Any] = dict(
            T_ego_cam=T_ego_cam, T_ego_radar=T_ego_radar, T_global_ego_cam=T_ge_cam, T_global_ego_radar=T_ge_radar,
            T_cam_radar_static=T_cam_radar_static,
            reference_T_cam_radar=self._reference(ref, T_ego_cam, T_cam_radar_static),
            reference_T_ego_radar=self._reference_mounts(ref, T_ego_cam, T_ego_radar)[1],
            radar_sweep_index=sweeps.sweep_index, radar_sweep_dt_s=sweeps.dt_s, radar_points_raw=sweeps.n_raw,
            radar_nonfinite_dropped=sweeps.n_nonfinite, radar_sweeps_used=len(sweeps.sweep_tokens),
            radar_sweeps_missing=len(sweeps.missing_paths), scene_token=ref.scene_token,
            radar_elevation_m=elevation if elevation > RADAR_Z_M else 0.0,
        )
        if sweeps.rows is not None:
            extras["radar_rows"] = sweeps.rows
            truth = self.root / "sim_truth" / self.radar_channel / (Path(rad["filename"]).stem + ".npz")
            if truth.is_file():
                extras["radar_truth_path"] = truth
        depth = self.root / "sim_depth" / self.camera_channel / (Path(cam["filename"]).stem + ".png")

        lidar_points = T_cam_lidar = None
        if self.conf.load_lidar:
            lidar_points, T_cam_lidar = self._lidar(ref, T_cam_global, extras)

        return RadarCameraFrame(
            index=i, sample_token=ref.sample_token, scene_name=ref.scene_name, vehicle=ref.vehicle,
            log_token=ref.log_token, camera_channel=self.camera_channel, radar_channel=self.radar_channel,
            camera_token=cam["token"], radar_token=rad["token"], timestamp_camera_us=int(cam["timestamp"]),
            timestamp_radar_us=int(rad["timestamp"]), image_path=image_path, camera=camera,
            radar_points=radar_points, radar_fields=radar_fields, T_cam_radar=T_cam_radar,
            lidar_points=lidar_points, T_cam_lidar=T_cam_lidar, depth_path=depth if depth.is_file() else None,
            extras=extras)

    def radar_sweeps_between(self, i: int) -> list[InterSweep]:
        """The radar's non-keyframe sweeps between frame ``i``'s previous keyframe and its keyframe sweep, oldest
        first (``data.sweeps.sweeps_between_keyframes``; empty on a keyframe-only root). Reads only their PCDs
        and ego poses, not frame ``i`` itself: they stay usable when its camera image is unreadable."""
        n = len(self)
        if not -n <= i < n:
            raise IndexError(f"frame index {i} out of range for {n} frames")
        out, missing = sweeps_between_keyframes(self.tables, self.frames[i % n].radar_sd, self.conf.radar_filter)
        self.radar_sweeps_missing += len(missing)
        # listed: every record the walk reached, a broken prev pointer's entry (no time; it ends the walk) too: one
        # that was not counted read "5 of the 0 radar sweep files ... do not read" (probe 45: equal timestamps)
        listed = len(missing) + len(out)
        # the third part: why each listed sweep that is on disk did not read (a truncated or zero-byte file)
        self.sweep_files[i % n] = (listed, [str(p) for p in missing], [s.why for s in out if s.why])
        return out

    def _lidar(self, ref: FrameRef, T_cam_global: np.ndarray, extras: dict) -> tuple[np.ndarray, np.ndarray]:
        t = self.tables
        sd = t.keyframe(ref.sample_token, self.conf.lidar_channel)
        if sd is None:
            raise DataError(f"sample has no {self.conf.lidar_channel} keyframe, and this run reads the LiDAR (for "
                            "lidar-densified depth, or with inspect's --set load_lidar=true): the frame is skipped; "
                            "restore the sample's LiDAR record, or read the root without LiDAR (calibrate, train, "
                            "evaluate: another --depth; inspect: --set load_lidar=false)",
                            path=str(t.path("sample_data")), token=ref.sample_token)
        _check_sync(ref.camera_sd, sd, "LiDAR", self.conf.max_sync_offset_s, t.path("sample_data"))
        path = t.file(sd)
        raw = read_lidar_bin(path)
        pts = raw[:, :4]
        finite = np.all(np.isfinite(pts[:, :3]), axis=1)
        if len(pts) and not finite.any():
            raise DataError(f"all {len(pts)} LiDAR points have NaN/inf coordinates; the file is corrupt",
                            path=str(path), token=sd["token"])
        extras["lidar_token"] = sd["token"]
        extras["lidar_nonfinite_dropped"] = int((~finite).sum())
        T_ge_lidar = t.T_global_ego(sd)
        _check_pose_pair(ref.camera_sd, extras["T_global_ego_cam"], sd, T_ge_lidar, "LiDAR", t.path("ego_pose"))
        T_cam_lidar = T_cam_global @ T_ge_lidar @ t.T_ego_sensor(sd)
        return np.ascontiguousarray(pts[finite], dtype=np.float32), T_cam_lidar

    @functools.cached_property
    def identity(self) -> str:
        """The identity of the data this object reads: the root's resolved path, the version and
        ``data.files.data_stamp`` (the tables by content, the sensor folders by their file names), hashed; computed
        once (the network's output cache is keyed by it: ``hybrid.network.NetworkRunner``)."""
        import hashlib

        from hybrid_calib.data.files import data_stamp

        stamp = data_stamp(self.root, self.version)["digest"]
        return hashlib.sha1(f"{self.root.resolve()}/{self.version}/{stamp}".encode("utf-8", "surrogateescape")
                            ).hexdigest()[:16]  # a root named in another encoding too (probe 66)

    def reference_source(self, vehicle: str) -> dict:
        """What ``vehicle``'s drift verdict and radar mount monitor compare against, as a result records it
        (``data.reference.ExportReference.source``): {"kind": "tables"} without ``DataConfig.reference``."""
        if self.export_reference is None:
            return {"kind": "tables"}
        return self.export_reference.source(vehicle)

    def reference_notes(self, vehicles=None) -> list[str]:
        """What a run on ``DataConfig.reference`` says once, before its frames: which vehicles are checked against
        the export; an export that names none of this root's vehicles (a wrong export: each is checked against its
        tables); a vehicle whose camera record in these tables is another than the one the export read (the camera
        was recalibrated since: the reference stays the exported radar-camera extrinsic). ``vehicles``: the ones the
        run calibrates (None: all; the others are not named). [] without a reference."""
        ref = self.export_reference
        if ref is None:
            return []
        by_vehicle = self.frames_by_vehicle()
        named = sorted(v for v in by_vehicle if v in ref.mounts)
        if not named:
            return [f"warning: the reference export {ref.path} replaced the mount of none of this root's vehicles "
                    f"(it exported {', '.join(sorted(ref.mounts)) or 'none'}; this root holds "
                    f"{', '.join(sorted(by_vehicle)[:6]) or 'none'}): every vehicle is checked against its tables"]
        named = [v for v in named if vehicles is None or v in vehicles]
        if not named:  # the export names vehicles of the root, none of those asked for
            return [f"reference: none of the vehicles asked for is in {ref.path}: each is checked against its tables"]
        out = [f"reference: {', '.join(named)} checked against the mount{'s' if len(named) > 1 else ''} exported in "
               f"{ref.path} (from {ref.data}, {ref.version}); any other vehicle against its tables"]
        for v in named:
            first = self.frames[by_vehicle[v][0]]
            try:
                T_cam = self.tables.T_ego_sensor(first.camera_sd)
            except (DataError, KeyError, TypeError):
                continue  # said where its frames are read
            # the record the export wrote for this frame's radar record (one per log: probe 139), else its first
            deg, cm = mount_offset(T_cam, ref.mounts_at(v, first.radar_sd.get("calibrated_sensor_token"))[0])
            if deg > SAME_CALIBRATION[0] or cm > SAME_CALIBRATION[1]:
                out.append(f"warning: vehicle {v}: its camera record here is {deg:.2f} deg / {cm:.1f} cm from the one "
                           f"the export read (the camera was recalibrated since, or the export is of another vehicle "
                           "of that name): it is checked against the exported radar-camera extrinsic")
        return out

    def reference_T_ego_radar(self, ref: FrameRef) -> np.ndarray:
        """(4, 4) the radar mount of the vehicle's reference at frame ``ref`` (``_reference_mounts``: what the radar
        mount monitor's level is measured against), from the tables alone."""
        T_ego_cam = self.tables.T_ego_sensor(ref.camera_sd)
        return self._reference_mounts(ref, T_ego_cam, self.tables.T_ego_sensor(ref.radar_sd))[1]

    def radar_motion(self, ref: FrameRef) -> np.ndarray:
        """(4, 4) ``N`` of frame ``ref``: the radar's motion between its keyframe's and the camera's timestamps, in
        the radar frame (docs/conventions.md "Transforms"; ``frame.T_cam_radar = T_cam_radar_static N``), from the
        tables alone (no sensor file read); ``DataError`` where reading the frame would refuse its poses or timing."""
        t = self.tables
        cam, rad = ref.camera_sd, ref.radar_sd
        _check_sync(cam, rad, "radar", self.conf.max_sync_offset_s, t.path("sample_data"))
        T_ego_radar, T_ge_cam, T_ge_radar = t.T_ego_sensor(rad), t.T_global_ego(cam), t.T_global_ego(rad)
        _check_pose_pair(cam, T_ge_cam, rad, T_ge_radar, "radar", t.path("ego_pose"))
        return se3_inverse(T_ego_radar) @ se3_inverse(T_ge_cam) @ T_ge_radar @ T_ego_radar

    def radar_motion_at(self, i: int) -> np.ndarray:
        """``radar_motion`` of frame ``i``."""
        return self.radar_motion(self.frames[i])

    def reference_T_cam_radar(self, ref: FrameRef) -> np.ndarray:
        """(4, 4) the vehicle's reference T_cam_radar at frame ``ref`` (``_reference``: its calibration tables, or the
        mount an earlier export wrote, ``DataConfig.reference``), from the tables alone (no sensor file read);
        ``DataError`` / ``KeyError`` when its calibrated_sensor records do not read."""
        T_ego_cam = self.tables.T_ego_sensor(ref.camera_sd)
        return self._reference(ref, T_ego_cam, se3_inverse(T_ego_cam) @ self.tables.T_ego_sensor(ref.radar_sd))

    def _reference(self, ref: FrameRef, T_ego_cam: np.ndarray, T_cam_radar_static: np.ndarray) -> np.ndarray:
        """The extrinsic a drift detector compares against: the vehicle's calibration tables (or, with
        ``DataConfig.reference``, the mount an earlier export wrote for it: ``_reference_mounts``). In a
        v1.0-sim root ``calibrated_sensor`` carries the simulator's ground truth, so the tables a
        real vehicle would have are ``sim_vehicle.json``'s factory calibration (truth + calibration
        error); roots simulated before it existed fall back to the nominal (fleet design) mount, real
        roots to the tables' own static extrinsic."""
        T_ego_cam_ref, T_ego_radar_ref = self._reference_mounts(ref, T_ego_cam, T_ego_cam @ T_cam_radar_static)
        return se3_inverse(T_ego_cam_ref) @ T_ego_radar_ref

    def _reference_mounts(self, ref: FrameRef, T_ego_cam: np.ndarray, T_ego_radar: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
        """(T_ego_cam, T_ego_radar), each (4, 4): the camera and radar mounts of the vehicle's reference
        (``_reference``): those an earlier export wrote for it (``DataConfig.reference``), else its calibration tables:
        a simulated vehicle's factory calibration (its ``calibrated_sensor`` holds the truth), the
        nominal radar mount of older simulated roots, else the tables' own. The radar mount monitor measures the
        radar's yaw against this radar mount, as on a real vehicle (against the truth it read 'the radar agrees with
        its tables' on a radar knocked before the drive, and blamed the camera)."""
        if self.export_reference is not None and (exported := self.export_reference.mounts_at(
                ref.vehicle, ref.radar_sd.get("calibrated_sensor_token"))):
            return exported  # the mounts an earlier export wrote for this vehicle (data.reference), for this record
        rec = self.sim_vehicles.get(ref.log_token)
        factory_radar = _sim_pose(rec, "factory_T_ego_radar")
        factory_cam = _sim_pose(rec, "factory_T_ego_cam")
        if factory_radar is not None and factory_cam is not None:
            return factory_cam, factory_radar
        T_ego_radar_nom = _sim_nominal_T_ego_radar(rec, self.radar_channel)
        return T_ego_cam, (T_ego_radar if T_ego_radar_nom is None else T_ego_radar_nom)


_NAMED_STAMP = re.compile(r"__(\d+)\.[A-Za-z0-9.]+$")  # nuScenes: samples/CHANNEL/<log>__CHANNEL__<timestamp>.ext


def _names_its_file(ref: FrameRef, shared: set) -> bool:
    """Whether each of ``ref``'s keyframe files among ``shared`` (names another frame reads too) carries ``ref``'s own
    record timestamp in its name; False where a name carries none (then neither frame is preferred)."""
    for sd in (ref.camera_sd, ref.radar_sd):
        name = sd.get("filename")
        if name in shared:
            m = _NAMED_STAMP.search(str(name))
            if m is None or int(m.group(1)) != sd.get("timestamp"):
                return False
    return True


def _check_channel_file(sd: dict, channel: str, table: Path, root: Path | None = None) -> None:
    """``DataError`` when a ``channel`` record names another channel's file (``samples/<CHANNEL>/...__<CHANNEL>__...``,
    nuScenes' layout): tables merged wrongly read the front-left radar's sweeps as RADAR_FRONT's, 86 deg off
    (probe 15). File names outside that layout are not judged."""
    name = str(sd.get("filename", ""))
    parts = name.replace("\\", "/").split("/")
    folder = parts[1] if len(parts) >= 3 and parts[0] in ("samples", "sweeps") else None
    if folder is not None and folder != channel and folder.upper() == channel.upper():  # the channel in another case
        if root is not None and (root / name).is_file():  # a copy whose folders really are so named: read (probe 40)
            return
        raise DataError(f"{channel} sample_data record names the file {name}: its channel is written {folder}, in "
                        f"another case than {channel} (file names are case-sensitive: samples/{channel}/...); fix the "
                        "filename in sample_data.json or the folder's name", path=str(table), token=sd.get("token"))
    if folder is not None and folder != channel and f"__{folder}__" in parts[-1]:
        raise DataError(f"{channel} sample_data record names the file {name}, a {folder} file: the record's "
                        f"calibrated_sensor says {channel}, its file another channel's; fix its filename or its "
                        f"calibrated_sensor_token in sample_data.json", path=str(table), token=sd.get("token"))


def load_sim_vehicles(vdir: Path) -> dict[str, dict]:
    """``VERSION/sim_vehicle.json`` (written by the simulator) -> log_token -> vehicle record; {} if absent.

    A file that cannot be read or parsed is read as absent (a ``SimVehicleWarning`` says so): the root is then
    what a root simulated before the file existed is (the drift reference comes from the calibrated_sensor
    tables). A file that parses but holds a malformed pose (``SIM_POSE_KEYS``, ``nominal``) is a ``DataError``
    naming the file, the log token and the key: every frame of that vehicle would use it."""
    path = vdir / "sim_vehicle.json"
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, OSError, RecursionError) as e:
        why = f"not valid JSON ({e})" if isinstance(e, (json.JSONDecodeError, UnicodeDecodeError)) else \
            "nested too deeply" if isinstance(e, RecursionError) else f"unreadable ({e})"
        warnings.warn(f"{path} is {why}; reading the root as one without it (the drift reference is the "
                      "calibrated_sensor tables' extrinsic and the simulator's factory calibration is not used): "
                      + ("make it readable, or " if isinstance(e, PermissionError) else "")
                      + "re-run hybrid-calib simulate to restore it, or delete the file to silence this",
                      SimVehicleWarning, stacklevel=3)
        return {}
    if isinstance(data, dict) and "vehicles" in data:
        data = data["vehicles"]
    if isinstance(data, list):
        bad = [i for i, rec in enumerate(data) if isinstance(rec, dict) and not isinstance(rec.get("log_token"), str)]
        if bad:
            # probe 142: a list or dict there was an internal error ("unhashable type") in every command
            raise DataError(f"sim_vehicle.json record {bad[0]} has no log_token string (got "
                            f"{type(data[bad[0]].get('log_token')).__name__}): each vehicle record names its log by "
                            "token; re-run hybrid-calib simulate, or delete the file to read the root as a real one",
                            path=str(path))
        data = {rec["log_token"]: rec for rec in data if isinstance(rec, dict)}
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise DataError("sim_vehicle.json must map log tokens to vehicle records", path=str(path))
    for log_token, rec in data.items():
        for key in SIM_POSE_KEYS:
            _sim_pose(rec, key, path, log_token)
        # the factory calibration is a pair: one without the other read the vehicle against its nominal radar mount
        # in silence (probe 146: a 0.98 deg turn that did not happen, and an oracle's "recalibrate")
        factory = {k: rec.get(k) is not None for k in ("factory_T_ego_radar", "factory_T_ego_cam")}
        if len(set(factory.values())) > 1:
            has, lacks = (k for want in (True, False) for k, v in factory.items() if v is want)
            raise DataError(f"sim_vehicle.json record of log {log_token} holds {has} but not {lacks} (absent or "
                            "null): the factory calibration the vehicle is compared with is the pair; re-run "
                            "hybrid-calib simulate, or remove both to read the vehicle against its nominal mount",
                            path=str(path))
        nominal = rec.get("nominal") or rec.get("nominal_extrinsics") or {}
        for channel, node in (nominal.items() if isinstance(nominal, dict) else ()):
            _sim_pose({"node": node}, "node", path, log_token, f"nominal.{channel}")
    return data


def simulated_root(data, version: str) -> bool:
    """Whether ``data``/``version`` is a simulated root, by the rule ``NuScenesRadarCamera.simulated`` reads it (its
    ``sim_vehicle.json`` holds vehicle records), without indexing the root: for the commands' early choices (the
    hybrid's depth, compare's oracle check, evaluate's and train's notes), which had tested the file's existence (an
    empty or unreadable file read as simulated there and as real in the run). Warnings are left to the dataset that
    loads the root; a file whose records do not read is the ``DataError`` the dataset would raise, naming it."""
    vdir = Path(data) / version
    if not vdir.is_dir():
        return False
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SimVehicleWarning)
        return bool(load_sim_vehicles(vdir))


class SimVehicleWarning(UserWarning):
    """``sim_vehicle.json`` exists but cannot be read; the root is read as one without it."""


# the poses of a sim_vehicle.json record (ego <- sensor mounts), checked when the file is loaded
SIM_POSE_KEYS = ("factory_T_ego_radar", "factory_T_ego_cam", "nominal_T_ego_radar", "nominal_T_ego_cam",
                 "true_T_ego_radar_start", "true_T_ego_cam")
_ROTATION_TOL = 1e-6  # |R^T R - I| of a 4x4 pose given as a matrix


def _sim_nominal_T_ego_radar(rec: dict | None, radar_channel: str) -> np.ndarray | None:
    """The nominal radar -> ego mounting of a simulated vehicle record, or None."""
    if not rec:
        return None
    nominal = rec.get("nominal") or rec.get("nominal_extrinsics") or {}
    node = nominal.get(radar_channel) if isinstance(nominal, dict) else None
    return _sim_pose({"node": node}, "node") if node is not None else _sim_pose(rec, "nominal_T_ego_radar")


def _sim_pose(rec: dict | None, key: str, path: Path | None = None, log_token: str | None = None,
              name: str | None = None) -> np.ndarray | None:
    """A (4, 4) pose stored under ``key`` of a simulated vehicle record ({rotation, translation} or a
    4x4 list), or None when absent. ``DataError`` naming ``path`` (sim_vehicle.json), the log token and the key
    (``name``, default ``key``) when it is not a unit quaternion and a finite translation within
    ``tables.MAX_MOUNT_TRANSLATION_M`` of the ego origin, or not a rigid 4x4 matrix."""
    node = rec.get(key) if rec else None
    if node is None:
        return None
    T, why = _sim_pose_or_reason(node)
    if T is None:
        raise DataError(f"sim_vehicle.json record of log {log_token} key {name or key!r}: {why}; expected "
                        "{\"rotation\": [w, x, y, z] unit quaternion, \"translation\": [x, y, z] metres} or a 4x4 "
                        "rigid transform: re-run hybrid-calib simulate, or delete sim_vehicle.json to read the root "
                        "without it (the drift reference is then the calibrated_sensor tables' extrinsic)",
                        path=str(path) if path is not None else "sim_vehicle.json", token=log_token)
    return T


def _sim_pose_or_reason(node) -> tuple[np.ndarray | None, str]:
    """(pose, "") of a sim_vehicle.json pose node, or (None, what is wrong, with the value)."""
    if isinstance(node, dict):
        missing = [k for k in ("rotation", "translation") if k not in node]
        if missing:
            return None, f"lacks {missing} (has {sorted(node)})"
        (q, why_q), (t, why_t) = vector_or_reason(node["rotation"], 4), vector_or_reason(node["translation"], 3)
        for field, why in (("rotation", why_q), ("translation", why_t)):
            if why:
                return None, f"{field!r} is {short_repr(node[field])}, {why}"
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > QUAT_NORM_TOL:
            return None, (f"'rotation' {short_repr(node['rotation'])} has norm {norm:.6g}, not 1 (tolerance "
                          f"{QUAT_NORM_TOL:g})")
        T = pose_from_nuscenes(q / norm, t)
    elif isinstance(node, list) and len(node) == 4 and all(_is_number_list(r) and len(r) == 4 for r in node):
        try:
            T = np.asarray(node, dtype=np.float64)
        except OverflowError:
            return None, f"a value beyond float range in {short_repr(node)}"
        if not np.all(np.isfinite(T)):
            return None, f"non-finite values in {short_repr(node)}"
        if not is_rigid(T, _ROTATION_TOL):
            R = T[:3, :3]
            mirrored = np.allclose(R @ R.T, np.eye(3), atol=_ROTATION_TOL) and np.linalg.det(R) < 0
            return None, (f"{short_repr(node)} is a reflection, not a rotation (determinant -1: a left-handed frame, "
                          "e.g. two axes swapped; a mount is a proper rotation)" if mirrored else  # probe 95
                          f"{short_repr(node)} is not rigid (rotation not orthonormal or last row not [0, 0, 0, 1])")
    else:
        return None, f"{short_repr(node)} is neither a {{rotation, translation}} object nor a 4x4 list of numbers"
    dist = math.hypot(*T[:3, 3])
    if dist > MAX_MOUNT_TRANSLATION_M:
        return None, (f"the translation puts the sensor {dist:.6g} m from the ego origin, more than "
                      f"{MAX_MOUNT_TRANSLATION_M:g} m")
    return T, ""


MAX_IMAGE_PX = 100_000  # an image side beyond this is not a camera's (nuScenes: 1600 x 900)


def _image_size_field(cam: dict, table: Path) -> tuple[int, int]:
    """A camera sample_data record's ``width`` / ``height``, pixels: positive whole numbers, 0 where unknown (absent
    or null, or both 0 as in the devkit's radar records; the size is then read from the image file). ``DataError``
    naming the record when one is not a number, is negative or fractional, or is 0 while the other is given (that
    turned the size check off silently, and a negative size passed with check_images=false)."""
    size = []
    for key in ("width", "height"):
        value = cam.get(key)
        value = 0 if value is None else value
        # (a float's finiteness; an int beyond int64 made np.isfinite a TypeError: probe 108, an internal error)
        if (isinstance(value, bool) or not isinstance(value, (int, float))
                or (isinstance(value, float) and not math.isfinite(value))):
            raise DataError(f"sample_data field {key!r} is {value!r}, expected an integer number of pixels (or 0 / "
                            "null when unknown); the table does not follow the nuScenes schema: fix or re-extract it",
                            path=str(table), token=cam["token"])
        if value < 0 or value > MAX_IMAGE_PX or value != int(value):
            raise DataError(f"sample_data field {key!r} is {value!r}, expected a positive whole number of pixels up to "
                            f"{MAX_IMAGE_PX} (or 0 / null when unknown); fix the record or re-extract the tables",
                            path=str(table), token=cam["token"])
        size.append(int(value))
    for zero, given, (a, b) in (("width", "height", size), ("height", "width", size[::-1])):
        if a == 0 and b > 0 and cam.get(zero) is not None:
            raise DataError(f"sample_data field {zero!r} is {cam[zero]!r} but {given!r} is {b}; a camera record gives "
                            "both image sizes in pixels, or neither (0 / null / absent: read from the image file): "
                            "fix the record or re-extract the tables", path=str(table), token=cam["token"])
    return size[0], size[1]


def _check_pose_pair(cam: dict, T_cam: np.ndarray, sd: dict, T_sd: np.ndarray, what: str, table: Path) -> None:
    """``DataError`` naming both sample_data records when their ego poses (``T_cam``, ``T_sd`` (4, 4) ego -> global
    at the camera's and the other record's time) lie farther apart than a road vehicle moves between the two
    timestamps: ``MAX_ROAD_SPEED_MPS`` times the gap plus ``POSE_PAIR_MARGIN_M``, or turned by more than
    ``MAX_EGO_TURN_DPS`` times the gap plus ``POSE_PAIR_MARGIN_DEG``. Inspect's jump test walks the radar's keyframe
    poses only: a camera pose 50 m off moved the frame's radar points into the image by its error, silently (probe
    29)."""
    dt = abs(sd["timestamp"] - cam["timestamp"]) * 1e-6
    rel = se3_inverse(T_cam) @ T_sd
    metres = float(np.linalg.norm(rel[:3, 3]))
    deg = float(np.degrees(np.linalg.norm(so3_log(rel[:3, :3]))))
    if metres <= MAX_ROAD_SPEED_MPS * dt + POSE_PAIR_MARGIN_M and deg <= MAX_EGO_TURN_DPS * dt + POSE_PAIR_MARGIN_DEG:
        return
    raise DataError(f"the ego poses of the camera's record (sample_data {cam['token']}) and the {what}'s are "
                    f"{metres:.2f} m and {deg:.1f} deg apart, {dt * 1e3:.0f} ms apart in time: no road vehicle moves "
                    f"so far ({MAX_ROAD_SPEED_MPS:g} m/s, {MAX_EGO_TURN_DPS:g} deg/s); one of the two ego_pose records "
                    "is wrong: fix it or re-extract the tables (the frame is skipped)", path=str(table),
                    token=sd["token"])


def _check_sync(cam: dict, sd: dict, what: str, limit_s: float, table: Path) -> None:
    """``DataError`` naming sample_data ``sd`` (and the camera record) when its timestamp is more than ``limit_s``
    seconds from the camera keyframe's. Timestamps are integer microseconds, compared exactly (a timestamp of
    1e30 us or one below zero is named, not turned into an offset of 1e26 ms)."""
    dt_us = sd["timestamp"] - cam["timestamp"]
    if abs(dt_us) <= limit_s * 1e6:
        return
    apart = f"{dt_us / 10**6:+.6g} s" if abs(dt_us) < 10**300 else "more than 1e294 s"
    raise DataError(f"{what} sample_data timestamp {sd['timestamp']} us is {apart} from the camera's "
                    f"({cam['timestamp']} us, sample_data {cam['token']}), more than max_sync_offset_s={limit_s:g} s "
                    "(nuScenes keyframes are under 0.1 s apart), so one of the timestamps is corrupt: fix the record "
                    "or re-extract the tables", path=str(table), token=sd["token"])
