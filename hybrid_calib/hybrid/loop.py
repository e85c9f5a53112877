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

A vehicle's drive (its frames, start and what errors are against) is ``hybrid.drives``; what the hybrid folds into
its trajectory after the loop (the LiDAR's and the Doppler's offsets, the drive-common errors, the yaw check, the
status words) is ``hybrid.corrections``.

Every method starts a vehicle from ``perturbation.vehicle_start(base, start, seed, vehicle)``: the
same start for every method and whatever else the run holds. ``base`` is the truth on simulated
roots and the tables' extrinsic on real roots, and errors are against it (``errors_against``); on a
simulated drive whose mount moved (a knocked radar) against the truth at its last frame, which the
final estimate describes.
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.motion import heading_residual
from hybrid_calib.atomic import leave_bars, out_dir_lock
from hybrid_calib.calib.covariance import prior_pinned_std
from hybrid_calib.calib.degeneracy import RowGeometry
from hybrid_calib.calib.drift import (
    DriftConfig,
    camera_side_note,
    doppler_level_note,
    one_pass_verdict,
    reference_test,
    unconverged,
    with_mount_step,
    with_turn_since_export,
)
from hybrid_calib.calib.lever_arm import LeverArmConfig
from hybrid_calib.calib.lidar_alignment import LidarAlignConfig
from hybrid_calib.calib.mount_monitor import MountMonitor, MountMonitorConfig, monitor_trust_reason, reference_mounts
from hybrid_calib.calib.oracle import OracleConfig
from hybrid_calib.calib.pipeline import height_plane_record, in_reference_nouns, trust_reason, untrusted
from hybrid_calib.calib.result import (
    DATA_STAMP,
    RUN_ONLY,
    CalibrationRun,
    Estimate,
    FrameEstimate,
    VehicleProgress,
    VehicleResult,
    config_digest,
    failed_vehicles_message,
    reuse_result,
)
from hybrid_calib.calib.schedule import GaussianPrior
from hybrid_calib.calib.window import SlidingWindowCalibrator, WindowConfig
from hybrid_calib.config import check_seed, freeze_dict_fields, merge, save_json_atomic, to_dict
from hybrid_calib.data.files import absolute_path, data_stamp, root_changed, root_changed_error, root_fingerprint
from hybrid_calib.data.pose_jitter import NOT_MEASURED
from hybrid_calib.data.reference import absolute_reference, reference_identity
from hybrid_calib.data.views import ViewConfig
from hybrid_calib.errors import (
    CheckpointError,
    DataError,
    HybridCalibError,
    check_api_out,
    check_out_not_in_dataset,
)
from hybrid_calib.geometry import local, se3_exp
from hybrid_calib.hybrid.average import AverageConfig, robust_average
from hybrid_calib.hybrid.corrections import (
    LEARNED_NOT_MEASURED,
    motion_bias_cov,
    reported_estimate,
    with_doppler,
    with_drive_error,
    with_end_reading_words,
    with_lidar,
    with_motion_bias,
    with_ood_off_words,
    with_prior_words,
    with_road_words,
    with_words,
    with_yaw_check,
)
from hybrid_calib.hybrid.drives import (
    Drive,
    checked_depth,
    effective_depth,
    open_drives,
    standstill_reason,
    start_of,
    sweep_files_record,
)
from hybrid_calib.hybrid.measurement import MeasurementConfig, frame_inputs, prior_trusted, unfitted_keys
from hybrid_calib.hybrid.motion import (
    MotionConfig,
    MotionGate,
    MotionSource,
    drive_std_rad,
    fold,
    gated_innovation,
    pair_partner,
)
from hybrid_calib.hybrid.network import (
    NetworkRunner,
    build_runner,
    clear_own_caches,
    mount_pass,
    refine_checkpoint,
    shipped_checkpoint,
)
from hybrid_calib.hybrid.ood import OODPolicy, decide, json_score, out_of_domain, skip_record
from hybrid_calib.metrics import extrinsic_error, nees
from hybrid_calib.perturbation import RANGES
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
    # an earlier export (hybrid-calib export's --out folder, or its export.json): the reference of the vehicles whose
    # mounts it wrote (their verdict, the radar mount monitor, a reference start); "" = every vehicle's tables
    reference: str = ""
    motion: MotionConfig = MotionConfig()  # the camera-VO / radar-Doppler motion constraint (hybrid; hybrid.motion)
    mount: MountMonitorConfig = MountMonitorConfig()  # radar mount steps, Doppler vs ego poses (calib.mount_monitor)
    lidar: LidarAlignConfig = LidarAlignConfig()  # the radar's lateral offset from the LiDAR (calib.lidar_alignment)
    doppler: LeverArmConfig = LeverArmConfig()  # the radar's forward offset from its Doppler in turns (calib.lever_arm)
    average: AverageConfig = AverageConfig()  # pure-avg
    oracle: OracleConfig = OracleConfig()  # oracle rows (simulated roots only)
    drift: DriftConfig = DriftConfig()  # reference chi-square test of the final estimate
    ood: OODPolicy = OODPolicy()  # out-of-domain frames and the inconclusive status (learned methods, hybrid.ood)
    views: ViewConfig = ViewConfig()  # frames repeating an earlier view (the ego stood still): left out (data.views)
    threads: int = 1  # torch CPU threads (1: on a busy 2-core machine 2 threads were 40x slower, measured)
    cache_dir: str = ""  # network-output cache ("" = none; run_calibration: OUT/network-cache)
    depth_cache: str = ""  # depth cache ("" = none; run_calibration: OUT/depth-cache)
    progress: bool = True  # tqdm per vehicle

    def __post_init__(self):
        freeze_dict_fields(self)  # data, measurement, split_options: read-only as the rest
        if self.method not in METHODS:
            raise ValueError(f"HybridConfig.method={self.method!r}; valid: {METHODS}")
        if self.start not in STARTS:
            raise ValueError(f"HybridConfig.start={self.start!r}; valid: {STARTS}")
        if self.split not in ("all", "train", "val", "test"):
            raise ValueError(f"HybridConfig.split={self.split!r}; valid: all, train, val, test")
        if self.max_frames < 0:
            raise ValueError(f"HybridConfig.max_frames must be >= 0 (0 = all frames), got {self.max_frames}")
        check_seed(self)
        if not 1 <= self.threads <= 256:
            raise ValueError(f"HybridConfig.threads must be in 1..256 (torch CPU threads), got {self.threads}")
        from hybrid_calib.config import merge
        from hybrid_calib.data.nuscenes import DataConfig

        merge(DataConfig, self.data, "data.")  # ConfigError naming --set data.KEY
        from learned.dataset import SplitConfig

        # checked when unused too (split all): an inf / NaN fraction was accepted and written as bare Infinity / NaN
        # into config.json and result.json, which strict JSON readers refuse (probe 40)
        merge(SplitConfig, self.split_options, "split_options.")
        if "reference" in self.data:  # one option: the run records and stamps conf.reference
            raise ValueError("data.reference: pass the earlier export with --reference (--set reference=PATH), not "
                             "data.reference")
        if "vehicles" in self.data:  # two vehicle filters: a wanted vehicle left out read "not in the data"
            raise ValueError("data.vehicles: choose the vehicles with --set vehicles=[...] (the one filter of the "
                             "network methods), not data.vehicles")


