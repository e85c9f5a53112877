"""What the report shows beyond ``result.json``, rebuilt from the run's data: the correspondence rows
and their residuals at the result, the start extrinsic, and a few camera frames across the drive.

The rows are those the run used: ``calib.pipeline.replay_inputs`` rebuilds them from the run's
effective config (``RUN/config.json``, next to ``result.json``) with the run's own seed, so oracle
rows and R1/R2 starts are identical to the run's; measurement files are read again.

The result a frame is drawn and scored with is its segment's estimate (``segment_estimates``): the
final one, or, when the window restarted during the drive (a step alarm, the radar mount monitor's change), the
window's estimate just before the restart's first frame for the frames before it (a knocked sensor has two
extrinsics).

Residuals: per row, the whitened residual norm ``|e_i|`` of the factor at that extrinsic
(``factors.gtsam_factors.frame_residuals``, no kernel) times the row's pixel sigma: the distance in
pixels the solver sees once the unknown elevation of the 2D radar is discounted. A row is an inlier
when ``|e_i|`` is below the schedule's final gate (as the covariance counts it).
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.calib.pipeline import CalibrateConfig, heights_plane, replay_inputs
from hybrid_calib.calib.result import IDENTITY_KEYS, CalibrationRun
from hybrid_calib.config import merge
from hybrid_calib.errors import DataError, HybridCalibError, OptionError, unencodable_words


@dataclass
class Residuals:
    """residual_px: (N,) pixels over every row of the drive; inlier: (N,) bool; gate_px: the gate in
    pixels at the median row sigma; n_frames: frames the rows come from."""

    residual_px: np.ndarray
    inlier: np.ndarray
    gate_px: float
    n_frames: int


@dataclass
class ShownFrame:
    """One camera frame of the drive with what the before / after figure draws (image pixels)."""

    index: int  # frame index in the dataset
    drive_index: int | None  # the frame's index in the vehicle's trajectory (None: not matched)
    result_label: str  # which estimate the result panel uses
    token: str
    image: np.ndarray  # (H, W, 3) uint8
    uv_start: np.ndarray  # (N, 2) the frame's radar points projected with the start
    uv_result: np.ndarray  # (N, 2) ... with the result
    depth_start: np.ndarray  # (N,) metres
    depth_result: np.ndarray
    pairs_start: tuple | None = None  # (obs (M, 2), pred (M, 2), inlier (M,)) correspondences, start
    pairs_result: tuple | None = None


def frame_words(frame) -> str:
    """How a page names a shown frame: by its place in the drive, as the plots count frames ("drive frame 12"), or by
    its dataset index where it is not in the trajectory."""
    return f"drive frame {frame.drive_index}" if frame.drive_index is not None else f"dataset frame {frame.index}"


@dataclass
class Evidence:
    """Per vehicle: start (4, 4) or None, start_label (what the start was), residuals or None, the frames
    shown, and notes (why something is absent)."""

    start: np.ndarray | None = None
    start_label: str = ""
    residuals: Residuals | None = None
    frames: list[ShownFrame] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


def segment_estimates(vr) -> dict[str, tuple[np.ndarray, str, int]]:
    """frame_id -> ((4, 4) the estimate of the frame's segment, a label, the frame's trajectory index).
    A segment starts at the first frame of a restarted window: where a frame's ``n_total`` (the frames its estimate
    fuses) falls below its predecessor's, the window restarted from the ``n_total`` frames ending there (the
    window's own step alarm restarts at the alarm frame; the radar mount monitor's from the change it measured, a
    few frames before its alarm). Each segment is drawn with the estimate of its last frame (the final one for the
    last segment). Probe 88: cut at the alarm frames, a knock's frames between the change and the alarm were drawn
    with the pre-knock estimate, labelled "result of frames 0-12" where the window had restarted from frame 8.
    Empty for batch results."""
    traj = vr.trajectory
    out: dict[str, tuple[np.ndarray, str, int]] = {}
    starts = [0]
    for k in range(1, len(traj)):
        if traj[k].n_total < traj[k - 1].n_total:
            starts.append(min(max(k - traj[k].n_total + 1, starts[-1] + 1), k))
    ends = [s - 1 for s in starts[1:]] + [len(traj) - 1]
    for start, end in zip(starts, ends):
        T = vr.final.T if end == len(traj) - 1 else traj[end].T
        label = ("result" if end == len(traj) - 1 and start == 0 else f"result of frame {traj[end].index}"
                 if start == end else f"result of frames {traj[start].index}-{traj[end].index}")
        for k in range(start, end + 1):
            out[traj[k].frame_id] = (T, label, traj[k].index)
    return out


LEARNED_METHODS = ("hybrid", "pure", "pure-avg")  # a result's ``correspondences`` when the network made its rows


def run_config(result_path: Path) -> CalibrateConfig | None:
    """The run's effective config (``config.json`` next to ``result.json``), or None when absent: calibrate's, or the
    ``HybridConfig`` of a method-oracle run of ``hybrid.run_calibration`` (what it ran: ``hybrid.loop.oracle_config``;
    probe 67: such a run's page showed no rows or residuals, its config "unreadable")."""
    p = Path(result_path).parent / "config.json"
    if not p.is_file():
        return None
    try:
        doc = json.loads(p.read_text())
        if isinstance(doc, dict):  # what the result depends on beyond the config: no config key
            doc = {k: v for k, v in doc.items() if k not in IDENTITY_KEYS}
        if isinstance(doc, dict) and doc.get("method") == "oracle":
            from hybrid_calib.hybrid.loop import HybridConfig, oracle_config

            return oracle_config(merge(HybridConfig, doc))
        return merge(CalibrateConfig, doc)
    except (OSError, ValueError, TypeError, RecursionError) as e:
        raise DataError(f"run config unreadable ({e}); without it the report cannot rebuild the run's rows",
                        path=str(p)) from None


def _factor_and_gate(conf: CalibrateConfig, mode: str):
    sub = conf.window if mode == "window" else conf.batch
    return sub.factor, float(sub.schedule.final_gate)


def _rows_residuals(T: np.ndarray, corr, factor_conf, gate: float) -> tuple[np.ndarray, np.ndarray]:
    import dataclasses

    from factors.gtsam_factors import frame_residuals

    e, _, w = frame_residuals(np.asarray(T, np.float64), corr, dataclasses.replace(factor_conf, kernel="none"))
    s = np.linalg.norm(e.reshape(-1, 2), axis=1)
    return s * np.asarray(corr.sigma_px), (s < gate) & (w > 0)


def _pairs(corr, T: np.ndarray, frame, factor_conf, gate: float) -> tuple:
    """Observed pixels mapped into the frame's image, predicted pixels of the rows' radar points
    (z as recorded) with T, and the inlier flags at T."""
    from hybrid_calib.geometry import transform_points

    K_img = frame.camera.K
    H = K_img @ np.linalg.inv(np.asarray(corr.K, np.float64))  # corr's image -> the image on disk
    obs = np.c_[np.asarray(corr.pixels), np.ones(len(corr))] @ H.T
    obs = obs[:, :2] / obs[:, 2:3]
    pred, _ = frame.camera.project(transform_points(T, np.asarray(corr.points_radar)))
    _, inl = _rows_residuals(T, corr, factor_conf, gate)
    return obs, pred, inl


def gather(run: CalibrationRun, result_path: Path, vehicle: str, data: str | Path | None, version: str | None,
           n_frames: int = 3) -> Evidence:
    """The evidence of one vehicle (module docstring). Without ``data`` (and when the run's data root is
    not there either) only notes saying what is missing."""
    ev = Evidence()
    vr = run.vehicles[vehicle]
    root = Path(data) if data is not None else Path(run.data)
    version = version or run.version
    if not (root / version).is_dir():
        if version != run.version or root.is_dir() and data is not None:  # given: say so, not a page without pictures
            raise OptionError("--version" if version != run.version else "--data",
                              f"{root / version} is not there; pass the root and version folder of the run's frames "
                              f"(it calibrated {run.data}, {run.version}), or leave --data / --version out")
        gone = (f"no data root: {root / version} is not there (pass --data ROOT --version V), so no camera frames, "
                "correspondences or residuals are shown")
        if words := unencodable_words(root):
            gone = f"no data root: {root / version} cannot be opened{words}; no camera frames are shown"
        import warnings

        warnings.warn(gone, stacklevel=2)  # said on the terminal too, as a data stamp that differs is
        ev.notes.append(gone)
        return ev
    if data is not None:
        _check_frames_there(root, version, vehicle, vr, run)
    if changed := _data_changed(result_path, root, version):
        import warnings

        warnings.warn(changed, stacklevel=2)
        ev.notes.append(changed)
        return ev
    by_token: dict = {}
    learned = run.correspondences in LEARNED_METHODS  # its config.json is a HybridConfig, its rows the network's
    try:
        conf = None if learned else run_config(result_path)
    except HybridCalibError as e:  # e.g. a config written by another version: the page goes on without rows
        conf = None
        ev.notes.append(str(e))
    if learned:
        ev.notes.append(f"a {run.correspondences} run: its rows came from the network at each frame, which the report "
                        "does not run again, so no correspondences or residuals are shown")
    elif conf is None:
        ev.notes.append(f"no usable run config ({Path(result_path).parent / 'config.json'}): the rows and the start "
                        "cannot be rebuilt, so no correspondences or residuals are shown")
    else:
        try:
            # this vehicle's rows alone (each vehicle's are drawn from (seed, vehicle): the same; probe 69: every
            # vehicle of the result was replayed for one page)
            # the rows do not depend on the reference (--reference): replayed without it, so an export changed or
            # removed since the run neither moves the start nor drops the rows (probe 77); the start is the one the
            # run recorded
            inputs = replay_inputs(root, version, run.correspondences,
                                   dataclasses.replace(conf, vehicles=(vehicle,), reference=""))
        except HybridCalibError as e:
            inputs = {}
            ev.notes.append(f"the run's rows could not be rebuilt ({e})")
        if vehicle in inputs:
            vi, ev.start = inputs[vehicle]
            recorded, _ = _recorded_start(vr)
            ev.start = ev.start if recorded is None else recorded
            ev.start_label = (f"the vehicle's reference ({reference_name(vr)})" if conf.start == "reference"
                              else f"the run's {conf.start} start (perturbed truth, seed {conf.seed})")
            # the heights' plane calibrate fitted with (its reference mount's road; the tables' here)
            conf = heights_plane(conf, vi)
            factor_conf, gate = _factor_and_gate(conf, run.mode)
            seg = segment_estimates(vr)
            rows = [_rows_residuals(seg.get(c.frame_id, (vr.final.T,))[0], c, factor_conf, gate)
                    for c in vi.frames if len(c)]
            if rows:
                sig = np.concatenate([np.asarray(c.sigma_px) for c in vi.frames if len(c)])
                ev.residuals = Residuals(np.concatenate([r for r, _ in rows]), np.concatenate([i for _, i in rows]),
                                         gate * float(np.median(sig)), len(rows))
            by_token = {c.frame_id: c for c in vi.frames}
        elif inputs:
            ev.notes.append(f"the run's rows hold no vehicle {vehicle} (they hold {', '.join(sorted(inputs))})")
    _frames(ev, root, version, vehicle, vr, n_frames, by_token,
            None if conf is None else _factor_and_gate(conf, run.mode), explicit=data is not None)
    return ev


def _data_changed(result_path: Path, root: Path, version: str) -> str:
    """Why the data at ``root`` / ``version`` are not those the result beside its ``data_stamp.json`` was computed
    from ("" when they are, or when it records no stamp): its pictures, rows and residuals would be drawn from
    other data next to its numbers (export refuses such a result for the same reason)."""
    from hybrid_calib.calib.result import data_differ, stored_digest

    if not data_differ(Path(result_path).parent, root, version):
        return ""
    if stored_digest(Path(result_path).parent) is None:  # probe 109: read as "no stamp", the other drive drawn
        return (f"{Path(result_path).parent / 'data_stamp.json'} is damaged, so whether the data at "
                f"{root / version} are those {result_path} was computed from cannot be told, and no camera frames, "
                "correspondences, residuals or attention are shown: they could come from other data; restore the "
                "file, or rerun the calibration on the data as they are")
    return (f"the data at {root / version} are not those {result_path} was computed from (its data_stamp.json "
            "differs from the data now: re-simulated, re-downloaded, tables edited, or frame files added, removed or "
            "renamed), so no camera frames, correspondences, residuals or attention are shown: they could come "
            "from other data; rerun the calibration on the data as they are, or pass the root it was computed on "
            "with --data")


def _check_frames_there(root: Path, version: str, vehicle: str, vr, run: CalibrationRun) -> None:
    """``OptionError`` when a ``--data`` root holds none of the frames the result calibrated for ``vehicle``
    (another root's vehicle of that name: its pictures and rows would be shown as this result's). A result
    without a trajectory (batch) names no frames: nothing to check."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    known = {f.frame_id for f in vr.trajectory}
    if not known:
        return
    ds = NuScenesRadarCamera(root, version, conf={"check_images": False})
    if not any(ref.sample_token in known or ref.camera_sd.get("token") in known for ref in ds.frames):
        raise OptionError("--data", f"{root / version} holds none of the {len(known)} frames this result calibrated "
                                    f"for vehicle {vehicle} (the run read {run.data}, {run.version}); pass the root "
                                    "the run calibrated, or leave --data out")


def reference_name(vr) -> str:
    """What a result's reference was, in a few words: its calibration tables, or the earlier export it was given."""
    src = (getattr(vr, "drift", None) or {}).get("reference") or {}
    return f"the mount exported in {src.get('path')}" if src.get("kind") == "export" else "its calibration tables"


def _recorded_start(vr) -> tuple[np.ndarray | None, str]:
    """(4, 4) the start a vehicle's result recorded (``VehicleResult.start``: learned methods) and what it
    was, or (None, "") when it recorded none or an unusable one."""
    rec = getattr(vr, "start", None)
    if not isinstance(rec, dict) or rec.get("T_cam_radar") is None:
        return None, ""
    try:
        T = np.asarray(rec["T_cam_radar"], np.float64)
    except (TypeError, ValueError):
        return None, ""
    if T.shape != (4, 4) or not np.isfinite(T).all():
        return None, ""
    kind = str(rec.get("kind", ""))
    if kind == "reference":
        return T, f"the vehicle's reference ({reference_name(vr)})"
    return T, f"the run's {kind} start (seed {rec.get('seed')})"


def _frames(ev: Evidence, root: Path, version: str, vehicle: str, vr, n: int, by_token: dict, fg,
            explicit: bool = False) -> None:
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.geometry import transform_points

    if n <= 0:
        ev.notes.append("no camera frames requested (--frames 0)")
        return
    try:
        ds = NuScenesRadarCamera(root, version)
    except HybridCalibError as e:  # the run's own root changed since the run: the page goes on without frames
        if explicit:  # a --data root given for the frames that cannot be read: say so
            raise
        ev.notes.append(f"no camera frames shown: {root / version} cannot be read ({e})")
        return
    idx = ds.frames_by_vehicle().get(vehicle)
    if not idx:
        ev.notes.append(f"vehicle {vehicle} has no frame in {root / version}: no camera frames shown")
        return
    known = {f.frame_id for f in vr.trajectory}  # the frames the run calibrated (e.g. --max-frames), when it says
    used = [i for i in idx if ds.frames[i].sample_token in known or ds.frames[i].camera_sd.get("token") in known]
    idx = used or idx
    start = ev.start
    if start is None:  # a learned run: the start it recorded (result.json "start"), not the tables
        start, label = _recorded_start(vr)
        if start is not None:
            ev.start, ev.start_label = start, label
    seg = segment_estimates(vr)
    for i in sorted({idx[int(round(k))] for k in np.linspace(0, len(idx) - 1, n)}):
        try:  # a frame whose files went missing or bad since the run is a note, not the end of the page
            f = ds[i]
            img = f.load_image()
        except DataError as e:
            ev.notes.append(f"frame {i} not shown: {e}")
            continue
        if start is None:
            start = np.asarray(f.extras.get("reference_T_cam_radar", f.T_cam_radar), np.float64)
            ev.start_label = "the vehicle's reference (its calibration tables)"
        T_res, label, k = seg.get(f.sample_token) or seg.get(f.camera_token) or (vr.final.T, "result", None)
        # the points as recorded reach the image through the frame's transform, the mount times N (docs/conventions.md
        # "Transforms"; probe 86: drawn through the mount, beside rows moved by N)
        N = f.radar_motion
        pts = np.asarray(f.radar_points)
        uv0, z0 = f.camera.project(transform_points(start @ N, pts))
        uv1, z1 = f.camera.project(transform_points(T_res @ N, pts))
        sf = ShownFrame(i, k, label, f.sample_token, img, uv0, uv1, z0, z1)
        corr = by_token.get(f.sample_token) or by_token.get(f.camera_token)
        if corr is not None and len(corr) and fg is not None:
            sf.pairs_start = _pairs(corr, start, f, *fg)
            sf.pairs_result = _pairs(corr, T_res, f, *fg)
        ev.frames.append(sf)
    if not ev.frames and (bad := [n for n in ev.notes if " not shown: " in n]):  # said on the terminal too: the
        import warnings  # page's notes alone left a run that showed no frame silent (probe 47: exit 0, "wrote ...")

        warnings.warn(f"no camera frame shown: {len(bad)} of the vehicle's frames did not read (first: "
                      f"{bad[0]}); the page says why for each", stacklevel=2)
    if ev.frames and by_token and all(s.pairs_result is None for s in ev.frames):  # rows there, none matched
        ev.notes.append("the correspondences are not drawn: the rows of the shown frames could not be matched")
