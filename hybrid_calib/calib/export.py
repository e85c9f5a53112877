"""The calibrated radar mounts written back as nuScenes tables (``export_mounts``; ``hybrid-calib export``).

A calibration measures the radar against the camera (``T_cam_radar``). Each exported vehicle's radar records
of ``calibrated_sensor.json`` are rewritten as ``T_ego_radar = T_ego_cam @ T_cam_radar`` with the camera's mount
from the same tables, taken as exact: radar-camera data cannot tell a moved camera from a moved radar (where the
radar mount monitor reads the radar at its tables' yaw, the drift verdict says the camera side is the likelier
cause: ``calib.drift.camera_side_note``; export.json repeats that sentence). Every sample_data of those records,
keyframes and sweeps, then reads the calibrated mount; every other record is written as it was.

Per camera axis (``calib.drift``'s test against the reference, ``AXIS_WORDS``): where it decides ("differs" or
"within": the estimate is known to better than the tolerance) the estimate's offset is written; where it does not
("undecided"; prior-pinned: the vertical offset and the pitch on most drives, which the data do not observe; or
dominated by a fleet prior) the reference's value is kept, since an estimate that cannot tell the tolerance apart
would only replace it with a noisier number. The reference is the one the verdict used
(``NuScenesRadarCamera.reference_T_cam_radar``): the tables, or on a simulated root the factory calibration of
``sim_vehicle.json`` (its ``calibrated_sensor`` holds the simulator's truth), or the mount an earlier export wrote
when the calibration was run against it (``--reference``; read again here, and refused when it has changed since).
Each replaced record in ``export.json``: ``before`` (the record as the root holds it: on a simulated root the
simulator's truth), ``reference`` (the reference mount, ``T_ego_cam T_ref``), ``after``, ``change`` (after against
``reference``, as the verdict) and ``camera`` (the camera record the radar's was written against: a later drive
checked against this export, ``data.reference``, reads its extrinsic as inv(camera) after). ``std_ego`` is the
estimate's 1-sigma in ego axes: along the camera axes the record keeps (``tables_kept``) it is not the written
value's; ``std_camera`` says per camera axis whether the record holds the estimate (with its 1-sigma) or the
reference's value (std None: the tables' own, unknown here).

Which vehicles (``which``):
- ``"recalibrate"`` (the default): those whose verdict against the tables is "recalibrate" (``calib.drift``: the
  estimate differs from them beyond the tolerance, with confidence). A mount within tolerance, or one the data
  cannot decide, keeps its tables: a new record would only replace them with a noisier number.
- ``"trusted"``: every vehicle whose estimate can be trusted.
A vehicle calibrated against an earlier export (``--reference``) whose own estimate is not written (its verdict
kept the reference, or it is not trusted) carries that export's mount into the new table (``carried``, ``own_why``):
the new export is the whole calibration a later drive is checked against.
Never exported: an untrusted estimate (``calib.covariance.untrusted_status``: not converged, out of the network's
domain, degenerate); a vehicle whose radar records hold more than one calibration along its drive (one estimate
cannot stand for both), or are shared with another vehicle, or are paired with camera mounts that differ; a result
computed from other data (its ``data_stamp.json``; without one, another recorded root); a vehicle whose verdict
names the camera side as the likelier cause (its radar's Doppler agrees with its tables). Each is said, with why,
in ``export.json``.

Outputs (``MountExport.save``): ``OUT/calibrated_sensor.json`` (the root's table, exported records replaced) and
``OUT/export.json`` (per vehicle: exported or why not, the records before and after, the estimate's 1-sigma in
ego axes). Copy the table into a copy of the root's version folder to use it; the root itself is never written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.calib.covariance import status_kind
from hybrid_calib.calib.drift import AXIS_WORDS, MAX_MOVE_M, pinned_conflict_words
from hybrid_calib.calib.mount_monitor import told_steps
from hybrid_calib.data.reference import EXPORT_SCHEMA as SCHEMA
from hybrid_calib.errors import DataError, OptionError

WHICH = ("recalibrate", "trusted")


@dataclass
class MountExport:
    """What ``export_mounts`` did: the new table's records and one entry per vehicle of the results."""

    data: str
    version: str
    which: str
    results: list[str]
    table: list[dict] = field(repr=False, default_factory=list)  # calibrated_sensor.json, exported records replaced
    vehicles: dict[str, dict] = field(default_factory=dict)  # name -> {"exported", "why", "records", "std_ego", ...}
    notes: list[str] = field(default_factory=list)

    @property
    def exported(self) -> list[str]:
        return sorted(n for n, v in self.vehicles.items() if v["exported"])

    def to_dict(self) -> dict:
        return {"schema": SCHEMA, "data": self.data, "version": self.version, "which": self.which,
                "results": self.results, "camera_mounts": "the tables' camera records, taken as exact",
                "exported": self.exported, "vehicles": self.vehicles, "notes": self.notes}

    def save(self, out: str | Path) -> tuple[Path, Path]:
        """Write ``out/calibrated_sensor.json`` and ``out/export.json`` (each atomically); their paths. An earlier
        export.json goes first: a run killed between the two leaves a table without its export.json (said by its
        absence), never a new table beside the old run's export.json; one that fails writing export.json (a full
        disk) removes the table it wrote, so that its rerun starts clean (probe 84: the next run took the table
        left alone for a copy of a root's and refused)."""
        from hybrid_calib.config import save_json_atomic

        out = Path(out)
        (out / "export.json").unlink(missing_ok=True)
        table = save_json_atomic(out / "calibrated_sensor.json", self.table)
        try:
            return table, save_json_atomic(out / "export.json", self.to_dict())
        except BaseException:
            table.unlink(missing_ok=True)
            raise