def measurement_config(runner: NetworkRunner, conf: HybridConfig) -> MeasurementConfig:
    """The checkpoint's fitted ``export["hybrid"]`` block with ``conf.measurement`` over it; a block that
    is wrong on its own is a ``DataError`` naming the checkpoint."""
    fitted = runner.ckpt.export.get("hybrid", {})
    try:
        merge(MeasurementConfig, fitted)
    except HybridCalibError as e:
        raise CheckpointError(f"checkpoint export.hybrid block is invalid ({e}); fix it in the JSON, or remove it and "
                              "fit it again with benchmarks/hybrid_fit.py --fit-into",
                              path=str(runner.ckpt.path)) from None
    coarse = getattr(runner, "coarse", None)  # a cascade (CascadeRunner): the refining checkpoint's block
    c_std = None if coarse is None else coarse.ckpt.export.get("hybrid", {}).get("drive_std")
    if c_std and "drive_std" in fitted:
        # The refining pass starts where the coarse one ended, and the networks do not learn translation (the linear
        # probe, docs/benchmarks.md): the cascade's drive-common error is not smaller than the coarse network's on
        # any axis. The shipped R0 block, fitted on 3 drives, put the lateral one at 1.1 mm (the R1 network's: 10 cm),
        # and a 10-frame drive read "differs by 8.15 cm (+- 1.68 cm): recalibrate", 4.5 sigma from the truth (probe 32).
        fitted = {**fitted, "drive_std": [max(float(a), float(b)) for a, b in zip(fitted["drive_std"], c_std,
                                                                                   strict=True)]}
    return merge(MeasurementConfig, {**fitted, **conf.measurement})


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
    frozen: int = 0  # frames whose camera image is an earlier frame's (``Drive.frozen``): against the domain test too
    causes: dict = field(default_factory=dict)  # out-of-domain passes by their camera image's cause (``ood_cause``)
    # where the reflectors the network matched lie (its iteration-0 rows, kept frames): the status names a straight
    # road as the oracle's does (``corrections.with_road_words``)
    geometry: RowGeometry = field(default_factory=RowGeometry)

    def repeated(self, drive: Drive, i: int) -> bool:
        """True (and recorded) when frame ``i`` repeats an earlier view of the drive (``Drive.repeats``) or its camera
        image is an earlier frame's (``Drive.frozen``: counted against the network's domain)."""
        rec = drive.repeats.get(i)
        if rec is None and (rec := drive.frozen.get(i)) is not None:
            self.frozen += 1
        if rec is not None:
            self.skipped.append(dict(rec))
        return rec is not None

    def unreadable(self, runner: NetworkRunner, i: int, k: int) -> None:
        """Record frame ``i`` (dataset index; ``k`` its position in the drive, the record's ``index``) as skipped:
        its files did not read (``runner.bad_reason``)."""
        self.unread += 1
        self.skipped.append({"index": int(k), "token": runner.token(i), "reason": runner.bad_reason(i)})

    def keep(self, runner: NetworkRunner, i: int, k: int, out, conf: HybridConfig) -> bool:
        """Score the pass of frame ``i`` (drive position ``k``); False (and recorded) when it is out of domain and
        dropped."""
        score = runner.ood_score(out) if conf.ood.enabled else float("nan")
        self.scores.append(score)
        if out_of_domain(score, conf.ood):
            cause, why = runner.ood_cause(out)
            if cause:
                self.causes[cause] = self.causes.get(cause, 0) + 1
            if self.drop:
                self.skipped.append(skip_record(k, runner.token(i), score, conf.ood, why))
                return False
        self.geometry.add(out.rows_first.points_radar)
        return True


