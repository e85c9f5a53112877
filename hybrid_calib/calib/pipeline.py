"""Calibrate every vehicle (log) of a dataset: the typed function behind ``hybrid-calib calibrate``.

Input frames per vehicle come either from oracle correspondences on a simulated root
(``correspondences="oracle"``) or from a directory of measurement files (``factors.io``: the output
directory of ``hybrid-calib evaluate``, a flat directory, or one sub-directory per vehicle), grouped
into vehicles by each file's ``vehicle`` field (a flat directory of files without one belongs to the
dataset's single vehicle). A file's optional network block (the network's SE(3) and covariance) is
carried in ``VehicleInput.network`` and summarised in the result (not fused yet).

Per vehicle: the initial extrinsic is the vehicle's reference (its calibration tables;
``extras["reference_T_cam_radar"]``) unless ``start`` asks for a perturbed truth (R1/R2, for
tests and demos); the sliding window (or the batch solve) runs over the frames; the final
estimate is tested against the reference (``drift.reference_test``); with ground truth (simulated
roots) errors, NEES and, for oracle data, the Cramer-Rao std are added.
"""

from __future__ import annotations

import dataclasses
import json
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.correspondences import repeat_message, repeated_frames
from factors.io import load_measurement_dir
from hybrid_calib.atomic import leave_bars
from hybrid_calib.calib.batch import BatchConfig, fit_change, fit_change_words, solve_batch
from hybrid_calib.calib.covariance import NOT_CONVERGED, prior_pinned_std, status_kind
from hybrid_calib.calib.drift import DriftConfig, reference_test, unconverged, with_turn_since_export
from hybrid_calib.calib.oracle import OracleConfig, oracle_from_frame
from hybrid_calib.calib.result import (
    DATA_STAMP,
    CalibrationRun,
    VehicleProgress,
    VehicleResult,
    config_digest,
    failed_vehicles_message,
    path_of,
    reuse_result,
)
from hybrid_calib.calib.schedule import GaussianPrior
from hybrid_calib.calib.window import SlidingWindowCalibrator, WindowConfig
from hybrid_calib.config import check_seed, merge, save_json_atomic, to_dict
from hybrid_calib.data.files import data_stamp, root_changed, root_changed_error, root_fingerprint
from hybrid_calib.data.reference import ASTRAY_ROT_DEG, ASTRAY_TRANS_M, absolute_reference, reference_identity
from hybrid_calib.data.summary import calibration_notes
from hybrid_calib.data.views import ViewConfig, repeated_views
from hybrid_calib.errors import DataError, HybridCalibError, OptionError
from hybrid_calib.perturbation import RANGES, vehicle_rng, vehicle_start
from hybrid_calib.sensors.camera import other_camera

MODES = ("window", "batch")
STARTS = ("reference", *RANGES)


@dataclass(frozen=True)
class CalibrateConfig:
    mode: str = "window"  # window (sliding window, one estimate per frame) | batch (whole drive at once)
    window: WindowConfig = WindowConfig()  # sliding-window settings (incl. factor, schedule, step detector)
    batch: BatchConfig = BatchConfig()  # batch settings (backend gtsam | ceres)
    oracle: OracleConfig = OracleConfig()  # oracle correspondences (simulated roots only)
    drift: DriftConfig = DriftConfig()  # reference chi-square test
    start: str = "reference"  # initial extrinsic: reference (vehicle tables) | R1 | R2 (perturbed truth)
    seed: int = 0  # seed of the oracle noise and of R1/R2 starts
    max_frames: int = 0  # frames per vehicle (0 = all)
    vehicles: tuple[str, ...] | None = None  # vehicles to calibrate (None = all)
    views: ViewConfig = ViewConfig()  # oracle: frames that repeat an earlier view (the ego stood still) are left out
    # an earlier export (hybrid-calib export's --out folder, or its export.json): the reference of the vehicles whose
    # mounts it wrote (data.reference); "" = every vehicle's tables
    reference: str = ""

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"CalibrateConfig.mode={self.mode!r}; valid: {MODES}")
        if self.start not in STARTS:
            raise ValueError(f"CalibrateConfig.start={self.start!r}; valid: {STARTS}")
        if self.max_frames < 0:
            raise ValueError(f"CalibrateConfig.max_frames must be >= 0 (0 = all frames), got {self.max_frames}")
        check_seed(self)


@dataclass
class VehicleInput:
    """Frames of one vehicle: correspondences (each with its camera timestamp), reference, truth."""

    vehicle: str
    frames: list = field(default_factory=list)  # list[Correspondences]
    reference: np.ndarray | None = None  # (4, 4) the tables' extrinsic
    truth: list = field(default_factory=list)  # per frame (4, 4) true static extrinsic (sim only)
    oracle_truths: list = field(default_factory=list)  # per frame OracleTruth (oracle only)
    network: list = field(default_factory=list)  # per frame factors.io.NetworkEstimate | None (files only)
    skipped: list = field(default_factory=list)  # [{"index" (its position in the drive, or None), "token", "reason"}]
    positions: list = field(default_factory=list)  # per frame its position in the drive (default: 0, 1, ...)
    against: str | None = None  # what ``truth`` is: "truth" (simulated; the default when given) or "tables" (real)
    reference_source: dict = field(default_factory=lambda: {"kind": "tables"})  # what ``reference`` is
    # (3,) the road's normal in the radar frame by the reference radar mount (the elevation model's height plane)
    road_normal: np.ndarray | None = None


# the oracle on the radar's recorded points (probe 133: 'weak' at NEES 49-219, none inside the 95 % ellipsoid)
RECORDED_ROWS = ("oracle.radar_points=recorded: the rows are the radar's recorded points, whose range and azimuth "
                 "noise the rows' pixel noise (oracle.sigma_px) does not hold, so the covariance is too small (NEES "
                 "50-220 on simulated drives); the default radar_points=truth gives a covariance that holds")


def road_normal(T_ego_radar) -> np.ndarray | None:
    """(3,) the ego frame's z axis (the road's normal) in the frame of a radar mounted at ``T_ego_radar`` (4, 4),
    or None for a mount more than 60 deg off level (the height model's plane is then the radar's own)."""
    n = np.asarray(T_ego_radar, np.float64)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    n = n / np.linalg.norm(n)
    return n if n[2] >= 0.5 and np.all(np.isfinite(n)) else None