def _std_ego(T_ego_radar: np.ndarray, cov: np.ndarray) -> dict:
    """The 1-sigma of a right-perturbation covariance (6, 6) [rad, m] of the radar's pose, about and along the ego
    axes: {"rot_x_ego_deg", ..., "t_z_ego_cm"}. The perturbation is the radar frame's, the same for ``T_cam_radar``
    and ``T_ego_radar``, so ``report_std`` of the radar in the ego frame turns it to ego axes."""
    from hybrid_calib.calib.covariance import report_std
    from hybrid_calib.metrics import std_dict

    return std_dict(report_std(T_ego_radar, cov), "ego")


def _std_camera(T_est: np.ndarray, cov: np.ndarray, kept: list[int]) -> dict:
    """Per camera axis (``AXIS_WORDS``): what the exported record holds there and its 1-sigma, {word: {"written":
    "estimate" | "tables", "std": deg or cm | None}}. Along a kept axis the record holds the tables' value, whose
    uncertainty is the tables' own (unknown here): its std is None, never the estimate's."""
    from hybrid_calib.calib.covariance import report_std

    std = report_std(T_est, cov)
    return {w: {"written": "tables" if i in kept else "estimate", "std": None if i in kept else float(std[i]),
                "unit": "deg" if i < 3 else "cm"} for i, w in enumerate(AXIS_WORDS)}


def _change(T_new: np.ndarray, T_old: np.ndarray) -> dict:
    """How far a new radar record is from the old one: rotation angle [deg], translation [cm], in ego axes."""
    from hybrid_calib.data.mounts import mount_offset

    rot_deg, trans_cm = mount_offset(T_new, T_old)
    return {"rot_deg": rot_deg, "trans_cm": trans_cm,
            "t_ego_cm": [float(v) for v in 100 * (T_new[:3, 3] - T_old[:3, 3])]}


def _record(T: np.ndarray) -> dict:
    from hybrid_calib.geometry import pose_to_nuscenes

    rotation, translation = pose_to_nuscenes(T)
    return {"translation": translation, "rotation": rotation}


def _kept_axes(vr) -> list[int]:
    """The camera axes (``calib.drift.AXIS_WORDS`` order) along which the tables are kept: those the result's
    per-axis test against the tables leaves undecided (its 3-sigma straddles the tolerance: the estimate is too
    uncertain to replace them), calls prior-pinned (the data do not observe them), or a fleet prior dominates
    (``calib.drift.prior_note``: the estimate restates the prior). Along the others (decision "differs" or
    "within") the estimate is measured to better than the tolerance, and it is written."""
    axes = (vr.drift or {}).get("axes") or {}
    dominated = set(((vr.drift or {}).get("prior") or {}).get("dominated") or ())  # a fleet prior's, not measured
    return [i for i, word in enumerate(AXIS_WORDS) if word in dominated
            or (a := axes.get(word) or {}).get("prior_pinned") or a.get("decision") not in ("differs", "within")]


def _keep_axes(T_ref: np.ndarray, T_est: np.ndarray, kept: list[int]) -> np.ndarray:
    """``T_est`` (4, 4, ``T_cam_radar``) with its offset from ``T_ref`` along the camera axes ``kept`` removed: the
    offset as every change is reported (``calib.covariance.camera_offset``: the rotation ``R_ref w`` and the
    translation ``t - t_ref``, camera axes), those components set to zero, and the rest applied to ``T_ref``, so that
    the record holds the estimate's own value along every axis it writes. (Masking the SE(3) tangent instead leaked
    the kept pitch times the kept vertical offset into the written translation through Exp's V(w): probe 54, a
    longitudinal offset written 0.24 cm from the tables where the estimate's is 0.05 cm.) ``T_est`` itself when
    nothing is kept."""
    from hybrid_calib.calib.covariance import camera_offset
    from hybrid_calib.geometry import so3_exp

    if not kept:
        return T_est
    d = camera_offset(T_ref, T_est)
    d[kept] = 0.0
    T = np.eye(4)
    T[:3, :3] = so3_exp(np.radians(d[:3])) @ np.asarray(T_ref, np.float64)[:3, :3]
    T[:3, 3] = np.asarray(T_ref, np.float64)[:3, 3] + d[3:] / 100.0
    return T


