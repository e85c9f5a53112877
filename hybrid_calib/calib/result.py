"""The calibrator's result types and the JSON schema of ``RUN/result.json`` (read it with
``CalibrationRun.load``; the compare, report and fleet commands read results only through it).

``result.json`` (``schema_version`` 2, ``schema`` "hybrid-calib/calibrate-result/v2")::

    {
      "schema": "hybrid-calib/calibrate-result/v2", "schema_version": 2,
      "data": str, "version": str, "correspondences": "oracle" | DIR, "mode": "window" | "batch",
      "vehicles": {
        VEHICLE: {
          "vehicle": str, "n_frames": int, "frames_skipped": [{"index", "token", "reason"}],  # index: the frame's
                                           # position in the drive as FRAME's (null: a file of no drive frame);
                                           # token: the frame's own (its camera sample_data token, as frame_id;
                                           # null index: the sample's), whichever file failed: the reason names
                                           # that file and its token
          "final": EXTRINSIC,              # the estimate after the last frame (window) / of the batch
          "truth": {"T_cam_radar", "report"} | null,  # when the data has ground truth: the mount at the drive's end
                                           # (+ "path": [{"index", "T_cam_radar"}] when it moved along the drive:
                                           # the mount from FRAME index on; truth_at)
          "error": {metrics.ExtrinsicError fields..., "nees": float} | null,
          "crb_std_cam": STD | null,       # Cramer-Rao std, oracle data only (docs: crb.py)
          "drift": DriftDecision.to_dict() | null,    # vs the vehicle's reference extrinsic
          "network": NETWORK | null,       # calibrate --correspondences only: the producer's own SE(3) (measurement
                                           # files with a network block); null for the learned methods, whose
                                           # network passes are in trajectory / frame_rows
          "step_alarms": [FRAME index, ...],   # the trajectory's index of each frame that raised an alarm
          "trajectory": [FRAME, ...],     # window mode: one per frame (pure: the network's per frame)
          "method": str, "checkpoint": str | null, "errors_against": "truth" | "tables" | null,
          "start": {"kind", "seed", "T_cam_radar"} | null,   # the vehicle's start (same for every method)
          "frame_rows": [{"frame_id", "used", "rejected", "network_ms", "ood_score",   # learned methods, per pass
                          # hybrid also: "deflation", "prior_used", "motion", "motion_z", "motion_skipped",
                          # "motion_rotation", "mount", "note" (docs/conventions.md); pure-avg: "weights"
                          }, ...],
          "config": {...} | null,         # the method's effective config (hybrid.HybridConfig; the oracle of
                                          # compare the same; calibrate's oracle: null, its config.json beside)
          "ood": {...} | null,            # learned methods: out-of-domain scores and decision (hybrid.ood)
          "mount": {...} | null,          # hybrid: the radar mount monitor (docs/conventions.md)
          "lidar": {"applied", "dy_m", "dy_std_m", "innovation_sigma", "dx_m", "dx_std_m", "forward_applied",
                    "range_offset_m", "coupling_m_per_rad", "coupling_x_m_per_rad", "coupling_spread_m_per_rad",
                    "coupling_x_spread_m_per_rad", "rows", "frames",
                    "moving_dropped", "scale_m", "note" (when not applied), "forward_note" (when the forward offset
                    is not)} | null
                                          # hybrid: the radar's lateral and forward offsets from the LiDAR
                                          # (calib.lidar_alignment; results before 2026-12-02: "dx_m_unused")
          "doppler": {"applied", "dx_m", "dx_std_m", "heading_bias_deg", "h", "pairs", "turning", "scale_deg",
                      "skipped", "note"} | null
                                          # hybrid: the radar's forward offset from its Doppler (calib.lever_arm)
          "height_plane": {"plane", "normal_radar", "words"} | null
                                          # the `height` elevation model's plane (pipeline.height_plane_record);
                                          # null for the other models and in results before 2026-12-07
        }
      },
      "vehicles_failed": {VEHICLE: reason}  # vehicles whose data could not be calibrated (e.g. no usable
    }                                       # frame); absent in older results

EXTRINSIC = {"T_cam_radar": 4x4 list, "report": {"roll_deg", "pitch_deg", "yaw_deg" (camera-axis Euler
angles of R_delta with R = R_delta R_axes), "t_m": [x, y, z]}, "cov_right_radar": 6x6 (right tangent,
radar frame, [rad, m]), "std_cam": STD, "status": str, "regularised": bool, "weak_directions": [...]}.

STD = {"rot_x_cam_deg", "rot_y_cam_deg", "rot_z_cam_deg", "t_x_cam_cm", "t_y_cam_cm", "t_z_cam_cm"}:
per-axis 1-sigma in CAMERA axes (``C_report = B C B^T``, docs/conventions.md); the keys are defined
once, in ``hybrid_calib.metrics.std_keys("cam")``.

FRAME = {"index" (the frame's position in the drive, counted from 0, every method), "frame_id", "timestamp_us",
EXTRINSIC without "report", "n_window", "n_total",
"inlier_fraction", "step_statistic", "step_threshold", "step_alarm", "solve_ms", "cov_ms", "events"}.

NETWORK = {"n_frames": frames with a network estimate, "frame_id": the last such frame, "iteration",
"T_cam_radar", "cov_right_radar" (or null), "std_cam" (or null), "error" (or null, vs the truth), "depth" (the depth
estimator the exporting network read, from its export_config.json; absent when it does not say)}.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.calib.covariance import STATUS_WORDS, CovarianceReport, report_std, status_kind
from hybrid_calib.config import is_number, json_default, read_out_record, save_json_atomic
from hybrid_calib.errors import DataError, HybridCalibError
from hybrid_calib.geometry import R_AXES_CAM_FROM_RADAR, camera_euler_from_rotation, local
from hybrid_calib.metrics import METRIC_KEYS, extrinsic_error, nees, std_dict, std_from_dict, std_keys

SCHEMA_VERSION = 2
SCHEMA = f"hybrid-calib/calibrate-result/v{SCHEMA_VERSION}"
# a result whose numbers contradict each other (``Estimate.from_dict``, ``VehicleResult._errors_measured``)
EDITED = "the file was edited (or written by an older hybrid-calib); recompute it (calibrate --overwrite)"
STD_FRAME = "cam"  # result std blocks are in camera axes (metrics.std_keys)


def extrinsic_report(T_cam_radar: np.ndarray) -> dict:
    """Euler/translation report of an extrinsic (docs/conventions.md "Report parametrisation")."""
    T = np.asarray(T_cam_radar, np.float64)
    rpy = np.degrees(camera_euler_from_rotation(T[:3, :3] @ R_AXES_CAM_FROM_RADAR.T))
    return {"roll_deg": float(rpy[0]), "pitch_deg": float(rpy[1]), "yaw_deg": float(rpy[2]),
            "t_m": [float(x) for x in T[:3, 3]]}


def _matrix(x, n: int, name: str) -> np.ndarray:
    """``x`` as a finite (n, n) float64 matrix; ``ValueError`` naming ``name`` otherwise (a result read back)."""
    try:
        a = np.asarray(x, np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} is not a {n}x{n} matrix of numbers (got {str(x)[:60]})") from None
    if a.shape != (n, n):
        raise ValueError(f"{name} is not a {n}x{n} matrix (shape {a.shape})")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} holds non-finite values (NaN/inf)")
    return a


def _transform(x, name: str) -> np.ndarray:
    """``_matrix`` of a rigid transform: an orthonormal rotation block with determinant +1 and [0, 0, 0, 1] below
    (1e-6); ``ValueError`` naming ``name`` otherwise (a hand-edited or damaged result)."""
    from hybrid_calib.geometry import is_rigid

    T = _matrix(x, 4, name)
    if not is_rigid(T, 1e-6):
        raise ValueError(f"{name} is not a rigid transform (its rotation block is not a rotation, or its last row is "
                         "not [0, 0, 0, 1])")
    return T


_KIND_WORDS = {str: "string", bool: "true or false", list: "list", int: "whole number"}


def _truth_path(truth, where: str) -> list:
    """A result's ``truth.path`` ([(index, (4, 4))]; [] when absent), ``ValueError`` naming the entry that is not."""
    path = (truth or {}).get("path") if isinstance(truth, dict) else None
    if path is None:
        return []
    if not isinstance(path, list):
        raise ValueError(f"{where}.path is a JSON {_json_kind(path)}, not a list of {{index, T_cam_radar}}")
    out = []
    for k, e in enumerate(path):
        e = _mapping(e, f"{where}.path[{k}]")
        if not (isinstance(e.get("index"), int) and not isinstance(e.get("index"), bool)):
            raise ValueError(f"{where}.path[{k}].index is not a frame index")
        # in drive order from frame 0 on, as path_of writes it (probe 59: an edited path scored the plots against
        # a mount the result's truth is not)
        if e["index"] < 0 or (out and e["index"] <= out[-1][0]):
            raise ValueError(f"{where}.path[{k}].index {e['index']} is not after the entry before it (the path "
                             f"lists where the mount changed, frame indices increasing from 0): {EDITED}")
        out.append((e["index"], _transform(e.get("T_cam_radar"), f"{where}.path[{k}].T_cam_radar")))
    return out