def on_road_plane(conf: CalibrateConfig, normal) -> CalibrateConfig:
    """``conf`` with the ``height`` elevation model's reference plane (``height_plane_normal``) set to the road's
    ``normal`` (3,) where the options leave it unset: the reflectors' heights are the road's, not the radar's
    plane's, so a radar mounted off level by its tables is not taken for level (probe 133: a radar pitched 2-3 deg
    put its yaw and roll 3-5 sigma off)."""
    if normal is None:
        return conf
    return dataclasses.replace(conf, window=dataclasses.replace(conf.window, factor=road_factor(conf.window.factor,
                                                                                                normal)),
                               batch=dataclasses.replace(conf.batch, factor=road_factor(conf.batch.factor, normal)))


def road_factor(fc, normal):
    """The factor config ``fc`` (``RadarPixelFactorConfig``) with the ``height`` model's plane the road's ``normal``
    (3,) where the options leave it unset (``on_road_plane``; the oracle benchmarks take it too)."""
    if normal is None or fc.elevation_model != "height" or fc.height_plane_normal is not None:
        return fc
    return dataclasses.replace(fc, height_plane_normal=tuple(float(v) for v in normal))


def heights_plane(conf: CalibrateConfig, vi: VehicleInput) -> CalibrateConfig:
    """``conf`` as ``calibrate_vehicle`` fits ``vi``'s rows: the height model's plane the road's (``on_road_plane``),
    except for the oracle's model draw (``oracle.elevation=model``), whose heights are drawn above the radar's own
    plane as the factor of that model reads them (probe 135: the road plane put a tilted mount's pitch 2.3 deg off,
    NEES 29.6)."""
    return conf if _drawn_above_radar(vi, conf) else on_road_plane(conf, vi.road_normal)


def _drawn_above_radar(vi: VehicleInput, conf: CalibrateConfig) -> bool:
    """Whether ``vi``'s rows are the oracle's model draw, whose heights lie above the radar's own plane."""
    return bool(vi.oracle_truths) and conf.oracle.elevation == "model"


def height_plane_record(given, used, radar_why: str = "") -> dict | None:
    """What the ``height`` elevation model measured the reflectors' heights from, for a result (``height_plane`` of
    ``calib.result``): ``{"plane": "road" | "option" | "radar", "normal_radar": [3] | None, "words"}``, where
    ``given`` / ``used`` are the factor configs (``RadarPixelFactorConfig``) before and after ``heights_plane`` and
    ``radar_why`` says why the radar's own plane was kept; None for the other elevation models."""
    if used.elevation_model != "height":
        return None
    n = used.height_plane_normal
    if n is None:
        return {"plane": "radar", "normal_radar": None,
                "words": "heights measured from the radar's own plane" + (f" ({radar_why})" if radar_why else "")}
    plane = "option" if given.height_plane_normal is not None else "road"
    words = ("heights measured from the plane the options set (height_plane_normal)" if plane == "option" else
             "heights measured from the road, as the reference mount puts the radar on it")
    return {"plane": plane, "normal_radar": [round(float(v), 9) for v in n], "words": words}


def radar_plane_why(vi: VehicleInput, conf: CalibrateConfig) -> str:
    """Why ``heights_plane`` keeps the radar's own plane for ``vi`` (the words of ``height_plane_record``)."""
    if _drawn_above_radar(vi, conf):
        return "the oracle's model draw puts its heights above the radar's plane"
    return "no reference mount within 60 deg of level puts the radar on the road"


def require_oracle_truth(data) -> None:
    """``OptionError`` (``--method``) when the root ``data`` has no simulator truth for the oracle (a real root)."""
    if not (Path(data) / "sim_truth").is_dir():
        raise OptionError("--method", f"oracle (also the default when no --method is given) reads the simulator's "
                                      f"true reflectors, and {data} has none (no sim_truth/ folder: a real root); "
                                      "calibrate it with --method hybrid (or pure, pure-avg)")


def _load_oracle(data, version: str, conf: CalibrateConfig, progress: bool = True, say: bool = True,
                 frameless: dict[str, str] | None = None, said: list | None = None) -> dict[str, VehicleInput]:
    """``say``: print the root's warnings and the reference's note (a replay for a report page, one per vehicle,
    said them again each time: probe 76). ``frameless``, when given, gets each vehicle of the tables the index left
    with no frame (vehicle -> why: ``NuScenesRadarCamera.frameless_vehicles``; probe 94: it vanished, rc 0)."""
    from tqdm import tqdm

    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    ds = NuScenesRadarCamera(data, version, conf={"check_images": False, "reference": conf.reference or None})
    require_oracle_truth(data)  # said before any frame is read (it had failed every one in turn)
    # a vehicle missing from the result, poses the motion compensation reads
    for line in calibration_notes(ds, conf.vehicles) if say else ():
        print(line, file=sys.stderr)
        if said is not None:  # the result keeps them (CalibrationRun.notes)
            said.append(line)
    if frameless is not None:
        frameless.update(ds.frameless_vehicles(conf.vehicles))
    out: dict[str, VehicleInput] = {}
    for vehicle, idx in sorted(ds.frames_by_vehicle().items()):
        if conf.vehicles is not None and vehicle not in conf.vehicles:
            continue
        vi = out[vehicle] = VehicleInput(vehicle, reference_source=ds.reference_source(vehicle))
        # its samples that hold no frame (a keyframe missing or put on another channel): listed, as the hybrid's
        vi.skipped.extend({"index": None, "token": s.token, "reason": s.reason}
                          for s in ds.lacking_keyframes.get(vehicle, []))
        idx = idx[: conf.max_frames] if conf.max_frames > 0 else idx
        repeats = repeated_views(ds.camera_poses(idx) if conf.views.enabled else [], conf.views)
        # drawn by (seed, vehicle) alone: the same rows whichever other vehicles the run holds, and in every
        # command (calibrate, fleet, compare, the report's replay)
        rng = vehicle_rng(conf.seed, vehicle, "oracle")
        unread: list[str] = []  # the frames that did not read, said after the bar
        for k, i in enumerate(tqdm(idx, desc=f"oracle {vehicle}", leave=leave_bars(), disable=not progress)):
            if k in repeats:  # the ego stood still: the true reflectors and their heights of the view it repeats
                vi.skipped.append(repeats[k].record(k, ds.frames[i].camera_sd["token"], conf.views))
                continue
            try:
                f = ds[i]
                c, t = oracle_from_frame(f, conf.oracle, rng)
            except DataError as e:  # one bad frame is recorded (by its position in the drive), the drive goes on
                # the frame's own token (its camera sample_data's, as the hybrid's and every frame_id); the reason
                # names the file that failed and its token
                vi.skipped.append({"index": k, "token": ds.frames[i].camera_sd["token"], "reason": str(e)})
                unread.append(f"skipping frame {k} of {vehicle}: {e}")
                continue
            vi.positions.append(k)
            vi.frames.append(c)
            vi.truth.append(t.T_cam_radar)
            vi.oracle_truths.append(t)
            if vi.reference is None:
                vi.reference = np.asarray(f.extras["reference_T_cam_radar"], np.float64)
                vi.road_normal = road_normal(f.extras["reference_T_ego_radar"])
        # the frames skipped, said as the learned methods say them (probe 146: in result.json only), after the
        # vehicle's bar; a vehicle none of whose frames read is one error naming its first (the run's own paragraph)
        for line in unread if say and vi.frames else ():
            print(line, file=sys.stderr)
    return out