def _carry(exp: MountExport, name: str, T_ref: np.ndarray, doppler: dict | None, vr, M_level: np.ndarray | None,
           toks: list[str], pairs: dict, users: dict, index: dict, ds, frame_of: dict) -> None:
    """A vehicle checked against an earlier export (``--reference``) and not exported with its own estimate: its
    records get that export's mount (``T_ego_cam T_ref``), marked ``carried``, so that this export is the whole
    calibration a later drive is checked against (probe 76: a drive unmoved since export 1 exported nothing, and the
    drive after it, checked against export 2, fell back to the tables from before the knock: "recalibrate"). Not
    where its records are shared with another vehicle, or paired with camera mounts that differ."""
    from hybrid_calib.data.mounts import same_calibration

    entry = exp.vehicles[name]
    if entry["exported"] or not toks or any(users[tok] - {name} for tok in toks):
        return
    carried, tables = [], []
    for tok in toks:
        cams = sorted(pairs[(name, tok)])
        T_cams = [ds.tables.T_ego_sensor({"token": f"(frames of {name})", "calibrated_sensor_token": c})
                  for c in cams]
        if any(not same_calibration(T, T_cams[0]) for T in T_cams[1:]):
            return
        carried.append((tok, T_cams[0]))
        tables.append(ds.reference_T_cam_radar(frame_of[(name, tok)]))
    if any(not same_calibration(T, tables[0]) for T in tables[1:]):  # a mount change in the tables: one mount
        entry["why"] += ("; the reference export's mount is not carried: its tables hold more than one radar-camera "
                         "calibration along the drive")  # cannot stand for both (probe 77)
        return
    src = entry.get("reference") or {}
    for tok, T_cam in carried:
        before = {k: exp.table[index[tok]][k] for k in ("translation", "rotation")}
        T_new = T_cam @ T_ref
        exp.table[index[tok]] = {**exp.table[index[tok]], **_record(T_new)}
        entry["records"].append({"token": tok, "before": before, "reference": _record(T_new), "after": _record(T_new),
                                 "change": _change(T_new, T_new), "change_from": "reference", "camera": _record(T_cam)})
    # the Doppler level against that mount: as the earlier export recorded it (the mount is the same), else this
    # drive's (``vr``: a drive that did not read a turn since), turned onto the written record
    doppler = doppler or (None if vr is None else _doppler_record(vr, carried[0][1] @ T_ref, M_level))
    if doppler:
        entry["doppler"] = doppler
    entry.update(exported=True, carried=True, own_why=entry["why"],
                 why=f"carried: {len(carried)} radar record(s) hold the mount of the export its verdict compared "
                     f"with ({src.get('path', '--reference')}), unchanged; its own estimate was not written "
                     f"({entry['why']})")


def _turned(T_cam_radar: np.ndarray, T_ego_cam: np.ndarray, delta_deg: float) -> np.ndarray:
    """(4, 4) ``T_cam_radar`` with its radar turned by ``delta_deg`` (left positive) about the vehicle's up axis at
    the radar (the radar mount monitor's yaw; its position kept), the camera at ``T_ego_cam``."""
    from scipy.spatial.transform import Rotation

    from hybrid_calib.geometry import se3_inverse

    T = T_ego_cam @ T_cam_radar  # a new array
    T[:3, :3] = Rotation.from_euler("z", delta_deg, degrees=True).as_matrix() @ T[:3, :3]
    return se3_inverse(T_ego_cam) @ T


def _doppler_record(vr, T_written: np.ndarray, M_ref: np.ndarray) -> dict | None:
    """The radar mount monitor's level of the mount at the drive's end (``current_level``), turned from the mount
    it was measured against (``M_ref`` (4, 4), the run's reference radar mount) to the written one (``T_written``):
    the radar's yaw on the vehicle minus the written mount's, by its Doppler against the ego poses [deg]. A later
    drive checked against this export compares its own level with it (``calib.drift.turned_since_export``); None
    without such a level."""
    from scipy.spatial.transform import Rotation

    from hybrid_calib.calib.mount_monitor import current_level

    lv = current_level(getattr(vr, "mount", None))  # the mount at the drive's end: what is written
    if lv is None:
        return None
    level, std = float(lv.get("level_deg", np.nan)), float(lv.get("std_deg", np.nan))
    turn = float(np.degrees(Rotation.from_matrix(T_written[:3, :3] @ M_ref[:3, :3].T).as_rotvec()[2]))  # ego z
    if not (np.isfinite(level) and np.isfinite(std)):
        return None
    return {"level_deg": level - turn, "std_deg": std, "pairs": int(lv.get("pairs", 0)),
            "of": "the radar's yaw on the vehicle minus the written mount's (its Doppler against the ego poses), deg"}


def _doppler_doubt(doppler: dict | None, std_camera: dict, kept: list[int], turn) -> str:
    """Words for an exported entry whose written yaw (its 1-sigma ``std_camera["yaw"]``) its radar's Doppler level
    (``_doppler_record``, with ``LEVEL_BIAS_DEG``) puts more than 2 of their combined 1-sigma away, "" otherwise (a yaw
    kept from the tables, or the Doppler's own turn written). Probe 129: a mount 1.39 deg off in yaw was written
    beside a Doppler record 1.37 +- 0.06 deg from it, and nothing said."""
    from hybrid_calib.calib.mount_monitor import doppler_std

    yaw = std_camera.get("yaw") or {}
    if not doppler or turn is not None or AXIS_WORDS.index("yaw") in kept or not isinstance(yaw.get("std"),
                                                                                          (int, float)):
        return ""
    level, sd = float(doppler["level_deg"]), doppler_std(doppler["std_deg"])
    z = abs(level) / max(float(np.hypot(sd, float(yaw["std"]))), 1e-12)
    if z <= 2.0:
        return ""
    return (f"; but the radar's own Doppler against the ego poses puts its yaw {level:+.2f} +- {sd:.2f} deg (1 sigma, "
            f"with its bias) from the written yaw, {z:.1f} of their combined 1-sigma: check the radar's yaw before "
            "using this record")


