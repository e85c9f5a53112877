"""nuScenes JSON tables: loading, indexing and token resolution.

Decision: hybrid-calib reads the JSON tables directly instead of using ``nuscenes-devkit``.

- The devkit cannot share an environment with this package: ``nuscenes-devkit==1.2.0`` (the
  current release, checked 2026-11) requires ``numpy<2.0.0`` while hybrid-calib pins
  ``numpy>=2,<2.5`` (torch 2.13, gtsam 4.3). Older devkit releases required ``opencv-python``,
  which installs the same ``cv2`` module as the ``opencv-python-headless`` build we pin (1.2.0
  moved to the headless build, so that clash is gone, the numpy one is not).
- It pulls dependencies we do not use (shapely, scikit-learn, pycocotools, descartes, fire) and
  loads all 13 tables eagerly, including the largest (annotations), and asserts that every map
  mask PNG exists, so partial copies without ``maps/`` (like the shared one-scene root) fail to
  open at all.
- We need seven tables (scene, sample, sample_data, calibrated_sensor, sensor, ego_pose, log),
  the sample -> per-channel sample_data reverse index, and errors that name the table file or
  the token that is wrong: a few hundred lines.

Compatibility with the devkit is checked out of band by ``examples/check_with_devkit.py``.

Formats follow the public nuScenes schema: every table is ``ROOT/VERSION/<name>.json``, a JSON
list of records, each a dict with a unique ``token``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable
from pathlib import Path, PurePosixPath

import numpy as np

from hybrid_calib.config import is_number
from hybrid_calib.errors import DataError, unencodable_words
from hybrid_calib.geometry import pose_from_nuscenes

# the per-sensor tables (millions of records on v1.0-trainval, most of channels never read): a record of them that
# does not follow the schema is left out and said, not a refusal of the root (probe 80: a null timestamp on one
# CAM_BACK_LEFT sweep record refused the whole root); the small tables stay strict
SIM_VERSION = "v1.0-sim"  # the version folder the simulator writes and the commands' default --version
LENIENT_TABLES = ("sample_data", "ego_pose")

# The tables the data layer needs, with the fields it reads from each record.
REQUIRED_TABLES: dict[str, tuple[str, ...]] = {
    "scene": ("token", "log_token", "first_sample_token", "name"),
    "sample": ("token", "timestamp", "scene_token"),
    "sample_data": ("token", "sample_token", "ego_pose_token", "calibrated_sensor_token", "timestamp",
                    "filename", "is_key_frame", "prev", "next"),
    "calibrated_sensor": ("token", "sensor_token", "translation", "rotation", "camera_intrinsic"),
    "sensor": ("token", "channel", "modality"),
    "ego_pose": ("token", "timestamp", "rotation", "translation"),
    "log": ("token", "vehicle"),
}


def available_versions(root: str | Path) -> list[str]:
    """Names of the folders under ``root`` that hold a ``sample.json`` table (the nuScenes versions)."""
    root = Path(root)
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if p.is_dir() and (p / "sample.json").is_file())


def version_name(version) -> str | None:
    """The version folder's name ``version`` gives ("v1.0-mini", and what tab completion types: "v1.0-mini/",
    "./v1.0-mini"), or None when it is a path (absolute, "..", a backslash) or no name at all."""
    if not isinstance(version, str) or "\\" in version or PurePosixPath(version).is_absolute():
        return None
    parts = PurePosixPath(version).parts
    return parts[0] if len(parts) == 1 and parts[0] != ".." else None


def version_dir(root: str | Path, version: str, fix: str = "pass one of them with --version") -> Path:
    """``ROOT/VERSION`` after checking that it exists. ``DataError`` lists the versions that do and says
    ``fix`` (where the caller's version came from)."""
    root = Path(root)
    if not root.is_dir():
        if words := unencodable_words(root):
            raise DataError(f"nuScenes root cannot be opened{words}", path=str(root))
        what = "is not a directory" if root.exists() else "does not exist"
        raise DataError(f"nuScenes root {what}; pass the folder that holds the version folder "
                        "(e.g. v1.0-mini) and samples/", path=str(root))
    # probe 101: an absolute --version read another root's tables with this root's files; "v1.0-mini/" (what tab
    # completion types) and "./v1.0-mini" name the folder itself (probe 102)
    if version_name(version) is None:
        name = PurePosixPath(version.replace("\\", "/")).name if isinstance(version, str) else ""
        raise DataError(f"version {version!r} is not a folder name: --version names the version folder under the "
                        f"root (e.g. v1.0-mini), not a path" + (f"; pass --version {name}" if name and name not in
                                                                 (".", "..", version) else "")
                        + " (and the folder that holds it as --data)", path=str(root))
    vdir = root / version
    if not vdir.is_dir() and (root / "sim_config.json").is_file() and not available_versions(root):
        raise DataError(f"version folder {version!r} does not exist under the nuScenes root; no version folder found "
                        "there, but sim_config.json is: an unfinished simulation (simulate writes the tables when "
                        "every frame is rendered); rerun the simulate command that made it to finish it",
                        path=str(vdir))
    if not vdir.is_dir():
        found = available_versions(root)
        hint = f"versions found there: {found}" if found else "no version folder (with sample.json) found there"
        if not found and (root / "sample.json").is_file():  # --data names the version folder itself
            hint += (f"; {root} is itself a version folder (it holds sample.json): pass its parent {root.parent} as "
                     f"the root, with --version {root.name}")
        elif not found and (below := [f"{c.name}/{v}" for c in sorted(root.iterdir()) if c.is_dir()
                                      for v in available_versions(c)][:3]):  # --data one level too high
            hint += f"; a folder below holds one ({', '.join(below)}): pass that folder as the root"
        # "pass one of them" only when there is one to pass (probe 23: it said so beside "no version folder found")
        todo = fix if found else "" if ";" in hint else ("pass the nuScenes root: the folder that holds the version "
                                                          "folder (e.g. v1.0-mini) and samples/")
        raise DataError(f"version folder {version!r} does not exist under the nuScenes root; {hint}"
                        + (f"; {todo}" if todo else ""), path=str(vdir))
    if not any((vdir / f"{name}.json").is_file() for name in REQUIRED_TABLES):
        found = [v for v in available_versions(root) if (root / v).resolve() != vdir.resolve()]
        hint = f"versions found there: {found}" if found else "no version folder (with sample.json) found there"
        if inner := available_versions(vdir):  # the archive's layout: ROOT/v1.0-mini/{samples, v1.0-mini/*.json}
            raise DataError(f"{vdir} holds the version folder {inner[0]} itself (the nuScenes archive unpacks so: the "
                            f"folder holding samples/ and {inner[0]}/ is the root): pass --data {vdir}",
                            path=str(vdir))
        raise DataError(f"{vdir} holds none of the nuScenes tables {sorted(REQUIRED_TABLES)}, so it is not a version "
                        f"folder (an empty or unfinished extraction, or the version names another folder); {hint}; "
                        + (f"{fix}, or extract" if found else "extract") + " the metadata archive there",
                        path=str(vdir))
    return vdir


def _missing_table(name: str, path: Path) -> DataError:
    return DataError(f"table {name!r} is missing; a nuScenes version folder needs the tables "
                     f"{sorted(REQUIRED_TABLES)}; re-extract the dataset's metadata archive", path=str(path))


def require_tables(root: str | Path, version: str) -> Path:
    """``ROOT/VERSION`` (``version_dir``) after checking that each of ``REQUIRED_TABLES`` is there, without reading
    one: ``DataError`` naming the first missing table, as loading it would. A run says this before anything it checks
    against the root's files (probe 124: the trainval metadata without its sample tables read "--depth: ... has no
    LiDAR files; pass another --depth", and every --depth another --depth error)."""
    vdir = version_dir(root, version)
    for name in REQUIRED_TABLES:
        if not (path := vdir / f"{name}.json").exists():
            raise _missing_table(name, path)
    return vdir


def load_table(vdir: Path, name: str, required_fields: Iterable[str] = ("token",),
               bad: list | None = None) -> list[dict]:
    """``vdir/<name>.json`` -> list of records, checked for the fields the data layer reads.

    Raises ``DataError`` naming the file when it is missing, not JSON, not a list of objects, or a
    record lacks a required field. With ``bad`` (a list), a record that fails the field checks is left out and
    recorded there as ``(token or None, reason, the record)`` instead, unless every record fails (the table is then
    not a nuScenes table): one bad record of a channel never read must not stop a whole root (probe 80).
    """
    path = Path(vdir) / f"{name}.json"
    if path.exists() and not path.is_file():  # a FIFO, a device, a folder: said as what it is (probe 27)
        from hybrid_calib.data.files import check_regular_file

        check_regular_file(path, f"table {name!r}")
    if not path.is_file():
        raise _missing_table(name, path)
    try:
        with open(path, encoding="utf-8-sig") as f:  # a UTF-8 byte order mark (some editors write one) is read past
            text = f.read()
        records = json.loads(text)
        # a lone UTF-16 surrogate escape ("\ud800") decodes to a str no file name or output can encode: an internal
        # error where it was printed or used as a path (probe 108); its records are checked one by one below
        lone = _has_lone_surrogate(text)
        del text
    except json.JSONDecodeError as e:
        raise DataError(f"table {name!r} is not valid JSON ({e.msg} at line {e.lineno} column {e.colno}); "
                        "the file is corrupt or truncated, re-extract it", path=str(path)) from None
    except (OSError, UnicodeDecodeError) as e:
        raise DataError(f"cannot read table {name!r}: {e}", path=str(path)) from None
    except RecursionError:
        raise DataError(f"table {name!r} nests JSON too deeply to read; it is not a nuScenes table, re-extract it",
                        path=str(path)) from None
    if not isinstance(records, list):
        raise DataError(f"table {name!r} must be a JSON list of records, found {type(records).__name__}",
                        path=str(path))
    required = tuple(required_fields)
    # the fast path of a record that is right, in C-level calls (a trainval table holds millions: probe 101 spent 16
    # of 29 s here); JSON decodes to exact types, so ``type(v) is int`` also refuses a bool
    need = frozenset(required)
    typed = tuple(k for k in required if _field_kind(k) is not None)
    types = tuple(_field_kind(k) for k in typed)
    named = "filename" in need  # a NUL in a file name stopped the whole root at the first frame (probe 108)
    names = tuple(k for k in _NAME_FIELDS if k in need)  # the small tables' names (printed in every line of a run)
    kept, errors = [], []
    for i, rec in enumerate(records):
        if (type(rec) is dict and rec.keys() >= need and tuple(map(type, map(rec.__getitem__, typed))) == types
                and not (named and "\x00" in rec["filename"]) and not (lone and _unencodable(rec))
                and not (names and any(_CONTROL.search(rec[k]) for k in names))):
            kept.append(rec)
            continue
        try:
            _check_record(name, i, rec, required, path)
        except DataError as e:
            if bad is None:
                raise
            errors.append((e, rec))
            continue
        kept.append(rec)
    if errors and not kept:  # every record: not a nuScenes table (or another schema), said by its first
        raise errors[0][0]
    for e, rec in errors:
        bad.append((e.token, f"{e.message}; the record is not used", rec))
    return kept


def _check_record(name: str, i: int, rec, required: tuple[str, ...], path: Path) -> None:
    """``DataError`` naming the table, the record's index and token and the field when record ``i`` is not an
    object holding each ``required`` field with its JSON type (``_field_kind``)."""
    if not isinstance(rec, dict):
        raise DataError(f"table {name!r} record {i} is {type(rec).__name__}, expected an object", path=str(path))
    missing = [k for k in required if k not in rec]
    if missing:
        raise DataError(f"table {name!r} record {i} lacks field(s) {missing}; the table does not follow "
                        "the nuScenes schema", path=str(path), token=_token(rec))
    for k in required:
        kind = _field_kind(k)
        if kind is not None and not _is_kind(rec[k], kind):
            raise DataError(f"table {name!r} record {i} field {k!r} is {rec[k]!r} ({type(rec[k]).__name__}), "
                            f"expected {kind.__name__}; the table does not follow the nuScenes schema: fix or "
                            "re-extract it", path=str(path), token=_token(rec) if k != "token" else None)
    if (key := _unencodable(rec)) is not None:
        raise DataError(f"table {name!r} record {i} field {key!r} holds a lone UTF-16 surrogate escape (\\ud800 .. "
                        "\\udfff), which is not Unicode text; fix or re-extract the table", path=str(path),
                        token=_token(rec) if key != "token" else None)
    for k in (k for k in _NAME_FIELDS if k in required):
        if _CONTROL.search(rec[k]):
            raise DataError(f"table {name!r} record {i} field {k!r} is {rec[k]!r}: it holds a control character (a "
                            "newline, a tab, a text-direction override, ...), which no name in the tables has; fix or "
                            "re-extract the table",
                            path=str(path), token=_token(rec))
    if "filename" in required and "\x00" in rec["filename"]:
        raise DataError(f"table {name!r} record {i} field 'filename' is {rec['filename']!r}: it holds a NUL character, "
                        "which no file name has; fix or re-extract the table", path=str(path), token=_token(rec))


# the names a run prints in its lines (a vehicle named "car\nFAKE LINE" forged a line of output: probe 108)
_NAME_FIELDS = ("vehicle", "name", "channel")
# control characters, C0 and C1, and the text-direction marks and overrides: a name printed with U+202E reversed the
# words after it on the terminal and in the page's title (probe 112)
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069]")
_SURROGATE_ESCAPE = re.compile(r"\\u[dD][89a-fA-F]")  # a literal prefix: one fast scan of the text (probe 110)
_ESCAPES = re.compile(r"(\\+)u[dD]([89a-fA-F])[0-9a-fA-F]{2}")
_HIGH, _LOW = re.compile(r"\\u[dD][89abAB][0-9a-fA-F]{2}"), re.compile(r"\\u[dD][c-fC-F][0-9a-fA-F]{2}")