def load_oracle(data, version: str, conf: CalibrateConfig | dict | None, progress: bool = True, say: bool = True
                ) -> dict[str, VehicleInput]:
    """Oracle inputs (simulated roots) of every vehicle in ``conf.vehicles`` (all when None), each vehicle's rows
    drawn from ``vehicle_rng(conf.seed, vehicle, "oracle")``; ``progress``: a bar per vehicle; ``say``: print the
    root's warnings (False where the caller opened the root and said them)."""
    return _load_oracle(data, version, merge(CalibrateConfig, conf), progress, say)


def _load_dir(directory: Path, data, version: str | None, conf: CalibrateConfig,
              absent: dict[str, str] | None = None, unknown: dict[str, str] | None = None, say: bool = True
              ) -> dict[str, VehicleInput]:
    """The measurement files of ``directory`` per vehicle; each vehicle of the root (``data``) with none of them is
    put in ``absent`` (``calibrate`` says so: they vanished from result.json without a word), each vehicle of the
    files that the root does not have in ``unknown`` (vehicle -> why), when given and another vehicle's files are
    there (probe 27: one such file stopped the run)."""
    bad: list = []  # (sub-directory, file, DataError) of each unreadable file: skipped, the others are used
    groups = load_measurement_dir(directory, bad)
    if bad and not groups:
        raise DataError(f"none of the {len(bad)} measurement file(s) reads; first: {bad[0][2]}", path=str(directory))
    refs: dict[str, np.ndarray] = {}
    sources: dict[str, dict] = {}  # vehicle -> what its reference is (the tables, or an earlier export's mount)
    truth_of: dict[str, np.ndarray] = {}  # frame token -> its static extrinsic in the root's tables
    unread: dict[str, Exception] = {}  # vehicle -> why the first of its frames' records did not read
    normals: dict[str, np.ndarray | None] = {}
    tokens: set[str] = set()
    frame_of: dict = {}  # token -> its frame (FrameRef) of the root, when there is one
    camera_K: dict[str, np.ndarray] = {}  # frame token -> its camera's intrinsics in the root's tables
    against = None  # what the errors are measured against: a simulated root's truth, a real root's tables
    if data is not None and version:
        from hybrid_calib.data.nuscenes import NuScenesRadarCamera, tables_extrinsic

        ds = NuScenesRadarCamera(data, version, conf={"check_images": False, "reference": conf.reference or None})
        against = "truth" if ds.simulated else "tables"
        for line in ds.reference_notes(conf.vehicles) if say else ():
            print(line, file=sys.stderr)
        _check_exported_from(directory, data, version)
        # a file names its frame by the camera sample_data token (evaluate's export) or the sample (the oracle's)
        frame_of = {t: ref for ref in ds.frames for t in (ref.camera_sd["token"], ref.sample_token,
                                                          ref.radar_sd["token"])}
        tokens = set(frame_of)
        for ref in ds.frames:  # each frame's camera intrinsics: a file's K must be of that camera (at some size)
            try:
                K = ds.tables.camera_intrinsic(ref.camera_sd)
            except DataError:
                continue  # said where the frame is read
            camera_K.update(dict.fromkeys((ref.camera_sd["token"], ref.sample_token, ref.radar_sd["token"]), K))
        for vehicle, idx in ds.frames_by_vehicle().items():
            # from the tables alone (the rows are in the files: probe 137, one unreadable sensor file of a first frame
            # stopped every vehicle), the first frame whose records read
            for i in idx:
                try:
                    refs[vehicle] = np.asarray(ds.reference_T_cam_radar(ds.frames[i]), np.float64)
                    normals[vehicle] = road_normal(ds.reference_T_ego_radar(ds.frames[i]))
                    break
                except (DataError, KeyError, TypeError, ValueError) as e:
                    unread.setdefault(vehicle, e)  # none reads: the vehicle fails with the first one's reason
            sources[vehicle] = ds.reference_source(vehicle)
        ids = [str(m.frame_id) for ms in groups.values() for m in ms]
        # each file's frame's own static extrinsic in the tables (a simulated root's truth, which moves where a mount
        # was knocked: probe 137, the first frame's for the whole drive put a 1.1 deg error at 4.1)
        truth_of = {t: T for t in set(ids) if t in frame_of
                    and (T := tables_extrinsic(ds.tables, frame_of[t].camera_sd, frame_of[t].radar_sd)) is not None}
        foreign = [i for i in ids if i not in tokens]
        if ids and len(foreign) == len(ids):  # another root's files: errors against this root's truth would be wrong
            raise DataError(f"none of the {len(ids)} measurement files' frames (sample or sample_data tokens, e.g. "
                            f"{foreign[0]!r}) is a frame of this root: they were exported from another dataset; pass "
                            f"the --data/--version they come from", path=str(directory))
    out: dict[str, VehicleInput] = {}
    for name, ms in groups.items():
        vehicle = name or (next(iter(refs)) if len(refs) == 1 else "all")
        if conf.vehicles is not None and vehicle not in conf.vehicles:
            continue
        ms = ms[: conf.max_frames] if conf.max_frames > 0 else ms
        ref = refs.get(vehicle)
        if ref is None:
            why = (f"vehicle {vehicle}: none of its frames' calibrated_sensor records read, so it has no reference "
                   f"extrinsic; first: {unread[vehicle]}" if vehicle in unread else
                   f"no reference extrinsic for vehicle {vehicle!r} of the measurement files: pass --data/--version "
                   f"of the dataset they come from (vehicles there: {sorted(set(refs) | set(unread))})")
            if unknown is None or not refs or len(groups) == 1:
                raise DataError(why, path=str(directory))
            unknown[vehicle] = f"{why}; its {len(ms)} file(s) in {directory} left out"
            continue
        # probe 45: a file whose K was not the root camera's (fx, fy doubled) was fused in silence, 0.3 deg further off
        wrong_K = {str(m.frame_id): why for m in ms if str(m.frame_id) in camera_K and
                   (why := other_camera(m.corr.K, camera_K[str(m.frame_id)]))}
        mine = [m for m in ms if (not tokens or str(m.frame_id) in tokens) and str(m.frame_id) not in wrong_K]
        timing: dict[str, str] = {}  # frame token -> why its rows cannot be moved to the camera's timestamp
        if frame_of:
            mine, timing = _at_camera_time(mine, frame_of, ds)
        truth = [truth_of.get(str(m.frame_id)) for m in mine]
        out[vehicle] = VehicleInput(vehicle, [m.corr for m in mine], ref,
                                    truth if truth and all(T is not None for T in truth) else [],
                                    network=[m.network for m in mine],
                                    against=against, reference_source=sources.get(vehicle, {"kind": "tables"}),
                                    road_normal=normals.get(vehicle))
        out[vehicle].skipped.extend({"index": None, "token": str(m.frame_id), "reason": "measurement file of a frame "
                                     "not in this root (another dataset's export): left out"}
                                    for m in ms if tokens and str(m.frame_id) not in tokens)
        out[vehicle].skipped.extend({"index": None, "token": token, "reason": (
            f"measurement file of frame {token}: {why} in the root's tables (exported from another camera or another "
            "root, or edited): left out")} for token, why in wrong_K.items())
        out[vehicle].skipped.extend({"index": None, "token": token, "reason": f"measurement file of frame {token}: "
                                     f"{why}: left out"} for token, why in timing.items())
    if absent is not None:
        for vehicle in sorted(refs):
            if vehicle not in out and (conf.vehicles is None or vehicle in conf.vehicles):
                absent[vehicle] = f"no measurement file in {directory}"
    for sub, path, e in bad:  # a file that does not read has no vehicle field: its folder's, else its frame's (the
        # file is named by its frame's token: probe 100 listed it under every vehicle), else every vehicle's
        owner = getattr(frame_of.get(Path(path).stem), "vehicle", None)
        for vehicle in [sub] if sub in out else [owner] if owner in out else list(out):
            out[vehicle].skipped.append({"index": None, "token": Path(path).stem,
                                         "reason": f"measurement file skipped: {e}"})
        if say:  # said as the frames' readers say theirs (probe 148: in result.json only)
            print(f"skipping measurement file {path}: {e}", file=sys.stderr)
    return out


