"""An earlier export as the reference of a later drive (``DataConfig.reference``; calibrate's and fleet's
``--reference``).

A drive is checked against a reference: by default the vehicle's calibration tables (a simulated vehicle's factory
calibration, ``sim_vehicle.json``). Once a knocked radar has been recalibrated and exported (``hybrid-calib export``:
``OUT/export.json`` beside the new ``calibrated_sensor.json``), a later drive of that vehicle must be checked against
the exported mount, not against tables that still hold the mount before the knock (every later drive read
"differs ...: recalibrate"). ``load_export_reference`` reads that export.json: per exported vehicle the camera
record the export read (``camera``) and the radar record it wrote (``after``), so the reference

    T_cam_radar = inv(camera) @ after      (the exported extrinsic exactly)
    T_ego_radar = after                     (the radar mount monitor's reference yaw)

Vehicles are matched by name (a log's vehicle; a simulated root's ``sim-veh-NNN``). A vehicle the export did not
replace (its tables were kept: within tolerance, undecided, not trusted) or does not name keeps its tables as its
reference, and ``source`` says which for each vehicle. Exports written before the ``camera`` field existed are
refused by name: export again. Where the export recorded the radar mount monitor's Doppler level against the mount it
wrote (``doppler``), ``source`` carries it: a later drive's own level is compared with it, drive against drive
(``calib.drift.turned_since_export``).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.data.mounts import mount_offset, same_calibration
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import se3_inverse

EXPORT_SCHEMA = "hybrid-calib/mount-export/v1"  # export.json's "schema" (``calib.export``)

# a mount farther than this from the vehicle's tables is no radar mount: an estimate there went astray
# (``calib.pipeline.trust_reason``), an export record there was edited. R2 starts lie up to 20 deg / 1.5 m per axis
# from the truth, but the truth lies near the tables (a knock: a few degrees; the nuScenes fleet's radar mounts differ
# by under 2 deg); measured (probe 10): a 3-frame highway drive's oracle solve from an R1 start ended 64 deg / 6.8 m
# off with 27 % of its rows fitting, status "weak", verdict "recalibrate", and export wrote the radar 5.3 m under the
# ground
ASTRAY_ROT_DEG = 25.0
ASTRAY_TRANS_M = 2.0


@dataclass(frozen=True)
class ExportReference:
    """What ``load_export_reference`` read from one export.json."""

    path: Path  # the export.json read (absolute)
    sha256: str  # of its bytes: a result records it, and export refuses a reference changed since
    data: str  # the root it was exported from, and its version
    version: str
    mounts: dict[str, tuple[np.ndarray, np.ndarray]] = field(repr=False, default_factory=dict)  # vehicle ->
    # (T_ego_cam, T_ego_radar), each (4, 4): the camera record the export read and the radar record it wrote
    kept: dict[str, str] = field(default_factory=dict)  # vehicle -> why the export kept its tables (its "why")
    # vehicle -> {"level_deg", "std_deg", ...}: the radar's yaw on the vehicle against the written mount, its Doppler
    # against the ego poses on the drive the export came from (``calib.drift.turned_since_export``), where recorded
    doppler: dict[str, dict] = field(default_factory=dict)
    # (vehicle, radar record token) -> (T_ego_cam, T_ego_radar) of each record the export wrote: a vehicle whose
    # logs' tables define its frame differently has one exported mount per log (probe 139)
    records: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = field(repr=False, default_factory=dict)

    def mounts_at(self, vehicle: str, radar_record: str | None) -> tuple[np.ndarray, np.ndarray] | None:
        """(T_ego_cam, T_ego_radar) the export wrote for ``vehicle`` at a frame whose radar calibrated_sensor record
        is ``radar_record``: that record's own when the export wrote it, else the vehicle's first; None when the
        export did not replace the vehicle's mount."""
        if vehicle not in self.mounts:
            return None
        return self.records.get((vehicle, str(radar_record)), self.mounts[vehicle])

    def T_cam_radar(self, vehicle: str) -> np.ndarray | None:
        """(4, 4) the exported extrinsic of ``vehicle``, or None when the export did not replace its mount."""
        m = self.mounts.get(vehicle)
        return None if m is None else se3_inverse(m[0]) @ m[1]

    def source(self, vehicle: str) -> dict:
        """What ``vehicle`` is checked against, as a result records it (``drift["reference"]``): {"kind": "export",
        "path", "sha256", "from": "ROOT (VERSION)"} for an exported vehicle, else {"kind": "tables", "why"}."""
        if vehicle in self.mounts:
            return {"kind": "export", "path": str(self.path), "sha256": self.sha256,
                    "from": f"{self.data} ({self.version})",
                    **({"doppler": self.doppler[vehicle]} if vehicle in self.doppler else {})}
        why = self.kept.get(vehicle)
        return {"kind": "tables", "why": (f"the export {self.path} kept its tables ({why[:200]})" if why else
                                          f"the export {self.path} does not name it")}