def truth_at(vr, index: int) -> np.ndarray | None:
    """The true mount at drive frame ``index`` of ``vr`` (a ``VehicleResult``): where it moved along the drive, the
    one of ``truth_path`` the frame falls in (a knocked radar's frames before the knock score against the mount
    before it; probe 54: every frame scored against the end's), else ``truth_T``; None without a truth."""
    if vr.truth_T is None:
        return None
    before = [T for k, T in vr.truth_path if k <= index]
    return before[-1] if before else (vr.truth_path[0][1] if vr.truth_path else vr.truth_T)


def path_of(indices, truths) -> list:
    """``truth_path`` of per-frame truths ((4, 4) each; None: unknown) at drive frame ``indices``: an entry where the
    mount changes (``same_calibration``); [] when it never does."""
    from hybrid_calib.data.mounts import same_calibration

    path, last = [], None
    for k, T in zip(indices, truths):
        if T is not None:
            last = (int(k), np.asarray(T, np.float64))
            if not path or not same_calibration(last[1], path[-1][1]):
                path.append(last)
    if len(path) > 1 and not np.array_equal(path[-1][1], last[1]):  # a drift's end, within the tolerance of the last
        path.append(last)  # entry: the path ends at the drive's end, where the errors are (probe 124: every drift of
    return path if len(path) > 1 else []  # more than ~184 frames, or slower than 0.01 deg per frame, wrote no result)


def _covariance(x, name: str) -> np.ndarray:
    """``_matrix`` of a covariance: symmetric and positive semi-definite (relative 1e-6); ``ValueError`` naming
    ``name`` otherwise."""
    C = _matrix(x, 6, name)
    scale = max(float(np.abs(C).max()), 1e-300)
    if scale > 1e12:  # rad^2, m^2: no estimate is that uncertain (and its eigenvalues overflow; probe 27)
        raise ValueError(f"{name} holds an entry of {scale:.3g}, beyond any covariance of an extrinsic (rad^2, m^2)")
    if not np.all(np.diag(C) > 0):  # an exact estimate: no result of a solve claims one (probe 27: all zeros)
        raise ValueError(f"{name} is not a covariance of an estimate (a variance is zero or negative)")
    if not np.allclose(C, C.T, atol=1e-6 * scale, rtol=0):
        raise ValueError(f"{name} is not a covariance: it is not symmetric")
    if (low := float(np.linalg.eigvalsh(0.5 * (C + C.T)).min())) < -1e-6 * scale:
        # probe 45: positive variances whose covariances exceed them read "not symmetric, or a negative variance"
        raise ValueError(f"{name} is not a covariance: it is not positive semi-definite (an eigenvalue of "
                         f"{low:.3g}: its covariances are larger than its variances allow)")
    return C


def _mapping(d, name: str) -> dict:
    """``d`` when it is a JSON object; ``TypeError`` naming ``name`` and what it is otherwise."""
    if not isinstance(d, dict):
        raise TypeError(f"{name} is a JSON {_json_kind(d)}, not an object")
    return d


# the numbers the reports and the terminal read from a hybrid result's blocks: finite where present
_BLOCK_NUMBERS = {
    "mount": ("frames_tested", "pairs_tested", "threshold", "finds_deg", "finds_within", "scatter_deg"),
    "lidar": ("dy_m", "dy_std_m", "dx_m", "dx_std_m", "rows", "frames", "innovation_sigma"),
    "doppler": ("dx_m", "dx_std_m", "pairs", "frames", "turning"),
}
# and those its words need once the block says it ran (its first key present): probe 63, a report's KeyError / None
_BLOCK_RAN = {"lidar": ("dy_m", "dy_std_m", "rows", "frames", "applied"),
              "doppler": ("dx_m", "pairs", "turning", "applied")}
# what each of them can be (probe 112: "+10.0 +- -2.0 cm" and "-3 sweep pairs" on the page); no upper bound: an offset
# the data hardly see has a std of ~1 km and more (the demo's Doppler: 1204 m), and its estimate may be as far off


def _count(x) -> bool:
    return float(x).is_integer() and 0 <= x < 10**9


_BLOCK_RANGES = {**dict.fromkeys(("dy_std_m", "dx_std_m"), lambda x: x > 0),
                 **dict.fromkeys(("rows", "frames", "pairs", "turning", "frames_tested", "pairs_tested"), _count),
                 **dict.fromkeys(("threshold", "scatter_deg"), lambda x: x >= 0)}  # innovation_sigma: either sign
_BLOCK_RANGE_WORDS = {**dict.fromkeys(("dy_std_m", "dx_std_m"), "a std that is not positive"),
                      **dict.fromkeys(("rows", "frames", "pairs", "turning", "frames_tested", "pairs_tested"),
                                      "not a count"),
                      **dict.fromkeys(("threshold", "scatter_deg"), "negative")}
_STEP_NUMBERS = ("step_deg", "std_deg", "change", "at")
_LEVEL_NUMBERS = ("level_deg", "std_deg", "frames", "pairs")


def _block(d: dict, key: str, where: str) -> dict | None:
    """The hybrid's ``mount`` / ``lidar`` / ``doppler`` block of a vehicle result read back: None, or an object
    whose numbers (``_BLOCK_NUMBERS``; each step's ``_STEP_NUMBERS``) are finite where present and whose
    ``applied`` is a boolean; ``TypeError`` / ``ValueError`` naming the field otherwise (a report crashed on
    them)."""
    b = d.get(key)
    if b is None:
        return None
    b = _mapping(b, f"{where}.{key}")
    for k in _BLOCK_NUMBERS[key]:
        if k in b and b[k] is not None and not is_number(b[k]):
            raise ValueError(f"{where}.{key}.{k} is {str(b[k])[:40]!r}, not a finite number")
        if k in b and b[k] is not None and not _BLOCK_RANGES.get(k, lambda x: True)(b[k]):
            raise ValueError(f"{where}.{key}.{k} is {str(b[k])[:40]!r}: {_BLOCK_RANGE_WORDS[k]}: {EDITED}")
    need = _BLOCK_RAN.get(key, ())
    if need and need[0] in b and (lack := [k for k in need if b.get(k) is None]):
        raise ValueError(f"{where}.{key} lacks {lack} beside its {need[0]}: {EDITED}")
    if key == "lidar" and "dx_std_m" in b and b.get("dx_m") is None:
        raise ValueError(f"{where}.lidar lacks dx_m beside its dx_std_m: {EDITED}")
    if key == "mount":
        blind = b.get("blind_frames")
        if blind is not None and not (isinstance(blind, list) and len(blind) == 2 and all(
                isinstance(v, int) and not isinstance(v, bool) and 0 <= v < 10**9 for v in blind)):
            raise ValueError(f"{where}.mount.blind_frames is {str(blind)[:40]}, not two frame counts: {EDITED}")
        levels = b.get("levels", [])
        if not isinstance(levels, list):
            raise TypeError(f"{where}.mount.levels is a JSON {_json_kind(levels)}, not an array")
        for j, lv in enumerate(levels):
            lv = _mapping(lv, f"{where}.mount.levels[{j}]")
            if bad := [k for k in _LEVEL_NUMBERS if k in lv and not is_number(lv[k])]:
                raise ValueError(f"{where}.mount.levels[{j}].{bad[0]} is {str(lv[bad[0]])[:40]!r}, not a finite "
                                 f"number: {EDITED}")
    if "applied" in b and not isinstance(b["applied"], bool):
        raise TypeError(f"{where}.{key}.applied is a JSON {_json_kind(b['applied'])}, not a boolean")
    steps = b.get("steps", [])
    if key == "mount" and not isinstance(steps, list):
        raise TypeError(f"{where}.mount.steps is a JSON {_json_kind(steps)}, not an array")
    for j, st in enumerate(steps if key == "mount" else ()):
        st = _mapping(st, f"{where}.mount.steps[{j}]")
        bad = [k for k in _STEP_NUMBERS if not is_number(st.get(k))]
        if bad:
            raise ValueError(f"{where}.mount.steps[{j}] lacks finite {bad}")
    return b