def _has_lone_surrogate(text: str) -> bool:
    """Whether JSON ``text`` holds a lone UTF-16 surrogate escape: a high one (``\\ud800`` .. ``\\udbff``) not followed
    by a low one, or a low one not preceded by a high one; an escaped backslash before "ud800" is text, not an
    escape (one such text had sent every record of a table through the slow check: 8x slower, probe 110)."""
    if _SURROGATE_ESCAPE.search(text) is None:
        return False
    for m in _ESCAPES.finditer(text):
        if len(m.group(1)) % 2 == 0:  # "\\\\ud800": a backslash, then the letters
            continue
        at = m.end(1) - 1  # the escape's backslash
        if m.group(2) in "89abAB":
            if not _LOW.match(text, m.end()):
                return True
        elif at < 6 or not _HIGH.match(text, at - 6):
            return True
    return False


def _unencodable(rec) -> str | None:
    """The first field of a record (its key) whose value, or the key itself, holds a lone surrogate; None if none."""
    if not isinstance(rec, dict):
        return None
    for k, v in rec.items():
        try:
            json.dumps([k, v], ensure_ascii=False).encode("utf-8")
        except UnicodeEncodeError:
            return k
    return None


def _within(off: tuple) -> bool:
    """Whether ``NuScenesTables._off_path``'s (metres, yaw, roll / pitch, and their allowances) is within them."""
    return all(v <= tol for v, tol in zip(off[:3], off[3:]))


