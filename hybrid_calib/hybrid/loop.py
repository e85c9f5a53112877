"""One vehicle with each method, and a whole run: the typed entry points of ``hybrid-calib
calibrate --method`` and of the fleet engine.

- ``hybrid``: frame by frame the network runs from the current fused estimate; its rows and SE(3)
  prior (``hybrid.measurement``: no double counting, per-frame shared error, trusted range) enter
  the sliding window (``calib.window``); the window's estimate is the next frame's start.
- ``pure``: the network alone on every frame from the vehicle's start; the result is the last
  frame's estimate and covariance, the trajectory the per-frame series.
- ``pure-avg``: the same per-frame outputs (cached: the same network passes as ``pure``) combined
  by a robust covariance-weighted SE(3) average (``hybrid.average``); the trajectory is the running
  average.
- ``oracle``: the factor graph on the simulator's true reflectors (``calib.pipeline``).

The learned methods drop the frames the network's out-of-domain score flags, and a vehicle with too
few frames in domain is ``inconclusive`` (``hybrid.ood``: the rule, and the result's ``ood`` block).

Every method starts a vehicle from ``perturbation.vehicle_start(base, start, seed, vehicle)``: the
same start for every method and whatever else the run holds. ``base`` is the truth on simulated
roots and the tables' extrinsic on real roots, and errors are against it (``errors_against``); on a
simulated drive whose mount moved (a knocked radar) against the truth at its last frame, which the
final estimate describes.
"""

from __future__ import annotations

import dataclasses
import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.calib.covariance import NOT_CONVERGED, analyse_information, prior_pinned_std
from hybrid_calib.calib.degeneracy import RowGeometry
from hybrid_calib.calib.drift import (
    DriftConfig,
    camera_side_note,
    reference_test,
    unconverged,
    with_mount_step,
)
from hybrid_calib.calib.ego_doppler import drive_sweeps
from hybrid_calib.calib.lever_arm import LeverArmConfig, apply_forward, refusal
from hybrid_calib.calib.lever_arm import fit as fit_lever_arm
from hybrid_calib.calib.lidar_alignment import LidarAlignConfig, align, apply_offsets, drive_frames, forward_refusal
from hybrid_calib.calib.lidar_alignment import innovation as lidar_innovation
from hybrid_calib.calib.lidar_alignment import refusal as lidar_refusal
from hybrid_calib.calib.mount_monitor import MountMonitor, MountMonitorConfig
from hybrid_calib.calib.oracle import OracleConfig
from hybrid_calib.calib.pipeline import trust_reason, untrusted
from hybrid_calib.calib.result import (
    DATA_STAMP,
    RUN_ONLY,
    CalibrationRun,
    Estimate,
    FrameEstimate,
    VehicleProgress,
    VehicleResult,
    failed_vehicles_message,
    reuse_result,
)
from hybrid_calib.calib.schedule import GaussianPrior
from hybrid_calib.calib.window import SlidingWindowCalibrator, WindowConfig
from hybrid_calib.config import merge, save_json_atomic, to_dict
from hybrid_calib.data.files import data_stamp
from hybrid_calib.errors import DataError, HybridCalibError, check_out_not_in_dataset, check_out_outside_data
from hybrid_calib.geometry import local, se3_exp
from hybrid_calib.hybrid.average import AverageConfig, robust_average
from hybrid_calib.hybrid.measurement import MeasurementConfig, frame_inputs, prior_trusted
from hybrid_calib.hybrid.motion import MotionConfig, MotionGate, MotionSource, fold, gated_innovation
from hybrid_calib.hybrid.network import (
    NetworkRunner,
    build_runner,
    clear_own_caches,
    refine_checkpoint,
    shipped_checkpoint,
)
from hybrid_calib.hybrid.ood import OODPolicy, decide, json_score, out_of_domain, skip_record
from hybrid_calib.metrics import extrinsic_error, nees
from hybrid_calib.perturbation import RANGES, vehicle_start
from hybrid_calib.words import join_and

METHODS = ("hybrid", "pure", "pure-avg", "oracle")
STARTS = ("reference", *RANGES)


@dataclass(frozen=True)
class HybridConfig:
    method: str = "hybrid"  # hybrid | pure | pure-avg | oracle
    checkpoint: str = ""  # "" = the shipped small checkpoint of the start range (R2 for R2, else R1)
    refine: str = ""  # refining network after it (a cascade): "" / "none" = none, "shipped" = the shipped R0, or a path
    depth: str = ""  # "" = the checkpoint's; a real root with LiDAR: lidar-densified
    start: str = "reference"  # reference (tables / nominal) | R1 | R2 (perturbed truth, or tables on real roots)
    seed: int = 0  # start seed (per vehicle: perturbation.vehicle_rng(seed, vehicle))
    max_frames: int = 0  # frames per vehicle (0 = all)
    vehicles: tuple[str, ...] | None = None  # vehicles to calibrate (None = all)
    split: str = "all"  # frames used: "all", or "train" | "val" | "test" of split_options (learned.dataset)
    split_options: dict = field(default_factory=dict)  # learned.dataset.SplitConfig overrides, e.g. {"by": "time"}
    window: WindowConfig = WindowConfig()  # the sliding window (hybrid, oracle)
    measurement: dict = field(default_factory=dict)  # MeasurementConfig overrides over the checkpoint's export.hybrid
    # DataConfig overrides for reading the root (hybrid_calib.data.nuscenes), e.g. {"radar_filter":
    # {"invalid_states": null}} for radar files without that field: --set data.radar_filter.invalid_states=null
    data: dict = field(default_factory=dict)
    motion: MotionConfig = MotionConfig()  # the camera-VO / radar-Doppler motion constraint (hybrid; hybrid.motion)
    mount: MountMonitorConfig = MountMonitorConfig()  # radar mount steps, Doppler vs ego poses (calib.mount_monitor)
    lidar: LidarAlignConfig = LidarAlignConfig()  # the radar's lateral offset from the LiDAR (calib.lidar_alignment)
    doppler: LeverArmConfig = LeverArmConfig()  # the radar's forward offset from its Doppler in turns (calib.lever_arm)
    average: AverageConfig = AverageConfig()  # pure-avg
    oracle: OracleConfig = OracleConfig()  # oracle rows (simulated roots only)
    drift: DriftConfig = DriftConfig()  # reference chi-square test of the final estimate
    ood: OODPolicy = OODPolicy()  # out-of-domain frames and the inconclusive status (learned methods, hybrid.ood)
    threads: int = 1  # torch CPU threads (1: on a busy 2-core machine 2 threads were 40x slower, measured)
    cache_dir: str = ""  # network-output cache ("" = none; run_calibration: OUT/network-cache)
    depth_cache: str = ""  # depth cache ("" = none; run_calibration: OUT/depth-cache)
    progress: bool = True  # tqdm per vehicle

    def __post_init__(self):
        if self.method not in METHODS:
            raise ValueError(f"HybridConfig.method={self.method!r}; valid: {METHODS}")
        if self.start not in STARTS:
            raise ValueError(f"HybridConfig.start={self.start!r}; valid: {STARTS}")
        if self.split not in ("all", "train", "val", "test"):
            raise ValueError(f"HybridConfig.split={self.split!r}; valid: all, train, val, test")
        if self.max_frames < 0:
            raise ValueError(f"HybridConfig.max_frames must be >= 0 (0 = all frames), got {self.max_frames}")
        if not 1 <= self.threads <= 256:
            raise ValueError(f"HybridConfig.threads must be in 1..256 (torch CPU threads), got {self.threads}")
        from hybrid_calib.config import merge
        from hybrid_calib.data.nuscenes import DataConfig

        merge(DataConfig, self.data, "data.")  # ConfigError naming --set data.KEY
        if "vehicles" in self.data:  # two vehicle filters: a wanted vehicle left out read "not in the data"
            raise ValueError("data.vehicles: choose the vehicles with --set vehicles=[...] (the one filter of the "
                             "network methods), not data.vehicles")


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

    @property
    def errors_against(self) -> str:
        return "truth" if self.simulated else "tables"

    def positions(self) -> dict[int, int]:
        """dataset index -> the frame's position in this drive (0-based): a learned trajectory's
        ``FrameEstimate.index``, so frames the loop dropped leave gaps instead of shifting later ones."""
        return {i: k for k, i in enumerate(self.indices)}