def _passes(runner: NetworkRunner, drive: Drive, T0: np.ndarray, conf: HybridConfig, tr: _Trace):
    """The network from the vehicle's start on every frame (cached), out-of-domain frames dropped:
    [(index, NetworkOutput)]."""
    from tqdm import tqdm

    outs = []
    for k, i in enumerate(tqdm(drive.indices, desc=f"network {drive.vehicle}", disable=not conf.progress,
                               leave=leave_bars())):
        if tr.repeated(drive, i):
            continue
        out = mount_pass(runner, i, T0)
        if out is None:
            tr.unreadable(runner, i, k)
        elif tr.keep(runner, i, k, out, conf):
            outs.append((i, out))
    return outs


def _pure(runner, drive, T0, conf, tr):
    traj, rows, pos = [], tr.rows, drive.positions()
    for i, out in _passes(runner, drive, T0, conf, tr):
        traj.append(_frame(pos[i], out.rows_last.frame_id, out.rows_last.timestamp_us,
                           reported_estimate(out.T, runner.network_cov(out), conf), 1, out.seconds * 1e3))
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
        traj.append(_frame(pos[i], out.rows_last.frame_id, out.rows_last.timestamp_us,
                           reported_estimate(M, cov, conf), k + 1,
                           out.seconds * 1e3 + (time.perf_counter() - t0) * 1e3))
        rows.append({"frame_id": out.rows_last.frame_id, "used": 0, "rejected": 0, "network_ms": out.seconds * 1e3,
                     "ood_score": json_score(runner.ood_score(out))})
    if passes:
        rows[-1]["weights"] = [float(x) for x in w]
    return with_drive_error(traj, mconf.drive_std, conf)


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
    g_frames, motion_gain, reported_cov = [], [], None
    in_window, pending = [], None  # drive positions of the window's frames; a mount step not yet applied
    claimed: set[int] = set()  # positions of the alarms that stand for the mount steps applied so far
    D = np.diag(np.asarray(mconf.drive_std, np.float64) ** 2)  # the network's drive-common error
    inflate = (n_priors or drive.n_views) * D
    s_mot = drive_std_rad(conf.motion, drive.simulated)
    motion_gate = MotionGate(conf.motion)
    recent: list = []  # (index, ego position, time) of the frames so far: the motion pair's partner (pair_partner)
    for k, i in enumerate(tqdm(drive.indices, desc=f"hybrid {drive.vehicle}", disable=not conf.progress,
                               leave=leave_bars())):
        here = motion.where(i) if motion is not None else (None, None)
        pair = pair_partner(recent, *here, conf.motion)
        recent = [*recent[-63:], (i, *here)]  # max_gap_s back at the least keyframe interval (sim: 0.05 s)
        reading = mount.update(k, i) if mount is not None else None
        if reading is not None and reading.step is not None:
            pending = reading.step
        if tr.repeated(drive, i):
            continue
        out = mount_pass(runner, i, T)
        if out is None:
            tr.unreadable(runner, i, k)
            continue
        if not tr.keep(runner, i, k, out, conf):
            continue
        trusted = prior_trusted(conf.start, runner.range, fused_cov, mconf.trust_sigma_frac)
        fi = frame_inputs(out, T, mconf, conf.window.factor, gate, trusted)
        if not len(fi.corr) and fi.prior is None:
            skipped.append({"index": k, "token": out.rows_first.frame_id, "reason": "no correspondence rows"})
            continue
        prior, mrec, gain = fi.prior, {}, np.zeros(6)  # gain: this frame's motion gain (none without a fold)
        if motion is not None and fi.prior is not None:
            prior = GaussianPrior(fi.prior.T, fi.prior.cov + inflate)
            tr.priors += 1
            # headings the radar's Doppler already contradicts (mirrored ego poses), or that jitter from record to
            # record (``data.pose_jitter``): rotation from the images
            ego = (mount is None or not mount.headings_implausible()) and not drive.poses_jitter
            m, why = motion.measurement(pair, i, T[:3, :3], ego) if pair is not None else (None, "first frame")
            if not ego:
                mrec["motion_rotation"] = ("images (the ego poses' heading jitters from record to record)"
                                           if drive.poses_jitter
                                           else "images (the ego poses' headings contradict the radar's Doppler)")
            # gated by the tighter of the estimate's covariance and this frame's pass with its drive error
            inn = None if m is None else gated_innovation(T, m, conf.motion, (fi.prior.cov + D, reported_cov),
                                                          drive.simulated)
            # the same measurement at the network's own output of this frame: whether the network moved with it
            r_net = None if m is None else heading_residual(fi.prior.T, m)[0]
            fo = (fold(prior, T, inn, conf.motion, gated=False)
                  if inn is not None and motion_gate.admit(inn, r_net) else None)
            if fo is not None:
                prior, gain = fo.prior, fo.gain_motion
                mrec = {**mrec, "motion": {"residual_deg": fo.residual_deg, "weight": fo.weight,
                                           "sigma_deg": float(np.degrees(inn.sigma)), "speed_mps": m.speed,
                                           "vo_inliers": m.n_vo_inliers, "paired_with": drive.positions()[pair],
                                           **({"admitted": "consensus"} if motion_gate.admitted_by_consensus
                                              else {})}}
            else:
                mrec = {**mrec, "motion_skipped": why or motion_gate.refused
                        or "residual outside the innovation gate (MotionConfig.gate)"}
            if inn is not None:
                mrec["motion_z"] = float(inn.z)
        fe, turned = cal.update(fi.corr, prior), None
        in_window.append(k)
        g_frames.append(gain)  # one per frame entering the window, so a restart keeps the two aligned
        if pending is not None:  # the radar turned: restart the window from the frames since the change
            keep = min(sum(p >= pending.change for p in in_window), conf.window.window)
            turned = fe.T @ se3_exp(np.array([0.0, 0.0, np.radians(pending.step_deg), 0.0, 0.0, 0.0]))
            cal.reset(keep_last=keep, T=turned)
            in_window = in_window[len(in_window) - keep:] if keep else []
            g_frames = g_frames[len(g_frames) - keep:] if keep else []
            seen = alarm_since(traj, pending.change, claimed)
            claimed.add(k if seen is None else seen)  # this step's alarm: not the next step's
            fe = dataclasses.replace(fe, step_alarm=fe.step_alarm or seen is None, events=(
                *fe.events, pending.describe(conf.mount.threshold) + f"; window restarted from frame {pending.change}"
                + ("" if seen is None else f" (the same step as the window's alarm at frame {seen})")))
            pending = None
        if fe.step_alarm or turned is not None:  # the window restarted: its estimate is not yet confirmed by motion
            motion_gate.reset()
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
    res.drift = {**unconverged(reference_test(final.T, final.cov, drive.reference, conf.drift, pinned).to_dict(),
                               final.status), "reference": drive.reference_source}
    truth = drive.base if drive.end is None else drive.end  # the mount at the drive's end (a knock moved it)
    e = local(truth, final.T)
    res.truth_T, res.truth_path = truth, drive.truth_path
    res.error = {**extrinsic_error(final.T, truth).as_dict(), "nees": nees(e, final.cov)}
    res.method = conf.method
    res.start = {"kind": conf.start, "seed": conf.seed, "T_cam_radar": T0.tolist()}
    res.errors_against = drive.errors_against
    return res