def _token(rec: dict) -> str | None:
    """A record's token when it is a string (a bad one is the field the message names)."""
    tok = rec.get("token")
    return tok if isinstance(tok, str) else None


_STR_FIELDS = ("prev", "next", "filename", "channel", "modality", "vehicle", "name")


def _field_kind(field: str) -> type | None:
    """The JSON type a required field must have (None: checked where it is used, e.g. rotations)."""
    if field.endswith("token") or field in _STR_FIELDS:
        return str
    return {"timestamp": int, "is_key_frame": bool}.get(field)


def _is_kind(value, kind: type) -> bool:
    return isinstance(value, kind) and not (kind is int and isinstance(value, bool))


def sensor_channels(root: str | Path, version: str) -> list[str]:
    """Every sensor channel in ``ROOT/VERSION/sensor.json``, read alone: the whole tables of a trainval root are
    millions of records, which a question of which sensors it has need not load (``NuScenesTables.channels``)."""
    return sorted({s["channel"] for s in load_table(version_dir(root, version), "sensor", REQUIRED_TABLES["sensor"])})


class NuScenesTables:
    """The seven tables of one nuScenes version, indexed by token.

    ``get(table, token)`` resolves a token or raises ``DataError`` naming the token, the table and
    the record that referenced it. ``channel_of(sample_data)`` and ``keyframe(sample_token, channel)``
    give the reverse index the devkit builds into ``sample['data']``.
    """

    def __init__(self, root: str | Path, version: str):
        self.root = Path(root)
        self.version = version
        self.vdir = version_dir(self.root, version)
        self.records: dict[str, list[dict]] = {}
        self.by_token: dict[str, dict[str, dict]] = {}
        # table -> token -> why its record was left out (LENIENT_TABLES): ``get`` says it for a reference to it
        self.bad_records: dict[str, dict[str, str]] = {}
        self.left_out_of_sample: dict[str, list[tuple[str, str]]] = {}  # sample -> its sample_data left out, why
        self.index_problems: list[tuple[str, str]] = []  # (token, reason)
        self._poses: dict[str, np.ndarray] = {}  # ego_pose token -> its (4, 4) pose, read
        self._smooth: dict[str, DataError | None] = {}  # sample_data token -> its pose check's refusal, or None
        for name, fields in REQUIRED_TABLES.items():
            bad: list | None = [] if name in LENIENT_TABLES else None
            recs = load_table(self.vdir, name, fields, bad)
            self.records[name] = recs
            self.by_token[name] = _index_by_token(recs, self.vdir / f"{name}.json")
            for tok, why, rec in bad or ():
                if tok is not None:
                    self.bad_records.setdefault(name, {})[tok] = why
                sample = rec.get("sample_token") if isinstance(rec, dict) and name == "sample_data" and \
                    rec.get("is_key_frame") is not False else None
                if isinstance(sample, str):  # a keyframe (or maybe one): its sample then lacks it, said with why
                    self.left_out_of_sample.setdefault(sample, []).append((tok or "?", why))
            if bad:  # said once per table (a trainval table holds millions of records)
                tok, why, _ = bad[0]
                self.index_problems.append((tok or "", f"{len(bad)} record(s) of {name}.json left out, first: {why}"
                                            + ("" if len(bad) == 1 else " (the others likewise)")))
        if not self.records["sample"]:
            raise DataError("table 'sample' holds no samples, so this version folder has no frames to read; "
                            "point --data/--version at a dataset with samples (e.g. v1.0-mini)",
                            path=str(self.path("sample")))
        if not self.records["scene"]:
            raise DataError(f"table 'scene' holds no scenes, so none of the {len(self.records['sample'])} samples "
                            "belongs to a scene and there are no frames to read; the table is truncated or from "
                            "another copy: re-extract the metadata", path=str(self.path("scene")))
        # calibrated_sensor token -> sensor record (channel, modality); unresolved ones raise on use.
        self._sensor_of_cs: dict[str, dict] = {}
        for cs in self.records["calibrated_sensor"]:
            sensor = self.by_token["sensor"].get(cs["sensor_token"])
            if sensor is not None:
                self._sensor_of_cs[cs["token"]] = sensor
        self._samples_by_scene: dict[str, list[dict]] = {}
        for s in self.records["sample"]:
            self._samples_by_scene.setdefault(s["scene_token"], []).append(s)
        # (sample_token, channel) -> keyframe sample_data record; problems found on the way.
        self.keyframes: dict[tuple[str, str], dict] = {}
        for lg in self.records["log"]:  # probe 40: a blank name keyed the result "" and a fleet job "vehicles/%"
            if isinstance(lg["vehicle"], str) and not lg["vehicle"].strip():
                lg["vehicle"] = f"log-{str(lg.get('logfile') or '').strip() or lg['token']}"
                self.index_problems.append((lg["token"], (
                    f"log {lg['token']} names no vehicle (its 'vehicle' is blank): its frames are read as vehicle "
                    f"{lg['vehicle']}; fill in log.json's vehicle to name it")))
        ambiguous: dict[tuple[str, str], dict] = {}  # (sample, channel) with two keyframes -> the first one
        self.ambiguous_keyframes: dict[tuple[str, str], str] = {}  # the same -> why neither is used
        # keyframes no channel or no sample could be found for: sample token (or "" when it does not resolve) -> their
        # sample_data tokens (the sample "has no keyframe" said nothing of them: probe 40)
        self.unplaced_keyframes: dict[str, list[str]] = {}
        for sd in self.records["sample_data"]:
            if not sd["is_key_frame"]:
                continue
            sensor = self._sensor_of_cs.get(sd["calibrated_sensor_token"])
            if sd["sample_token"] not in self.by_token["sample"]:  # said once below (a partial copy has many)
                self.unplaced_keyframes.setdefault("", []).append(sd["token"])
                continue
            if sensor is None:
                self.unplaced_keyframes.setdefault(sd["sample_token"], []).append(sd["token"])
                self.index_problems.append((sd["token"], self._unresolved_cs_reason(sd)))
                continue
            key = (sd["sample_token"], sensor["channel"])
            if key in self.keyframes or key in ambiguous:  # one of them carries another sensor's calibration
                first = self.keyframes.pop(key, None) or ambiguous[key]
                ambiguous[key] = first
                swept = [str(r.get("filename", "")).startswith("sweeps/") for r in (first, sd)]
                own = [f"/{key[1]}/" in str(r.get("filename", "")) for r in (first, sd)]
                if any(swept):
                    why = ("the one under sweeps/ is a sweep marked is_key_frame (a converter that marks every "
                           "sample_data a keyframe); neither is used, set is_key_frame false on sweeps/ records")
                elif all(own):  # both the channel's files: one names another sample (probe 47: 5 s apart)
                    why = self._other_sample_reason(key[0], first, sd)
                else:
                    why = (f"the calibrated_sensor_token of the one whose file is not a {key[1]} file is wrong (it "
                           f"names the {key[1]} sensor); neither is used, fix the record")
                self.ambiguous_keyframes[key] = (f"sample {key[0]} has two {key[1]} keyframes, sample_data "
                                                 f"{first['token']} ({first.get('filename')}) and {sd['token']} "
                                                 f"({sd.get('filename')}): {why}")
                self.index_problems.append((sd["token"], self.ambiguous_keyframes[key]))
                continue
            self.keyframes[key] = sd
        if lost := self.unplaced_keyframes.get(""):
            sd = self.by_token["sample_data"][lost[0]]
            self.index_problems.append((sd["token"], (
                f"{len(lost)} keyframe sample_data record(s) reference samples not in sample.json (first: "
                f"{sd['token']}, {sd.get('filename')}, sample {sd['sample_token']}): they are no frame; the tables are "
                "inconsistent or a partial copy: re-extract the metadata")))

    def _other_sample_reason(self, sample_token: str, a: dict, b: dict) -> str:
        """Why two keyframes of one channel's own files name one sample: one record's sample_token names another
        sample; the one whose timestamp lies farther from the sample's is named."""
        t = self.by_token["sample"].get(sample_token, {}).get("timestamp")
        ta, tb = a.get("timestamp"), b.get("timestamp")
        if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in (t, ta, tb)):
            return "one record's sample_token names another sample; neither is used, fix that record"
        far = a if abs(ta - t) > abs(tb - t) else b
        return (f"one record's sample_token names another sample: sample_data {far['token']} lies "
                f"{abs(far['timestamp'] - t) / 1e6:.2f} s from the sample's timestamp ({abs(ta - tb) / 1e6:.2f} s "
                "from the other), so its sample_token is likely wrong; neither is used, fix that record")

    def _unresolved_cs_reason(self, sd: dict) -> str:
        cs = self.by_token["calibrated_sensor"].get(sd["calibrated_sensor_token"])
        if cs is None:
            return (f"sample_data {sd['token']} references calibrated_sensor {sd['calibrated_sensor_token']}, "
                    "which is not in calibrated_sensor.json; the tables are inconsistent")
        return (f"calibrated_sensor {cs['token']} references sensor {cs['sensor_token']}, which is not in "
                "sensor.json; the tables are inconsistent")

    def path(self, name: str) -> Path:
        """The file of table ``name``."""
        return self.vdir / f"{name}.json"

    def file(self, sd: dict) -> Path:
        """The data file of sample_data record ``sd``: its ``filename`` under the root. ``DataError`` naming the
        record when the filename is empty, absolute or climbs out of the root with '..' (it read a directory, or
        a file outside the dataset, as the frame's)."""
        name = sd["filename"]
        posix = PurePosixPath(name)
        problems = {"is empty": not name.strip(), "is absolute": posix.is_absolute() or Path(name).is_absolute(),
                    "leaves the root ('..')": ".." in posix.parts}
        why = next((text for text, bad in problems.items() if bad), "")
        if why:
            raise DataError(f"sample_data field 'filename' {name!r} {why}; filenames are relative to the root, e.g. "
                            "samples/CAM_FRONT/x.jpg: fix the record or re-extract the tables",
                            path=str(self.path("sample_data")), token=sd["token"])
        return self.root / name

    def get(self, table: str, token: str, referenced_by: str = "") -> dict:
        """The record of ``table`` with ``token``; ``DataError`` if it does not resolve."""
        rec = self.by_token[table].get(token)
        if rec is None and (why := self.bad_records.get(table, {}).get(token)):
            raise DataError(why + (f" (referenced by {referenced_by})" if referenced_by else ""),
                            path=str(self.path(table)), token=token)
        if rec is None:
            by = f" (referenced by {referenced_by})" if referenced_by else ""
            raise DataError(f"token does not resolve in table {table!r}{by}; the tables are inconsistent or "
                            "from different versions: re-extract the metadata", path=str(self.path(table)),
                            token=token)
        return rec

    def channels(self) -> list[str]:
        """Every sensor channel present in sensor.json (``sensor_channels``, without loading the other tables)."""
        return sorted({s["channel"] for s in self.records["sensor"]})

    def modality(self, channel: str) -> str:
        """The ``modality`` (camera / radar / lidar) sensor.json gives a channel, read in lower case ("Radar" is a
        radar); "" if it is not there; "a/b" when several records name the channel with different modalities."""
        return "/".join(sorted({str(s["modality"]).lower() for s in self.records["sensor"] if s["channel"] == channel}))

    def channel_of(self, sd: dict) -> str:
        """The sensor channel (e.g. ``RADAR_FRONT``) of a sample_data record."""
        sensor = self._sensor_of_cs.get(sd["calibrated_sensor_token"])
        if sensor is None:
            raise DataError(self._unresolved_cs_reason(sd), path=str(self.path("sample_data")), token=sd["token"])
        return sensor["channel"]

    def keyframe(self, sample_token: str, channel: str) -> dict | None:
        """The keyframe sample_data of ``channel`` in a sample, or None if the sample has none."""
        return self.keyframes.get((sample_token, channel))

    def scene_samples(self, scene: dict) -> list[dict]:
        """The samples of a scene in time order (follows ``first_sample_token`` / ``next``).

        Falls back to sorting the scene's samples by timestamp when the chain is broken, so one
        bad ``next`` pointer does not drop the rest of the scene.
        """
        chain: list[dict] = []
        token = scene["first_sample_token"]
        seen: set[str] = set()
        while token and token not in seen:
            rec = self.by_token["sample"].get(token)
            if rec is None or rec["scene_token"] != scene["token"]:
                break
            seen.add(token)
            chain.append(rec)
            token = rec.get("next", "")
        all_in_scene = self._samples_by_scene.get(scene["token"], [])
        if len(chain) == len(all_in_scene):
            return chain
        return sorted(all_in_scene, key=lambda s: s["timestamp"])

    def T_ego_sensor(self, sd: dict) -> np.ndarray:
        """(4, 4) sensor -> ego of a sample_data record (its calibrated_sensor)."""
        cs = self.get("calibrated_sensor", sd["calibrated_sensor_token"], f"sample_data {sd['token']}")
        return _pose(cs, self.path("calibrated_sensor"), MAX_MOUNT_TRANSLATION_M, "a sensor mount")

    def T_global_ego(self, sd: dict) -> np.ndarray:
        """(4, 4) ego -> global at a sample_data record's timestamp (its ego_pose). ``DataError`` naming both
        tokens when the ego pose's own timestamp is more than ``MAX_EGO_POSE_OFFSET_US`` from the record's (nuScenes
        writes them equal: a pose seconds away moved the radar's yaw from its Doppler by 3 deg, silently; probe
        27), or when it lies off the path its channel's neighbouring records' poses trace (``_check_smooth``)."""
        T = self._T_global_ego(sd)
        key = sd["token"]
        if key not in self._smooth:  # the tables do not change: each record's pose is checked once (~1 ms)
            try:
                self._check_smooth(sd, T)
                self._smooth[key] = None
            except DataError as e:
                self._smooth[key] = e
        if (e := self._smooth[key]) is not None:
            raise DataError(e.message, path=e.path, token=e.token)
        return T

    def _check_smooth(self, sd: dict, T: np.ndarray) -> None:
        """``DataError`` naming the ego_pose record when ``T`` (4, 4), ``sd``'s ego pose, lies farther from the path
        its channel's neighbouring records' poses trace (the sample_data ``prev`` and ``next`` name; ``_off_path``:
        linear in position and along the geodesic in rotation, between two records or beyond them) than the
        vehicle's motion can explain. Pairs of the records up to two away on either side are tried, interpolating
        between the sides or extrapolating from one, and at a chain's end, where one side is all there is, the pair
        two and three away (a scene's first and last records, on nuScenes its first and last keyframes: probe 81).
        A record any pair explains passes, so a neighbour that is itself off the path does not condemn a good
        record, if neither pose of that pair is itself off the path (``_borne_out``: two adjacent bad poses explained
        each other, probe 83); one refused needs two pairs that do not explain it (one alone cannot tell its error from
        the record's). Nothing is checked without them (records farther than ``POSE_NEIGHBOUR_MAX_GAP_S``, a short
        chain); a root whose tables hold keyframes only is checked with a wide allowance. Probe 80: one radar
        keyframe's pose turned by 5 deg (or moved by 1 m) passed the road-vehicle limits of a frame's pose pair,
        moved the frame's radar points by it and raised a false "the radar turned" in the mount monitor."""
        (p1, p2, p3), (n1, n2, n3) = self._along(sd, "prev", 3), self._along(sd, "next", 3)
        failed = []
        pairs = [(p1, n1), (p2, n1), (p1, n2), (p2, p1), (n1, n2)]
        # a chain's end: one side only; the pair beyond the nearest record speaks only where that record is itself off
        # the path (its wide allowance let 2.5 deg of yaw and 0.5 m pass at a channel's first record: probe 83)
        end = (n2, n3, n1) if p1 is None else (p3, p2, p1) if n1 is None else None
        pairs += [end[:2]] if end else []
        for a, b in pairs:
            off = self._off_path(a, sd, b, T)
            if off is None:
                continue
            rescue = end is not None and (a, b) == end[:2]
            if not _within(off) or (rescue and end[2] is not None and self._borne_out(end[2], sd)):
                # a pair holding a pose that is itself off the path still counts (probe 152: discounting it let two
                # adjacent bad poses at a chain's end, and every other pose of a chain 100 m off, pass); on a chain of
                # keyframes only a good record beside a bad one is then refused too, and the words say so
                failed.append((a, b, off))
            elif self._borne_out(a, sd) and self._borne_out(b, sd):
                return
        if len(failed) < 2:  # one pair alone cannot tell the record's error from its own (a short chain's end)
            return
        a, b, (metres, yaw, tilt, tol_m, tol_yaw, tol_tilt) = failed[0]
        t = sd["timestamp"]

        def when(r: dict) -> str:
            dt = (r["timestamp"] - t) / 1e3
            return f"{abs(dt):.0f} ms {'after' if dt > 0 else 'before'}"

        try:
            channel = f" ({self.channel_of(sd)}{', a keyframe' if sd.get('is_key_frame') else ''})"
        except DataError:
            channel = ""
        raise DataError(f"the ego pose of sample_data {sd['token']}{channel} lies {metres:.2f} m, {yaw:.1f} deg in yaw "
                        f"and {tilt:.1f} deg in roll / pitch from the path its neighbours' poses trace (sample_data "
                        f"{a['token']} and {b['token']} of the same channel, {when(a)} and {when(b)}; a road "
                        f"vehicle's motion explains {tol_m:.2f} m, {tol_yaw:.1f} deg and {tol_tilt:.1f} deg, and the "
                        "records around it do not explain it either): its ego_pose record is "
                        "wrong, or one of those neighbours' is (on a chain of keyframes alone, 500 ms apart, a record "
                        "beside a wrong one is refused with it: the one refused with the largest offset is the likely "
                        "culprit), or the vehicle braked or turned beyond any car: fix the record or re-extract the "
                        "tables (the record is not used)", path=str(self.path("ego_pose")),
                        token=sd.get("ego_pose_token"))

    def _along(self, rec: dict, key: str, n: int, skip: dict | None = None) -> list[dict | None]:
        """The ``n`` records of ``rec``'s channel the sample_data ``key`` ("prev" or "next") leads to in turn, nearest
        first, ``skip`` passed over; None for each beyond the chain's end."""
        by, out, seen = self.by_token["sample_data"], [], {id(rec)}
        while len(out) < n and (rec := by.get(rec.get(key) or "")) is not None and id(rec) not in seen:
            seen.add(id(rec))  # a pointer back into the chain (a corrupt table) ends it
            if rec is not skip:
                out.append(rec)
        return out + [None] * (n - len(out))

    def _borne_out(self, r: dict, skip: dict) -> bool:
        """Whether record ``r``'s own pose lies on the path of its channel's records around it (up to two on either
        side, ``skip`` left out), or none can be compared. A pair through which a record passes must hold no pose
        that is itself off the path: two adjacent poses wrong by the same amount each lay on the path through the
        other and a good record, and both passed (probe 83: up to 0.9 m, 4 deg of yaw, 7 deg of pitch)."""
        near = [x for x in self._along(r, "prev", 2, skip) + self._along(r, "next", 2, skip) if x is not None]
        try:
            T = self._T_global_ego(r)
        except DataError:
            return False
        compared = False
        for i, a in enumerate(near):
            for b in near[i + 1:]:
                off = self._off_path(a, r, b, T)
                if off is None:
                    continue
                if _within(off):
                    return True
                compared = True
        return not compared

    def _off_path(self, a: dict | None, sd: dict, b: dict | None, T: np.ndarray):
        """(metres, yaw deg, roll / pitch deg, and the three allowed): ``T`` against the pose at ``sd``'s time on the
        path through records ``a`` and ``b`` of its channel (linear in position and time, along the rotation's
        geodesic; between them, or beyond both), the rotation's error split into yaw about the vehicle's up axis and
        the rest. Allowed: the margins ``POSE_SMOOTH_MARGIN_*`` plus what an acceleration of ``MAX_EGO_ACCEL_MPS2``
        (``MAX_EGO_ROT_ACCEL_DPS2`` in rotation) moves the vehicle off a constant-rate path, |t - ta| |t - tb| / 2.
        None when they cannot be compared (a record missing, two records at one time, farther than
        ``POSE_NEIGHBOUR_MAX_GAP_S`` from ``sd``, a pose that does not read: said where that record is read)."""
        from hybrid_calib.geometry import so3_exp, so3_log

        if a is None or b is None:
            return None
        ta, t, tb = a.get("timestamp"), sd.get("timestamp"), b.get("timestamp")
        if not all(is_number(x) for x in (ta, t, tb)) or ta == tb or t in (ta, tb) or \
                max(abs(t - ta), abs(t - tb)) * 1e-6 > POSE_NEIGHBOUR_MAX_GAP_S:
            return None
        try:
            Ta, Tb = self._T_global_ego(a), self._T_global_ego(b)
        except DataError:
            return None
        s = (t - ta) / (tb - ta)
        R = Ta[:3, :3] @ so3_exp(s * so3_log(Ta[:3, :3].T @ Tb[:3, :3]))
        metres = float(np.linalg.norm((1 - s) * Ta[:3, 3] + s * Tb[:3, 3] - T[:3, 3]))
        r = np.degrees(so3_log(R.T @ T[:3, :3]))  # in the vehicle's frame: z up
        k = 0.5 * abs((t - ta) * (t - tb)) * 1e-12
        return (metres, float(abs(r[2])), float(np.hypot(r[0], r[1])), POSE_SMOOTH_MARGIN_M + MAX_EGO_ACCEL_MPS2 * k,
                POSE_SMOOTH_MARGIN_YAW_DEG + MAX_EGO_ROT_ACCEL_DPS2 * k,
                POSE_SMOOTH_MARGIN_TILT_DEG + MAX_EGO_ROT_ACCEL_DPS2 * k)

    def T_global_ego_unchecked(self, sd: dict) -> np.ndarray:
        """``T_global_ego`` without the check against the path its neighbours' poses trace: for what measures how
        the poses scatter (``data.pose_jitter``), which that check would refuse the noisiest of."""
        return self._T_global_ego(sd)

    def _T_global_ego(self, sd: dict) -> np.ndarray:
        """``T_global_ego`` without the neighbours' check."""
        ep = self.get("ego_pose", sd["ego_pose_token"], f"sample_data {sd['token']}")
        if (T := self._poses.get(ep["token"])) is None:  # read once (the pose check reads each neighbour's too)
            T = self._poses[ep["token"]] = _pose(ep, self.path("ego_pose"), MAX_EGO_TRANSLATION_M, "an ego pose")
        T = T.copy()
        a, b = ep.get("timestamp"), sd.get("timestamp")
        if is_number(a) and is_number(b) and abs(a - b) > MAX_EGO_POSE_OFFSET_US:
            raise DataError(f"the ego pose of sample_data {sd['token']} is at {a} us, {(a - b) / 1e6:+.3f} s from the "
                            f"record's own time {b} us (nuScenes writes them equal; at most "
                            f"{MAX_EGO_POSE_OFFSET_US / 1e3:g} ms): the record's ego_pose_token names another "
                            "instant's pose; fix the record or re-extract the tables", path=str(self.path("ego_pose")),
                            token=ep.get("token"))
        return T

    def camera_intrinsic(self, sd: dict, size: tuple[int, int] | None = None) -> np.ndarray:
        """(3, 3) float64 camera matrix of a camera sample_data record. ``DataError`` naming calibrated_sensor.json,
        the record's token and the value when it is not a finite 3x3 matrix with third row [0, 0, 1], focal
        lengths in ``FOCAL_RANGE_PX`` and the principal point inside the image extended by its own size on each
        side (``size`` (width, height) in pixels; else the record's width / height; unknown: within
        ``MAX_PRINCIPAL_POINT_PX``)."""
        cs = self.get("calibrated_sensor", sd["calibrated_sensor_token"], f"sample_data {sd['token']}")
        rows = cs["camera_intrinsic"]
        try:  # ragged rows, strings, booleans, objects: not a matrix
            K = np.asarray(rows, dtype=np.float64) if isinstance(rows, list) and all(
                _is_number_list(row) for row in rows) else np.full(0, np.nan)
        except (ValueError, OverflowError):  # ragged rows; an integer beyond float range
            K = np.full(0, np.nan)
        path, token = str(self.path("calibrated_sensor")), cs["token"]
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise DataError(f"calibrated_sensor camera_intrinsic must be a finite 3x3 matrix with positive focal "
                            f"lengths, got {cs['camera_intrinsic']!r}; is this a camera channel?",
                            path=path, token=token)
        fix = "fix the record or re-extract the tables"
        if np.max(np.abs(K[2] - [0.0, 0.0, 1.0])) > 1e-6:
            raise DataError(f"calibrated_sensor camera_intrinsic third row is {rows[2]!r}, expected [0, 0, 1] (a "
                            f"pinhole camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]); {fix}", path=path,
                            token=token)
        if abs(K[1, 0]) > 1e-6:
            raise DataError(f"calibrated_sensor camera_intrinsic second row is {rows[1]!r}, expected [0, fy, cy] (a "
                            f"pinhole camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]); {fix}", path=path,
                            token=token)
        if abs(K[0, 1]) > MAX_SKEW_PX:  # read as 0 (the projection keeps fx, fy, cx, cy): every projection was off
            raise DataError(f"calibrated_sensor camera_intrinsic has a skew of {K[0, 1]:.6g} px (its [0][1] entry); "
                            "hybrid-calib models a zero-skew pinhole camera (as nuScenes'): resample the images to a "
                            f"zero-skew camera and write its matrix, or {fix}", path=path, token=token)
        lo, hi = FOCAL_RANGE_PX
        for name, v in (("fx", K[0, 0]), ("fy", K[1, 1])):
            if not lo <= v <= hi:
                raise DataError(f"calibrated_sensor camera_intrinsic {name} is {v:.6g} px, outside the plausible "
                                f"range {lo:g}..{hi:g} px (nuScenes cameras have about 1266 px); {fix}", path=path,
                                token=token)
        width, height = size or (_positive_int(sd.get("width")), _positive_int(sd.get("height")))
        for name, v, extent in (("cx", K[0, 2], width), ("cy", K[1, 2], height)):
            if extent:
                ok, bound = -extent <= v <= 2 * extent, f"{-extent}..{2 * extent} px (the image, {extent} px, " \
                    "extended by its own size on each side)"
            else:
                ok, bound = abs(v) <= MAX_PRINCIPAL_POINT_PX, f"+-{MAX_PRINCIPAL_POINT_PX:g} px (image size unknown)"
            if not ok:
                raise DataError(f"calibrated_sensor camera_intrinsic principal point {name} is {v:.6g} px, outside "
                                f"{bound}; {fix}", path=path, token=token)
        return K