def reference_words(source: dict | None) -> str:
    """A result's reference (``ExportReference.source``; None: an older result, the tables) in a few words: "tables"
    or "the export PATH"."""
    if isinstance(source, dict) and source.get("kind") == "export":
        return f"the export {source.get('path')}"
    return "tables"


def _export_json(path: str | Path) -> Path:
    """The export.json a ``--reference`` names, absolute and normalised: the file itself, or in the export's folder."""
    p = Path(os.path.abspath(path))
    return p / "export.json" if p.is_dir() else p


def _path_of(path: str | Path) -> Path:
    """``_export_json``, which must be a file (``DataError`` naming it otherwise)."""
    p = _export_json(path)
    if not p.is_file():
        where = "holds no export.json" if Path(path).is_dir() else "does not exist"
        raise DataError(f"--reference {path} {where}; pass the --out folder of a hybrid-calib export run (or its "
                        "export.json)", path=str(p))
    return p


def _pose(rec, what: str, path: Path, vehicle: str) -> np.ndarray:
    from hybrid_calib.data.tables import _pose as table_pose

    if not isinstance(rec, dict):
        raise DataError(f"vehicle {vehicle}: its record's {what!r} is a JSON {type(rec).__name__}, not a "
                        "{translation, rotation} object; export again", path=str(path))
    missing = [k for k in ("rotation", "translation") if k not in rec]
    if missing:  # probe 77: a KeyError was an internal error
        raise DataError(f"vehicle {vehicle}: its {what!r} record has no {' or '.join(missing)}; export again",
                        path=str(path))
    try:
        return table_pose({**rec, "token": f"{vehicle} {what}"}, path, 100.0, "a sensor mount")
    except DataError as e:
        raise DataError(f"vehicle {vehicle}: its {what!r} record does not read ({e.args[0] if e.args else e}); export "
                        "again", path=str(path)) from None