def resolve_depth(data, version: str, conf: HybridConfig) -> tuple[str, str]:
    """(depth spec, note): ``conf.depth``, or lidar-densified on a real root with LiDAR, or "" (the
    checkpoint's)."""
    from hybrid_calib.data.tables import NuScenesTables
    from learned.depth import LidarDepth

    if conf.depth:
        return conf.depth, ""
    tables = NuScenesTables(data, version)
    simulated = (tables.vdir / "sim_vehicle.json").is_file()
    if not simulated and "LIDAR_TOP" in tables.channels():
        return LidarDepth.name, "real root without --depth: using lidar-densified depth (the LiDAR through the tables)"
    return "", ""


def effective_depth(data, version: str, conf: HybridConfig) -> str:
    """The depth estimator a learned run uses: ``--depth``, the real root's lidar-densified, or the checkpoint's."""
    return resolve_depth(data, version, conf)[0] or trained_depth(conf.checkpoint or shipped_checkpoint(conf.start))


def trained_depth(checkpoint) -> str:
    """The depth spec a checkpoint (path) was trained with (``learned.depth.trained_with``)."""
    from learned.checkpoint import read_checkpoint_meta
    from learned.depth import trained_with

    return trained_with(read_checkpoint_meta(checkpoint)[1].get("train_config"))


def open_drives(data, version: str, conf: HybridConfig, lidar: bool, unreadable: dict | None = None):
    """(frames, {vehicle: Drive}) of a root, restricted to ``conf.vehicles``, the frames of
    ``conf.split`` (``learned.dataset.split_indices`` with ``conf.split_options``) and ``conf.max_frames``.
    A vehicle none of whose frames reads is a ``DataError`` (naming the first bad file), or, when
    ``unreadable`` is a dict, recorded there (vehicle -> reason) and left out."""
    from hybrid_calib.data.summary import keyframe_gap_warning
    from learned.dataset import open_frames, split_indices

    frames = open_frames(data, version, lidar=lidar, options=conf.data)
    simulated = bool(getattr(frames, "sim_vehicles", {}))
    for vehicle, names in getattr(frames, "calibration_splits", {}).items():  # said where the names appear
        left = [n for n in names if conf.vehicles is not None and n not in conf.vehicles]
        print(f"vehicle {vehicle}: its frames hold {len(names)} camera-radar calibrations in the tables, calibrated "
              f"as {', '.join(names)}" + (f" ({', '.join(left)} not among the vehicles asked for)" if left else ""),
              file=sys.stderr)
    for log, words in (frames.intrinsic_changes() if hasattr(frames, "intrinsic_changes") else {}).items():
        print(f"log {log}: {words}", file=sys.stderr)
    if dup := getattr(frames, "duplicates", None):  # the index read them once (data.nuscenes._once_per_file)
        first = next(iter(dup.items()))
        print(f"note: {len(dup)} sample(s) read the same sensor files as earlier samples (first: {first[0]}, as "
              f"{first[1]}): the tables list one recording twice; each frame is read once (hybrid-calib inspect lists "
              "them)", file=sys.stderr)
    by_scene: dict[str, list[int]] = {}
    for ref in getattr(frames, "frames", []):
        if isinstance(ref.camera_sd.get("timestamp"), int):
            by_scene.setdefault(ref.scene_token, []).append(ref.camera_sd["timestamp"])
    if gap := keyframe_gap_warning(by_scene.values()):  # inspect said it; a calibration read time from them silently
        print(f"{gap}: the radar mount monitor, its Doppler pairs and the motion constraint read time from them; fix "
              "the tables before trusting this calibration", file=sys.stderr)
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
        idx = idx[: conf.max_frames] if conf.max_frames > 0 else idx
        f, first_error = None, None
        for i in idx:  # the first readable frame gives the extrinsics
            try:
                f = frames[i]
                break
            except DataError as e:
                first_error = first_error or e
                continue
        if f is None:
            reason = (f"vehicle {vehicle}: no readable frame ({len(idx)} frame(s) tried; first: "
                      f"{first_error if first_error is not None else '-'})")
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
                                 for s in getattr(frames, "lacking_keyframes", {}).get(vehicle, [])])
    for vehicle, skips in sorted(getattr(frames, "lacking_keyframes", {}).items()):  # a vehicle of no frame at all
        if vehicle in by_vehicle or vehicle in drives or (conf.vehicles is not None and vehicle not in conf.vehicles):
            continue
        reason = (f"vehicle {vehicle}: no frame: none of its {len(skips)} sample(s) has both keyframes the run reads "
                  f"(first: {skips[0].reason}); hybrid-calib inspect lists its channels")
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
        raise DataError(f"vehicle(s) {missing} not in the data (vehicles: {present})", path=str(data))
    return frames, drives


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


def measurement_config(runner: NetworkRunner, conf: HybridConfig) -> MeasurementConfig:
    """The checkpoint's fitted ``export["hybrid"]`` block with ``conf.measurement`` over it; a block that
    is wrong on its own is a ``DataError`` naming the checkpoint."""
    fitted = runner.ckpt.export.get("hybrid", {})
    try:
        merge(MeasurementConfig, fitted)
    except HybridCalibError as e:
        raise DataError(f"checkpoint export.hybrid block is invalid ({e}); fix it in the JSON, or remove it and fit "
                        "it again with benchmarks/hybrid_fit.py --fit-into", path=str(runner.ckpt.path)) from None
    return merge(MeasurementConfig, {**fitted, **conf.measurement})


# What a learned method does not measure, as a (6,) right-tangent mask (radar axes: rotation about x = roll, about y =
# pitch; translation along z = height): the network's roll and pitch are its learned prior of the radar's mount seen
# through the camera, and its height is the start's (it does not learn translation). Measured (session 22, simulated
# urban and highway drives with the same seeds, the radar tilted by 1.5-2 deg in roll and / or pitch or not at all):
# the hybrid's roll and pitch moved by at most 0.18 deg whatever the radar's tilt, so a tilted radar is not seen (docs/
# benchmarks.md, "What the hybrid does not measure"). A 2D radar
# has no elevation: neither its Doppler nor its ranges against the LiDAR see these three either. They are named
# "prior-pinned, not measured" in the status and the reference test (calib.covariance, calib.drift); only the mask
# matters (covariance.pinned_camera_axes).
LEARNED_NOT_MEASURED = np.array([1.0, 1.0, 0.0, 0.0, 0.0, 1.0])