def unfitted_reason(runner, method: str, ood_enabled: bool = True) -> str:
    """Why a learned result's covariance cannot be trusted for want of a fit, or "": the network's
    covariance scale (``export.cov_scale``, every learned method) and the measurement model with its
    drive-common error (``export.hybrid``, hybrid and pure-avg) are fitted per checkpoint on
    validation drives; without them the reported covariance shrinks with frames while the network's
    error on the drive does not (measured: a fine-tuned checkpoint without them said `ok` with the
    translation error outside 3 sigma in 4 of 5 trials). The out-of-domain model (``export.ood``) too, unless the
    test is switched off (``ood_enabled`` False: its own words say so): without it no frame's input was checked to be
    like the network's training drives, which is where its covariance was fitted (probe 105: a checkpoint without it
    read `weak` with no word of the test, while the README promised `inconclusive`)."""
    coarse = getattr(runner, "coarse", None)  # a cascade: its first stage's drive-common error enters too
    first = ""
    if coarse is not None and method != "pure" and unfitted_keys((coarse.ckpt.export or {}).get("hybrid")):
        # (measurement_config; probe 106: without it the refining stage's smaller one stood alone, the lateral std
        # 3.24 -> 1.20 cm, NEES 13.4, with no word)
        first = (f"checkpoint {Path(coarse.ckpt.path).resolve()} (the cascade's first stage) has no fitted "
                 "export.hybrid, so the cascade's covariance is not calibrated; fit benchmarks/hybrid_fit.py "
                 "--fit-into on validation drives")
    export = runner.ckpt.export or {}
    wanted = ("cov_scale", *(("hybrid",) if method != "pure" else ()), *(("ood",) if ood_enabled else ()))
    partial = unfitted_keys(export["hybrid"]) if "hybrid" in wanted and "hybrid" in export else []
    missing = [k for k in wanted if k not in export or (k == "hybrid" and partial)]  # a block, but not a fit
    if not missing:
        return first
    how = {"cov_scale": "hybrid-calib evaluate --fit-uncertainty", "hybrid": "benchmarks/hybrid_fit.py --fit-into",
           "ood": "benchmarks/ood_fit.py --fit-into"}
    lacks = f" (its block lacks {', '.join(partial)})" if partial else ""
    # the path absolute, as the result's own checkpoint field (probe 110: the words named it as typed)
    words = (f"checkpoint {Path(runner.ckpt.path).resolve()} has no fitted "
             f"{' / '.join('export.' + k for k in missing)}{lacks}, so "
             + ("its covariance is not calibrated" if missing != ["ood"] else
                "no frame was checked to be like the network's training drives")
             + f"; fit {' and '.join(how[k] for k in missing)} on validation drives")
    words += (" (or run without the out-of-domain test, --set ood.enabled=false, which the status then names)"
              if missing == ["ood"] and not first else "")
    # both stages of a cascade unfitted: both named (session 45 named only the first, and a user who fitted it met
    # the second on the next run)
    return f"{first}; and {words}" if first else words