def _std_block(x, name: str) -> np.ndarray:
    """(6,) a ``std_dict`` (``STD_FRAME``) read back: every value a finite JSON number >= 0 (a singular bound's clipped
    variance reads 0: ``calib.covariance.report_std``); ``ValueError`` naming the key otherwise (probe 112: a
    Cramer-Rao std written as "NaN" or -1 was printed as nan / -1.000)."""
    x = _mapping(x, name)
    for k in std_keys(STD_FRAME):
        if k not in x:
            raise ValueError(f"{name} lacks {k}: {EDITED}")
        if not (is_number(x[k]) and x[k] >= 0):
            raise ValueError(f"{name}.{k} is {str(x[k])[:40]!r}, not a std (a finite number >= 0): {EDITED}")
    return np.array([float(x[k]) for k in std_keys(STD_FRAME)])


def _network(d: dict, where: str) -> dict | None:
    """A vehicle result's ``network`` block (NETWORK of the module docstring) read back: None, or the block with
    its counts whole numbers, its frame a string, its transform rigid, its covariance one and its error finite;
    ``ValueError`` / ``TypeError`` naming the field otherwise (probe 112: text there reached the page as HTML, a
    string error was an internal error in report)."""
    n = _object_or_null(d, "network", where)
    if n is None:
        return None
    where = f"{where}.network"
    for k in ("n_frames", "iteration"):
        if not (isinstance(n.get(k), int) and not isinstance(n.get(k), bool) and 0 <= n[k] < 10**9):
            raise ValueError(f"{where}.{k} is {str(n.get(k))[:40]!r}, not a count: {EDITED}")
    if not isinstance(n.get("frame_id"), str):
        raise TypeError(f"{where}.frame_id is a JSON {_json_kind(n.get('frame_id'))}, not a string: {EDITED}")
    if "T_cam_radar" in n:
        _transform(n["T_cam_radar"], f"{where}.T_cam_radar")
    if n.get("cov_right_radar") is not None:
        _covariance(n["cov_right_radar"], f"{where}.cov_right_radar")
    if n.get("std_cam") is not None:
        _std_block(n["std_cam"], f"{where}.std_cam")
    if "depth" in n and not isinstance(n["depth"], str):
        raise TypeError(f"{where}.depth is a JSON {_json_kind(n['depth'])}, not a string: {EDITED}")
    e = _object_or_null(n, "error", where)
    if e is not None and (bad := [k for k in METRIC_KEYS if not is_number(e.get(k))]):  # metrics.ExtrinsicError's
        raise ValueError(f"{where}.error.{bad[0]} is {str(e.get(bad[0]))[:40]!r}, not a finite number: {EDITED}")
    return n


def _trajectory_fits(traj: list, n_frames: int, skipped: list, step_alarms, where: str) -> None:
    """``ValueError`` naming the field unless a read-back trajectory is one the calibrators write: none (a batch
    solve) or one entry per frame used (``n_frames``), in drive order, each frame's index below the frames read (used
    and skipped), and ``step_alarms`` (when present) its alarms' indices (probe 112: 100 000 entries of an 8-frame
    result, or an index of 10**6, were drawn as they were)."""
    if not traj:
        return
    if len(traj) != n_frames:
        raise ValueError(f"{where}.trajectory holds {len(traj)} frames but {where}.n_frames is {n_frames}: {EDITED}")
    idx = [f.index for f in traj]
    if idx[0] < 0 or any(b <= a for a, b in zip(idx, idx[1:])) or idx[-1] >= n_frames + len(skipped):
        raise ValueError(f"{where}.trajectory's frame indices ({str(idx)[:60]}) are not increasing drive positions "
                         f"below the {n_frames + len(skipped)} frames read (used and skipped): {EDITED}")
    if step_alarms is not None and step_alarms != [f.index for f in traj if f.step_alarm]:
        raise ValueError(f"{where}.step_alarms ({str(step_alarms)[:60]}) are not the trajectory's alarms: {EDITED}")


def _object_or_null(d: dict, key: str, where: str) -> dict | None:
    """``d[key]`` when it is an object or absent / null; ``TypeError`` naming the field otherwise (probe 27: a
    ``drift`` of "x" was an internal error in report and export, and stopped a resumed fleet)."""
    return None if d.get(key) is None else _mapping(d[key], f"{where}.{key}")


def _drift(d: dict, where: str) -> dict | None:
    """A vehicle result's ``drift`` block read back: None, or an object whose ``verdict_kind`` is one of
    ``drift.VERDICT_KINDS`` and is said by its ``verdict`` sentence (a hand-edited kind made report headline and
    export act on a "recalibrate" the sentence does not say; probe 27)."""
    from hybrid_calib.calib.drift import VERDICT_KINDS

    b = _object_or_null(d, "drift", where)
    if b is None:
        return b
    _drift_fields(b, f"{where}.drift")
    if "verdict_kind" not in b:
        return b
    kind, verdict = b["verdict_kind"], b.get("verdict", "")
    if kind not in VERDICT_KINDS:
        raise ValueError(f"{where}.drift.verdict_kind is {str(kind)[:40]!r}, not one of {list(VERDICT_KINDS)}")
    if not isinstance(verdict, str) or (verdict and kind not in verdict):
        raise ValueError(f"{where}.drift.verdict_kind {kind!r} is not what its verdict says "
                         f"({str(verdict)[:60]!r}): the file was edited")
    return b


_DRIFT_NUMBERS = ("statistic", "p_value", "threshold", "rot_change_deg", "trans_change_cm", "alpha", "dof")
_DRIFT_FLAGS = ("significant", "exceeds_margin", "drifted")
_DRIFT_WORDS = ("verdict", "test", "verdict_test")
_DRIFT_MAY_BE_INFINITE = ("statistic", "threshold", "axes.std", "axes.tolerance")
_AXIS_DECISIONS = ("within", "differs", "undecided")


def _drift_fields(b: dict, where: str) -> None:
    """The fields of a ``drift`` block (``calib.drift.DriftDecision.to_dict``, ``prior_note``) that report, export and
    the fleet summary read, of the JSON kind they are written as; ``TypeError`` / ``ValueError`` naming the field
    otherwise (probe 61: a null p-value and an axis of "x" were internal errors in report and export). No number may
    be NaN, and only ``_DRIFT_MAY_BE_INFINITE`` infinite (a singular covariance's statistic; probe 88: a NaN statistic
    was printed beside p = 0, an infinite change as "inf deg", a NaN change turned "recalibrate" into "cannot
    tell")."""
    def number(x, key: str = "") -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool) and not math.isnan(x) and \
            (math.isfinite(x) or key in _DRIFT_MAY_BE_INFINITE)

    for keys, ok, kind in ((_DRIFT_NUMBERS, number, "number"), (_DRIFT_FLAGS, lambda x: isinstance(x, bool),
                                                                 "true or false"),
                           (_DRIFT_WORDS, lambda x: isinstance(x, str), "string")):
        for key in keys:
            if key in b and not (ok(b[key], key) if kind == "number" else ok(b[key])):
                if kind == "number" and isinstance(b[key], float):
                    raise ValueError(f"{where}.{key} is {b[key]}, not a number the reference test writes: {EDITED}")
                raise TypeError(f"{where}.{key} is a JSON {_json_kind(b[key])}, not a {kind}: {EDITED}")
    ranges = {"p_value": (0, 1), "statistic": (0, math.inf), "threshold": (0, math.inf), "alpha": (0, 1),
              "dof": (1, 6)}  # probe 112: "p-value 7", "statistic -5.0", "dof 0" were printed as they were
    for key, (lo, hi) in ranges.items():
        if key in b and not (lo <= b[key] <= hi and (key != "dof" or float(b[key]).is_integer())):
            raise ValueError(f"{where}.{key} is {b[key]}, outside [{lo}, {hi}]: not what the reference test writes: "
                             f"{EDITED}")
    from hybrid_calib.calib.drift import AXIS_KEYS, AXIS_WORDS

    for key, value in _mapping(b.get("delta_camera") or {}, f"{where}.delta_camera").items():
        if key not in AXIS_KEYS or not number(value):
            raise ValueError(f"{where}.delta_camera.{key} is {str(value)[:40]}: a number on one of {list(AXIS_KEYS)} "
                             f"is expected: {EDITED}")
    for name, a in _mapping(b.get("axes") or {}, f"{where}.axes").items():
        a = _mapping(a, f"{where}.axes.{name}")
        if name not in AXIS_WORDS:
            raise ValueError(f"{where}.axes has {str(name)[:40]!r}, not one of {list(AXIS_WORDS)}: {EDITED}")
        bad = [k for k in ("delta", "std", "tolerance") if k in a and not number(a[k], f"axes.{k}")]
        bad += [k for k in ("prior_pinned",) if k in a and not isinstance(a[k], bool)]
        bad += [k for k in ("decision",) if k in a and a[k] not in _AXIS_DECISIONS]
        if bad:
            raise ValueError(f"{where}.axes.{name}.{bad[0]} is {str(a[bad[0]])[:40]}: not what the reference test "
                             f"writes (numbers, prior_pinned true or false, decision one of {list(_AXIS_DECISIONS)}): "
                             f"{EDITED}")
    if (prior := _object_or_null(b, "prior", where)) is not None:
        for key in ("dominated", "pulled"):
            if not isinstance(got := prior.get(key, []), list) or any(w not in AXIS_WORDS for w in got):
                raise ValueError(f"{where}.prior.{key} is {str(got)[:60]}: a list of {list(AXIS_WORDS)} is expected: "
                                 f"{EDITED}")
        if not isinstance(prior.get("words", ""), str):
            raise TypeError(f"{where}.prior.words is a JSON {_json_kind(prior['words'])}, not a string: {EDITED}")