FOCAL_RANGE_PX = (1.0, 1e5)  # plausible focal lengths, pixels (a 1e-300 px focal length made K singular)
MAX_PRINCIPAL_POINT_PX = 1e5  # |cx|, |cy| bound, pixels, when the image size is not known
MAX_SKEW_PX = 0.5  # |K[0][1]| beyond this is refused (probe 34: a 500 px skew was dropped without a word)


def _positive_int(value) -> int:
    """A record's width / height when it is a positive whole number of at most ``MAX_PRINCIPAL_POINT_PX``, else 0
    (unknown; probe 146: a height of 1e308 was an internal error comparing it with a float)."""
    ok = is_number(value) and 0 < value <= MAX_PRINCIPAL_POINT_PX
    return int(value) if ok and value == int(value) else 0


def _index_by_token(records: list[dict], path: Path) -> dict[str, dict]:
    """token -> record; ``DataError`` naming the file and the token when a token appears twice."""
    out: dict[str, dict] = {}
    for i, rec in enumerate(records):
        token = rec["token"]
        if token in out:
            raise DataError(f"token appears twice in table {path.stem!r} (records {records.index(out[token])} and "
                            f"{i}); tokens must be unique, so the table is corrupt or two tables were merged: "
                            "re-extract the metadata", path=str(path), token=token)
        out[token] = rec
    return out