def _read_reference(src: dict, cache: dict) -> tuple[object, str]:
    """The earlier export a result's ``drift.reference`` names (``src``), read again once per path (``cache``: path
    -> (``data.reference.ExportReference`` or None, why)): (it, "") when it is the file the calibration read (its
    sha256), else (None, why not), for the kept axes and the change must be of the verdict's reference."""
    from hybrid_calib.data.reference import load_export_reference

    path = str(src.get("path"))
    if path not in cache:
        try:
            ref = load_export_reference(path)
        except DataError as e:
            cache[path] = (None, f"the export its verdict compared with (--reference {path}) does not read now ({e}); "
                                 "restore it, or calibrate again")
        else:
            cache[path] = (ref, "") if ref.sha256 == src.get("sha256") else (
                None, f"the export its verdict compared with ({ref.path}) has been replaced since the calibration; "
                      "calibrate again against the export as it is now")
    return cache[path]


def _used_references(found: dict, cache: dict) -> dict:
    """path -> ``data.reference.ExportReference`` of each earlier export the results' verdicts compared with
    (``drift.reference``; ``_read_reference``); one that no longer reads, or has changed since, is left out (its
    vehicles' entries say why)."""
    out = {}
    for _, vr in found.values():
        src = (vr.drift or {}).get("reference") or {}
        if src.get("kind") == "export" and (ref := _read_reference(src, cache)[0]) is not None:
            out[str(src.get("path"))] = ref
    return out


def _export_reference(vr, name: str, cache: dict):
    """(the earlier export the result's verdict compared with, ``data.reference.ExportReference`` naming ``name``,
    or None for the tables; why the vehicle is not exported, or ""): ``_read_reference``."""
    src = (vr.drift or {}).get("reference")
    if not isinstance(src, dict) or src.get("kind") != "export":
        return None, ""
    ref, why = _read_reference(src, cache)
    if ref is not None and name not in ref.mounts:
        ref, why = None, (f"the export its verdict compared with ({ref.path}) has been replaced since the "
                          "calibration; calibrate again against the export as it is now")
    return ref, (f"not exported: {why}" if why else "")


def _against_export(vr) -> bool:
    """Whether ``vr``'s verdict compared with an earlier export (``--reference``), not the tables."""
    src = (vr.drift or {}).get("reference")
    return isinstance(src, dict) and src.get("kind") == "export"


def _kept(vr) -> str:
    """What ``vr``'s record keeps when its estimate is not written: the tables, or against an earlier export
    (``--reference``) that export's mount (probe 105: a chained vehicle read "kept the tables: the verdict against
    them ..." while its record held the export's mount)."""
    return "the exported mount" if _against_export(vr) else "the tables"


def _why_not(vr, which: str) -> str:
    """Why a vehicle's estimate is not exported under ``which`` ("" when it is)."""
    from hybrid_calib.calib.covariance import untrusted_status

    if why := untrusted_status(vr.final.status):
        quoted = "" if status_kind(vr.final.status) == "inconclusive" else f" ({vr.final.status.split(';')[0][:160]})"
        return f"not exported: {why}, so the estimate is no calibration{quoted}"  # inconclusive: its reason is quoted
    if getattr(vr, "method", None) == "pure":  # the network's last pass alone (calib.drift.one_pass_verdict)
        return ("not exported: one pass of the network alone (method pure) is no calibration; calibrate with --method "
                "hybrid")
    prior = (vr.drift or {}).get("prior") or {}
    if not prior.get("refused") and (prior.get("conflict") or {}).get("conflict"):  # calib.drift.with_prior
        return (f"not exported: {vr.drift['prior']['words']} (the estimate is pulled toward a prior this drive's data "
                "contradict)")
    if side := (vr.drift or {}).get("camera_side"):  # the radar did not move on the vehicle: do not move its record
        return f"not exported: {side}; writing the radar's record would move a radar its own Doppler says did not move"
    yaw = ((vr.drift or {}).get("axes") or {}).get("yaw") or {}
    mount = getattr(vr, "mount", None) or {}
    if getattr(vr, "method", None) in ("hybrid", "pure-avg") and yaw.get("decision") == "differs" and \
            not (mount.get("yaw_check") or told_steps(mount)):  # the Doppler's level, or a turn it measured
        # a learned yaw alone carries the network's bias on the input (probe 23: the real scene with the mount
        # monitor off and the domain test loosened exported a 1.97 +- 0.16 deg yaw; its Doppler read 0.93)
        return (f"not exported: the yaw differs from the tables by {abs(float(yaw.get('delta', 0.0))):.2f} deg, and "
                "the radar's own Doppler did not check it (no radar mount monitor level to compare with: "
                "mount.enabled=false, or too few sweep pairs): a learned method's yaw alone is not written; "
                "calibrate with the mount monitor on")
    kind = (vr.drift or {}).get("verdict_kind")
    if which == "recalibrate" and not kind and vr.drift:  # probe 88: read "the verdict ... is 'none'" while the
        # report derived "recalibrate" from the same block's numbers
        return (f"kept {_kept(vr)}: result.json stores no verdict against them (its drift block has no verdict_kind: "
                "written by an older hybrid-calib, or edited; `hybrid-calib report` derives one from its numbers, "
                "export writes only a verdict the calibrator stored): recompute it (calibrate --overwrite), or "
                "--which trusted writes every trusted estimate")
    if which == "recalibrate" and kind != "recalibrate":
        return (f"kept {_kept(vr)}: the verdict against {'it' if _against_export(vr) else 'them'} is "
                f"'{kind or 'none'}', not 'recalibrate' (result.json "
                "says why); --which trusted writes every trusted estimate")
    conflict = pinned_conflict_words((vr.drift or {}).get("axes") or {})
    if conflict and len(_kept_axes(vr)) < len(AXIS_WORDS):  # a record it writes would keep the tables along the
        # pinned axis the data put far from them (probe 95); where it writes nothing, the tables are kept as they were
        return (f"not exported: {conflict} (writing only the axes the data decide would keep the tables' value "
                "along those)")
    return ""