def _array(d: dict, key: str, where: str) -> list:
    """``d[key]`` (absent: []) when it is a JSON array; ``TypeError`` naming the field otherwise."""
    x = d.get(key, [])
    if not isinstance(x, list):
        raise TypeError(f"{where}.{key} is a JSON {_json_kind(x)}, not an array")
    return x


def _error(d: dict, where: str) -> dict | None:
    """A vehicle result's ``error`` block read back: None, or an object of finite numbers (``ValueError`` naming
    the key otherwise: a page of 'rotation nan deg' was written from one)."""
    e = d.get("error")
    if e is None:
        return None
    e = _mapping(e, f"{where}.error")
    # (a NEES of a singular covariance may be inf: kept, the metrics themselves never are)
    if bad := [k for k, v in e.items() if not (is_number(v) or v is None or isinstance(v, (str, bool))
                                                or (k == "nees" and isinstance(v, float) and not np.isnan(v)))]:
        raise ValueError(f"{where}.error.{bad[0]} is {str(e[bad[0]])[:40]!r}, not a finite number")
    return e


def _json_kind(x) -> str:
    return {list: "array", str: "string", bool: "boolean", int: "number", float: "number",
            type(None): "null"}.get(type(x), type(x).__name__)


@dataclass(frozen=True)
class Estimate:
    """An extrinsic with its trustworthy covariance.

    T: (4, 4) T_cam_radar. cov: (6, 6) right tangent, radar frame [rad, m]. std: (6,) camera axes
    [deg x3, cm x3]. status: "ok" | "weak: ..." | "degenerate: ..." | "inconclusive: ..." (+ notes;
    ``calib.covariance``). A solve's own status keeps its word and marks a failure in its notes ("ok (NOT CONVERGED:
    only 0 % of ...)"): read whether it can be trusted with ``calib.covariance.untrusted_status``, not from the first
    word (a vehicle's result turns such a status into "inconclusive: ...").
    """

    T: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    status: str
    regularised: bool = False
    weak_directions: tuple[str, ...] = ()
    info: np.ndarray | None = None  # (6, 6) information before regularisation (for tests/NEES)

    def __post_init__(self):
        # read-only float64 copies: an estimate handed out (a window's output, a result's final) cannot be changed in
        # place by its reader (``est.T[:3, 3] += ...`` moved the window's own state; probe 33)
        for name in ("T", "cov", "std", "info"):
            value = getattr(self, name)
            if value is not None:
                value = np.array(value, np.float64)
                value.flags.writeable = False
                object.__setattr__(self, name, value)

    @classmethod
    def from_report(cls, T: np.ndarray, rep: CovarianceReport, info: np.ndarray | None = None,
                    note: str = "") -> Estimate:
        status = rep.status + (f" ({note})" if note else "")
        return cls(np.asarray(T, np.float64), rep.cov, rep.std_report, status, rep.regularised,
                   rep.weak_directions, info)

    def to_dict(self, report: bool = True) -> dict:
        """EXTRINSIC of the module docstring (without "report" when ``report=False``)."""
        d = {"T_cam_radar": np.asarray(self.T).tolist()}
        if report:
            d["report"] = extrinsic_report(self.T)
        d.update({"cov_right_radar": np.asarray(self.cov).tolist(), "std_cam": std_dict(self.std, STD_FRAME),
                  "status": self.status, "regularised": bool(self.regularised),
                  "weak_directions": list(self.weak_directions)})
        return d

    @classmethod
    def from_dict(cls, d: dict, where: str = "estimate") -> Estimate:
        """EXTRINSIC (or FRAME) back; ``TypeError`` / ``ValueError`` naming ``where`` when it is not an
        object or its transform / covariance is not a finite 4x4 / 6x6 matrix (``KeyError``: a missing key)."""
        d = _mapping(d, where)
        # each key named with its path (probe 148: "(KeyError: 'std_cam')", "'NoneType' object is not subscriptable")
        if missing := [k for k in ("T_cam_radar", "cov_right_radar", "std_cam", "status") if k not in d]:
            raise KeyError(f"{where} lacks {', '.join(missing)}: {EDITED}")
        std_cam = _mapping(d["std_cam"], f"{where}.std_cam")
        if missing := [k for k in std_keys(STD_FRAME) if k not in std_cam]:
            raise KeyError(f"{where}.std_cam lacks {', '.join(missing)}: {EDITED}")
        std = np.asarray(std_from_dict(std_cam, STD_FRAME), np.float64)
        if not np.all(np.isfinite(std)):  # a page showed "pitch 0.892 +- nan deg" under a verdict with a std
            raise ValueError(f"{where}.std_cam holds a non-finite value")
        T = _transform(d["T_cam_radar"], f"{where}.T_cam_radar")
        cov = _covariance(d["cov_right_radar"], f"{where}.cov_right_radar")
        # the std is the covariance's, in camera axes (``report_std``): a page showed "pitch -1.000 deg" (probe 38)
        if not np.allclose(std, own := report_std(T, cov), rtol=1e-6, atol=1e-9):
            k = int(np.argmax(np.abs(std - own) - 1e-6 * np.abs(own)))
            raise ValueError(f"{where}.std_cam.{std_keys(STD_FRAME)[k]} is {std[k]:.6g}, but its covariance "
                             f"(cov_right_radar) gives {own[k]:.6g}: {EDITED}")
        # typed as written (probe 59: a numeric status was an internal error in report and export)
        for key, kind, default in (("status", str, None), ("regularised", bool, False), ("weak_directions", list, [])):
            if not isinstance(d.get(key, default), kind):
                raise TypeError(f"{where}.{key} is a JSON {_json_kind(d[key])}, not a {_KIND_WORDS[kind]}: {EDITED}")
        if bad := [w for w in d.get("weak_directions", []) if not isinstance(w, str)]:  # probe 61: [1] in report
            raise TypeError(f"{where}.weak_directions holds a JSON {_json_kind(bad[0])}, not only strings: {EDITED}")
        if not status_kind(d["status"]):  # what trust is read from (probe 71: "INCONCLUSIVE: ..." or "" exported)
            raise ValueError(f"{where}.status {d['status'][:60]!r} does not open with one of "
                             f"{', '.join(STATUS_WORDS)}: {EDITED}")
        return cls(T, cov, std, d["status"], d.get("regularised", False), tuple(d.get("weak_directions", ())))