QUAT_NORM_TOL = 1e-3  # |norm(q) - 1| up to this is rounding in the file: renormalised; beyond it the record is rejected
# an ego pose's timestamp against its sample_data record's: equal in nuScenes; 25 ms (half a LiDAR sweep) moves a
# vehicle at 30 m/s by 0.75 m, beyond which the pose belongs to another instant
MAX_EGO_POSE_OFFSET_US = 25_000
# plausibility bounds of a translation, metres: a sensor mount (calibrated_sensor) sits on the vehicle, and nuScenes
# map coordinates (ego_pose) reach a few km; beyond these the record is corrupt (1e30 m overflowed the solvers)
MAX_MOUNT_TRANSLATION_M = 50.0
MAX_EGO_TRANSLATION_M = 1e7
MAX_EGO_TURN_DPS = 120.0  # a road vehicle's yaw rate stays well below this (a tight turn at walking pace: ~60 deg/s)
# one frame's records (camera, radar, LiDAR) are tens of ms apart: their ego poses may differ by the vehicle's motion
# in that time plus this much of localisation noise (nuScenes: centimetres, a tenth of a degree)
POSE_PAIR_MARGIN_M = 0.5
POSE_PAIR_MARGIN_DEG = 2.0
# an ego pose against the path its channel's neighbouring records' poses trace (NuScenesTables._check_smooth):
# measured on the real scene-0916, every channel's poses (3173 records with both neighbours, 100-250 ms apart) lie
# within 1.6 cm and 0.30 deg of it (benchmarks/pose_smoothness.py); the simulator's keyframe-only camera (neighbours
# 1 s apart) within 0.13 m and 0.14 deg. Allowed: a margin plus what an acceleration of MAX_EGO_ACCEL_MPS2 (in
# rotation MAX_EGO_ROT_ACCEL_DPS2) moves the vehicle off a constant-rate path. 20 m/s^2 is twice any car's braking or
# cornering (~10), and covers the simulator's default stops (probe 81: highway stops on its default 3 s ramp brake at
# 13-14 m/s^2, and their exact poses were refused at 10; 35 m/s on urban turns, 14-27 m/s^2, only partly). Yaw's
# margin is 1 deg (a 2 deg yaw error passed the 2 deg of session 39's first version: probe 81), roll / pitch's 2 deg
# (the pitch a road's bumps put in the poses: a 3 deg bump over 0.3 s laid on the real scene's poses sat 1.4 deg off)
POSE_SMOOTH_MARGIN_M = 0.2
POSE_SMOOTH_MARGIN_YAW_DEG = 1.0
POSE_SMOOTH_MARGIN_TILT_DEG = 2.0
MAX_EGO_ACCEL_MPS2 = 20.0
MAX_EGO_ROT_ACCEL_DPS2 = 90.0
POSE_NEIGHBOUR_MAX_GAP_S = 1.5