def _estimate(T: np.ndarray, cov: np.ndarray, conf: HybridConfig, note: str = "") -> Estimate:
    cov = 0.5 * (cov + cov.T)
    rep = analyse_information(T, np.linalg.inv(cov), conf.window.covariance, cov_hint=cov,
                              pinned_std=LEARNED_NOT_MEASURED, pinned_marginalised=True)
    return Estimate.from_report(T, rep, None, note)


def _frame(k: int, fid: str, ts: int, est: Estimate, n: int, ms: float) -> FrameEstimate:
    return FrameEstimate(k, fid, ts, est, n_window=n, n_total=n, inlier_fraction=float("nan"), step_statistic=None,
                         step_threshold=None, step_alarm=False, solve_ms=ms, cov_ms=0.0)


@dataclass
class _Trace:
    """What a learned method records besides its trajectory: skipped frames, per-frame rows, the
    out-of-domain score of every pass, and whether out-of-domain frames are dropped."""

    drop: bool = True
    skipped: list = field(default_factory=list)
    rows: list = field(default_factory=list)
    scores: list = field(default_factory=list)
    priors: int = 0  # network priors the hybrid inflated by its drive-common error (``_hybrid``)
    unread: int = 0  # frames whose inputs did not read (the network never ran): they count against the domain test
    # where the reflectors the network matched lie (its iteration-0 rows, kept frames): the status names a straight
    # road as the oracle's does (``with_road_words``)
    geometry: RowGeometry = field(default_factory=RowGeometry)

    def unreadable(self, runner: NetworkRunner, i: int) -> None:
        """Record frame ``i`` as skipped: its files did not read (``runner.bad_reason``)."""
        self.unread += 1
        self.skipped.append({"index": int(i), "token": runner.token(i), "reason": runner.bad_reason(i)})

    def keep(self, runner: NetworkRunner, i: int, out, conf: HybridConfig) -> bool:
        """Score the pass; False (and recorded) when it is out of domain and dropped."""
        score = runner.ood_score(out) if conf.ood.enabled else float("nan")
        self.scores.append(score)
        if self.drop and out_of_domain(score, conf.ood):
            self.skipped.append(skip_record(i, runner.token(i), score, conf.ood))
            return False
        self.geometry.add(out.rows_first.points_radar)
        return True


def _passes(runner: NetworkRunner, drive: Drive, T0: np.ndarray, conf: HybridConfig, tr: _Trace):
    """The network from the vehicle's start on every frame (cached), out-of-domain frames dropped:
    [(index, NetworkOutput)]."""
    from tqdm import tqdm

    outs = []
    for i in tqdm(drive.indices, desc=f"network {drive.vehicle}", disable=not conf.progress, leave=False):
        out = runner.run(i, T0)
        if out is None:
            tr.unreadable(runner, i)
        elif tr.keep(runner, i, out, conf):
            outs.append((i, out))
    return outs


def with_drive_error(traj: list[FrameEstimate], drive_std, conf: HybridConfig) -> list[FrameEstimate]:
    """The trajectory with the drive-common network error ``diag(drive_std^2)`` added to every
    reported covariance (``measurement`` module doc, item 4); unchanged when it is zero."""
    D = np.diag(np.asarray(drive_std, np.float64) ** 2)
    if not np.any(D):
        return traj
    return [with_cov(f, f.cov + D, conf) for f in traj]


def with_cov(f: FrameEstimate, cov: np.ndarray, conf: HybridConfig, T: np.ndarray | None = None) -> FrameEstimate:
    """Frame ``f`` re-reported with covariance ``cov`` (6, 6) (and estimate ``T``, when given), keeping
    the window's own notes (a solve that did not converge, a restart after a step)."""
    notes = [f.estimate.status[i:].split(")")[0] for key in (NOT_CONVERGED, "recovering")
             if (i := f.estimate.status.find(key)) >= 0]
    return dataclasses.replace(f, estimate=_estimate(f.T if T is None else T, cov, conf, "; ".join(notes)))


def with_road_words(traj: list[FrameEstimate], geometry: RowGeometry, conf: HybridConfig) -> list[FrameEstimate]:
    """The trajectory with its last status naming a straight road (``calib.degeneracy.along_road`` on the reflectors
    the network matched, the oracle's rule and thresholds): an "ok" becomes "weak", a "weak" gets the words; an
    untrusted status is left as it is. Words only: the drive-common error term already widens the covariance for a
    network error that does not average out (probe 16: no hybrid status named a straight road; the oracle's all do)."""
    from hybrid_calib.calib.covariance import status_kind
    from hybrid_calib.calib.degeneracy import along_road

    frac = along_road(geometry, conf.window.covariance.degeneracy)
    if frac is None or not traj:
        return traj
    last = traj[-1]
    words = (f"all the reflectors the network matched lie along the road ({100 * frac:.0f} % on two lines parallel "
             "to the travel direction): every frame shows it one kind of scene, so its error there does not average "
             "out over the drive")
    kind = status_kind(last.estimate.status)
    if kind not in ("ok", "weak"):
        return traj
    status = f"weak: {words}" if kind == "ok" else f"{last.estimate.status}; {words}"
    return [*traj[:-1], dataclasses.replace(last, estimate=dataclasses.replace(last.estimate, status=status))]


def with_prior_words(traj: list[FrameEstimate]) -> list[FrameEstimate]:
    """The trajectory with its last status naming what a learned method does not measure (``LEARNED_NOT_MEASURED``):
    roll and pitch (the network's learned prior of the radar's mount) and the vertical offset (the start's), each
    unless the covariance's reading already named it prior-pinned. An "ok" becomes "weak"; an untrusted status is left
    as it is. Words only: the reported stds are the fitted spread of the network's errors on simulated fleets (probe
    16: a radar pitched 2 deg read "differs by 0.07 deg +- 0.82 deg" in pitch, its status naming only offsets)."""
    from hybrid_calib.calib.covariance import status_kind

    if not traj or status_kind(traj[-1].estimate.status) not in ("ok", "weak"):
        return traj
    last = traj[-1]
    status, std = last.estimate.status, last.estimate.std
    named = [w for w, i in (("roll", 2), ("pitch", 0), ("vertical offset", 4))
             if not re.search(rf"\b{w} \([^)]*\) is prior-pinned", status)]
    if not named:
        return traj
    units = {"roll": (2, "deg"), "pitch": (0, "deg"), "vertical offset": (4, "cm")}
    stds = ", ".join(f"{w} {std[units[w][0]]:.2g} {units[w][1]}" for w in named)
    what = [*(["the network's learned prior of the radar's mount, seen through the camera"]
              if {"roll", "pitch"} & set(named) else []),
            *(["the vertical offset is the start's"] if "vertical offset" in named else [])]
    words = (f"{join_and(named)} {'is' if len(named) == 1 else 'are'} prior-pinned, not measured by this drive ("
             f"{'; '.join(what)}; std {stds}): a 2D radar has no elevation, so a radar tilted or raised off the "
             "fleet's mounts is not seen")
    status = f"weak: {words}" if status_kind(status) == "ok" else f"{status}; {words}"
    return [*traj[:-1], dataclasses.replace(last, estimate=dataclasses.replace(last.estimate, status=status))]