def learned_prior_reason(res: VehicleResult) -> str:
    """Why a learned result's roll or pitch cannot be trusted, or "": the drive does not measure them (a 2D radar has no
    elevation), so they are the network's learned prior of the radar's mount seen through the camera, and where that
    prior lies more than 3 of its stds beyond the tolerance from the tables, the camera or the radar sits outside the
    fleet the network learned (or the tables are wrong), and the prior's std is no measure of the error. Probe 122: a
    camera mounted with an 8 deg roll (tables right), a cropped image (principal point off centre) and a radar
    recording elevation read 3.7-6.1 deg off in roll or pitch, 4.7-8 sigma, under a `weak` status."""
    from hybrid_calib.calib.drift import pinned_conflicts

    found = [(n, a) for n, a in pinned_conflicts((res.drift or {}).get("axes") or {}) if n in ("roll", "pitch")]
    if not found:
        return ""
    diffs = "; ".join(f"{n} by {abs(float(a['delta'])):.2f} deg "
                      f"({abs(float(a['delta'])) / max(float(a['std']), 1e-12):.1f} stds)" for n, a in found)
    names = join_and([n for n, _ in found])
    return (f"the network's {names} (its learned prior of the radar's mount, seen through the camera: this drive does "
            f"not measure {'it' if len(found) == 1 else 'them'}) differs from the tables' {diffs}: the camera or the "
            "radar sits outside the mounts the network learned (a rolled or tilted camera, a cropped image, a radar "
            "that records elevation), or the tables are wrong; that prior's std is no measure of this error")


def other_rows_reason(runner, conf: HybridConfig) -> str:
    """Why a hybrid result's covariance is not the fitted one, or "": ``--set measurement.rows`` chose rows other than
    those the checkpoint's ``export.hybrid`` was fitted with (its pixel noise, shared and drive-common errors belong to
    them). Probe 117: rows=last (the last iteration's rows restate the network's SE(3) and do not pin the forward
    offset) put it 6-27 m off with a 0.2-0.6 m std (NEES 1070-2467), and only the 2 m guard said a word, blaming the
    tables first; calibrate's and compare's --help gave it as their example."""
    fitted = (runner.ckpt.export or {}).get("hybrid") or {}
    rows = conf.measurement.get("rows")
    if conf.method != "hybrid" or rows is None or "rows" not in fitted or rows == fitted["rows"]:
        return ""
    return (f"--set measurement.rows={rows} overrides the rows the checkpoint's export.hybrid was fitted with "
            f"({fitted['rows']}), so its covariance is not calibrated for them; drop the override, or fit "
            "benchmarks/hybrid_fit.py --fit-into with these rows on validation drives")


# the HybridConfig blocks only some methods read (``window``, ``average``, ``drift``, ... are read by more): a
# ``--set`` of one for another method was accepted and had no effect
BLOCK_METHODS = {"oracle": ("oracle",), "measurement": ("hybrid", "pure-avg"), "motion": ("hybrid",),
                 "mount": ("hybrid",), "lidar": ("hybrid",), "doppler": ("hybrid",), "average": ("pure-avg",)}