def _is_number_list(value) -> bool:
    """A flat JSON list of numbers (int or float; not bool, str, null or a nested list)."""
    return isinstance(value, list) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)


def _vector(rec: dict, key: str, n: int, what: str, path: Path) -> np.ndarray:
    """A record's field ``key`` as (n,) float64: a flat JSON list of ``n`` finite numbers. ``DataError`` naming the
    table, the record's token and the field otherwise (numpy read ``[[1], [2], [3]]``, ``[true, false, true]`` and
    ``["1", 2, 3]`` as numbers)."""
    v, why = vector_or_reason(rec[key], n)
    if v is not None:
        return v
    raise DataError(f"table {path.stem!r} field {key!r} is {short_repr(rec[key])} ({why}); expected {what}: fix the "
                    "record or re-extract the tables", path=str(path), token=rec.get("token"))


def short_repr(value) -> str:
    """``repr(value)`` cut to 80 characters, for naming a bad value in a message."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def vector_or_reason(value, n: int) -> tuple[np.ndarray | None, str]:
    """((n,) float64, "") of a flat JSON list of ``n`` finite numbers, or (None, "not a list of n numbers" |
    "non-finite"): numpy would read ``[[1], [2], [3]]``, ``[true, false, true]`` and ``["1", 2, 3]`` as numbers,
    and an integer beyond float range as inf."""
    if not _is_number_list(value) or len(value) != n:
        return None, f"not a list of {n} numbers"
    try:
        v = np.asarray(value, dtype=np.float64)
    except OverflowError:  # an integer beyond float range
        return None, "non-finite"
    return (v, "") if np.all(np.isfinite(v)) else (None, "non-finite")


def _unit_quaternion(rec: dict, path: Path) -> np.ndarray:
    """A record's ``rotation`` [w, x, y, z] as a unit quaternion; ``DataError`` when its norm is far from 1."""
    q = _vector(rec, "rotation", 4, "a [w, x, y, z] unit quaternion (4 numbers)", path)
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise DataError(f"rotation quaternion has norm {norm:.6g}, not 1 (tolerance {QUAT_NORM_TOL:g}); the "
                        "record is corrupt: fix or re-extract it", path=str(path), token=rec.get("token"))
    return q / norm