def sweep_files_record(frames, indices) -> dict:
    """The mount block's words on the radar's sweep files between keyframes over dataset ``indices`` (those the
    monitor read): ``sweeps_absent`` when the tables list sweeps and none is on disk (a keyframe-only copy), else
    ``sweeps_missing`` {"n", "of", "first"} when some are missing."""
    seen = [getattr(frames, "sweep_files", {}).get(i) for i in indices]
    listed = sum(s[0] for s in seen if s)
    missing = [p for s in seen if s for p in s[1]]
    if listed and len(missing) == listed:
        return {"sweeps_absent": True}
    return {"sweeps_absent": False, **({"sweeps_missing": {"n": len(missing), "of": listed, "first": missing[0]}}
                                       if missing else {})}


def _since_last_step(mon: MountMonitor | None) -> int:
    """The drive position the radar's current mount starts at: its last step's change, or 0."""
    return mon.steps[-1].change if mon is not None and mon.steps else 0


def _fold_last(traj: list[FrameEstimate], conf: HybridConfig, a, why: str, refused: str, apply, record=None
               ) -> tuple[list[FrameEstimate], dict]:
    """The trajectory with the alignment ``a`` (``None``: not measured, because ``why``) folded into its last
    estimate by ``apply(T, cov, a)`` unless ``refused`` says why not, and the alignment's result block
    (``record(a)`` when applied; default ``a.record(True)``)."""
    if a is None:
        return traj, {"applied": False, "note": why}
    if refused:
        return traj, a.record(False, refused)
    last = traj[-1]
    T, cov = apply(last.T, last.cov, a)
    return [*traj[:-1], with_cov(last, cov, conf, T)], (record or (lambda a: a.record(True)))(a)


def with_lidar(traj: list[FrameEstimate], drive: Drive, frames, conf: HybridConfig, mon: MountMonitor | None,
               motion: MotionSource | None = None) -> tuple[list[FrameEstimate], dict]:
    """The trajectory with the LiDAR's lateral (and, when it is certain enough, forward) offset
    (``calib.lidar_alignment``) folded into its last estimate, and the result's ``lidar`` block (what was
    measured, and whether and why not it was applied).
    Frames: those the loop used, after the radar's last mount step (the mount before it was another)."""
    since = _since_last_step(mon)
    indices = [drive.indices[f.index] for f in traj if f.index >= since and 0 <= f.index < len(drive.indices)]
    lfs = drive_frames(frames, indices, conf.lidar, motion.velocity if motion is not None else None,
                       conf.motion.velocity)
    if not lfs:
        return traj, {"applied": False, "note": "no LiDAR in the frames (the alignment needs the LiDAR keyframes "
                                                "and the tables' LiDAR-camera extrinsic; the frames are read with "
                                                "their LiDAR only for --depth lidar-densified)"}
    a, why = align(lfs, traj[-1].T, conf.lidar)
    if a is None:
        return traj, {"applied": False, "note": why}
    no_dx, z = forward_refusal(a, conf.lidar), lidar_innovation(a, traj[-1].cov)
    if no := lidar_refusal(a, conf.lidar, traj[-1].cov):
        return traj, a.record(False, no, innovation=z)
    return _fold_last(traj, conf, a, why, "", lambda T, cov, a: apply_offsets(T, cov, a, forward=not no_dx),
                      lambda a: a.record(True, forward=not no_dx, forward_why=no_dx, innovation=z))


def with_doppler(traj: list[FrameEstimate], drive: Drive, frames, conf: HybridConfig, mon: MountMonitor | None,
                 motion: MotionSource | None) -> tuple[list[FrameEstimate], dict]:
    """The trajectory with the radar's forward offset from its Doppler in turns (``calib.lever_arm``) folded
    into its last estimate, and the result's ``doppler`` block (what was measured, and whether and why not it
    was applied). Sweeps: every frame of the drive after the radar's last mount step (the Doppler does not
    depend on the network's domain); velocities: the motion source's (one Doppler fit per frame)."""
    velocity, cache = (motion.velocity, motion.sweeps) if motion is not None else (None, None)
    sweeps, T_ego_cam = drive_sweeps(frames, drive.indices[_since_last_step(mon):], velocity, conf.doppler.sweeps,
                                     cache)
    if T_ego_cam is None:
        return traj, {"applied": False, "note": "no camera mount (T_ego_cam) in the tables: the ego poses cannot "
                                                "be carried to the camera"}
    a, why = fit_lever_arm(sweeps, traj[-1].T, T_ego_cam, conf.doppler)
    wrong = (mon.summary().get("implausible") or "") if mon is not None else ""  # the same pairs: not trusted
    return _fold_last(traj, conf, a, why, (wrong or refusal(a, conf.doppler)) if a else "", apply_forward)


def with_yaw_check(traj: list[FrameEstimate], drive: Drive, conf: HybridConfig, mon: MountMonitor | None
                   ) -> tuple[list[FrameEstimate], dict | None]:
    """The trajectory with its last estimate's yaw checked against the radar's own yaw on the vehicle (the mount
    monitor's level: ``calib.mount_monitor.yaw_agreement``), and the check's record (None: no monitor, or no one
    level to compare with). Where the two disagree (both put the radar off its tables' yaw, by amounts more than 3
    sigma apart), one of them, or the camera's mount in the tables, is wrong and nothing here tells which: the
    estimate's variance about the ego z axis grows by the squared difference, so its 1-sigma covers the other
    measurement too, and its status says so. Measured on nuScenes scene-0916 (probe 9): the loop on its in-domain
    frames put the radar's yaw 1.97 +- 0.16 deg off the tables, its Doppler 0.93 +- 0.10; without the check the
    verdict read "recalibrate" by 1.97 deg (and 1.11 +- 0.34 from another start)."""
    if mon is None or drive.ego_radar is None or not traj:
        return traj, None
    from hybrid_calib.calib.mount_monitor import yaw_agreement
    from hybrid_calib.geometry import se3_inverse

    last = traj[-1]
    # the tables' camera mount: their radar mount and the reference extrinsic (the truth's on simulated roots: probe 16)
    check = yaw_agreement(last.T, last.cov, drive.ego_radar @ se3_inverse(drive.reference), drive.ego_radar,
                          mon.summary())
    if check is None or not check["disagree"]:
        return traj, check
    from hybrid_calib.calib.covariance import report_std

    u, d = np.asarray(check["direction"]), np.radians(check["difference_deg"])
    cov = last.cov + d * d * np.outer(u, u)
    words = (f"its yaw disagrees with the radar's own: the estimate puts the radar {check['estimate_deg']:+.2f} +- "
             f"{check['estimate_std_deg']:.2f} deg from its tables' yaw on the vehicle, the radar's Doppler against "
             f"the ego poses {check['doppler_deg']:+.2f} +- {check['doppler_std_deg']:.2f} deg "
             f"({check['sigmas']:.1f} sigma apart): the estimate, or the camera's mount in the tables (which the "
             "comparison takes as exact), is wrong; the yaw's 1-sigma is widened to cover both")
    # the data's own words kept (they say what the drive observes; the widening is this disagreement's, said after)
    est = dataclasses.replace(last.estimate, cov=cov, std=report_std(last.T, cov),
                              status=f"{last.estimate.status} ({words})")
    return [*traj[:-1], dataclasses.replace(last, estimate=est)], {**check, "widened": True, "words": words}