@dataclass(frozen=True)
class FrameEstimate:
    """What the sliding window outputs after one frame."""

    index: int  # 0-based frame number: its position in the drive (learned methods), else the window's count
    frame_id: str
    timestamp_us: int
    estimate: Estimate
    n_window: int  # frames currently in the window
    n_total: int  # frames whose information the estimate holds (window + marginalised)
    inlier_fraction: float  # mean robust weight > 0.5 over the window's rows (NaN: none fitted, pure; null in JSON)
    step_statistic: float | None  # windowed chi-square (None when not tested yet)
    step_threshold: float | None
    step_alarm: bool
    solve_ms: float  # wall time of the window solve (incl. the step test), ms
    cov_ms: float  # wall time of the covariance, ms
    events: tuple[str, ...] = ()  # e.g. "step change detected: window reset, convex restart"

    @property
    def T(self) -> np.ndarray:
        return self.estimate.T

    @property
    def cov(self) -> np.ndarray:
        return self.estimate.cov

    @property
    def status(self) -> str:
        return self.estimate.status

    def to_dict(self) -> dict:
        """FRAME of the module docstring."""
        return {
            "index": self.index, "frame_id": self.frame_id, "timestamp_us": int(self.timestamp_us),
            **self.estimate.to_dict(report=False), "n_window": self.n_window, "n_total": self.n_total,
            # null where no rows were fitted (pure: NaN, written as a bare NaN that strict JSON readers refuse)
            "inlier_fraction": float(self.inlier_fraction) if np.isfinite(self.inlier_fraction) else None,
            "step_statistic": None if self.step_statistic is None else float(self.step_statistic),
            "step_threshold": None if self.step_threshold is None else float(self.step_threshold),
            "step_alarm": bool(self.step_alarm), "solve_ms": float(self.solve_ms), "cov_ms": float(self.cov_ms),
            "events": list(self.events),
        }

    @classmethod
    def from_dict(cls, d: dict, where: str = "frame") -> FrameEstimate:
        d = _mapping(d, where)
        keys = ("index", "frame_id", "timestamp_us", "n_window", "n_total", "inlier_fraction", "step_statistic",
                "step_threshold", "step_alarm", "solve_ms", "cov_ms")
        if missing := [k for k in keys if k not in d]:
            raise KeyError(f"{where} lacks {missing}")  # a bare KeyError 'index' named no frame (probe 27)
        # typed as written (probe 59: a step_alarm "false" read as an alarm, bool("false"); events a number)
        for key, kind in (("step_alarm", bool), ("events", list), ("timestamp_us", int), ("index", int),
                          ("frame_id", str)):
            if key in d and (not isinstance(d[key], kind) or (kind is int and isinstance(d[key], bool))):
                raise TypeError(f"{where}.{key} is a JSON {_json_kind(d[key])}, not a {_KIND_WORDS[kind]}: {EDITED}")
        # counts and times as written (probe 63: n_total Infinity, solve_ms NaN in compare.json's ms per frame)
        if bad := [k for k in ("n_window", "n_total", "solve_ms", "cov_ms") if not is_number(d[k]) or d[k] < 0]:
            raise ValueError(f"{where}.{bad[0]} is {str(d[bad[0]])[:40]}, not a finite count or time: {EDITED}")
        return cls(
            index=int(d["index"]), frame_id=d["frame_id"], timestamp_us=int(d["timestamp_us"]),
            estimate=Estimate.from_dict(d, where), n_window=int(d["n_window"]), n_total=int(d["n_total"]),
            inlier_fraction=float("nan" if d["inlier_fraction"] is None else d["inlier_fraction"]),
            step_statistic=d["step_statistic"],
            step_threshold=d["step_threshold"], step_alarm=bool(d["step_alarm"]), solve_ms=float(d["solve_ms"]),
            cov_ms=float(d["cov_ms"]), events=tuple(d.get("events", ())),
        )


@dataclass
class VehicleResult:
    """Everything ``calibrate`` produces for one vehicle (log). ``network``: NETWORK of the module
    docstring (the producer's own SE(3) of the last frame that has one), or None."""

    vehicle: str
    final: Estimate
    trajectory: list[FrameEstimate] = field(default_factory=list)
    truth_T: np.ndarray | None = None
    # where the true mount moved along the drive (a knocked simulated radar): [(frame index, (4, 4) the mount from
    # it on)], first frame first; [] when it did not move (truth_T throughout)
    truth_path: list = field(default_factory=list)
    error: dict | None = None
    crb_std: np.ndarray | None = None
    drift: dict | None = None
    skipped: list[dict] = field(default_factory=list)
    n_frames: int = 0
    network: dict | None = None
    method: str = ""  # oracle | hybrid | pure | pure-avg ("" = files / older results)
    checkpoint: str | None = None  # the network checkpoint (learned methods)
    start: dict | None = None  # {"kind": reference|R1|R2, "seed", "T_cam_radar"}: the vehicle's start
    errors_against: str | None = None  # "truth" (simulated roots) | "tables" (real roots) | None
    frame_rows: list[dict] = field(default_factory=list)  # per frame {"used", "rejected", ...} (learned methods)
    config: dict | None = None  # the effective method config (learned methods)
    ood: dict | None = None  # out-of-domain scores and decision (learned methods; hybrid.ood.decide)
    mount: dict | None = None  # the radar mount monitor: steps and levels (hybrid; calib.mount_monitor.summary)
    lidar: dict | None = None  # the LiDAR's lateral offset of the radar (hybrid; calib.lidar_alignment record)
    doppler: dict | None = None  # the radar's forward offset from its Doppler in turns (hybrid; calib.lever_arm record)
    height_plane: dict | None = None  # the height model's reference plane the rows were fitted with (module docstring)

    def to_dict(self) -> dict:
        return {
            "vehicle": self.vehicle, "n_frames": self.n_frames, "frames_skipped": self.skipped,
            "final": self.final.to_dict(),
            "truth": None if self.truth_T is None else {
                "T_cam_radar": np.asarray(self.truth_T).tolist(), "report": extrinsic_report(self.truth_T),
                **({"path": [{"index": int(k), "T_cam_radar": np.asarray(T).tolist()} for k, T in self.truth_path]}
                   if self.truth_path else {})},
            "error": self.error,
            "crb_std_cam": None if self.crb_std is None else std_dict(self.crb_std, STD_FRAME),
            "drift": self.drift, "network": self.network,
            "step_alarms": [f.index for f in self.trajectory if f.step_alarm],
            "trajectory": [f.to_dict() for f in self.trajectory],
            "method": self.method, "checkpoint": self.checkpoint, "start": self.start,
            "errors_against": self.errors_against, "frame_rows": self.frame_rows, "config": self.config,
            "ood": self.ood, "mount": self.mount, "lidar": self.lidar, "doppler": self.doppler,
            "height_plane": self.height_plane,
        }

    @classmethod
    def from_dict(cls, d: dict, vehicle: str | None = None) -> VehicleResult:
        """``TypeError`` / ``ValueError`` naming the vehicle and the field for an entry that is not an object,
        or an estimate whose transform / covariance is not a finite 4x4 / 6x6 matrix; ``KeyError``: a missing key.
        A number beyond a float's range (JSON allows a 400-digit integer; Infinity where a count is read) is a
        ``ValueError`` too (probe 63: an OverflowError was an internal error in export, report and a fleet resume)."""
        try:
            return cls._from_dict(d, vehicle)
        except OverflowError as e:
            where = f"vehicles[{vehicle!r}]" if vehicle is not None else "vehicle result"
            raise ValueError(f"{where} holds a number beyond a float's range ({e}): {EDITED}") from None

    @classmethod
    def _from_dict(cls, d: dict, vehicle: str | None) -> VehicleResult:
        where = f"vehicles[{vehicle!r}]" if vehicle is not None else "vehicle result"
        d = _mapping(d, where)
        truth, crb = d.get("truth"), d.get("crb_std_cam")
        trajectory = _array(d, "trajectory", where)
        if "n_frames" not in d:  # probe 88: read as 0, the page said "0 frames" of a 16-frame result
            raise ValueError(f"{where}.n_frames is missing: {EDITED}")
        n_frames = d["n_frames"]
        if not (isinstance(n_frames, int) and not isinstance(n_frames, bool) and n_frames >= 0):
            raise ValueError(f"{where}.n_frames is {str(n_frames)[:40]!r}, not a count of frames")
        for key in ("method", "vehicle"):
            if not isinstance(d.get(key, ""), str):
                raise TypeError(f"{where}.{key} is a JSON {_json_kind(d[key])}, not a string")
        frames = [FrameEstimate.from_dict(f, f"{where}.trajectory[{k}]") for k, f in enumerate(trajectory)]
        skipped = list(_array(d, "frames_skipped", where))
        _trajectory_fits(frames, n_frames, skipped, d.get("step_alarms"), where)
        return cls(
            vehicle=d.get("vehicle", vehicle or ""), final=Estimate.from_dict(d["final"], f"{where}.final"),
            trajectory=frames,
            truth_T=None if truth is None else _transform(_mapping(truth, f"{where}.truth")["T_cam_radar"],
                                                       f"{where}.truth.T_cam_radar"), error=_error(d, where),
            truth_path=_truth_path(truth, f"{where}.truth"),
            crb_std=None if crb is None else _std_block(crb, f"{where}.crb_std_cam"), drift=_drift(d, where),
            skipped=skipped, n_frames=n_frames, network=_network(d, where), method=d.get("method", ""),
            checkpoint=d.get("checkpoint"),
            start=_object_or_null(d, "start", where), errors_against=d.get("errors_against"),
            frame_rows=list(_array(d, "frame_rows", where)), config=_object_or_null(d, "config", where),
            ood=_object_or_null(d, "ood", where), mount=_block(d, "mount", where),
            lidar=_block(d, "lidar", where), doppler=_block(d, "doppler", where),
            height_plane=_object_or_null(d, "height_plane", where),
        )._errors_measured(where)._path_ends_at_truth(where)

    def _path_ends_at_truth(self, where: str) -> VehicleResult:
        """Itself, when its ``truth_path`` (if any) ends at its ``truth_T`` (the mount at the drive's end, which the
        errors are against); ``ValueError`` otherwise (probe 59: an edited path drew the plots against another)."""
        from hybrid_calib.data.mounts import same_calibration

        # within the tables' tolerance: the path and the end's truth may be read from two records of one mount
        if self.truth_path and (self.truth_T is None or not same_calibration(self.truth_path[-1][1], self.truth_T)):
            raise ValueError(f"{where}.truth.path ends at another mount than {where}.truth.T_cam_radar (the drive's "
                             f"end): {EDITED}")
        return self

    def _errors_measured(self, where: str) -> VehicleResult:
        """Itself, when its ``error`` block is what its final estimate and truth give (``metrics.extrinsic_error``
        and the NEES, as the calibrators compute them); ``ValueError`` naming the key otherwise: a page printed "NEES
        -3.00" and an error against a truth the file no longer held (probe 38)."""
        if self.error is None:
            return self
        if self.truth_T is None:
            raise ValueError(f"{where}.error is given but {where}.truth is not, an error against no truth: {EDITED}")
        own = extrinsic_error(self.final.T, self.truth_T).as_dict()
        try:
            own["nees"] = nees(local(self.truth_T, self.final.T), self.final.cov)
        except (ValueError, np.linalg.LinAlgError):  # a singular covariance: the NEES written was inf
            own["nees"] = float("inf")
        if missing := [k for k in own if k not in self.error]:  # probe 61: report and compare read every one
            raise ValueError(f"{where}.error lacks {', '.join(missing)} (the final estimate against {where}.truth "
                             f"gives them): {EDITED}")
        for key, value in self.error.items():
            if key in own and not (value == own[key] or (is_number(value) and np.isclose(value, own[key],
                                                                                          rtol=1e-6, atol=1e-9))):
                raise ValueError(f"{where}.error.{key} is {str(value)[:40]}, but the final estimate against "
                                 f"{where}.truth gives {own[key]:.6g}: {EDITED}")
        return self

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_json(cls, text: str) -> VehicleResult:
        return cls.from_dict(json.loads(text))