def _at_camera_time(ms: list, frame_of: dict, ds) -> tuple[list, dict[str, str]]:
    """The measurement files ``ms`` (``factors.io.FrameMeasurements`` of frames of the root ``ds``; ``frame_of``: token
    -> its ``FrameRef``) with their points moved to their camera's timestamp through the ego motion between the two
    (``factors.io.at_camera_time``; a file that says it did so itself is kept as it is), and {token: why} of those
    left out: a timestamp that is not its frame's keyframe's (rows of another image or sweep, which the motion of
    the keyframes would misplace), or poses the frame's reading refuses."""
    from factors.io import at_camera_time

    kept, why = [], {}
    for m in ms:
        token, ref = str(m.frame_id), frame_of[str(m.frame_id)]
        stamps = [(what, int(got), int(sd["timestamp"])) for what, got, sd in (
            ("camera", m.timestamp_us, ref.camera_sd), ("radar", m.timestamp_radar_us, ref.radar_sd))]
        if off := [f"its {what} timestamp {got} us is not the frame's {what} keyframe's ({want} us)"
                   for what, got, want in stamps if got and got != want]:
            why[token] = (" and ".join(off) + ": its rows are of another image or radar sweep, which this reader "
                          "cannot place; write the keyframes' rows (timestamp 0 = the keyframes')")
            continue
        try:
            kept.append(at_camera_time(m, ds.radar_motion(ref)))
        except DataError as e:
            why[token] = f"the ego motion between its radar and camera timestamps does not read ({e})"
    return kept, why


def _network_summary(vi: VehicleInput) -> dict | None:
    """NETWORK of ``calib.result``: the producer's own SE(3) of the last frame that has one."""
    from hybrid_calib.calib.covariance import report_std
    from hybrid_calib.calib.result import STD_FRAME
    from hybrid_calib.metrics import extrinsic_error, std_dict

    last = [(c, n) for c, n in zip(vi.frames, vi.network) if n is not None]
    if not last:
        return None
    c, n = last[-1]
    return {
        "n_frames": len(last), "frame_id": c.frame_id, "iteration": int(n.iteration),
        "T_cam_radar": np.asarray(n.T_cam_radar).tolist(),
        "cov_right_radar": None if n.cov is None else np.asarray(n.cov).tolist(),
        "std_cam": None if n.cov is None else std_dict(report_std(n.T_cam_radar, n.cov), STD_FRAME),
        "error": extrinsic_error(n.T_cam_radar, vi.truth[-1]).as_dict() if vi.truth else None,
    }


# why an estimate from a network's exported rows is not trusted (measured on clean simulated drives, probe 7: NEES
# 36-415 and "recalibrate" at p 1e-97 on 2 of 3 healthy vehicles)
NETWORK_ROWS = ("its rows are a network's (exported by hybrid-calib evaluate), fused here as independent measurements: "
                "their errors share the network's bias on the drive, which only the hybrid models, so the covariance "
                "is far too small; calibrate with --method hybrid for an estimate with a covariance to trust")


# (ASTRAY_ROT_DEG / ASTRAY_TRANS_M: farther than any radar mount sits from its tables; data.reference)