def _pure(runner, drive, T0, conf, tr):
    traj, rows, pos = [], tr.rows, drive.positions()
    for i, out in _passes(runner, drive, T0, conf, tr):
        traj.append(_frame(pos[i], out.rows_last.frame_id, out.rows_last.timestamp_us,
                           _estimate(out.T, runner.network_cov(out), conf), 1, out.seconds * 1e3))
        rows.append({"frame_id": out.rows_last.frame_id, "used": 0, "rejected": 0, "network_ms": out.seconds * 1e3,
                     "ood_score": json_score(runner.ood_score(out))})
    return traj


def _pure_avg(runner, drive, T0, conf, tr):
    mconf = measurement_config(runner, conf)
    S = np.diag(np.asarray(mconf.shared_std, np.float64) ** 2)
    passes, rows = _passes(runner, drive, T0, conf, tr), tr.rows
    Ts = np.stack([o.T for _, o in passes]) if passes else np.zeros((0, 4, 4))
    covs = np.stack([runner.network_cov(o) + S for _, o in passes]) if passes else np.zeros((0, 6, 6))
    traj, M, pos = [], None, drive.positions()
    for k, (i, out) in enumerate(passes):
        t0 = time.perf_counter()
        M, cov, w = robust_average(Ts[: k + 1], covs[: k + 1], conf.average, M)
        traj.append(_frame(pos[i], out.rows_last.frame_id, out.rows_last.timestamp_us, _estimate(M, cov, conf), k + 1,
                           out.seconds * 1e3 + (time.perf_counter() - t0) * 1e3))
        rows.append({"frame_id": out.rows_last.frame_id, "used": 0, "rejected": 0, "network_ms": out.seconds * 1e3,
                     "ood_score": json_score(runner.ood_score(out))})
    if passes:
        rows[-1]["weights"] = [float(x) for x in w]
    return with_drive_error(traj, mconf.drive_std, conf)


def motion_bias_cov(C: np.ndarray, g: np.ndarray, motion_std_rad: float) -> np.ndarray:
    """``C + s^2 (C g)(C g)^T``: the window's covariance ``C`` (6, 6) with a heading bias common to
    the drive's motion measurements (std ``s`` rad) carried through their summed gain ``g = sum(w J)``
    (6,) (a consider covariance)."""
    gm = C @ g
    return C + motion_std_rad ** 2 * np.outer(gm, gm)


def with_motion_bias(traj: list[FrameEstimate], motion_gain: list[np.ndarray], motion_std_rad: float,
                     conf: HybridConfig) -> list[FrameEstimate]:
    """The trajectory with ``motion_bias_cov`` in every reported covariance (``motion_gain``: per frame)."""
    return [with_cov(f, motion_bias_cov(f.cov, g, motion_std_rad), conf) for f, g in zip(traj, motion_gain)]


def _hybrid(runner, drive, T0, conf, tr, motion: MotionSource | None = None, mount: MountMonitor | None = None,
            n_priors: int | None = None):
    """The closed loop (module doc), with the motion constraint folded into each frame's prior when
    ``motion`` is given (``hybrid.motion``), and the radar mount monitor (``calib.mount_monitor``)
    run on every frame when ``mount`` is given: its alarm restarts the window from the change point,
    turned by the yaw step it measured.

    The network's error common to a drive (``drive_std``, ``measurement`` item 4) enters in one of
    two ways. Network priors alone: added to the reported covariance afterwards (``with_drive_error``;
    the estimate is then their average, whatever their weights). With motion measurements the split
    of the estimate between the two sources matters, so the common error enters the weights: each
    frame's network prior covariance is inflated by ``N D`` (D = ``diag(drive_std^2)``; N = ``n_priors``, the
    network priors the window fuses, known only after a pass: default the drive's frames, and ``vehicle_learned``
    reruns with the count where frames were skipped or dropped, ``DRIVE_ERROR_RERUN``). The N priors
    ``x + b + e_k`` with a common ``b ~ N(0, D)`` carry, by generalised least squares, ``(C / N + D)^-1`` about
    x; N priors of covariance ``C + N D`` carry exactly that after the last frame, and less before it
    (conservative). The motion then decides
    what the network's bias cannot average out (the yaw), and the network the rest.
    """
    from tqdm import tqdm

    skipped, rows = tr.skipped, tr.rows
    mconf = measurement_config(runner, conf)
    cal = SlidingWindowCalibrator(T0, conf.window)
    gate = conf.window.schedule.final_gate
    T, fused_cov, traj = T0.copy(), None, []
    g_frames, motion_gain, prev, reported_cov = [], [], None, None
    in_window, pending = [], None  # drive positions of the window's frames; a mount step not yet applied
    D = np.diag(np.asarray(mconf.drive_std, np.float64) ** 2)  # the network's drive-common error
    inflate = (n_priors or len(drive.indices)) * D
    s_mot = np.radians(conf.motion.drive_std_deg)
    motion_gate = MotionGate(conf.motion)
    for k, i in enumerate(tqdm(drive.indices, desc=f"hybrid {drive.vehicle}", disable=not conf.progress,
                               leave=False)):
        pair, prev = prev, i
        reading = mount.update(k, i) if mount is not None else None
        if reading is not None and reading.step is not None:
            pending = reading.step
        out = runner.run(i, T)
        if out is None:
            tr.unreadable(runner, i)
            continue
        if not tr.keep(runner, i, out, conf):
            continue
        trusted = prior_trusted(conf.start, runner.range, fused_cov, mconf.trust_sigma_frac)
        fi = frame_inputs(out, T, mconf, conf.window.factor, gate, trusted)
        if not len(fi.corr) and fi.prior is None:
            skipped.append({"index": int(i), "token": out.rows_first.frame_id, "reason": "no correspondence rows"})
            continue
        prior, mrec = fi.prior, {}
        if motion is not None and fi.prior is not None:
            prior = GaussianPrior(fi.prior.T, fi.prior.cov + inflate)
            tr.priors += 1
            # headings the radar's Doppler already contradicts (mirrored ego poses): rotation from the images
            ego = mount is None or not mount.headings_implausible()
            m, why = motion.measurement(pair, i, T[:3, :3], ego) if pair is not None else (None, "first frame")
            if not ego:
                mrec["motion_rotation"] = "images (the ego poses' headings contradict the radar's Doppler)"
            # gated by the tighter of the estimate's covariance and this frame's pass with its drive error
            inn = None if m is None else gated_innovation(T, m, conf.motion, (fi.prior.cov + D, reported_cov))
            fo = fold(prior, T, inn, conf.motion, gated=False) if inn is not None and motion_gate.admit(inn) else None
            g_frames.append(fo.gain_motion if fo is not None else np.zeros(6))
            if fo is not None:
                prior = fo.prior
                mrec = {**mrec, "motion": {"residual_deg": fo.residual_deg, "weight": fo.weight,
                                   "sigma_deg": float(np.degrees(inn.sigma)), "speed_mps": m.speed,
                                   "vo_inliers": m.n_vo_inliers,
                                   **({"admitted": "consensus"} if motion_gate.admitted_by_consensus else {})}}
            else:
                mrec = {**mrec, "motion_skipped": why or "residual outside the innovation gate (MotionConfig.gate)"}
            if inn is not None:
                mrec["motion_z"] = float(inn.z)
        fe, turned = cal.update(fi.corr, prior), None
        in_window.append(k)
        if pending is not None:  # the radar turned: restart the window from the frames since the change
            keep = min(sum(p >= pending.change for p in in_window), conf.window.window, len(g_frames) or 10 ** 9)
            turned = fe.T @ se3_exp(np.array([0.0, 0.0, np.radians(pending.step_deg), 0.0, 0.0, 0.0]))
            cal.reset(keep_last=keep, T=turned)
            in_window = in_window[len(in_window) - keep:] if keep else []
            g_frames = g_frames[len(g_frames) - keep:] if keep else []
            seen = alarm_since(traj, pending.change)
            fe = dataclasses.replace(fe, step_alarm=fe.step_alarm or seen is None, events=(
                *fe.events, pending.describe(conf.mount.threshold) + f"; window restarted from frame {pending.change}"
                + ("" if seen is None else f" (the same step as the window's alarm at frame {seen})")))
            pending = None
        traj.append(dataclasses.replace(fe, index=k))  # the frame's position in the drive, not the window's count
        g_mot = np.sum(g_frames, axis=0) if g_frames else np.zeros(6)
        motion_gain.append(g_mot)
        T, fused_cov = fe.T if turned is None else turned, fe.cov
        if motion is not None:  # the estimate's uncertainty with the motion's common bias: the gate's
            reported_cov = motion_bias_cov(fe.cov, g_mot, s_mot)
        used = int(round(fe.inlier_fraction * len(fi.corr)))
        rows.append({"frame_id": fi.corr.frame_id, "used": used, "rejected": len(fi.corr) - used,
                     "deflation": fi.deflation, "prior_used": fi.prior_used, "network_ms": out.seconds * 1e3,
                     "ood_score": json_score(runner.ood_score(out)), **mrec,
                     **({"mount": reading.record()} if reading is not None else {}),
                     **({"note": fi.note} if fi.note else {})})
    if motion is None:
        return with_drive_error(traj, mconf.drive_std, conf)
    return with_motion_bias(traj, motion_gain, s_mot, conf)