def _pose(rec: dict, path: Path, max_translation_m: float = float("inf"), what: str = "a pose") -> np.ndarray:
    """(4, 4) child -> parent of an ego_pose / calibrated_sensor record; ``DataError`` naming the table, token and
    field when its rotation or translation is not a flat list of 4 / 3 finite numbers (or not a unit quaternion),
    or the translation is more than ``max_translation_m`` from the parent's origin (``what`` names the record kind
    in that message)."""
    q = _unit_quaternion(rec, path)
    t = _vector(rec, "translation", 3, "[x, y, z] metres (3 numbers)", path)
    dist = math.hypot(*t)  # no overflow warning for 1e300
    if not dist <= max_translation_m:  # "not <=": inf too
        raise DataError(f"table {path.stem!r} field 'translation' is {short_repr(rec['translation'])}, {dist:.6g} m "
                        f"from the origin; {what} "
                        f"must lie within {max_translation_m:g} m, so the record is corrupt: fix the record or "
                        "re-extract the tables", path=str(path), token=rec.get("token"))
    try:
        T = pose_from_nuscenes(q, t)
    except (ValueError, TypeError) as e:
        raise DataError(f"invalid rotation/translation ({e}); expected a [w, x, y, z] unit quaternion and "
                        "[x, y, z] metres", path=str(path), token=rec.get("token")) from None
    if not np.all(np.isfinite(T)):
        raise DataError("non-finite rotation/translation", path=str(path), token=rec.get("token"))
    return T