def failed_vehicles_message(failed: dict[str, str], each: int = 240) -> str:
    """One paragraph for vehicles that all failed (vehicle -> reason): the first reason in full, then each other
    vehicle with its own reason (its first ``each`` characters; probe 40: "1 more vehicle(s) failed as well: X" named
    no reason of X's, where the README promises each vehicle's)."""
    (first, reason), *rest = failed.items()
    def short(v: str, why: str) -> str:
        why = why if why.startswith(f"vehicle {v}") else f"{v}: {why}"
        return why if len(why) <= each else why[: each - 3] + "..."
    more = (f"; {len(rest)} more vehicle(s) failed as well: {', '.join(v for v, _ in rest)} ("
            + "; ".join(short(v, why) for v, why in rest) + ")") if rest else ""
    return f"{reason}{more}"


@dataclass
class CalibrationRun:
    """One ``calibrate`` run: every vehicle's result and where the inputs came from (``result.json``)."""

    data: str
    version: str
    correspondences: str  # "oracle" or the measurement directory
    mode: str  # "window" | "batch"
    vehicles: dict[str, VehicleResult] = field(default_factory=dict)
    vehicles_failed: dict[str, str] = field(default_factory=dict)  # vehicle -> why it has no result (bad data)
    # what the run said of the data before reading a frame (``data.summary.calibration_notes``: samples of no vehicle,
    # ego poses that jump, ...): kept with the result, where the console's lines are lost (probe 108)
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "data": self.data, "version": self.version,
                "correspondences": self.correspondences, "mode": self.mode,
                "vehicles": {name: v.to_dict() for name, v in self.vehicles.items()},
                "vehicles_failed": dict(self.vehicles_failed), "notes": list(self.notes)}

    def raise_if_none_done(self) -> None:
        """``DataError`` when every vehicle failed (the reasons, joined): nothing to write."""
        if self.vehicles_failed and not self.vehicles:
            raise DataError(failed_vehicles_message(self.vehicles_failed), path=self.data)

    @classmethod
    def from_dict(cls, d: dict, source: str = "") -> CalibrationRun:
        """Raises ``DataError`` (naming ``source``) for another schema version."""
        version = d.get("schema_version") if isinstance(d, dict) else None
        if version == SCHEMA_VERSION and d.get("schema") != SCHEMA:  # probe 109: another schema's name was read
            raise DataError(f"not a calibrate result: its \"schema\" is {str(d.get('schema'))[:60]!r}, not {SCHEMA!r}; "
                            "pass the result.json of a hybrid-calib calibrate run", path=source or None)
        if version != SCHEMA_VERSION:
            raise DataError(f"not a calibrate result of schema_version {SCHEMA_VERSION} (found {_found(d)}); "
                            + _what_it_is(d), path=source or None)
        vehicles = _mapping(d["vehicles"], '"vehicles"')
        failed = _mapping(d.get("vehicles_failed") or {}, '"vehicles_failed"')
        for key in ("data", "version", "correspondences", "mode"):  # paths and names: "data": 5 was an internal error
            if not isinstance(d[key], str):
                raise TypeError(f'"{key}" is a JSON {type(d[key]).__name__}, not a string')
        notes = d.get("notes") or []  # (absent in results written before it)
        if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
            raise TypeError('"notes" is not a list of strings')
        return cls(d["data"], d["version"], d["correspondences"], d["mode"],
                   {name: VehicleResult.from_dict(v, name) for name, v in vehicles.items()},
                   {str(k): str(v) for k, v in failed.items()}, list(notes))

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_json(cls, text: str, source: str = "") -> CalibrationRun:
        return cls.from_dict(json.loads(text), source)

    def save(self, path: str | Path) -> Path:
        """Write ``path`` (``result.json``) atomically; ``ValueError`` naming the entry, and nothing written, when the
        run would not load back (a NaN in an error or a matrix: a result.json that ``load`` then refuses)."""
        d = self.to_dict()
        try:
            CalibrationRun.from_json(json.dumps(d, default=json_default))
        except (KeyError, TypeError, ValueError, DataError) as e:
            raise ValueError(f"not written: {path} would not load back ({type(e).__name__}: {e})") from None
        return save_json_atomic(Path(path), d)

    @classmethod
    def load(cls, path: str | Path) -> CalibrationRun:
        """Read a ``result.json`` (or the run folder holding one); ``DataError`` naming it when it is missing, not JSON,
        another schema, or incomplete / invalid (a missing key, an entry that is not an object, a non-finite or
        misshapen matrix)."""
        path = Path(path)
        if path.is_dir() and (path / "result.json").is_file():  # the run's folder (probe 93: "Is a directory")
            path = path / "result.json"
        elif path.is_dir():  # another command's folder (probe 107: a compare run's read "[Errno 21] Is a directory")
            held = ("a compare run's folder (its tables are compare.md and compare.json)"
                    if (path / "compare.json").is_file() else
                    "a fleet run's folder: each vehicle's result is vehicles/<job>/result.json"
                    if (path / "manifest.json").is_file() else "a folder with no result.json")
            raise DataError(f"is {held}; pass the result.json of a hybrid-calib calibrate run (or its folder)",
                            path=str(path))
        try:
            text = path.read_text()
            return cls.from_json(text, str(path))
        except (OSError, json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
            why = "nested too deeply" if isinstance(e, RecursionError) else e
            raise DataError(f"calibrate result unreadable ({why}); pass the result.json of a hybrid-calib calibrate "
                            "run", path=str(path)) from None
        except (KeyError, TypeError, ValueError) as e:
            said = e.args[0] if isinstance(e, KeyError) and e.args else e  # a KeyError's str() quotes its words
            raise DataError(f"calibrate result incomplete or invalid ({type(e).__name__}: {said}); re-run hybrid-calib "
                            "calibrate with --overwrite", path=str(path)) from None


def _found(d) -> str:
    """What a JSON that is not a calibrate result holds, in a few words: its ``schema_version`` or ``schema``, its
    keys, or its type (the whole file, repr'd, had been the message: a 70 kB line for a result wrapped in a list,
    probe 47)."""
    if isinstance(d, dict):
        if d.get("schema_version") is not None:
            return f"schema_version {str(d['schema_version'])[:40]!r}"
        if isinstance(d.get("schema"), str):
            return f"a file of schema {d['schema'][:80]!r}"
        keys = ", ".join(repr(str(k)[:30]) for k in list(d)[:6]) + (", ..." if len(d) > 6 else "")
        return f"a JSON object without a schema_version (keys: {keys or 'none'})"
    if isinstance(d, list):
        return f"a JSON list of {len(d)} item(s), not an object"
    text = repr(d)
    return f"a JSON {type(d).__name__}, {text[:60]}{'...' if len(text) > 60 else ''}"


FLEET_FILES = {"hybrid-calib/fleet-summary/v1": "a fleet summary (summary.json)",
               "hybrid-calib/fleet-manifest/v1": "a fleet manifest (manifest.json)"}


def _what_it_is(d) -> str:
    """What a JSON that is not a calibrate result looks like, and what to pass instead."""
    if isinstance(d, dict) and d.get("schema") in FLEET_FILES:
        return (f"it is {FLEET_FILES[d['schema']]}: each vehicle's calibrate result of a fleet run is "
                "OUT/vehicles/<job id>/result.json (its row in the summary names it)")
    if isinstance(d, dict) and isinstance(d.get("schema"), str) and "calibrate-result" not in d["schema"]:
        return ("it is another command's output: pass the result.json of a hybrid-calib calibrate run (calibrate "
                "... --out OUT writes OUT/result.json)")
    if isinstance(d, dict) and {"n_frames", "metrics", "rows"} <= set(d):
        return ("it is an evaluate summary (hybrid-calib evaluate's results.json): pass the result.json of a "
                "calibrate run (calibrate ... --out OUT writes OUT/result.json)")
    if isinstance(d, list) and len(d) == 1 and isinstance(d[0], dict) and d[0].get("schema_version") is not None:
        return "its one item looks like a result: pass the object itself, not a list holding it"
    if isinstance(d, dict) and {"methods", "trials"} <= set(d):
        return ("it is a compare summary (compare.json): the report reads a calibrate run's result.json (compare's "
                "tables are compare.md)")
    if isinstance(d, dict) and {"vehicle", "final"} <= set(d):
        return ("it is one vehicle's result (a compare trial, or a calibrate run's vehicles-done entry): pass the "
                "result.json of a calibrate run (hybrid-calib calibrate ... --out OUT writes OUT/result.json)")
    return "pass the result.json of a hybrid-calib calibrate run, or re-run calibrate with --overwrite"


DATA_STAMP = "data_stamp.json"  # beside result.json: ``data.files.data_stamp`` of the data it was computed from
def stored_digest(out: str | Path) -> str | None:
    """The data digest recorded beside a result (``out/DATA_STAMP``): "" when there is none (an older version's
    result), None when the file is damaged (it vouches for nothing)."""
    path = Path(out) / DATA_STAMP
    if not path.exists():
        return ""
    try:
        digest = json.loads(path.read_text()).get("digest")
    except (OSError, ValueError, AttributeError, RecursionError):
        return None
    return digest if isinstance(digest, str) and digest else None


def config_digest(cfg: dict) -> str:
    """SHA-1 of a run's ``config.json`` content (canonical JSON), recorded in ``DATA_STAMP`` beside its result: a
    config.json edited afterwards (to the options of the next run) vouched for a result of other options (probe 150)."""
    import hashlib

    as_read = json.loads(json.dumps(cfg, default=json_default))  # what the file holds: numpy scalars, tuples, paths
    return hashlib.sha1(json.dumps(as_read, sort_keys=True).encode()).hexdigest()


def _stored_config_digest(out: Path) -> str | None:
    """The config digest ``DATA_STAMP`` records (``config_digest``): "" when none is (an older result, or no stamp),
    None when it is not a digest (damaged: it vouches for nothing)."""
    try:
        stamp = json.loads((out / DATA_STAMP).read_text())
    except (OSError, ValueError, RecursionError):
        return ""  # a stamp that does not read is the data digest's to refuse (``stored_digest``)
    if not isinstance(stamp, dict) or "config" not in stamp:
        return ""
    digest = stamp["config"]
    return digest if isinstance(digest, str) and digest else None


def data_differ(out: str | Path, root: str | Path, version: str) -> bool:
    """Whether the data digest recorded beside a result (``out/DATA_STAMP``) differs from the data at ``root`` /
    ``version`` now (``data.files.data_stamp``), or is damaged (it vouches for nothing: probe 109, export wrote a
    mount computed from other data); False when it records none (export and report refuse, or leave out, what such a
    result would draw from other data)."""
    from hybrid_calib.data.files import data_stamp

    stored = stored_digest(out)
    return stored is None or (bool(stored) and stored != data_stamp(root, version)["digest"])


RUN_ONLY = ("progress", "threads", "cache_dir", "depth_cache")  # config keys of how a run ran, not of what it gave
# what a run's config.json records beside its options: the identity of what it read (the data, the network's files, the
# --reference export, the measurement rows); no option of a config (probe 121: report read "unknown option(s)
# ['correspondences_stamp']" and drew no rows)
IDENTITY_KEYS = ("data_stamp", "network", "reference_sha256", "correspondences_stamp")


class OtherConfiguration(HybridCalibError):
    """``VehicleProgress`` refused an ``--out`` whose finished vehicles are of another configuration (the message
    says what differs and what to do)."""


class VehicleProgress:
    """The vehicles a ``calibrate`` run into ``out`` has finished, kept so that an interrupted run resumes where it
    stopped: ``out/vehicles-done/`` holds one JSON per finished vehicle (``VehicleResult``) or failed one
    (``{"failed": reason}``), written atomically as each ends, and ``stamp.json`` (data, version, source and the
    effective config). ``finish`` removes the folder once ``result.json`` holds everything.

    - Kept vehicles of another configuration (another stamp, the ``RUN_ONLY`` keys aside, so a moved folder still
      resumes) are never discarded silently: ``HybridCalibError`` naming what differs, unless ``fresh``
      (``--overwrite``), which starts afresh.
    - Each record carries the key of its stamp and vehicle (``_record_key``): a record copied from another run or
      renamed, or a damaged file, is recomputed, and said so on stderr; so a damaged or missing ``stamp.json``
      loses nothing (the records of this run are kept, and the stamp written again).
    - The folder is a cache: a vehicle that cannot be kept (a directory in its file's place) is warned about and
      the run goes on."""

    def __init__(self, out: str | Path, data, version: str, source: str, conf: dict, fresh: bool = False):
        import shutil
        import sys

        self.dir = Path(out) / "vehicles-done"
        self.stamp = json.loads(json.dumps({"data": str(Path(str(data)).resolve()), "version": version,
                                            "source": str(source), "config": conf}, default=str))
        self.done: dict[str, VehicleResult | str] = {}
        self._said = False  # the kept vehicles said on opening (``fill`` does not say them again)
        changed: list[str] = []
        if self.dir.exists() and not self.dir.is_dir():
            raise HybridCalibError(f"{self.dir} is a file, not the folder where hybrid-calib keeps the vehicles an "
                                   "interrupted run finished; move it away (or pass another --out) and rerun")
        if self.dir.is_dir() and fresh:
            shutil.rmtree(self.dir, ignore_errors=True)
        if self.dir.is_dir():
            from hybrid_calib.atomic import finished as written  # a killed write's temporary file is no record

            kept = sorted(f for f in written(self.dir.glob("*.json")) if f.name != "stamp.json")
            try:
                old = json.loads((self.dir / "stamp.json").read_text())
                changed = _changes(old, self.stamp) if isinstance(old, dict) else []
            except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError):
                changed = []  # a damaged or missing stamp: each record's own key tells whether it is this run's
            finished = [f for f in kept if _holds_result(f)]  # a failure alone is no work to keep: the corrected
            if changed and finished:  # command (another --depth, --start) runs, as the failure's message advised
                more = f"; {len(changed) - 4} more" if len(changed) > 4 else ""
                # the same command on changed data cannot finish that run (probe 42: "rerun that run's command" was
                # the command just run)
                how = ("the data changed since, so that run cannot be finished: pass --overwrite to discard them and "
                       "calibrate the data as it is now" if all(c.startswith("the data in --data") for c in changed)
                       else "rerun that run's command to finish it, pass --overwrite to discard them")
                raise OtherConfiguration(
                    f"{self.dir} holds {len(finished)} vehicle(s) finished by an interrupted run of another "
                    f"configuration ({'; '.join(changed[:4])}{more}); {how}, or pass another --out")
            if changed:
                shutil.rmtree(self.dir, ignore_errors=True)
            for f in kept if not changed else ():
                name, why = self._read(f)
                if why:
                    print(f"vehicles-done: {f.name} is recomputed: {why}", file=sys.stderr)
            if finished := sorted(n for n, r in self.done.items() if isinstance(r, VehicleResult)):
                # a rerun says what it keeps, as fleet's (probe 40: a resumed calibrate said nothing of them)
                print(f"kept {len(finished)} vehicle(s) an interrupted run into this --out finished (same data and "
                      f"options): {', '.join(finished[:5])}{' ...' if len(finished) > 5 else ''}", file=sys.stderr)
                self._said = True  # ``fill`` does not say it again ("resuming: ..." beside it: probe 50)
        if not self.dir.is_dir() or not changed:
            save_json_atomic(self.dir / "stamp.json", self.stamp)

    def _read(self, f: Path) -> tuple[str, str]:
        """Keep one record into ``done``: (vehicle, "") or (name, why it is not this run's)."""
        try:
            d = json.loads(f.read_text())
            name = str(d["vehicle"])
            if f != self._path(name) or d.get("key") != _record_key(self.stamp, name):
                return name, "not this run's record of that vehicle (copied from another run, or renamed)"
            self.done[name] = str(d["failed"]) if "failed" in d else VehicleResult.from_dict(d["result"], name)
            return name, ""
        except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError) as e:
            return "", f"unreadable ({type(e).__name__}: {str(e)[:200]})"

    def _path(self, name: str) -> Path:
        from hybrid_calib.data.files import file_part

        return self.dir / f"{file_part(name)}.json"

    def record(self, name: str, result: VehicleResult | str) -> None:
        """Keep one vehicle's result (or, a string, why it failed); one that cannot be kept is warned about (the
        folder is a cache: the run goes on, and the vehicle is in its result.json)."""
        import sys

        body = {"failed": result} if isinstance(result, str) else {"result": result.to_dict()}
        try:
            save_json_atomic(self._path(name), {"vehicle": name, "key": _record_key(self.stamp, name), **body})
        except (OSError, HybridCalibError) as e:
            print(f"vehicles-done: {name} could not be kept ({e}); an interruption now would compute it again",
                  file=sys.stderr)

    def finish(self) -> None:
        import shutil

        shutil.rmtree(self.dir, ignore_errors=True)

    def fill(self, run: CalibrationRun, names, compute: Callable[[str], VehicleResult],
             on_vehicle: Callable[[VehicleResult], object] | None = None, announce: bool = True) -> None:
        """Each vehicle of ``names`` into ``run``: what an interrupted run kept, as it is, else ``compute(name)``,
        kept as soon as it ends; a ``DataError`` is that vehicle's failure (recorded, the others go on).
        ``on_vehicle`` is called with each newly computed result; with ``announce`` (progress shown), each vehicle
        computed of several is said first ("vehicle k of N: name")."""
        import sys

        if self.done and announce and not self._said:
            print(f"resuming: {len(self.done)} vehicle(s) finished by an interrupted run ({self.dir})",
                  file=sys.stderr)
        names = list(names)
        for k, name in enumerate(names, 1):
            if name in self.done:
                kept = self.done[name]
                if isinstance(kept, str):
                    run.vehicles_failed[name] = kept
                else:
                    run.vehicles[name] = kept
                continue
            if announce and len(names) > 1:  # the vehicles' own bars say nothing of the whole (probe 124)
                print(f"vehicle {k} of {len(names)}: {name}", file=sys.stderr, flush=True)
            try:
                vr = compute(name)
            except DataError as e:  # this vehicle's data: recorded, the other vehicles go on
                run.vehicles_failed[name] = str(e)
                self.record(name, str(e))
                continue
            run.vehicles[name] = vr
            self.record(name, vr)
            if on_vehicle is not None:
                on_vehicle(vr)