def trust_reason(res: VehicleResult, T_reference: np.ndarray) -> str:
    """Why ``res``'s final estimate cannot be trusted whatever its covariance says, or "": its last solve did not
    converge (``schedule.convergence_note``'s NOT CONVERGED: a status that still opened with "weak"), or it lies
    farther from the vehicle's tables ``T_reference`` (4, 4) than ``ASTRAY_ROT_DEG`` / ``ASTRAY_TRANS_M``."""
    from hybrid_calib.calib.covariance import untrusted_status
    from hybrid_calib.data.mounts import mount_offset

    status = res.final.status  # read through the one reading of a status (a degenerate one's stds already say it)
    reasons = [f"{untrusted_status(status)} (NOT CONVERGED: too few of its rows fit the estimate)"
               if NOT_CONVERGED in status and status_kind(status) != "inconclusive" else ""]
    rot_deg, trans_cm = mount_offset(np.asarray(res.final.T, np.float64), np.asarray(T_reference, np.float64))
    if away := no_view_reason(T_reference):  # said as the cause, not "the solve went astray ... a longer drive"
        reasons.append(away)
    elif not (np.isfinite(rot_deg) and np.isfinite(trans_cm)) or rot_deg > ASTRAY_ROT_DEG or \
            trans_cm > 100 * ASTRAY_TRANS_M:
        astray = "the solve went astray (too few frames or rows for its start: calibrate a longer drive)"
        tables = ("the tables' mount itself is wrong (a rotation or translation in calibrated_sensor.json: "
                  "hybrid-calib inspect warns when the radar's points miss the image with it, or a sensor is upside "
                  "down in it)")
        last = res.trajectory[-1] if res.trajectory else None
        fit = getattr(last, "inlier_fraction", float("nan")) if NOT_CONVERGED not in status else float("nan")
        # a converged solve whose rows fit puts the doubt on the tables first (probe 95: the oracle found the truth
        # from tables 45-180 deg off and read "the solve went astray ... calibrate a longer drive" first)
        which = (f"{tables}: the solve converged with {fit:.0%} of its rows fitting the estimate; or {astray}"
                 if np.isfinite(fit) and fit >= FITS_FRACTION else f"{astray}, or {tables}")
        reasons.append(f"the estimate lies {rot_deg:.1f} deg and {trans_cm / 100:.2f} m from the vehicle's tables, "
                       f"farther than any radar mount sits from them ({ASTRAY_ROT_DEG:g} deg, {ASTRAY_TRANS_M:g} m): "
                       f"{which}")
    reasons.append(unseen_end_reason(res))
    return "; and ".join(r for r in reasons if r)


FITS_FRACTION = 0.5  # a converged solve with at least this share of its last frame's rows inside: its rows fit it
NO_VIEW_DEG = 90.0  # the radar's boresight this far from the camera's optical axis: no field of view is that wide


def no_view_reason(T_reference: np.ndarray) -> str:
    """Why a camera and a radar cannot be calibrated together, or "": their tables' extrinsic ``T_reference``
    (4, 4) turns the radar's boresight more than ``NO_VIEW_DEG`` from the camera's optical axis (probe 34: a rear
    radar paired with the front camera read "the solve went astray (... calibrate a longer drive)")."""
    x_cam = np.asarray(T_reference, np.float64)[:3, 0]  # the radar's boresight in camera axes
    away = float(np.degrees(np.arccos(np.clip(x_cam[2], -1.0, 1.0))))
    if not away > NO_VIEW_DEG:
        return ""
    return (f"the vehicle's tables turn the radar {away:.0f} deg away from the camera's optical axis, so the two share "
            "no view: nothing the radar sees is in the image (a side or rear radar paired with this camera, or a mount "
            "rotation written wrong in calibrated_sensor.json: hybrid-calib inspect says which)")


# a drive whose last frames gave nothing to fuse, this many of them at least (and a quarter of the drive), ends with an
# estimate of the mount before them: a radar knocked away from the camera's view looks exactly so (probe 34: turned
# 180 deg at frame 4 of 8, the oracle's frames 4-7 had no reflector in the image, the result was "weak", scored
# against frame 3's truth with a yaw "within tolerance")
UNSEEN_END_FRAMES = 3


def unseen_end_reason(res: VehicleResult) -> str:
    """Why an estimate cannot stand for the mount at the drive's end, or "": the drive's last frames (at least
    ``UNSEEN_END_FRAMES`` and a quarter of its frames) are all in ``res.skipped`` (no rows, unreadable, repeated rows;
    not the frames the network's domain test dropped, which its own reason names, nor repeated views), so
    the estimate is of the mount before them. Frame positions are the skipped entries' and the trajectory's
    ``index`` (the drive's frame numbers from 0)."""
    # frames the domain test left out are its reason's to say (``hybrid.ood``), not this one's; a repeated view
    # (``data.views``: the ego stood still) is the view it repeats, which was fused (probe 49: a drive ending at a red
    # light read "a radar knocked, blocked or failed there")
    skipped = {int(s["index"]) for s in res.skipped if isinstance(s, dict) and isinstance(s.get("index"), int)
               and "ood_score" not in s and "repeats" not in s}
    used = {int(f.index) for f in res.trajectory} or (set(range(max(skipped) + 1)) - skipped if skipped else set())
    if not skipped or not used:
        return ""
    last, end = max(used), max(skipped | used)
    n_after = end - last
    if n_after < max(UNSEEN_END_FRAMES, 0.25 * (end + 1)) or not all(k in skipped for k in range(last + 1, end + 1)):
        return ""
    why = {int(s["index"]): str(s.get("reason", "")) for s in res.skipped
           if isinstance(s, dict) and isinstance(s.get("index"), int)}
    if all("not found" in why.get(k, "") for k in range(last + 1, end + 1)):  # probe 101: a partial download
        return (f"the drive's last {n_after} of {end + 1} frames (from frame {last + 1} on) have no sensor file on "
                "disk (listed in frames_skipped): a partial download or a moved folder, so this estimate is the mount "
                f"up to frame {last}, not at the drive's end"
                + (f" (its errors are against frame {last}'s truth)" if res.errors_against == "truth" else ""))
    return (f"the drive's last {n_after} of {end + 1} frames (from frame {last + 1} on) gave nothing to fuse (listed "
            "in frames_skipped): a radar knocked, blocked or failed there sees nothing the camera sees, so this "
            f"estimate is the mount up to frame {last}, not at the drive's end"
            + (f" (its errors are against frame {last}'s truth)" if res.errors_against == "truth" else ""))