# the keys of ``window`` every learned method reads (how an estimate's std is reported: ``reported_estimate``); the
# others (its length, schedule, factor noise) only the window's methods, hybrid and oracle (probe 100: --method pure
# with --set window.window=3 ran, bit-identical)
WINDOW_KEYS_OF_ALL = ("covariance",)
# the methods that look for a step inside the drive (the window's step test; the hybrid's radar mount monitor too):
# pure and pure-avg look for none, and a fleet of them counted "0 drifted inside the drive" for radars knocked
# 1.5 deg mid-drive (probe 50)
STEP_METHODS = ("hybrid", "oracle")


def unused_blocks(method: str, overrides: dict) -> list[str]:
    """The settings of ``overrides`` (``--set``) that ``method`` does not read, as ``"block.*"`` for a block
    (``BLOCK_METHODS``) and ``"window.KEY"`` for a window key of a method with no window (``WINDOW_KEYS_OF_ALL``)."""
    out = [f"{k}.*" for k, methods in BLOCK_METHODS.items() if k in overrides and method not in methods]
    if method in ("pure", "pure-avg") and isinstance(window := overrides.get("window"), dict):
        out += [f"window.{k}" for k in window if k not in WINDOW_KEYS_OF_ALL]
    return out


def range_note(start: str, trained: str, checkpoint: str) -> str:
    """A note when the start range is wider than the one the network was trained on ("" otherwise): its
    estimates are then outside what it learned (e.g. the R0 network from an R2 start)."""
    if start not in RANGES or trained not in RANGES or RANGES[start] <= RANGES[trained]:
        return ""
    return (f"the start range {start} (+-{RANGES[start][0]:g} deg, +-{RANGES[start][1]:g} m) is wider than the "
            f"{trained} range the checkpoint {checkpoint} was trained on: expect poor estimates; use a checkpoint "
            f"trained on {start} (or --refine it after one)")


def alarm_since(traj: list, change: int, claimed=()) -> int | None:
    """The drive position of the latest step alarm in ``traj`` at or after position ``change``, or None. One knock,
    one alarm: when the window's own test already fired for the step the mount monitor has just found (at or after
    its change point), the monitor's finding is recorded on its frame with that alarm's position, not raised
    again (on a knocked test drive the window fired at frame 23 and the monitor at 24, for one knock at 20).
    ``claimed``: positions of alarms that already stand for an earlier step of the monitor: a drift's next step
    changes from the frame of the last alarm (probe 43: steps from 23 and 48, found at 35 and 57, read "the same step
    as the window's alarm at frame 23/48" and raised no alarm of their own)."""
    return next((f.index for f in reversed(traj) if f.step_alarm and f.index >= change and f.index not in claimed),
                None)