def reuse_result(out: str | Path, data, version: str, source: str, conf: dict) -> CalibrationRun:
    """The ``CalibrationRun`` an earlier run left in ``out`` (``result.json``), when it was computed from the same
    ``data`` root, ``version``, ``source`` (correspondences, or the learned method) and effective config ``conf``
    (``to_dict``; its ``config.json``, the ``RUN_ONLY`` keys aside). ``HybridCalibError`` naming what differs
    otherwise: the earlier result would be reported as this run's."""
    out = Path(out)
    try:
        run = CalibrationRun.load(out / "result.json")
    except DataError as e:  # the run's own output, not a result the user passed (probe 109: "pass the result.json
        # of a hybrid-calib calibrate run")
        raise HybridCalibError(f"{out / 'result.json'}, left by an earlier run into this --out, does not read "
                               f"({e.message}): pass --overwrite to recompute it, or another --out") from None
    old = read_out_record(out / "config.json", "calibrate config", "the configuration its result.json was computed "
                          "with: pass --overwrite to recompute, or another --out")
    if (recorded := _stored_config_digest(out)) is None:
        raise HybridCalibError(f"{out / DATA_STAMP} is damaged (its config digest is not one), so whether "
                               f"{out / 'config.json'} is the configuration {out / 'result.json'} was computed with "
                               "cannot be told: pass --overwrite to recompute, or another --out")
    if recorded and recorded != config_digest(old):
        raise HybridCalibError(f"{out / 'config.json'} is not the configuration {out / 'result.json'} was computed "
                               "with (it was edited since), so the result cannot be told to be this run's: pass "
                               "--overwrite to recompute, or another --out")

    def where(d):  # an older result's relative path, or a new one's absolute path: the same root either way
        return str(Path(str(d)).resolve()) if d else d

    changed = _changes({"data": where(run.data), "version": run.version, "source": run.correspondences, "config": old},
                       {"data": where(data), "version": version, "source": source, "config": conf})
    # the same path, but the data in it may have changed since
    then = "" if changed or data is None else stored_digest(out)
    if then != "":
        from hybrid_calib.data.files import data_stamp

        if then is None:  # damaged: it cannot vouch for the data, so the result is not reused
            raise HybridCalibError(f"{out / DATA_STAMP} is damaged, so whether {data}'s data changed since "
                                   f"{out / 'result.json'} was computed cannot be told: pass --overwrite to recompute, "
                                   "or another --out")
        now = data_stamp(data, version)
        if then != now["digest"]:
            raise HybridCalibError(f"{out / 'result.json'} was computed before {data}'s data changed (its tables or "
                                   f"sensor folders were modified since, the newest at {now['newest']}): pass "
                                   "--overwrite to recompute it from the data as they are now, or another --out")
    if changed:
        more = f"; {len(changed) - 4} more" if len(changed) > 4 else ""
        raise HybridCalibError(f"{out} holds the result of another run ({'; '.join(changed[:4])}{more}; "
                               f"{out / 'result.json'}), "
                               "which this run would report as its own; pass --overwrite to recompute, or another "
                               "--out")
    return run