LEARNED = {"hybrid": _hybrid, "pure": _pure, "pure-avg": _pure_avg}


def _finish(res: VehicleResult, drive: Drive, T0: np.ndarray, conf: HybridConfig) -> VehicleResult:
    final = res.final
    # the directions the method does not measure are named prior-pinned in the verdict (oracle: the elevation prior's)
    pinned = prior_pinned_std(conf.window.factor) if conf.method == "oracle" else LEARNED_NOT_MEASURED
    res.drift = unconverged(reference_test(final.T, final.cov, drive.reference, conf.drift, pinned).to_dict(),
                            final.status)
    truth = drive.base if drive.end is None else drive.end  # the mount at the drive's end (a knock moved it)
    e = local(truth, final.T)
    res.truth_T = truth
    res.error = {**extrinsic_error(final.T, truth).as_dict(), "nees": nees(e, final.cov)}
    res.method = conf.method
    res.start = {"kind": conf.start, "seed": conf.seed, "T_cam_radar": T0.tolist()}
    res.errors_against = drive.errors_against
    return res


def unfitted_reason(runner, method: str) -> str:
    """Why a learned result's covariance cannot be trusted for want of a fit, or "": the network's
    covariance scale (``export.cov_scale``, every learned method) and the measurement model with its
    drive-common error (``export.hybrid``, hybrid and pure-avg) are fitted per checkpoint on
    validation drives; without them the reported covariance shrinks with frames while the network's
    error on the drive does not (measured: a fine-tuned checkpoint without them said `ok` with the
    translation error outside 3 sigma in 4 of 5 trials)."""
    export = runner.ckpt.export or {}
    missing = [k for k in ("cov_scale", *(("hybrid",) if method != "pure" else ())) if k not in export]
    if not missing:
        return ""
    how = {"cov_scale": "hybrid-calib evaluate --fit-uncertainty", "hybrid": "benchmarks/hybrid_fit.py --fit-into"}
    return (f"checkpoint {runner.ckpt.path} has no fitted {' / '.join('export.' + k for k in missing)}, so its "
            f"covariance is not calibrated; fit {' and '.join(how[k] for k in missing)} on validation drives")


# the HybridConfig blocks only some methods read (``window``, ``average``, ``drift``, ... are read by more): a
# ``--set`` of one for another method was accepted and had no effect
BLOCK_METHODS = {"oracle": ("oracle",), "measurement": ("hybrid", "pure-avg"), "motion": ("hybrid",),
                 "mount": ("hybrid",), "lidar": ("hybrid",), "doppler": ("hybrid",)}


def unused_blocks(method: str, overrides: dict) -> list[str]:
    """The config blocks of ``overrides`` (``--set``) that ``method`` does not read (``BLOCK_METHODS``)."""
    return [k for k, methods in BLOCK_METHODS.items() if k in overrides and method not in methods]


STANDSTILL_M = 1.0  # a drive whose ego poses travel less than this, metres: its frames are one view


def standstill_reason(frames, drive: Drive) -> str:
    """Why a learned result of a drive that did not move cannot be trusted, or "": its frames repeat one view, so the
    network's passes on them share their errors, yet each entered as an independent frame (a stand-still drive's
    1-sigma shrank from 1 frame to 10 with the same estimate, NEES 13.7 -> 23.3 on real data: probe 7)."""
    travel = getattr(frames, "ego_travel_m", lambda idx: None)(drive.indices) if len(drive.indices) > 1 else None
    if travel is None or travel >= STANDSTILL_M:
        return ""
    return (f"the vehicle did not move (its ego poses travel {travel:.2f} m over {len(drive.indices)} frames): the "
            "frames repeat one view, so they are not independent measurements and the covariance is too small; "
            "calibrate on a drive")


def range_note(start: str, trained: str, checkpoint: str) -> str:
    """A note when the start range is wider than the one the network was trained on ("" otherwise): its
    estimates are then outside what it learned (e.g. the R0 network from an R2 start)."""
    if start not in RANGES or trained not in RANGES or RANGES[start] <= RANGES[trained]:
        return ""
    return (f"the start range {start} (+-{RANGES[start][0]:g} deg, +-{RANGES[start][1]:g} m) is wider than the "
            f"{trained} range the checkpoint {checkpoint} was trained on: expect poor estimates; use a checkpoint "
            f"trained on {start} (or --refine it after one)")


def alarm_since(traj: list, change: int) -> int | None:
    """The drive position of the latest step alarm in ``traj`` at or after position ``change``, or None. One knock,
    one alarm: when the window's own test already fired for the step the mount monitor has just found (at or after
    its change point), the monitor's finding is recorded on its frame with that alarm's position, not raised
    again (on a knocked test drive the window fired at frame 23 and the monitor at 24, for one knock at 20)."""
    return next((f.index for f in reversed(traj) if f.step_alarm and f.index >= change), None)


def mount_monitor(frames, drive: Drive, conf: HybridConfig, motion: MotionSource | None) -> MountMonitor | None:
    """A fresh radar mount monitor for the hybrid on this drive, or None (another method, turned off,
    no frames given, or no ``T_ego_radar`` in the data). Its Doppler velocities are the motion
    source's (``conf.motion.velocity``, each frame's fitted once for both)."""
    if conf.method != "hybrid" or not conf.mount.enabled or frames is None or drive.ego_radar is None:
        return None
    src = motion or MotionSource(frames, conf.motion)
    return MountMonitor(frames, drive.ego_radar, conf.mount, src.velocity, src.sweeps)