def load_export_reference(path: str | Path) -> ExportReference:
    """The export.json of ``path`` (a file, or an export's ``--out`` folder) as a reference (module doc);
    ``DataError`` naming the file (and vehicle) when it is not there, not an export, of another schema, or holds a
    record that does not read (an export of an older version without ``camera``: export again)."""
    p = _path_of(path)
    try:
        raw = p.read_bytes()
        doc = json.loads(raw.decode("utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        why = "nested too deeply" if isinstance(e, RecursionError) else f"{type(e).__name__}: {str(e)[:200]}"
        raise DataError(f"--reference: export unreadable ({why}); pass the export.json of a hybrid-calib export run",
                        path=str(p)) from None
    if not isinstance(doc, dict) or doc.get("schema") != EXPORT_SCHEMA:
        found = doc.get("schema") if isinstance(doc, dict) else None
        raise DataError(f"--reference: not a hybrid-calib export (its schema is {str(found)[:60]!r}, not "
                        f"{EXPORT_SCHEMA!r}); pass the export.json of a hybrid-calib export run", path=str(p))
    vehicles = doc.get("vehicles")
    if not isinstance(vehicles, dict):
        raise DataError("--reference: the export's 'vehicles' is not an object of vehicle -> entry; export again",
                        path=str(p))
    mounts: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    kept: dict[str, str] = {}
    doppler: dict[str, dict] = {}
    by_record: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}
    for name, entry in vehicles.items():
        if not isinstance(entry, dict):
            raise DataError(f"--reference: vehicle {name}'s entry is not an object; export again", path=str(p))
        records = entry.get("records")
        if not isinstance(entry.get("exported"), bool):  # probe 76: "true" read as kept, its why saying exported
            raise DataError(f"--reference: vehicle {name}'s 'exported' is {str(entry.get('exported'))[:40]!r}, not "
                            "true or false; export again", path=str(p))
        if entry.get("exported") is not True:
            kept[name] = str(entry.get("why", ""))
            continue
        if not isinstance(records, list) or not records:
            raise DataError(f"--reference: vehicle {name} is marked exported with no record; export again",
                            path=str(p))
        pairs = []
        for rec in records:
            if not isinstance(rec, dict) or "camera" not in rec:
                raise DataError(f"--reference: vehicle {name}'s exported record names no camera mount (an export "
                                "written before hybrid-calib recorded it): export again with this version",
                                path=str(p))
            pairs.append((_pose(rec["camera"], "camera", p, name), _pose(rec.get("after"), "after", p, name)))
            if isinstance(rec.get("token"), str):
                by_record[(name, rec["token"])] = pairs[-1]
            if not isinstance(rec.get("before"), dict):  # probe 150: without it the check below was skipped, and
                # an 'after' turned 40 or 180 deg was the reference, the words blaming the vehicle's tables
                raise DataError(f"--reference: vehicle {name}'s exported record holds no 'before' (the record it "
                                "replaced, which its 'after' is checked against): the file was edited or damaged; "
                                "export again", path=str(p))
            # probe 109: a mount 3 m or 180 deg off read, and the words blamed the vehicle's tables
            deg, cm = mount_offset(pairs[-1][1], _pose(rec["before"], "before", p, name))
            if not (deg <= ASTRAY_ROT_DEG and cm <= 100 * ASTRAY_TRANS_M):
                raise DataError(f"--reference: vehicle {name}'s exported radar mount ('after') is {deg:.1f} deg / "
                                f"{cm:.0f} cm from the record it replaced ('before'), farther than any radar "
                                f"mount sits from its tables ({ASTRAY_ROT_DEG:g} deg, {ASTRAY_TRANS_M:g} m): the "
                                "file was edited or damaged; export again", path=str(p))
        Ts = [se3_inverse(c) @ r for c, r in pairs]
        for T in Ts[1:]:
            if not same_calibration(T, Ts[0]):
                raise DataError(f"--reference: vehicle {name}'s exported records hold {len(Ts)} radar-camera "
                                "extrinsics that differ: one reference per vehicle; export it again", path=str(p))
        mounts[name] = pairs[0]
        if (dop := entry.get("doppler")) is not None:
            level, std = (dop.get("level_deg"), dop.get("std_deg")) if isinstance(dop, dict) else (None, None)
            # a level is a yaw on the vehicle (a radar does not sit half a turn off its mount), its std of a few
            # hundredths of a degree: 1e9 silenced the test, 370 read "turned by 369.99 deg" (probe 78)
            if not (_number(level) and _number(std) and abs(level) <= 90 and 0 < std <= 10):
                raise DataError(f"--reference: vehicle {name}'s 'doppler' record is {str(dop)[:80]}, not "
                                "{level_deg: a yaw within 90 deg, std_deg: in (0, 10] deg}; export again",
                                path=str(p))
            doppler[name] = {**dop, "level_deg": float(level), "std_deg": float(std)}
    # what the export was computed from, as it says it (probe 150: an edited null read "from None")
    data, version = (doc.get(k) if isinstance(doc.get(k), str) and doc.get(k) else "an unnamed root" if k == "data"
                     else "an unnamed version" for k in ("data", "version"))
    return ExportReference(p, hashlib.sha256(raw).hexdigest(), data, version, mounts, kept, doppler, by_record)


def _number(x) -> bool:
    """A finite JSON number (not a bool, not a string)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and bool(np.isfinite(x))


def absolute_reference(path: str) -> str:
    """A config's ``reference`` as one absolute, normalised path of the export.json ("" stays ""): a run resumed,
    reused or reported from another folder reads the same export, and the folder and its export.json, or a path
    through "..", are one reference (probe 76: each was "another run")."""
    return str(_export_json(path)) if path else ""


def reference_identity(path: str) -> dict:
    """``{"reference_sha256": digest}`` of the export a config's ``reference`` names (``{}`` for none): what a result
    depends on beyond its config, so that an export replaced at the same path is not taken for the one an earlier
    result was checked against (``DataError`` when it does not read)."""
    return {"reference_sha256": load_export_reference(path).sha256} if path else {}


# the calibrator's sentences name the reference "its tables"; against an earlier export (this module) the mount
# compared with is the exported one: the words say so (session 38 left "its tables" there, only the first line, the
# page's "Checked against" and the fleet summary saying what it meant). Longest phrases first.
EXPORT_NOUNS = (("its mount in the tables", "its exported mount"), ("as its tables say", "as the export says"),
                ("its tables'", "the exported mount's"),
                ("its tables", "the exported mount"))


def reference_nouns(text: str, source: dict | None) -> str:
    """``text`` with the reference named as ``source`` (a result's ``drift["reference"]``) is: unchanged against the
    tables, "its tables" turned into the exported mount (``EXPORT_NOUNS``) against an export."""
    if not isinstance(source, dict) or source.get("kind") != "export" or not isinstance(text, str):
        return text
    for tables, export in EXPORT_NOUNS:
        text = text.replace(tables, export)
    return text