def _changes(old: dict, new: dict) -> list[str]:
    """What differs between two runs' stamps (``data``, ``version``, ``source``: correspondences or the learned
    method, and ``config``: the effective config, None when unknown), in words; the ``RUN_ONLY`` config keys aside.
    The config is compared only when the rest is the same (another method's config has other keys)."""
    def same_path(a, b) -> bool:
        return str(a) == str(b) or Path(str(a)).resolve() == Path(str(b)).resolve()

    changed = [f"{what} {a!r} -> {b!r}" for what, a, b, same in (
        ("--data", old.get("data"), new["data"], same_path), ("--version", old.get("version"), new["version"],
                                                                 lambda a, b: a == b),
        ("method / correspondences", old.get("source"), new["source"], same_path)) if not same(a, b)]
    old_conf = old.get("config")
    if isinstance(old_conf, dict) and not changed:
        from hybrid_calib.config import changed_options

        new_conf, special = new["config"], IDENTITY_KEYS
        changed = changed_options(  # the leaf keys (motion.vo.features: 4000 -> 3000), not two cut JSON objects
            {k: v for k, v in old_conf.items() if k not in RUN_ONLY + special},
            {k: v for k, v in new_conf.items() if k not in RUN_ONLY + special})
        if old_conf.get("data_stamp") != new_conf.get("data_stamp") and "data_stamp" in new_conf:
            changed.append("the data in --data (its tables or sensor folders changed since)")
        if old_conf.get("correspondences_stamp") != new_conf.get("correspondences_stamp") and \
                "correspondences_stamp" in new_conf:
            changed.append(
                "the measurement files in --correspondences: " + (
                    "none is there now" if not new_conf["correspondences_stamp"] else
                    "the earlier run recorded no stamp of its rows (written by an older hybrid-calib)"
                    if "correspondences_stamp" not in old_conf else
                    "other rows (exported again since, or another folder of that name)"))
        if old_conf.get("reference_sha256") != new_conf.get("reference_sha256") and old_conf.get(
                "reference") == new_conf.get("reference") and "reference_sha256" in new_conf:
            changed.append("the --reference export's file (exported again at the same path since)")
        if old_conf.get("network") != new_conf.get("network") and "network" in new_conf:
            chosen = [w for w in changed if w.split(":")[0] in ("checkpoint", "refine", "start")]
            changed.append(f"the network (another checkpoint: {', '.join(c.split(':')[0] for c in chosen)} changed; "
                           "the shipped one follows --start)" if chosen else
                           "the network checkpoint's files (changed since: retrained or edited at the same path; or "
                           "the earlier run did not record them)")
    return changed


def _holds_result(f: Path) -> bool:
    """Whether a ``vehicles-done`` record holds a finished vehicle's result (not a failure, not unreadable)."""
    try:
        d = json.loads(f.read_text())
        return isinstance(d, dict) and "result" in d
    except (OSError, ValueError, RecursionError):
        return False


def _record_key(stamp: dict, name: str) -> str:
    """The key a kept vehicle's record carries: its run's stamp (the ``RUN_ONLY`` config keys aside) and name."""
    import hashlib

    core = {**stamp, "config": {k: v for k, v in stamp["config"].items() if k not in RUN_ONLY}}
    return hashlib.sha1(json.dumps([core, name], sort_keys=True, default=str).encode()).hexdigest()