# the hybrid reruns a drive whose network priors (frames read, in domain, with a prior) are fewer than this fraction
# of its frames, with their count as the drive-common error's N (``_hybrid``): 5 of 10 frames unreadable reported a
# 1-sigma 1.35 times that of the 5 alone. Above it the excess is under ~5 % of the std, not worth a second pass.
DRIVE_ERROR_RERUN = 0.9


def _run_learned(runner, drive, T0, conf, tr, motion, frames, n_priors: int | None = None):
    """(trajectory, the mount monitor or None) of one pass over the drive (``n_priors``: ``_hybrid``)."""
    if conf.method == "hybrid":
        mon = mount_monitor(frames, drive, conf, motion)
        return _hybrid(runner, drive, T0, conf, tr, motion, mon, n_priors), mon
    return LEARNED[conf.method](runner, drive, T0, conf, tr), None


def vehicle_learned(runner: NetworkRunner, drive: Drive, conf: HybridConfig, note: str = "",
                    motion: MotionSource | None = None, frames=None) -> VehicleResult:
    """A learned method (hybrid | pure | pure-avg) on one drive with a loaded network; ``motion``:
    the frames' motion measurements (hybrid only; None = the network alone); ``frames``: the root's
    frames by dataset index, for the radar mount monitor (hybrid only; None = no monitor)."""
    T0 = start_of(drive, conf)
    tr = _Trace(drop=True)
    traj, mon = _run_learned(runner, drive, T0, conf, tr, motion, frames)
    ood = decide(tr.scores, conf.ood, runner.ood_note, unread=tr.unread)
    ood["dropped"] = sum("ood_score" in s for s in tr.skipped)
    total = ood["frames"] + ood.get("unread", 0)  # the frames that did not read count too (hybrid.ood.decide)
    if ood["inconclusive"] and not ood["dropped"]:  # nothing was dropped: the pass already used every frame
        ood.update(rerun_in_domain=ood["in_domain"], note=(
            f"too few frames in domain ({ood['in_domain']} of {total}, the scores above; none was dropped): the "
            "estimate uses every frame that read and is not trusted"))
    elif ood["inconclusive"]:  # too few frames in domain: every frame, nothing dropped, and say so (hybrid.ood)
        tr = _Trace(drop=False)
        traj, mon = _run_learned(runner, drive, T0, conf, tr, motion, frames)
        # the rerun's passes start elsewhere (no frame dropped), so their scores differ: frame_rows hold them
        rerun_in = sum(not out_of_domain(x, conf.ood) for x in tr.scores)
        ood.update(dropped=0, rerun_in_domain=int(rerun_in), note=(
            f"too few frames in domain on the pass that drops them ({ood['in_domain']} of {total}, the "
            "scores above): the estimate uses every frame and is not trusted; on that every-frame pass "
            f"{rerun_in} of {len(tr.scores)} frames scored in domain (the scores in frame_rows)"))
    n_priors = None
    if tr.priors and tr.priors < DRIVE_ERROR_RERUN * len(drive.indices):  # the drive error counted N / n times
        n_priors = tr.priors
        tr = _Trace(drop=tr.drop)
        traj, mon = _run_learned(runner, drive, T0, conf, tr, motion, frames, n_priors)
        ood["dropped"] = sum("ood_score" in s for s in tr.skipped) if tr.drop else 0
    if not traj:
        wider = range_note(conf.start, runner.range, runner.checkpoint)
        raise DataError(f"vehicle {drive.vehicle}: no usable frame ({len(tr.skipped)} skipped; first: "
                        f"{tr.skipped[0]['reason'] if tr.skipped else '-'})" + (f"; {wider}" if wider else ""))
    lidar = None
    if conf.method == "hybrid" and conf.lidar.enabled and frames is not None:
        traj, lidar = with_lidar(traj, drive, frames, conf, mon, motion)
    doppler = None
    if conf.method == "hybrid" and conf.doppler.enabled and frames is not None:
        traj, doppler = with_doppler(traj, drive, frames, conf, mon, motion)
    yaw_check = None
    if conf.method == "hybrid":
        traj, yaw_check = with_yaw_check(traj, drive, conf, mon)
        traj = with_road_words(traj, tr.geometry, conf)
    traj = with_prior_words(traj)
    res = VehicleResult(drive.vehicle, traj[-1].estimate, traj, skipped=drive.index_skips + tr.skipped,
                        n_frames=len(traj))
    res.lidar = lidar
    res.doppler = doppler
    res.checkpoint = runner.checkpoint
    res.frame_rows = tr.rows
    res.ood = ood
    res.mount = None if mon is None else {**mon.summary(), **sweep_files_record(frames, drive.indices),
                                          **({"yaw_check": yaw_check} if yaw_check else {})}
    res.config = {**to_dict(conf), "measurement_effective": to_dict(measurement_config(runner, conf)),
                  "depth_effective": runner.depth_name, **({"depth_note": note} if note else {}),
                  **({"drive_error_priors": n_priors} if n_priors else {})}
    if wider := range_note(conf.start, runner.range, runner.checkpoint):
        res.config["range_note"] = wider
    res = _finish(res, drive, T0, conf)
    res.drift = camera_side_note(res.drift, res.mount)
    if conf.method == "pure":
        res.drift = one_pass_verdict(res.drift)
    reason = "; and ".join(r for r in (ood["inconclusive"], unfitted_reason(runner, conf.method),
                                       standstill_reason(frames, drive), trust_reason(res, drive.reference)) if r)
    if reason:
        untrusted(res, reason)
    if res.drift:  # a step the radar mount monitor measured stands whatever the estimate at the end can tell
        res.drift = with_mount_step(res.drift, res.mount)
    return res


def one_pass_verdict(drift: dict | None) -> dict | None:
    """``drift`` of a ``pure`` result (the network's last pass alone) with its verdict turned into "cannot tell": one
    pass decides nothing about the mount. Its errors are heavy-tailed (probe 10: 1.8 % of 627 single-pass yaw
    estimates beyond 3 sigma, 0.27 % for a Gaussian), and every "recalibrate" it gave on simulated drives was
    false (8 of 8, e.g. "differs by 7.92 deg in yaw (+- 2.20)" on a mount 0.02 deg from its tables)."""
    if not drift or drift.get("verdict_kind") == "cannot tell":
        return drift
    return {**drift, "drifted": False, "verdict_kind": "cannot tell", "one_pass": drift.get("verdict"),
            "verdict": "cannot tell: one pass of the network alone (method pure) decides nothing about the mount "
                       f"(it read: {drift.get('verdict')}); its single-frame errors are heavy-tailed: calibrate "
                       "with --method hybrid (or pure-avg) to decide"}