def _check_stamp(path: Path, run, root: Path, version: str) -> str:
    """"" when the result at ``path`` (``run``) was computed from the data now at ``root`` / ``version``, else why
    it is refused. Its data stamp decides (a root moved or copied elsewhere is the same data); without one, the
    root and version it records must be these (vehicle names repeat across roots: every simulated root has a
    sim-veh-000, nuScenes' n015 drives in several releases)."""
    from hybrid_calib.calib.result import DATA_STAMP, data_differ, stored_digest

    stored = stored_digest(path.parent)
    same_place = (not run.data or Path(run.data).resolve() == root.resolve()) and run.version in (None, "", version)
    if data_differ(path.parent, root, version):
        where = "" if same_place else f", on {run.data} ({run.version}), not on {root} ({version})"
        if stored is None:  # damaged (probe 109: read as no stamp, and a mount of other data was written)
            return (f"{path}: its {DATA_STAMP} is damaged, so it cannot show the data now to be those it was computed "
                    "from; restore the file, or re-run the calibration on this root")
        return (f"{path} was computed from other data{where} (its {DATA_STAMP} differs from the data now: re-run the "
                "calibration on this root, or pass the root it was computed on)")
    if not stored and not same_place:
        return (f"{path} was computed on {run.data} ({run.version}), not on {root} ({version}), and records no data "
                "stamp that would show them to be the same data: pass the root it was computed on")
    return ""