def mount_monitor(frames, drive: Drive, conf: HybridConfig, motion: MotionSource | None) -> MountMonitor | None:
    """A fresh radar mount monitor for the hybrid on this drive, or None (another method, turned off,
    no frames given, or no ``T_ego_radar`` in the data). Its Doppler velocities are the motion
    source's (``conf.motion.velocity``, each frame's fitted once for both)."""
    if conf.method != "hybrid" or not conf.mount.enabled or frames is None or drive.ego_radar is None:
        return None
    src = motion or MotionSource(frames, conf.motion)
    return MountMonitor(frames, drive.ego_radar, conf.mount, src.velocity, src.sweeps,
                        mount_at=reference_mounts(frames))


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
    ood = decide(tr.scores, conf.ood, runner.ood_note, unread=tr.unread, frozen=tr.frozen, causes=tr.causes)
    ood["dropped"] = sum("ood_score" in s for s in tr.skipped)
    # the frames that did not read, and the frozen ones, count too (hybrid.ood.decide)
    total = ood["frames"] + ood.get("unread", 0) + ood.get("frozen", 0)
    if ood["inconclusive"] and not ood["dropped"]:  # nothing was dropped: the pass already used every frame
        ood.update(rerun_in_domain=ood["in_domain"], note=(
            f"too few frames in domain ({ood['in_domain']} of {total}, the scores above; none was dropped): the "
            "estimate uses every frame that read and is not trusted"))
    elif ood["inconclusive"] and traj and conf.ood.inconclusive_frames == "in-domain" and \
            ood["in_domain"] >= conf.ood.min_in_domain_frames:  # enough to estimate from: the pass that dropped
        ood.update(note="in-domain")  # the others is kept (hybrid.ood, rule 2); its words once the last pass ran
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
    if tr.priors and tr.priors < DRIVE_ERROR_RERUN * drive.n_views:  # the drive error counted N / n times
        n_priors = tr.priors
        tr = _Trace(drop=tr.drop)
        traj, mon = _run_learned(runner, drive, T0, conf, tr, motion, frames, n_priors)
        ood["dropped"] = sum("ood_score" in s for s in tr.skipped) if tr.drop else 0
    if ood.get("note") == "in-domain":  # the frames the last pass used: a rerun's passes start elsewhere, and
        # their scores differ (probe 47: "uses those 21" on a pass that used 24 and dropped 17)
        # two passes, two scores per frame: each count says whose (probe 52: "22 of 41" beside "18 used, 23
        # dropped", one frame 0.87 in the scores and 2.60 in frames_skipped)
        again = n_priors is not None
        ood.update(note=(f"too few frames in domain ({ood['in_domain']} of {total} on the first pass, the scores "
                         f"above): the estimate uses the {len(traj)} frame(s) its {'last ' if again else ''}pass "
                         f"scored in domain ({ood['dropped']} dropped, in frames_skipped with "
                         f"{'that pass' if again else 'their'} scores"
                         + ("; a pass that starts from another estimate scores the frames differently" if again
                            else "") + ") and is not trusted"))
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
        traj, yaw_check = with_yaw_check(traj, drive, conf, mon, lidar)
        traj = with_end_reading_words(traj, mon)
        traj = with_road_words(traj, tr.geometry, conf)
        if motion is not None and drive.poses_jitter:  # data.pose_jitter
            traj = with_words(traj, drive.heading_jitter.words())
    traj = with_ood_off_words(with_prior_words(traj), conf.ood.enabled)
    res = VehicleResult(drive.vehicle, traj[-1].estimate, traj, skipped=drive.index_skips + tr.skipped,
                        n_frames=len(traj))
    res.lidar = lidar
    res.doppler = doppler
    res.checkpoint = runner.checkpoint
    res.frame_rows = tr.rows
    res.ood = ood
    res.mount = None if mon is None else {**mon.summary(), **sweep_files_record(frames, drive.indices),
                                          **({"yaw_check": yaw_check} if yaw_check else {}),
                                          "heading_jitter": (drive.heading_jitter.to_dict()
                                                             if drive.heading_jitter is not None else NOT_MEASURED)}
    mconf = measurement_config(runner, conf)
    if conf.method == "hybrid" and mconf.rows != "none":  # rows in the window's factor (pure, pure-avg and
        # measurement.rows=none: the network's SE(3) only, no plane: probe 138)
        res.height_plane = height_plane_record(conf.window.factor, conf.window.factor,
                                               "the hybrid's rows, as the checkpoint's fitted measurement model reads "
                                               "them")
    res.config = {**to_dict(conf), "measurement_effective": to_dict(mconf),
                  "depth_effective": runner.depth_name, **({"depth_note": note} if note else {}),
                  **({"drive_error_priors": n_priors} if n_priors else {})}
    if wider := range_note(conf.start, runner.range, runner.checkpoint):
        res.config["range_note"] = wider
    res = _finish(res, drive, T0, conf)
    res.drift = camera_side_note(res.drift, res.mount)
    if conf.method == "pure":
        res.drift = one_pass_verdict(res.drift)
    reason = "; and ".join(r for r in (ood["inconclusive"], unfitted_reason(runner, conf.method, conf.ood.enabled),
                                       other_rows_reason(runner, conf), learned_prior_reason(res),
                                       standstill_reason(frames, drive),
                                       monitor_trust_reason(res.mount, conf.mount.max_level_deg),
                                       trust_reason(res, drive.reference)) if r)
    if reason:
        untrusted(res, reason)
    if res.drift:  # a step the radar mount monitor measured stands whatever the estimate at the end can tell
        res.drift = doppler_level_note(with_turn_since_export(with_mount_step(res.drift, res.mount), res.mount,
                                                             conf.method),
                                       res.mount)
    return in_reference_nouns(res)


def oracle_config(conf: HybridConfig, vehicles: tuple[str, ...] | None = None):
    """The ``calib.pipeline.CalibrateConfig`` that method oracle of ``conf`` runs (``vehicles``: default the conf's):
    one mapping, for the run and for the report that rebuilds its rows from its config.json."""
    from hybrid_calib.calib.pipeline import CalibrateConfig

    return CalibrateConfig(window=conf.window, oracle=conf.oracle, drift=conf.drift, start=conf.start,
                           views=conf.views, seed=conf.seed, max_frames=conf.max_frames, reference=conf.reference,
                           vehicles=conf.vehicles if vehicles is None else vehicles)


def vehicle_oracle(data, version: str, drive: Drive, conf: HybridConfig) -> VehicleResult:
    """The factor graph on oracle rows (simulated roots), from the vehicle's start."""
    from hybrid_calib.calib.pipeline import calibrate_vehicle, load_oracle

    if not drive.simulated:
        raise HybridCalibError("method oracle needs a simulated root (the true reflectors); use hybrid, pure or "
                               "pure-avg on real data")
    cconf = oracle_config(conf, (drive.vehicle,))
    vi = load_oracle(data, version, cconf, conf.progress, say=False)[drive.vehicle]  # open_drives said them
    T0 = start_of(drive, conf)
    res = calibrate_vehicle(vi, cconf, progress=conf.progress, T_start=T0)
    res.config = to_dict(conf)
    res = _finish(res, drive, T0, conf)
    res.drift = with_turn_since_export(res.drift, None, "oracle")  # against an export: no Doppler test, said
    if why := trust_reason(res, drive.reference):
        untrusted(res, why)
    return in_reference_nouns(res)


