"""Radar sweep loading: one PCD with NaN handling and filters, or several accumulated into one frame.

Multi-sweep accumulation follows the radar sample_data ``prev`` pointers and moves each older
sweep into the newest sweep's radar frame through the ego poses (docs/conventions.md):
``T_radar(t0)_radar(tk) = inv(T_ego_radar(t0)) inv(T_global_ego(t0)) T_global_ego(tk) T_ego_radar(tk)``.
Sweep records whose files are absent (the nuScenes mini / keyframe-only releases) are reported
back to the caller, which warns once; they are not errors.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.data.files import check_regular_file
from hybrid_calib.data.filters import MAX_RANGE_M, RadarFilterConfig, filter_radar, finite_mask
from hybrid_calib.data.pcd import read_radar_pcd
from hybrid_calib.data.tables import NuScenesTables
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import se3_inverse

_VELOCITY_PAIRS = (("vx", "vy"), ("vx_comp", "vy_comp"))
_FILTER_OPTION = {"invalid_state": "invalid_states", "dyn_prop": "dynprop_states", "ambig_state": "ambig_states"}
AT_SENSOR_M = 0.01  # a radar point this close to the sensor is no reflector (the ARS 408 sees from ~0.2 m)


@dataclass
class RadarSweeps:
    """Radar points of one frame (filtered, finite), in the newest sweep's radar frame.

    points: (N,) structured array with every PCD field; x, y, z (metres) and the velocity fields
      (m/s) of older sweeps are expressed in the newest radar frame.
    rows: (N,) int64 row indices into the newest PCD (single sweep only, else None).
    sweep_index: (N,) int16, 0 = newest sweep, k = k sweeps earlier.
    dt_s: (N,) float32 seconds, newest timestamp minus the point's sweep timestamp (>= 0).
    """

    points: np.ndarray
    rows: np.ndarray | None
    sweep_index: np.ndarray
    dt_s: np.ndarray
    n_raw: int = 0  # points in the read files before filtering
    n_nonfinite: int = 0  # points dropped because x, y or z was NaN/inf (or beyond filters.MAX_RANGE_M)
    sweep_tokens: list[str] = field(default_factory=list)  # sample_data tokens used, newest first
    missing_paths: list[str] = field(default_factory=list)  # earlier sweep files absent on disk


# a radar file with more than this fraction of its points NaN/inf (or beyond MAX_RANGE_M) is corrupt, not a sweep
# with a few bad points dropped: nuScenes' and the simulator's files hold none (probe 80: half of a real sweep NaN was
# read as a good frame, and moved pure's answer by 2.8 deg, with no word in calibrate)
NONFINITE_CORRUPT_FRACTION = 0.1


def load_filtered_sweep(path: Path, conf: RadarFilterConfig, token: str) -> tuple[np.ndarray, np.ndarray, int, int]:
    """One radar PCD -> (points kept (K,) structured, rows kept (K,) int64, n_raw, n_nonfinite).

    ``DataError`` (naming the file and token) for an unreadable file, a PCD without x/y/z or the
    fields a filter needs, or a sweep more than ``NONFINITE_CORRUPT_FRACTION`` of whose points are NaN.
    """
    raw = read_radar_pcd(path)
    names = raw.dtype.names or ()
    missing = [n for n in ("x", "y", "z") if n not in names]
    if missing:
        raise DataError(f"radar PCD lacks field(s) {missing}; it is not a nuScenes radar file", path=str(path),
                        token=token)
    for name in names:
        kind = raw.dtype[name]
        if (name in ("x", "y", "z") and kind.kind != "f") or (name in _FILTER_OPTION and kind.shape):
            what = "float (TYPE F) values with COUNT 1" if name in ("x", "y", "z") else "one value (COUNT 1)"
            raise DataError(f"radar PCD field {name!r} holds {kind.base}{list(kind.shape) or ''} per point, expected "
                            f"{what}; the header does not describe a nuScenes radar file, re-export it",
                            path=str(path), token=token)
    try:
        rows, n_nonfinite = filter_radar(raw, conf)
    except KeyError as e:
        fields, options = list(e.args), [_FILTER_OPTION[f] for f in e.args]
        one = len(fields) == 1
        sets = " ".join(f"radar_filter.{o}=null" for o in options)
        data_sets = " ".join(f"data.radar_filter.{o}=null" for o in options)
        raise DataError(f"radar PCD lacks field{'' if one else 's'} {', '.join(map(repr, fields))} needed by the radar "
                        f"filter{'' if one else 's'}; disable {'that filter' if one else 'those filters'} "
                        f"({sets}: --set {sets} in inspect, --set {data_sets} with the network methods of calibrate, "
                        "fleet and compare)", path=str(path), token=token) from None
    if len(raw) and n_nonfinite == len(raw):
        raise DataError(f"all {len(raw)} radar points have NaN/inf coordinates (or lie beyond {MAX_RANGE_M:g} m); "
                        "the file is corrupt, re-export it",
                        path=str(path), token=token)
    # a byte-swapped body reads as points beyond MAX_RANGE_M (dropped above) and points at the sensor itself (1e-8 m):
    # nearly every point implausible, with a few left to be "the sweep"
    at_sensor = np.hypot(raw["x"].astype(np.float64), raw["y"].astype(np.float64)) < AT_SENSOR_M
    if len(raw) >= 3 and np.mean(at_sensor | ~finite_mask(raw)) > 0.9 and at_sensor.any():
        raise DataError(f"{int(at_sensor.sum())} of the {len(raw)} radar points lie at the sensor itself (within "
                        f"{100 * AT_SENSOR_M:g} cm) and {n_nonfinite} are NaN or beyond {MAX_RANGE_M:g} m: the file is "
                        "byte-swapped or corrupt, re-export it", path=str(path), token=token)
    if len(raw) and n_nonfinite > NONFINITE_CORRUPT_FRACTION * len(raw):
        raise DataError(f"{n_nonfinite} of the {len(raw)} radar points have NaN/inf coordinates (or lie beyond "
                        f"{MAX_RANGE_M:g} m), "
                        f"more than {100 * NONFINITE_CORRUPT_FRACTION:g} %: the file is corrupt (a radar writes none), "
                        "re-export it", path=str(path), token=token)
    return raw[rows], rows, len(raw), n_nonfinite


def accumulate_radar(tables: NuScenesTables, sd: dict, nsweeps: int, conf: RadarFilterConfig) -> RadarSweeps:
    """The radar points of sample_data ``sd`` plus up to ``nsweeps - 1`` earlier sweeps.

    The newest sweep's file must exist (``DataError`` otherwise); earlier sweeps whose files are
    absent are listed in ``missing_paths`` and skipped.
    """
    if nsweeps < 1:
        raise ValueError(f"nsweeps must be >= 1, got {nsweeps}")
    path0 = tables.file(sd)
    pts0, rows0, n_raw, n_nan = load_filtered_sweep(path0, conf, sd["token"])
    out = RadarSweeps(points=pts0, rows=rows0, sweep_index=np.zeros(len(pts0), np.int16),
                      dt_s=np.zeros(len(pts0), np.float32), n_raw=n_raw, n_nonfinite=n_nan,
                      sweep_tokens=[sd["token"]])
    if nsweeps == 1:
        return out
    T_radar0_global = se3_inverse(tables.T_global_ego(sd) @ tables.T_ego_sensor(sd))
    parts, sweep_idx, dts = [pts0], [out.sweep_index], [out.dt_s]
    prev_token = sd["prev"]
    for k in range(1, nsweeps):
        if not prev_token:
            break
        prev = tables.get("sample_data", prev_token, f"sample_data {sd['token']} (prev pointer)")
        prev_token = prev["prev"]
        path = tables.file(prev)
        if not path.is_file():
            out.missing_paths.append(str(path))
            continue
        pts, _, n_raw_k, n_nan_k = load_filtered_sweep(path, conf, prev["token"])
        T = T_radar0_global @ tables.T_global_ego(prev) @ tables.T_ego_sensor(prev)
        pts = _transform_structured(pts, T)
        parts.append(pts)
        sweep_idx.append(np.full(len(pts), k, np.int16))
        dts.append(np.full(len(pts), (sd["timestamp"] - prev["timestamp"]) * 1e-6, np.float32))
        out.n_raw += n_raw_k
        out.n_nonfinite += n_nan_k
        out.sweep_tokens.append(prev["token"])
    if len(parts) > 1:
        out.points = np.concatenate(parts)
        out.rows = None
        out.sweep_index = np.concatenate(sweep_idx)
        out.dt_s = np.concatenate(dts)
    return out


@dataclass(frozen=True)
class InterSweep:
    """One non-keyframe radar sweep, in its own radar frame (not moved): what the Doppler needs of it.

    points: (N, 3) metres, filtered and finite; fields: per-point PCD fields (N,) each (``vx``, ``vy`` m/s);
    T_global_ego: (4, 4) the ego pose at its timestamp (its sample_data's ego_pose). ``why`` is set (and
    ``points`` empty) when its file could not be read: the sweep is then named but carries nothing."""

    token: str
    timestamp_us: int | None  # None: a record that could not be resolved (a broken ``prev`` pointer)
    T_global_ego: np.ndarray
    points: np.ndarray
    fields: dict
    why: str = ""

    @classmethod
    def unreadable(cls, token: str, timestamp_us: int | None, why: str) -> InterSweep:
        """A sweep named with why it carries nothing (no pose, no points)."""
        return cls(token, timestamp_us, np.full((4, 4), np.nan), np.zeros((0, 3)), {}, f"sweep unreadable: {why}")


def _walk_between(tables: NuScenesTables, sd: dict, limit: int):
    """Yield ``(token, record, error)`` for the non-keyframe sweeps before ``sd``, newest first, back to the
    previous keyframe of its channel, the scene's start or ``limit`` records; a ``prev`` pointer that does not
    resolve, or that comes back to a record already walked (a cycle) or to one not older than the record pointing
    at it, is yielded once with ``record`` None and its ``DataError``, and ends the walk."""
    token, newer, seen = sd.get("prev", ""), sd, {sd.get("token")}
    for _ in range(limit):
        if not token:
            return
        try:
            rec = tables.get("sample_data", token, f"sample_data {newer['token']} (prev pointer)")
            if token in seen or not _older(rec, newer):
                why = "comes back to a record already walked (a cycle)" if token in seen else \
                    f"points at a record not older than it ({rec.get('timestamp')} >= {newer.get('timestamp')} us)"
                raise DataError(f"sample_data {newer['token']}: its prev pointer {why}; the sweeps before it are not "
                                "used: fix or re-extract the tables", path=str(tables.path("sample_data")), token=token)
        except DataError as e:
            yield token, None, e
            return
        if rec.get("is_key_frame", False):
            return
        seen.add(token)
        yield token, rec, None
        token, newer = rec.get("prev", ""), rec


def records_between(tables: NuScenesTables, sd: dict, limit: int = 20) -> list[dict]:
    """The ``sample_data`` records of ``sd``'s channel between its previous keyframe and ``sd`` (neither included),
    oldest first, whether or not their files are on disk (a mini copy lists them without ``sweeps/``); the walk ends
    at a broken ``prev`` pointer (``sweeps_between_keyframes`` says it)."""
    return [rec for _, rec, err in _walk_between(tables, sd, limit) if err is None][::-1]


def _older(rec: dict, newer: dict) -> bool:
    """Whether ``rec``'s timestamp is before ``newer``'s (True when either is not a number: said elsewhere)."""
    a, b = rec.get("timestamp"), newer.get("timestamp")
    if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (a, b)):
        return True
    return a < b


def sweep_files_between(tables: NuScenesTables, sd: dict, limit: int = 20) -> tuple[int, int, int, int, str]:
    """(the non-keyframe sweep records between the previous keyframe and ``sd``, how many of their files are on
    disk, how many further records are broken (a ``prev`` pointer that does not resolve, a file name outside the
    root), how many of the files on disk do not read as radar PCDs, the first of those with why, or ""): what
    ``inspect`` reports (probe 23: a truncated and an empty sweep were counted on disk, ready to pair)."""
    from hybrid_calib.data.pcd import read_radar_pcd

    records = on_disk = broken = unreadable = 0
    first = ""
    for _, rec, err in _walk_between(tables, sd, limit):
        if err is not None:
            return records, on_disk, broken + 1, unreadable, first
        try:
            path = tables.file(rec)
        except DataError:
            broken += 1
            continue
        records += 1
        if path.is_file():
            on_disk += 1
            try:
                read_radar_pcd(path)
            except (DataError, OSError, ValueError) as e:
                unreadable += 1
                first = first or str(e)
    return records, on_disk, broken, unreadable, first


def sweeps_between_keyframes(tables: NuScenesTables, sd: dict, conf: RadarFilterConfig, limit: int = 20
                             ) -> tuple[list[InterSweep], list[Path]]:
    """(the non-keyframe sweeps between the previous keyframe of ``sd``'s channel and ``sd``, oldest first;
    the files of those the tables list and the disk lacks). Follows the ``prev`` pointers until a keyframe, the scene's
    start or ``limit`` sweeps (nuScenes' RADAR_FRONT: 6-7 per 0.5 s interval). Absent files (keyframe-only
    releases such as a mini copy without ``sweeps/``) are counted, not errors; a file that exists but does
    not read as a radar PCD, or a record whose file name or ego pose is broken, comes back with ``why`` (the
    caller skips it in words), and so does a path that is there but is not a file (a directory). A ``prev``
    pointer that does not resolve ends the walk with such an entry, its time unknown (``timestamp_us`` None): the
    sweeps after it are kept, one bad record never stops a drive."""
    out, missing = [], []
    for token, rec, err in _walk_between(tables, sd, limit):
        if err is not None:
            out.append(InterSweep.unreadable(token, None, str(err)))
            break
        try:
            path = tables.file(rec)
            if not path.exists():
                missing.append(path)
                continue
            check_regular_file(path, "radar sweep file", rec["token"])
            pose = tables.T_global_ego(rec)
            pts, _, _, _ = load_filtered_sweep(path, conf, rec["token"])
        except DataError as e:
            out.append(InterSweep.unreadable(rec["token"], int(rec["timestamp"]), str(e)))
            continue
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
        out.append(InterSweep(rec["token"], int(rec["timestamp"]), pose, xyz,
                              {n: pts[n] for n in pts.dtype.names or ()}))
    return out[::-1], missing


def _transform_structured(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Move a structured radar array's x, y, z (and velocity vectors, z velocity taken as 0) by T."""
    out = points.copy()
    xyz = np.stack([points["x"], points["y"], points["z"]], axis=1).astype(np.float64)
    moved = xyz @ T[:3, :3].T + T[:3, 3]
    for i, n in enumerate(("x", "y", "z")):
        out[n] = moved[:, i]
    names = points.dtype.names or ()
    for vx, vy in _VELOCITY_PAIRS:
        if vx in names and vy in names:
            v = np.stack([points[vx], points[vy], np.zeros(len(points))], axis=1).astype(np.float64)
            vr = v @ T[:3, :3].T
            out[vx], out[vy] = vr[:, 0], vr[:, 1]
    return out