def export_mounts(results: list[str | Path], out: str | Path | None = None, data: str | Path | None = None,
                  version: str | None = None, which: str = "recalibrate",
                  vehicles: list[str] | None = None, overwrite: bool = False) -> MountExport:
    """The calibrated radar mounts of ``results`` (``result.json`` files of one root: calibrate, fleet vehicles,
    demo) as the root's ``calibrated_sensor`` table (module doc); saved to ``out`` when given. ``data`` /
    ``version``: the root (default: the one the results record); ``vehicles``: only these (default: every vehicle
    of the results). ``DataError`` / ``OptionError`` naming the file or option when nothing can be exported
    from these inputs at all; a vehicle that cannot be exported is said in its entry. An ``out`` that holds an
    export already is refused unless ``overwrite`` (one command takes every result file of one table)."""
    from hybrid_calib.calib.result import CalibrationRun, stored_digest
    from hybrid_calib.data.mounts import same_calibration
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    if which not in WHICH:
        raise OptionError("--which", f"{which!r} is not a choice; valid: {', '.join(WHICH)}")
    if not results:
        raise OptionError("RESULT", "no result file given; pass the result.json of a calibrate or fleet run")
    paths = [Path(p).absolute() for p in results]  # export.json names them wherever it was typed (probe 72)
    # a run's folder is its result.json (CalibrationRun.load reads either): its data stamp lies beside that file
    # (probe 127: a folder's stamp was looked for in its parent, "records no data stamp", and a mount computed from
    # tables edited since was written)
    paths = [p / "result.json" if p.is_dir() and (p / "result.json").is_file() else p for p in paths]
    if twice := sorted({str(p) for p in paths if paths.count(p) > 1}):  # a folder and its result.json (probe 130)
        raise OptionError("RESULT", f"{twice[0]} is given twice (as a run's folder and its result.json, or twice as "
                                    "typed): pass each result once")
    runs = [(p, CalibrationRun.load(p)) for p in paths]
    roots = {(str(Path(r.data).resolve()), r.version) for _, r in runs if r.data}
    given = data is not None
    if data is None:
        if len(roots) != 1:
            raise OptionError("--data", f"the results record {len(roots)} data roots ({sorted(roots) or 'none'}); "
                                        "export one root's results at a time (one export per root), or pass the "
                                        "root whose tables to export with --data (and --version)")
        data, recorded_version = next(iter(roots))
        version = version or recorded_version
    root = Path(data)
    version = version or runs[0][1].version
    if not (root / str(version)).is_dir():
        # a root the results record, moved since, is not a --data the user gave (probe 71)
        raise OptionError("--data", f"{root / str(version)} is not a folder: pass the nuScenes root the results "
                                    "were computed on, with --version its version folder" if given else
                                    f"the root the results record, {root / str(version)}, is not there (moved or "
                                    "removed?): pass where it is now with --data (and --version)")
    if out is not None:
        from hybrid_calib.errors import check_out_not_in_dataset

        o, vdir = Path(out).resolve(), (root / version).resolve()
        if o == vdir or vdir in o.parents:
            raise OptionError("--out", f"{out} is the root's own version folder: export never writes the root's "
                                       "tables; pass another folder and copy calibrated_sensor.json into a copy of it")
        # the root of the results (itself, its sensor folders) and any other root's (its calibrated_sensor.json)
        check_out_not_in_dataset(out, data=root, version=version)
        if (Path(out) / "export.json").is_file() and not overwrite:  # exported vehicle by vehicle, the last won
            raise OptionError("--out", f"{out} holds an export already (export.json); pass --overwrite to replace it, "
                                       "or another --out. To put several vehicles in one table, pass all their "
                                       "result files to one export command")
        if (Path(out) / "calibrated_sensor.json").exists() and not (Path(out) / "export.json").is_file() \
                and not overwrite:  # a table no export wrote: a user's copy of a root's (probe 40: replaced in silence)
            raise OptionError("--out", f"{Path(out) / 'calibrated_sensor.json'} exists and no export wrote it (no "
                                       "export.json beside it): it may be a copy of a root's table; pass another "
                                       "--out, or --overwrite to replace it")
    ds = NuScenesRadarCamera(root, version, conf={"check_images": False})
    t = ds.tables
    found: dict[str, tuple[Path, object]] = {}
    for p, run in runs:
        for name, vr in run.vehicles.items():
            if name in found:
                raise DataError(f"vehicle {name} is in two result files ({found[name][0]} and {p}); pass one of "
                                "them", path=str(p))
            found[name] = (p, vr)
    if vehicles:
        failed = {n for _, run in runs for n in run.vehicles_failed}
        if unknown := sorted(set(vehicles) - set(found) - failed):
            raise OptionError("--vehicle", f"{', '.join(unknown)} not in the results; they hold "
                                           f"{', '.join(sorted(found))}"
                                           + (f" (and failed: {', '.join(sorted(failed))})" if failed else ""))
        if asked_failed := sorted(set(vehicles) & failed - set(found)):  # probe 40: "holds no calibrated vehicle"
            reasons = {n: why for _, run in runs for n, why in run.vehicles_failed.items()}
            raise DataError(f"vehicle {', '.join(asked_failed)} failed in the run, nothing to export for it ("
                            f"{reasons[asked_failed[0]]}); calibrated there: {', '.join(sorted(found)) or 'none'}",
                            path=str(paths[0]))
        found = {n: found[n] for n in vehicles if n in found}
    if not found:
        raise DataError(f"{', '.join(map(str, paths))} hold{'s' if len(paths) == 1 else ''} no calibrated vehicle: "
                        "nothing to export (a failed vehicle is listed under vehicles_failed)", path=str(paths[0]))
    stale = {p: why for p, run in runs if (why := _check_stamp(p, run, root, version))}
    unstamped = sorted(str(p) for p in {p for p, _ in found.values()} if p not in stale and not stored_digest(p.parent))
    # the radar and camera calibrated_sensor records of every vehicle's frames
    radar_of: dict[str, set[str]] = {}
    pairs: dict[tuple[str, str], set[str]] = {}  # (vehicle, radar record) -> camera records
    frame_of: dict[tuple[str, str], object] = {}  # (vehicle, radar record) -> its first frame
    for ref in ds.frames:
        r, c = ref.radar_sd["calibrated_sensor_token"], ref.camera_sd["calibrated_sensor_token"]
        radar_of.setdefault(ref.vehicle, set()).add(r)
        pairs.setdefault((ref.vehicle, r), set()).add(c)
        frame_of.setdefault((ref.vehicle, r), ref)
    users: dict[str, set[str]] = {}
    for v, toks in radar_of.items():
        for tok in toks:
            users.setdefault(tok, set()).add(v)
    exp = MountExport(str(root), version, which, [str(p) for p in paths],
                      table=[dict(rec) for rec in t.records["calibrated_sensor"]])
    index = {rec["token"]: i for i, rec in enumerate(exp.table)}
    read: dict[str, tuple] = {}  # each reference export read once (_read_reference)
    carry: dict[str, tuple] = {}  # vehicle -> (the reference export's T_cam_radar its verdict compared with, its
    # Doppler record or None, the result whose level may stand for it or None, the radar mount the level is against)
    for name, (p, vr) in sorted(found.items()):
        entry = {"result": str(p), "status": vr.final.status, "verdict": (vr.drift or {}).get("verdict"),
                 "exported": False, "why": "", "records": [], "std_ego": None}
        exp.vehicles[name] = entry
        if ((vr.drift or {}).get("reference") or {}).get("kind") == "export":
            entry["reference"] = vr.drift["reference"]
        # an earlier export the verdict compared with (--reference): read again first, a changed one refused whatever
        # the verdict (probe 76: the default --which said only "kept the tables" for one edited since)
        ref_obj, ref_why = (None, "") if p in stale else _export_reference(vr, name, read)
        exported_ref = None if ref_obj is None else ref_obj.T_cam_radar(name)
        why = (f"not exported: {stale[p]}" if p in stale else "") or ref_why or _why_not(vr, which)
        if ref_obj is not None:  # the earlier export's Doppler record, else this drive's (against the same mount)
            own = vr if (vr.drift or {}).get("verdict_kind") != "recalibrate" else None  # unless it turned since
            carry[name] = (exported_ref, ref_obj.doppler.get(name), own, ref_obj.mounts[name][1])
        toks = sorted(radar_of.get(name, ()))
        if not why and not toks:
            skips = ds.skipped  # the index's own problems (a record that does not resolve drops its frames)
            why = (f"not exported: no frame of {root} ({version}) is of vehicle {name}"
                   + (f" (the root's index skipped {len(skips)} item(s); first: {skips[0].reason[:200]})" if skips
                      else "") + "; pass the root it was calibrated on, or fix its tables")
        if not why and (shared := sorted({u for tok in toks for u in users[tok]} - {name})):
            why = (f"not exported: its radar records are shared with vehicle(s) {', '.join(shared)} of the root; one "
                   "record cannot hold two vehicles' mounts")
        if why:
            entry["why"] = why
            continue
        T_est = np.asarray(vr.final.T, np.float64)
        kept = _kept_axes(vr)
        # a turn since the earlier export that its Doppler decided (calib.drift.with_turn_since_export) where the
        # estimate keeps the yaw: the export's mount turned by it about the vehicle's up axis (probe 78: the reference
        # was carried unchanged, and every later drive read "recalibrate" again)
        turn = (vr.drift or {}).get("since_export") or {}
        turn = turn if turn.get("beyond") and ref_obj is not None and AXIS_WORDS.index("yaw") in kept else None
        if not (vr.drift or {}).get("axes"):  # an older result: no per-axis test to say what was measured
            entry["why"] = ("not exported: the result holds no per-axis test against the tables (written by an older "
                            "version): calibrate again to export it")
            continue
        if len(kept) == len(AXIS_WORDS) and turn is None:  # the record would be the tables' own
            entry["why"] = (f"kept {_kept(vr)}: the data decide no axis against the tolerance (each is undecided "
                            "or prior-pinned), so there is nothing measured to write")
            if (vr.drift or {}).get("at_end"):  # "recalibrate" for a step the mount monitor measured in the drive
                # probe 123: that later drive read "cannot tell" too (a 1 deg turn, the hybrid's yaw std 0.3 deg) and
                # export "kept the tables": the advice led nowhere without saying what decides
                entry["why"] = ("not exported: the radar turned on the vehicle during the drive (its verdict: "
                                "recalibrate), but the estimate after the turn decides no axis against the tolerance "
                                "yet (too few frames since the turn); calibrate a drive recorded after it and export "
                                "that: a turn the estimate's yaw cannot decide there (the hybrid's: from ~1.5 deg) "
                                "stays 'cannot tell' and keeps the tables; then measure the radar's mount (its Doppler "
                                "level on that drive, in result.json's mount block, says how far it turned) or "
                                "recalibrate it with a target")
            continue
        new: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
        refs = []  # the reference T_cam_radar per record: one calibration along the drive
        for tok in toks:
            cams = sorted(pairs[(name, tok)])
            T_cams = [t.T_ego_sensor({"token": f"(frames of {name})", "calibrated_sensor_token": c}) for c in cams]
            if any(not same_calibration(T, T_cams[0]) for T in T_cams[1:]):
                why = (f"not exported: its radar record {tok} is paired with {len(cams)} camera mounts that differ "
                       "(the camera was re-mounted along the drive); one radar record cannot fit both")
                break
            # kept axes: the reference the verdict compared against (the tables; a simulated root's factory
            # calibration, sim_vehicle.json, since its calibrated_sensor holds the simulator's truth)
            # (or the earlier export the run was given: --reference)
            T_tables = ds.reference_T_cam_radar(frame_of[(name, tok)])
            T_ref = T_tables if exported_ref is None else exported_ref
            if turn is not None:  # its Doppler's turn since the export, about the vehicle's up axis at the radar
                T_ref = _turned(T_ref, T_cams[0], float(turn["delta_deg"]))
            if not new:  # the mount the radar mount monitor measured against (the reference's radar record)
                M_ref = ds.reference_T_ego_radar(frame_of[(name, tok)]) if ref_obj is None else \
                    ref_obj.mounts[name][1]
            # the change is measured from the reference too (the tables' own record on a real root; on a simulated
            # one its factory calibration, as the verdict: the record there holds the truth)
            new.append((tok, T_cams[0] @ T_ref, T_cams[0] @ _keep_axes(T_ref, T_est, kept), T_cams[0]))
            refs.append(T_tables)  # the tables' own, with --reference too (probe 77: the guard below never fired)
        # judged on the reference, as the verdict: a simulated root's records hold the simulator's truth, and a
        # knocked radar's (--extrinsic-change step) was refused as "a mount change" the user's tables do not hold,
        # where a real fleet's one record is exported (probe 50)
        if not why and any(not same_calibration(T, refs[0]) for T in refs[1:]):
            why = ("not exported: its tables hold more than one radar-camera calibration along the drive (a mount "
                   "change); the estimate stands for the drive's end only")
        moves = [_change(T_new, T_base)["trans_cm"] for _, T_base, T_new, _ in new]
        if not why and moves and max(moves) > 100 * MAX_MOVE_M:
            # probe 23: the cascade on the real scene, its domain test loosened, wrote a radar 97.4 cm from its tables
            # with a lateral 1-sigma of 0.96 cm; a radar does not travel that far on its bracket
            base, wrong = (("the exported mount", "the export is") if _against_export(vr) else  # moves from it (p107)
                           ("its tables", "the tables are"))
            why = (f"not exported: it would move the radar {max(moves):.1f} cm from {base}, farther than a radar "
                   f"moves on its bracket ({100 * MAX_MOVE_M:g} cm): the estimate or {wrong} wrong; check both "
                   "(a drive of other scenes, the LiDAR's and the Doppler's offsets in result.json) before writing one")
        if why:
            entry["why"] = why
            continue
        for tok, T_base, T_new, T_cam in new:
            before = {k: exp.table[index[tok]][k] for k in ("translation", "rotation")}
            exp.table[index[tok]] = {**exp.table[index[tok]], **_record(T_new)}
            # "change" is after vs "reference" (what the verdict compared with), not vs "before" (the record as the
            # root held it: on a simulated root the simulator's truth; probe 24 read before -> after 1.75 cm beside a
            # change of 0.02 cm)
            entry["records"].append({"token": tok, "before": before, "reference": _record(T_base),
                                     "after": _record(T_new), "change": _change(T_new, T_base),
                                     "change_from": "reference",
                                     # the camera record the radar's was written against: a later drive's reference
                                     # extrinsic is inv(camera) after (data.reference, --reference)
                                     "camera": _record(T_cam)})
        cov = np.asarray(vr.final.cov, np.float64)
        if doppler := _doppler_record(vr, new[0][2], M_ref):
            entry["doppler"] = doppler
        if turn is not None:
            entry["doppler_turn"] = {"delta_deg": float(turn["delta_deg"]), "std_deg": float(turn["std_deg"])}
            kept = [i for i in kept if AXIS_WORDS[i] != "yaw"]  # written: the Doppler's, with its own std
        std_camera = _std_camera(T_est, cov, kept)
        if turn is not None:
            std_camera["yaw"] = {"written": "doppler", "std": float(turn["std_deg"]), "unit": "deg"}
        owner = "the exported mount's" if _against_export(vr) else "the tables'"  # what a kept axis holds (probe 106)
        doubt = _doppler_doubt(entry.get("doppler"), std_camera, kept, turn)
        entry.update(exported=True, std_ego=_std_ego(new[0][2], cov), std_camera=std_camera,
                     tables_kept=[AXIS_WORDS[i] for i in kept],
                     why=f"exported: {len(new)} radar record(s) replaced" + (
                         f" ({owner} {', '.join(AXIS_WORDS[i] for i in kept)} kept: the data do not decide "
                         f"{'it' if len(kept) == 1 else 'them'} against the tolerance)"
                         if kept else "") + (
                         f"; its yaw: the earlier export's turned by {float(turn['delta_deg']):+.2f} +- "
                         f"{float(turn['std_deg']):.2f} deg (1 sigma, left positive) about the vehicle's up axis, "
                         "the radar's turn since that export by its Doppler" if turn is not None else "") + doubt)
    for p, run in runs:  # a vehicle whose calibration failed is named, not dropped
        for name, reason in sorted(run.vehicles_failed.items()):
            if (not vehicles or name in vehicles) and name not in exp.vehicles:
                exp.vehicles[name] = {"result": str(p), "status": None, "verdict": None, "exported": False,
                                      "why": f"not exported: its calibration failed ({str(reason)[:300]})",
                                      "records": [], "std_ego": None}
    # a vehicle of the earlier export(s) these results were checked against (--reference) whose own estimate is not
    # written here (kept, untrusted, failed, or not among the results: probe 77) carries that export's mount
    used = _used_references(found, read)
    for name in sorted(set(carry) | {n for r in used.values() for n in r.mounts}):
        if vehicles and name not in vehicles:
            continue
        Ts = [carry[name]] if name in carry else [(r.T_cam_radar(name), r.doppler.get(name), None, None)
                                                  for r in used.values() if name in r.mounts]
        if any(not same_calibration(T, Ts[0][0]) for T, _ in Ts[1:]):
            exp.notes.append(f"vehicle {name}: the reference exports of these results hold different mounts for it: "
                             "none is carried")
            continue
        if name not in exp.vehicles:
            if name not in radar_of:
                exp.notes.append(f"vehicle {name} of the reference export ({', '.join(sorted(map(str, used)))}) has no "
                                 f"frame in {root} ({version}): its mount is not carried into this table")
                continue
            exp.vehicles[name] = {"result": None, "status": None, "verdict": None, "exported": False,
                                  "why": "not among the results", "records": [], "std_ego": None,
                                  "reference": next(r.source(name) for r in used.values() if name in r.mounts)}
        _carry(exp, name, *Ts[0], sorted(radar_of.get(name, ())), pairs, users, index, ds, frame_of)
    if unstamped:  # a fleet vehicle's result (its stamp is in the fleet's manifest) or an older run's
        exp.notes.append(f"{', '.join(unstamped)} record{'s' if len(unstamped) == 1 else ''} no data stamp beside "
                         "it (data_stamp.json): not checked against the data as they are now")
    if ds.sim_vehicles and exp.exported:  # probe 50: copied into a root as said, it replaced the truth in silence
        exp.notes.append("a simulated root: its calibrated_sensor.json holds the simulator's truth (and the records "
                         "not exported still do), while the verdicts compared with each vehicle's factory calibration "
                         "(sim_vehicle.json; or the earlier export a run was given with --reference); a copy of "
                         "the root with this table measures its errors against the "
                         "exported mounts, not the truth, and keeps the same reference for its verdicts")
    if out is not None:
        exp.save(out)
    return exp