def _check_exported_from(folder: Path, data, version: str) -> None:
    """``DataError`` when an ``evaluate`` export in ``folder`` records the data stamps of the roots it read
    (``export_config.json`` ``data.stamps``) and none is that of ``data`` / ``version`` now: its rows were measured on
    other images (a copy of the root with other files shares its tokens: probe 23 fused them as this root's,
    bit-identical to the original's). An export that records no stamp is not judged."""
    from hybrid_calib.data.files import data_stamp

    rec = _export_record(folder).get("data")
    rec = rec if isinstance(rec, dict) else {}
    stamps, roots = rec.get("stamps"), rec.get("roots")
    stamps, roots = (list(v) if isinstance(v, list) else [] for v in (stamps, roots))
    if not stamps or data_stamp(data, version)["digest"] in stamps:
        return
    raise DataError(f"the measurement files were exported from other data than {data} ({version}) holds now: the "
                    f"export records the data stamps of {', '.join(map(str, roots)) or 'its roots'} and none is this "
                    "root's (another root whose tokens coincide, or this root changed since); re-run hybrid-calib "
                    "evaluate on this root, or pass the --data it was exported from", path=str(folder))


def _export_record(folder: Path) -> dict:
    """An ``evaluate`` export's ``export_config.json`` in ``folder`` ({} when absent or unreadable: a folder of
    measurement files need not come from evaluate)."""
    try:
        rec = json.loads((folder / "export_config.json").read_text())
    except (OSError, ValueError, RecursionError):
        return {}
    return rec if isinstance(rec, dict) else {}


def _exporter(folder: Path) -> tuple[str | None, str | None]:
    """(checkpoint, depth) an ``evaluate`` export in ``folder`` ran its network with (its ``export_config.json``: the
    checkpoint, and ``eval.depth``, the checkpoint's training depth filled in), each None where it does not say."""
    rec = _export_record(folder)
    ckpt, ev = rec.get("checkpoint"), rec.get("eval")
    depth = ev.get("depth") if isinstance(ev, dict) else None
    return (ckpt if isinstance(ckpt, str) else None), (depth if isinstance(depth, str) and depth else None)


_PINNED = re.compile(r"(?:^|: |; )([a-z][a-z ]*?) \(((?:rotation|translation) [^)]*)\) is prior-pinned")


def pinned_by_prior(res: VehicleResult, own_status: str) -> None:
    """``res`` (a calibration with a fleet prior) saying each direction that the drive's own calibration (its status
    ``own_status``) calls prior-pinned and whose status no longer does: the prior pins it, the drive does not measure
    it; an "ok" becomes "weak". Probe 125: a prior 0.05 deg / 3 mm tight on pitch and the vertical offset (hand-edited:
    a fleet's own carries their common error) read "ok", its vertical offset 38.7 cm off at a 0.3 cm std."""
    names = [f"{w} ({axis})" for w, axis in _PINNED.findall(own_status) if f"{w} ({axis}) is prior-pinned" not in
             res.final.status]
    kind = status_kind(res.final.status)
    if not names or kind not in ("ok", "weak"):
        return
    words = (f"{' and '.join(names)} {'is' if len(names) == 1 else 'are'} pinned by the fleet prior, not measured by "
             "this drive (its own calibration calls them prior-pinned): their stds are the prior's")
    status = f"weak: {words}" if kind == "ok" else f"{res.final.status}; {words}"
    res.final = dataclasses.replace(res.final, status=status)
    if res.trajectory:
        res.trajectory[-1] = dataclasses.replace(res.trajectory[-1], estimate=res.final)


def untrusted(res: VehicleResult, reason: str) -> None:
    """``res`` marked ``inconclusive: reason`` (its own status kept after it), its last frame and its drift verdict
    with it ("cannot tell": an untrusted estimate's difference from the tables is no reason to recalibrate)."""
    from hybrid_calib.calib.covariance import inconclusive_status

    res.final = dataclasses.replace(res.final, status=inconclusive_status(reason, res.final.status))
    if res.trajectory:
        res.trajectory[-1] = dataclasses.replace(res.trajectory[-1], estimate=res.final)
    if res.drift:
        res.drift = unconverged(res.drift, res.final.status)


def in_reference_nouns(res: VehicleResult) -> VehicleResult:
    """``res`` whose verdict and status name its reference as it is (``data.reference.reference_nouns``: against an
    earlier export, "its tables" is the exported mount). The last step of each method's result."""
    from hybrid_calib.calib.drift import drift_in_reference_nouns
    from hybrid_calib.data.reference import reference_nouns

    src = (res.drift or {}).get("reference")
    status = reference_nouns(res.final.status, src)
    if status != res.final.status:
        res.final = dataclasses.replace(res.final, status=status)
        if res.trajectory:
            res.trajectory[-1] = dataclasses.replace(res.trajectory[-1], estimate=res.final)
    res.drift = drift_in_reference_nouns(res.drift)
    # what the radar mount monitor found implausible, and the Doppler lever arm's note that repeats it (probe 107:
    # "a radar's mount is within 10 deg of its tables" beside a level read against the exported mount)
    for block, key in ((res.mount, "implausible"), (getattr(res, "doppler", None), "note")):
        if isinstance(block, dict) and isinstance(block.get(key), str):
            block[key] = reference_nouns(block[key], src)
    return res


def _start(vi: VehicleInput, conf: CalibrateConfig) -> np.ndarray:
    if conf.start == "reference":
        return vi.reference
    if not vi.truth:
        raise HybridCalibError(f"start={conf.start} needs ground truth (a simulated root); use start=reference")
    # seeded by (seed, vehicle) alone: the same start as every other method (hybrid_calib.hybrid)
    return vehicle_start(vi.truth[0], conf.start, conf.seed, vi.vehicle)