def vehicle_oracle(data, version: str, drive: Drive, conf: HybridConfig) -> VehicleResult:
    """The factor graph on oracle rows (simulated roots), from the vehicle's start."""
    from hybrid_calib.calib.pipeline import CalibrateConfig, calibrate_vehicle, load_oracle

    if not drive.simulated:
        raise HybridCalibError("method oracle needs a simulated root (the true reflectors); use hybrid, pure or "
                               "pure-avg on real data")
    cconf = CalibrateConfig(window=conf.window, oracle=conf.oracle, drift=conf.drift, start=conf.start,
                            seed=conf.seed, max_frames=conf.max_frames, vehicles=(drive.vehicle,))
    vi = load_oracle(data, version, cconf, conf.progress)[drive.vehicle]
    T0 = start_of(drive, conf)
    res = calibrate_vehicle(vi, cconf, progress=conf.progress, T_start=T0)
    res.config = to_dict(conf)
    res = _finish(res, drive, T0, conf)
    if why := trust_reason(res, drive.reference):
        untrusted(res, why)
    return res


class _Session:
    """What run_vehicle / run_calibration share: the frames, the drives and (learned methods) the network."""

    def __init__(self, data, version: str, conf: HybridConfig):
        from learned.depth import needs_lidar

        self.data, self.version, self.conf = data, version, conf
        self.runner, self.note, self.motion = None, "", None
        self.unreadable: dict[str, str] = {}  # vehicle -> why none of its frames reads
        if conf.method == "oracle":
            self.frames, self.drives = open_drives(data, version, conf, lidar=False, unreadable=self.unreadable)
            self._check_some_drive()
            return
        depth, self.note = resolve_depth(data, version, conf)
        ckpt = conf.checkpoint or shipped_checkpoint(conf.start)
        conf = self.conf = self._trained_sweeps(conf, ckpt)
        effective = depth or trained_depth(ckpt)  # "" = the checkpoint's own (lidar-densified needs the LiDAR)
        self.frames, self.drives = open_drives(data, version, conf, lidar=needs_lidar(effective),
                                               unreadable=self.unreadable)
        self._check_some_drive()
        self.runner = build_runner(ckpt, refine_checkpoint(conf.refine), self.frames, depth, conf.cache_dir,
                                   conf.depth_cache, conf.threads)
        self.motion = (MotionSource(self.frames, conf.motion, conf.cache_dir)
                       if conf.method == "hybrid" and conf.motion.enabled else None)

    def _trained_sweeps(self, conf: HybridConfig, ckpt) -> HybridConfig:
        """``conf`` reading the radar sweeps per frame the checkpoint's training run read (its train_config.json),
        unless ``--set data.nsweeps`` says otherwise (then a differing count is said): a network trained on 3 sweeps
        was fed 1, silently."""
        import sys

        from learned.checkpoint import trained_data

        trained = trained_data(ckpt).get("nsweeps")
        if not isinstance(trained, int) or trained < 1:
            return conf
        if "nsweeps" not in conf.data:
            if trained != 1:
                print(f"note: {trained} radar sweeps per frame, as the checkpoint's training run read (--set "
                      "data.nsweeps=N to change)", file=sys.stderr)
                conf = dataclasses.replace(conf, data={**conf.data, "nsweeps": trained})
        elif conf.data["nsweeps"] != trained:
            print(f"note: data.nsweeps={conf.data['nsweeps']}, but the checkpoint was trained on {trained} sweeps per "
                  "frame: its inputs differ from what it learned", file=sys.stderr)
        return conf

    def _check_some_drive(self) -> None:
        """``DataError`` when every vehicle is unreadable (one vehicle: the run_vehicle / fleet job case)."""
        if self.unreadable and not self.drives:
            raise DataError(failed_vehicles_message(self.unreadable), path=str(self.data))

    def vehicle(self, name: str) -> VehicleResult:
        drive = self.drives[name]
        if self.conf.method == "oracle":
            return vehicle_oracle(self.data, self.version, drive, self.conf)
        return vehicle_learned(self.runner, drive, self.conf, self.note, self.motion, self.frames)


def network_identity(conf: HybridConfig) -> dict:
    """``{"network": {"checkpoint": digest[, "refine": digest]}}``: what a learned method's result depends on
    beyond its config, the contents of its checkpoints (``learned.checkpoint.checkpoint_digest``), so that one
    retrained or edited at the same path is not taken for the one an earlier result was computed with; ``{}`` for
    oracle."""
    from learned.checkpoint import checkpoint_digest

    if conf.method == "oracle":
        return {}
    refine = refine_checkpoint(conf.refine)
    return {"network": {"checkpoint": checkpoint_digest(conf.checkpoint or shipped_checkpoint(conf.start)),
                        **({"refine": checkpoint_digest(refine)} if refine else {})}}


def run_vehicle(data: str | Path, version: str, vehicle: str, conf: HybridConfig | dict | None = None
                ) -> VehicleResult:
    """Calibrate ONE vehicle of a nuScenes root with ``conf.method`` (plain data in: paths, names, a
    frozen config; the one result type out). The fleet engine's per-job entry point."""
    conf = merge(HybridConfig, conf)
    conf = dataclasses.replace(conf, vehicles=(vehicle,))
    return _Session(data, version, conf).vehicle(vehicle)


def run_calibration(data: str | Path, version: str, out: str | Path, conf: HybridConfig | dict | None = None,
                    overwrite: bool = False, on_vehicle: Callable[[VehicleResult], object] | None = None
                    ) -> CalibrationRun:
    """Every vehicle with ``conf.method``; writes ``out/result.json`` (``CalibrationRun``) and
    ``out/config.json``. Network outputs and depth are cached under ``out`` unless the config names
    folders. With ``overwrite=False`` an existing result is returned untouched."""
    conf = merge(HybridConfig, conf)
    out = Path(out)
    for option, path in (("--set cache_dir", conf.cache_dir), ("--set depth_cache", conf.depth_cache)):
        check_out_outside_data(path or None, data, version, option)  # the run's own writes would change its data stamp
        check_out_not_in_dataset(path or None, option)
    # what the result depends on: the config with the depth estimator it resolves to (--depth lidar-densified and
    # the real root's default are one run) and the checkpoints' contents
    stamped = {**to_dict(conf), **({"depth": effective_depth(data, version, conf)} if conf.method != "oracle" else {}),
               **network_identity(conf)}
    if (out / "result.json").is_file() and not overwrite:
        return reuse_result(out, data, version, conf.method, stamped)
    if overwrite:
        clear_own_caches(out, conf.cache_dir, conf.depth_cache)
    conf = dataclasses.replace(conf, cache_dir=conf.cache_dir or str(out / "network-cache"),
                               depth_cache=conf.depth_cache or str(out / "depth-cache"))
    stamp = data_stamp(data, version)  # before reading: data that change during the run are not this result's
    session = _Session(data, version, conf)
    if not session.drives:
        raise DataError("no vehicle to calibrate (check --set vehicles=... and the dataset)", path=str(data))
    mode = {"hybrid": "window", "oracle": "window", "pure": "network", "pure-avg": "average"}[conf.method]
    run = CalibrationRun(str(Path(data).resolve()), version, conf.method, mode,
                         vehicles_failed=dict(session.unreadable))
    done = VehicleProgress(out, data, version, conf.method, {**stamped, "data_stamp": stamp["digest"]},
                           fresh=overwrite)
    done.fill(run, list(session.drives), session.vehicle, on_vehicle, conf.progress)
    run.raise_if_none_done()
    save_json_atomic(out / "config.json", {**stamped, **{k: v for k, v in to_dict(conf).items() if k in RUN_ONLY}})
    save_json_atomic(out / DATA_STAMP, stamp)  # a rerun on changed data must not reuse it
    run.save(out / "result.json")
    done.finish()
    return run