class _Session:
    """What run_vehicle / run_calibration share: the frames, the drives and (learned methods) the network."""

    def __init__(self, data, version: str, conf: HybridConfig, depth_option: str = "--depth"):
        """``depth_option``: how the command takes a depth, for its refusal (compare's ``--set depth``)."""
        from learned.depth import needs_lidar

        self.data, self.version, self.conf = data, version, conf
        self.runner, self.note, self.motion = None, "", None
        self.unreadable: dict[str, str] = {}  # vehicle -> why none of its frames reads
        self.said: list[str] = []  # what opening the root said of its data (CalibrationRun.notes)
        if conf.method == "oracle":
            self.frames, self.drives = open_drives(data, version, conf, lidar=False, unreadable=self.unreadable,
                                                   said=self.said)
            self._check_some_drive()
            return
        depth, self.note, effective = checked_depth(data, version, conf, depth_option)  # "": the checkpoint's own
        ckpt = conf.checkpoint or shipped_checkpoint(conf.start)
        conf = self.conf = self._trained_sweeps(conf, ckpt)
        self.frames, self.drives = open_drives(data, version, conf, lidar=needs_lidar(effective),
                                               unreadable=self.unreadable, said=self.said)
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
    # paths absolute, as the data's is: the same run typed from another folder is this run (probe 119: refused as
    # "another run", and an interrupted one could not be resumed from there)
    conf = dataclasses.replace(conf, reference=absolute_reference(conf.reference),
                               checkpoint=absolute_path(conf.checkpoint), refine=absolute_path(conf.refine))
    out = Path(out)
    check_api_out(out, "calibrate", data, version)
    for option, path in (("--set cache_dir", conf.cache_dir), ("--set depth_cache", conf.depth_cache)):
        # the run's own writes would change its data stamp; any root's tables could be replaced
        check_out_not_in_dataset(path or None, option, data=data, version=version)
    if (out / "result.json").is_file() and not overwrite and not os.access(out, os.W_OK):  # a read-only archive's
        return _calibrate_into(data, version, out, conf, overwrite, on_vehicle)  # result: reused, nothing written
    with out_dir_lock(out, "calibrate", reentrant=True):  # probe 140: a library run and a command in one folder
        return _calibrate_into(data, version, out, conf, overwrite, on_vehicle)


def _calibrate_into(data, version: str, out: Path, conf: HybridConfig, overwrite: bool,
                    on_vehicle: Callable[[VehicleResult], object] | None) -> CalibrationRun:
    """``run_calibration`` once its folder is checked and locked."""
    # what the result depends on: the config with the depth estimator it resolves to (--depth lidar-densified and
    # the real root's default are one run) and the checkpoints' contents
    stamped = {**to_dict(conf), **({"depth": effective_depth(data, version, conf)} if conf.method != "oracle" else {}),
               **network_identity(conf), **reference_identity(conf.reference)}
    if (out / "result.json").is_file() and not overwrite:
        return reuse_result(out, data, version, conf.method, stamped)
    if overwrite:
        clear_own_caches(out, conf.cache_dir, conf.depth_cache)
    # absolute, as the data's path is (probe 72: a run resumed from another folder recorded each vehicle's caches
    # relative to the folder its part was typed in)
    conf = dataclasses.replace(conf, cache_dir=conf.cache_dir or str(out.resolve() / "network-cache"),
                               depth_cache=conf.depth_cache or str(out.resolve() / "depth-cache"))
    stamp = data_stamp(data, version)  # before reading: data that change during the run are not this result's
    seen = root_fingerprint(data, version)
    session = _Session(data, version, conf)
    if not session.drives:
        raise DataError("no vehicle to calibrate (check --set vehicles=... and the dataset)", path=str(data))
    mode = {"hybrid": "window", "oracle": "window", "pure": "network", "pure-avg": "average"}[conf.method]
    run = CalibrationRun(str(Path(data).resolve()), version, conf.method, mode,
                         vehicles_failed=dict(session.unreadable), notes=list(session.said))
    done = VehicleProgress(out, data, version, conf.method, {**stamped, "data_stamp": stamp["digest"]},
                           fresh=overwrite)
    done.fill(run, list(session.drives), session.vehicle, on_vehicle, conf.progress)
    run.raise_if_none_done()
    if root_changed(data, version, seen, stamp["digest"]):  # another process rewrote the root under the run (probe
        done.finish()  # 142); its kept vehicles too: a rerun would reuse frames that vanished (probe 144)
        raise root_changed_error(data)
    cfg = {**stamped, **{k: v for k, v in to_dict(conf).items() if k in RUN_ONLY}}
    save_json_atomic(out / "config.json", cfg)
    # a rerun on changed data must not reuse it, nor one whose config.json was edited since (probe 150)
    save_json_atomic(out / DATA_STAMP, {**stamp, "config": config_digest(cfg)})
    run.save(out / "result.json")
    done.finish()
    return run