def calibrate_vehicle(vi: VehicleInput, conf: CalibrateConfig, progress: bool = True,
                      prior: GaussianPrior | None = None, T_start: np.ndarray | None = None) -> VehicleResult:
    """Calibrate one vehicle's frames; returns the per-frame trajectory (window) and the final estimate.
    ``prior``: an optional Gaussian prior on T_cam_radar (e.g. the fleet's, ``hybrid_calib.fleet.prior``),
    given with the first frame (window; it then lives in the marginal prior) or to the batch solve. The vehicle is
    then also calibrated without it: the verdict against the tables is that calibration's (``drift.tested_on``), and
    a prior the drive's own data contradict (``drift.prior_conflict``) is refused: that calibration is the result, its
    verdict saying why (``drift.refused_prior``).
    ``T_start`` (4, 4): the start extrinsic (default: ``conf.start`` drawn for the vehicle)."""
    from tqdm import tqdm

    from hybrid_calib.calib.covariance import camera_offset, report_std
    from hybrid_calib.geometry import local
    from hybrid_calib.metrics import extrinsic_error, nees

    given = conf.window.factor if conf.mode == "window" else conf.batch.factor
    conf = heights_plane(conf, vi)

    # a frame without rows (a network that matched nothing confidently) carries no information
    pos = list(vi.positions) if len(vi.positions) == len(vi.frames) else list(range(len(vi.frames)))
    repeats = repeated_frames(vi.frames)  # the same rows again (a stalled or replayed feed): one measurement
    frames = [c for i, c in enumerate(vi.frames) if len(c) and i not in repeats]
    kept = [k for i, (k, c) in enumerate(zip(pos, vi.frames)) if len(c) and i not in repeats]
    skipped = vi.skipped + [{"index": k, "token": c.frame_id, "reason": "no correspondence rows"}
                            for k, c in zip(pos, vi.frames) if not len(c)]
    skipped += [{"index": pos[i], "token": vi.frames[i].frame_id,
                 "reason": repeat_message(vi.frames[i].frame_id, vi.frames[j].frame_id)} for i, j in repeats.items()]
    if not frames:
        raise DataError(f"vehicle {vi.vehicle}: no usable frame ({len(skipped)} skipped; first: "
                        f"{skipped[0]['reason'] if skipped else '-'})")
    T0 = _start(vi, conf) if T_start is None else np.asarray(T_start, np.float64)
    traj = []
    if conf.mode == "window":
        cal = SlidingWindowCalibrator(T0, conf.window)
        for k, c in enumerate(tqdm(frames, desc=f"calibrate {vi.vehicle}", disable=not progress)):
            # index: the frame's position in the drive (as the learned methods', the skipped frames' and the mount
            # monitor's), not the window's count of frames it used
            traj.append(dataclasses.replace(cal.update(c, prior=prior if k == 0 else None), index=kept[k]))
        final = traj[-1].estimate
    else:
        final = solve_batch(frames, T0, conf.batch, priors=None if prior is None else [prior]).estimate
    res = VehicleResult(vi.vehicle, final, traj, skipped=skipped, n_frames=len(frames))
    res.start = {"kind": conf.start, "seed": conf.seed, "T_cam_radar": T0.tolist()}
    res.errors_against = (vi.against or "truth") if vi.truth else None
    fc = conf.window.factor if conf.mode == "window" else conf.batch.factor
    res.height_plane = height_plane_record(given, fc, radar_plane_why(vi, conf))
    if prior is None:
        drift = reference_test(final.T, final.cov, vi.reference, conf.drift, prior_pinned_std(fc))
        res.drift = unconverged(drift.to_dict(), final.status)
    else:
        from hybrid_calib.calib.drift import prior_conflict, prior_note, refused_prior, with_prior

        # the drive's own estimate: the verdict is its (a prior says where a fleet's mounts are, not whether this one
        # moved: probe 21's 6-frame drives of radars knocked 1.5 deg in roll lost 3 of 9 "recalibrate" to it)
        own = calibrate_vehicle(vi, conf, progress, None, T0)
        conflict = None if final.info is None else prior_conflict(final.T, final.info, np.asarray(prior.T),
                                                                  np.asarray(prior.cov))
        note = prior_note(final.std, report_std(np.asarray(prior.T), np.asarray(prior.cov)), conflict,
                          own.final.std, camera_offset(own.final.T, final.T))
        if conflict and conflict["conflict"]:  # the drive's data contradict the prior: its own estimate, and why
            own.drift = with_prior(own.drift, refused_prior(note))
            return own
        res.drift = {**with_prior(own.drift, note), "tested_on": "the drive's own data: the same calibration without "
                     "the fleet prior (its estimate is what the verdict compares with the tables); the reported "
                     "estimate holds the prior",
                     # what a fleet prior is fitted on next (fleet.summary): a prior fitted on estimates that hold a
                     # prior counts that prior's information again (probe 21 MED-4)
                     "own_estimate": {"T_cam_radar": own.final.T.tolist(), "cov_right_radar": own.final.cov.tolist()}}
        pinned_by_prior(res, own.final.status)
    res.network = _network_summary(vi)
    if vi.truth:
        T_true = vi.truth[-1]
        res.truth_T, res.truth_path = T_true, path_of(pos, vi.truth)
        e = local(T_true, final.T)
        res.error = {**extrinsic_error(final.T, T_true).as_dict(), "nees": nees(e, final.cov)}
    # what the verdict compared with; against an export, that the oracle tests no turn since it (no mount monitor)
    res.drift = with_turn_since_export({**res.drift, "reference": vi.reference_source}, None, "oracle")
    if vi.oracle_truths and conf.oracle.radar_points == "recorded":
        untrusted(res, RECORDED_ROWS)
    if conf.mode == "batch" and (change := fit_change(final.T, frames, kept, conf.batch)):  # no window, no step test
        res.drift["fit_change"] = change
        untrusted(res, fit_change_words(change))
    if vi.oracle_truths:
        from hybrid_calib.calib.crb import oracle_crb

        T_true = vi.truth[-1]
        try:
            res.crb_std = report_std(T_true, oracle_crb(T_true, vi.frames, vi.oracle_truths, conf.oracle.sigma_px, fc))
        except (np.linalg.LinAlgError, ValueError):  # no inlier row pins a direction (oracle.outlier_frac=1): none;
            res.crb_std = None  # it ended the whole run with 'internal error: Singular matrix'
            res.final = dataclasses.replace(res.final, status=res.final.status + (
                " (no Cramer-Rao bound: the true reflectors' rows leave a direction unconstrained)"))
    return res


def calibrate(data, version: str, correspondences: str, out: Path, conf: CalibrateConfig | dict | None = None,
              overwrite: bool = False, on_vehicle: Callable[[VehicleResult], object] | None = None,
              priors: dict[str, GaussianPrior] | None = None, progress: bool = True) -> CalibrationRun:
    """Calibrate every vehicle and write ``out/result.json`` (``CalibrationRun``, schema in
    ``calib.result``) and the effective config ``out/config.json``. ``correspondences``: "oracle" or
    a measurement directory (``factors.io``; e.g. the ``--out`` of ``hybrid-calib evaluate``).
    ``on_vehicle`` is called with each vehicle's result as soon as it is computed (``hybrid-calib
    calibrate`` draws its plots there). With ``overwrite=False`` an existing result is read and
    returned untouched (idempotent; ``on_vehicle`` is not called). ``priors``: vehicle -> Gaussian prior
    on its T_cam_radar (``calibrate_vehicle``); ``progress`` False hides the per-vehicle bars."""
    conf = merge(CalibrateConfig, conf)
    conf = dataclasses.replace(conf, reference=absolute_reference(conf.reference))
    out = Path(out)
    result_path = out / "result.json"
    cfg = {**to_dict(conf), **reference_identity(conf.reference)}  # the export's content too (--reference)
    if correspondences != "oracle":  # the rows themselves, and where they are from any folder (probe 119)
        from factors.io import measurement_stamp

        correspondences = str(Path(correspondences).resolve())
        cfg["correspondences_stamp"] = measurement_stamp(correspondences)
    if result_path.is_file() and not overwrite:
        return reuse_result(out, data, version, str(correspondences), cfg)
    # before reading: data that change during the run are not this result's
    stamp_data = None if data is None else data_stamp(data, version)
    seen = None if data is None else root_fingerprint(data, version)
    absent: dict[str, str] = {}
    unknown: dict[str, str] = {}  # files of a vehicle the root lacks, a vehicle of no frame: failed, the others run
    said: list[str] = []
    if correspondences == "oracle":
        inputs = _load_oracle(data, version, conf, progress, frameless=unknown, said=said)
    else:
        inputs = _load_dir(Path(correspondences), data, version, conf, absent, unknown)
    if not inputs and unknown:  # each vehicle asked for has no frame, or no file: why, as a run that fails them
        raise DataError(failed_vehicles_message(unknown), path=str(data))
    if not inputs:
        asked = "" if conf.vehicles is None else f" among the vehicles asked for (--set vehicles={list(conf.vehicles)})"
        raise DataError(f"no vehicle to calibrate{asked}: check the vehicle names (hybrid-calib inspect lists them) "
                        "and that the root's frames read", path=str(data))
    if absent:  # said, not failed: an export of one split covers the vehicles of that split only
        import sys

        print(f"note: {len(absent)} vehicle(s) of the root have no measurement file in {correspondences} and are not "
              f"calibrated ({', '.join(sorted(absent)[:5])}{', ...' if len(absent) > 5 else ''}): the export covered "
              "other vehicles or frames; export them too (hybrid-calib evaluate --split all) to calibrate them",
              file=sys.stderr)
    run = CalibrationRun(str(Path(data).resolve()), version, str(correspondences), conf.mode,  # read from anywhere
                         notes=said)
    run.vehicles_failed.update(unknown)
    # the vehicles an interrupted run finished (each vehicle's start and oracle rows are seeded by its name:
    # skipping them leaves the others' draws as they were)
    stamp = {**cfg, "priors": {k: [np.asarray(p.T).tolist(), np.asarray(p.cov).tolist()]
                                         for k, p in sorted((priors or {}).items())},
             **({} if stamp_data is None else {"data_stamp": stamp_data["digest"]})}
    done = VehicleProgress(out, data, version, str(correspondences), stamp, fresh=overwrite)
    method = "oracle" if correspondences == "oracle" else "measurements"  # rows from a directory (factors.io)
    # the exporting network and the depth it read (the report's attention figure draws it on that: probe 142)
    exporter, depth = (None, None) if correspondences == "oracle" else _exporter(Path(correspondences))

    def one(name: str) -> VehicleResult:
        res = calibrate_vehicle(inputs[name], conf, progress, (priors or {}).get(name))
        res.method = method
        if res.network is not None:  # a network's rows (hybrid-calib evaluate's export): never a trusted verdict
            res.checkpoint = exporter
            if depth is not None:
                res.network = {**res.network, "depth": depth}
            untrusted(res, NETWORK_ROWS)
        elif why := trust_reason(res, inputs[name].reference):
            untrusted(res, why)
        return in_reference_nouns(res)

    done.fill(run, list(inputs), one, on_vehicle, progress)
    run.raise_if_none_done()
    if stamp_data is not None and root_changed(data, version, seen, stamp_data["digest"]):  # rewritten under the run
        done.finish()  # (probes 142, 144)
        raise root_changed_error(data)
    save_json_atomic(out / "config.json", cfg)
    if stamp_data is not None:  # a rerun on changed data must not reuse it, nor an edited config.json (probe 150)
        save_json_atomic(out / DATA_STAMP, {**stamp_data, "config": config_digest(cfg)})
    run.save(result_path)
    done.finish()
    return run


def replay_inputs(data, version: str, correspondences: str, conf: CalibrateConfig | dict | None = None
                  ) -> dict[str, tuple[VehicleInput, np.ndarray]]:
    """The inputs a ``calibrate`` run saw, rebuilt from its data and effective config (``RUN/config.json``):
    ``{vehicle: (VehicleInput, (4, 4) start extrinsic)}``. The seed and the order of the draws are
    ``calibrate``'s own (each vehicle's rows and start drawn by (seed, vehicle) alone), so oracle rows and
    R1/R2 starts come out identical to the run's. Used by the report (residuals, before/after)."""
    conf = merge(CalibrateConfig, conf)
    if correspondences == "oracle":  # no bar: a page's replay is not a calibration (probe 91: its bars read as one)
        inputs = _load_oracle(data, version, conf, progress=False, say=False)
    else:
        inputs = _load_dir(Path(correspondences), data, version, conf, say=False)
    return {name: (vi, _start(vi, conf)) for name, vi in inputs.items()}
