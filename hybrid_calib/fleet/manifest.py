"""``OUT/manifest.json``: the fleet's job list and each job's state, rewritten atomically on every change.

Schema (``schema`` "hybrid-calib/fleet-manifest/v1")::

    {"schema": "hybrid-calib/fleet-manifest/v1", "method": str, "seed": int,
     "jobs": {JOB_ID: {"job": Job.to_dict(),
                       "state": "pending" | "running" | "done" | "failed",
                       "reason": str | null, "file": str | null,    # why it failed, and which file
                       "attempts": int, "wall_s": float | null, "cpu_s": float | null, "host": str | null,
                       "result": "vehicles/<id>/result.json" | null}}}

Resume rules (``Manifest.open``): a job whose result file is complete (written atomically, so
present means complete) is ``done``, whatever state the manifest last recorded (a driver killed
after the job wrote its result, before the manifest was saved); a job without one is ``pending``,
or stays ``failed`` (with its reason) until it is retried. Nothing done is recomputed, and a job id
is never listed twice. A done job recorded with other result-defining options (another root, version,
``--set``/``--max-frames``, checkpoint or prior) is refused (``DataError`` naming the job and the
options), not reported as this run's result. A manifest that does not read is kept aside
(``manifest.damaged.json``) and one entry that does not read is dropped, each said (``recovered``); a job the
manifest does not list whose folder holds a complete result and the job record it was computed for
(``jobs.JOB_RECORD``), of the same vehicle, data and options, is adopted as done: a damaged manifest had stopped
the run ("move it away to start over"), and moving it away recomputed every finished vehicle (probe 109).

Saving: one job per line (``json.dumps`` per entry, the C encoder: a 1000-job manifest, 1.9 MB,
took 0.67 s against 1.09 s indented, on the shared 2-core box at load 8), at most every
``save_every_s`` seconds while jobs run (``mark_running`` / ``record``) and at most a fifth of the
driver's time (a save that took t waits 4 t for the next): saving every change cost a 1000-vehicle
fleet two saves per vehicle, O(N^2) in all. ``flush`` writes what is left. A driver killed between
two saves loses only bookkeeping (``attempts``, ``wall_s``, ``host``, a failure's reason), never a
result: the resume rules read the result files.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from hybrid_calib.config import save_text_atomic
from hybrid_calib.data.files import file_part
from hybrid_calib.errors import DataError
from hybrid_calib.fleet.jobs import Job

SCHEMA = "hybrid-calib/fleet-manifest/v1"
STATES = ("pending", "running", "done", "failed")


def result_complete(path: str | Path) -> bool:
    """Whether ``path`` is a readable ``result.json`` (one vehicle's ``CalibrationRun``)."""
    from hybrid_calib.calib.result import CalibrationRun

    try:
        return bool(CalibrationRun.load(path).vehicles)
    except DataError:
        return False


@dataclass
class Manifest:
    path: Path
    method: str
    seed: int
    jobs: dict[str, dict] = field(default_factory=dict)  # id -> entry (module doc)
    renamed: dict[str, str] = field(default_factory=dict)  # old id -> new id of a vehicle (``_follow_renames``)
    stale: list[str] = field(default_factory=list)  # done jobs whose root's data changed since (``_data_changed``)
    recovered: list[str] = field(default_factory=list)  # what a damaged manifest cost, in words (module doc)
    save_every_s: float = 1.0  # the most often mark_running / record rewrite the file
    _next_save: float = field(default=float("-inf"), repr=False)  # and at most 1/5 of the driver's time
    _dirty: bool = field(default=False, repr=False)

    @classmethod
    def open(cls, path: str | Path, jobs: list[Job], method: str, seed: int) -> Manifest:
        """The manifest at ``path`` merged with ``jobs`` (new jobs added as ``pending``; the
        resume rules of the module doc applied), written back. ``DataError`` when it belongs to
        another method or seed (its results would be mixed)."""
        path = Path(path)
        m = cls(path, method, seed)
        doc = None
        if path.is_file():
            try:
                doc = json.loads(path.read_text())
                if not isinstance(doc, dict) or doc.get("schema") != SCHEMA or "jobs" not in doc:
                    raise ValueError(f"schema {doc.get('schema') if isinstance(doc, dict) else None!r}")
            except (OSError, ValueError, KeyError, TypeError, RecursionError) as e:
                why = "nested too deeply" if isinstance(e, RecursionError) else f"{type(e).__name__}: {str(e)[:200]}"
                doc, aside = None, _aside(path)
                m.recovered.append(f"the fleet manifest {path} did not read ({why}): kept as {aside.name}, and the "
                                   "jobs' folders read instead (a vehicle with its result and job record is kept)")
        if doc is not None:
            if (doc.get("method"), doc.get("seed")) != (method, seed):
                raise DataError(f"this OUT holds a fleet run of method {doc.get('method')!r}, seed {doc.get('seed')}; "
                                f"pass the same --method/--seed or another --out", path=str(path))
            m.jobs = _checked_jobs(doc["jobs"], path, m.recovered)
        m.renamed = _follow_renames(m.jobs, jobs, path)
        stamps: dict = {}  # (root, version) -> data_stamp, computed once per root
        adopted = 0
        for job in jobs:
            e, found = m.jobs.get(job.id), False
            if e is None:  # not listed (a new vehicle, or a manifest lost): its folder's job record stands for it,
                # checked as a listed job is (probe 110: a damaged manifest and other options recomputed in silence)
                rec = _job_record(job)
                e = m.jobs[job.id] = {"job": rec or job.to_dict(), "state": "pending", "reason": None, "file": None,
                                      "attempts": 0, "wall_s": None, "cpu_s": None, "host": None, "result": None}
                if rec is None:
                    continue
                found = True
            complete, why = _result_of(job)
            if complete and not _same_vehicle(e["job"], job):  # before the data stamp and the result's own root:
                # another root's vehicle of the same
                # name (every simulated root names its vehicles sim-veh-000, ...) read as "its data changed" and was
                # overwritten, the two roots mixed in one fleet view and prior (probe 50)
                a = e["job"]
                raise DataError(f"this OUT holds vehicle {job.id} of another root ({a.get('vehicle')!r} of "
                                f"{a.get('data')}, {a.get('version')}); this run's {job.id} is {job.vehicle!r} of "
                                f"{job.data}, {job.version}: pass another --out, or list both roots in one command "
                                "(their vehicles are then named by root)", path=str(path))
            done = complete and not why
            if why and (e["state"] == "done" or found):  # probe 109: recomputed unsaid
                m.recovered.append(f"{job.id}: its result {job.result_path} {why}: calibrated again")
            if done and _data_changed(job, stamps):  # re-downloaded, re-simulated: computed again, and said
                done = False
                m.stale.append(job.id)
            if done and (changed := _changed_options(e["job"], job)):
                raise DataError(f"this OUT holds vehicle {job.id} calibrated with other options "
                                f"({'; '.join(changed)}), so this run would report that result as its own; pass the "
                                f"same options, or another --out (or move {job.out} away to calibrate it again)",
                                path=str(path))
            e["job"] = job.to_dict()  # a job not done yet runs with this run's options
            if done:  # at least the attempt that wrote it, which a driver killed before its save had not counted
                # (probe 91: "done" after 0 attempts)
                e.update(state="done", reason=None, file=None, result=rel_path(job.result_path, path.parent),
                         attempts=max(int(e.get("attempts") or 0), 1))
                adopted += found
            elif e["state"] != "failed":
                e.update(state="pending", result=None)
        if adopted and (m.recovered or doc is None):
            m.recovered.append(f"{adopted} vehicle(s) the manifest did not list are kept: their folders hold a "
                               "complete result of the same vehicle, data and options (and their job record)")
        ids = {job.id for job in jobs}
        for jid, e in m.jobs.items():  # jobs of earlier runs only (e.g. another root): the same resume rules
            if jid not in ids and e["state"] in ("done", "running"):
                done = bool(e.get("result")) and result_complete(path.parent / str(e["result"]))
                if not done and e["state"] == "done" and e.get("result") and (path.parent / str(e["result"])).exists():
                    m.recovered.append(f"{jid}: its result {path.parent / str(e['result'])} does not read (damaged): "
                                       "calibrated again")
                e.update(state="done" if done else "pending", result=e.get("result") if done else None)
        m.save()
        return m

    def save(self) -> Path:
        """Write the file now (atomic; one job per line, module doc)."""
        t0 = time.monotonic()
        head = json.dumps({"schema": SCHEMA, "method": self.method, "seed": self.seed})[:-1]
        rows = ",\n".join(f"{json.dumps(k)}: {json.dumps(e)}" for k, e in sorted(self.jobs.items()))
        save_text_atomic(self.path, f"{head}, \"jobs\": {{\n{rows}\n}}}}\n")
        self._next_save = time.monotonic() + max(self.save_every_s, 4 * (time.monotonic() - t0))
        self._dirty = False
        return self.path

    def flush(self) -> None:
        """Write the changes not yet saved (``save_every_s``)."""
        if self._dirty:
            self.save()

    def _changed(self) -> None:
        self._dirty = True
        if time.monotonic() >= self._next_save:
            self.save()

    def todo(self) -> list[Job]:
        """Jobs to run now: pending and failed ones (failed ones are retried), in id order."""
        return [Job.from_dict(e["job"]) for _, e in sorted(self.jobs.items()) if e["state"] in ("pending", "failed")]

    def mark_running(self, ids: list[str], host: str | None = None) -> None:
        for i in ids:
            e = self.jobs[i]
            e.update(state="running", attempts=int(e["attempts"]) + 1, host=host)
        self._changed()

    def release_running(self) -> None:
        """Jobs marked running back to pending: the run that marked them stops (interrupted: probe 84, its manifest said
        every job of a dead run "running", queued ones too); the next run runs them."""
        for e in self.jobs.values():
            if e["state"] == "running":
                e["state"] = "pending"
                self._dirty = True

    def record(self, outcome: dict) -> dict:
        """Store one job's outcome (``jobs.run_job`` or an engine's failure record); returns its entry."""
        e = self.jobs[outcome["id"]]
        e.update(state=outcome["state"], reason=outcome.get("reason"), file=outcome.get("file"),
                 wall_s=outcome.get("wall_s"), cpu_s=outcome.get("cpu_s"), host=outcome.get("host") or e.get("host"),
                 result=rel_path(outcome["result"], self.path.parent) if outcome.get("result") else None)
        self._changed()
        return e

    def counts(self) -> dict[str, int]:
        return {s: sum(e["state"] == s for e in self.jobs.values()) for s in STATES}


def _data_changed(job: Job, stamps: dict) -> bool:
    """Whether ``job``'s root changed since its result was computed (``calib.result.DATA_STAMP`` beside it against
    ``data.files.data_stamp`` now): a fleet rerun after a re-download or a re-simulation reported the old vehicles
    as done for the new data. A result without a stamp (an older version's) is kept; a damaged stamp vouches for
    nothing."""
    from hybrid_calib.calib.result import stored_digest
    from hybrid_calib.data.files import data_stamp

    then = stored_digest(job.out)
    if then == "":
        return False
    key = (os.path.realpath(job.data), job.version)
    if key not in stamps:
        stamps[key] = data_stamp(job.data, job.version)["digest"]
    return then != stamps[key]  # a damaged stamp (None) vouches for nothing: computed again


def _same_vehicle(a: dict, job: Job) -> bool:
    """Whether the manifest's job record ``a`` is ``job``'s vehicle: the same vehicle of the same root and version."""
    return (a.get("vehicle"), a.get("version")) == (job.vehicle, job.version) and \
        os.path.realpath(str(a.get("data"))) == os.path.realpath(job.data)


def _follow_renames(entries: dict[str, dict], jobs: list[Job], path: Path) -> dict[str, str]:
    """Move each vehicle an earlier run recorded under another id to its id in this run (old id -> new id).

    A job id is the vehicle's name, prefixed with its root's folder name only when two roots share the name
    (``jobs.discover_jobs``): a root added to (or dropped from) the command renames vehicles, and the rerun
    calibrated them again under the new id and kept the old entries, so the fleet view and prior counted those
    vehicles twice (10 for 7). The entry and its folder (``vehicles/<id>/``, renamed atomically) follow the
    vehicle; a folder that cannot move leaves the vehicle to be calibrated again under its new id."""
    ids = {j.id for j in jobs}
    renamed = {}
    for job in jobs:
        if job.id in entries:
            continue
        old = next((k for k, e in entries.items() if k not in ids and _same_vehicle(e["job"], job)), None)
        if old is None:
            continue
        e = entries.pop(old)
        # the folder beside this manifest (a job's recorded "out" is absolute: stale when --out was moved)
        src, dst = path.parent / "vehicles" / file_part(old), Path(job.out)
        moved = False
        try:
            if src.is_dir() and not dst.exists():
                dst.parent.mkdir(parents=True, exist_ok=True)
                os.replace(src, dst)
                moved = True
        except OSError:
            pass
        e["job"] = {**e["job"], "id": job.id, "out": job.out}
        e["result"] = None
        entries[job.id] = e
        # not moved (its new folder exists, or the move failed): calibrated again under the new id, the old
        # folder left as it is
        renamed[old] = job.id if moved else f"{job.id} (calibrated again: {src} could not move to {dst})"
    return renamed


def _aside(path: Path) -> Path:
    """Move an unreadable manifest out of the way, kept (``manifest.damaged.json``, numbered when taken); returns
    where it went."""
    aside, n = path.with_name("manifest.damaged.json"), 1
    while aside.exists():
        n += 1
        aside = path.with_name(f"manifest.damaged-{n}.json")
    os.replace(path, aside)
    return aside


def _job_record(job: Job) -> dict | None:
    """The job record (``jobs.JOB_RECORD``, a ``Job.to_dict``) a finished job left in ``job``'s folder, or None (none,
    or one that does not read: its result is then not adopted)."""
    from hybrid_calib.fleet.jobs import JOB_RECORD

    try:
        rec = json.loads((Path(job.out) / JOB_RECORD).read_text())
        Job.from_dict(rec)
    except (OSError, ValueError, TypeError, KeyError, RecursionError, AttributeError):
        return None
    return rec


def _result_of(job: Job) -> tuple[bool, str]:
    """(whether ``job``'s folder holds a complete result, ``result_complete``; why it is not this job's when a result
    file is there, "" when it is): this job's holds ``job.vehicle`` and was computed on ``job.data`` (probe 110:
    another root's result copied into the folder was kept as this vehicle's). One read of the file."""
    from hybrid_calib.calib.result import CalibrationRun

    p = Path(job.result_path)
    if not p.exists():
        return False, ""
    try:
        run = CalibrationRun.load(p)
    except DataError:
        return False, "does not read (damaged)"
    if job.vehicle not in run.vehicles:
        return bool(run.vehicles), f"holds no result of {job.vehicle} ({', '.join(sorted(run.vehicles)) or 'none'})"
    if os.path.realpath(run.data) != os.path.realpath(job.data):
        return True, f"was computed on {run.data}, not on {job.data}"
    return True, ""


def _checked_jobs(jobs, path: Path, dropped: list[str]) -> dict[str, dict]:
    """The ``jobs`` of a manifest read back, each entry checked to be what ``Manifest`` writes (module doc); an entry
    that is not is left out and said in ``dropped`` (its job is then read from its folder, ``_job_record``)."""
    if not isinstance(jobs, dict):
        dropped.append(f"the fleet manifest's \"jobs\" is a JSON {type(jobs).__name__}, not an object of job entries: "
                       "the jobs' folders read instead")
        return {}
    kept = {}
    for jid, e in jobs.items():
        try:
            if not isinstance(e, dict):
                raise TypeError(f"a JSON {type(e).__name__}, not an object")
            if e.get("state") not in STATES:
                raise ValueError(f"state {e.get('state')!r}, not one of {STATES}")
            job = Job.from_dict(e["job"]) if isinstance(e.get("job"), dict) else None
            if job is None or job.id != jid:
                raise ValueError(f"job {e.get('job')!r} is not this entry's job record")
            if isinstance(e.get("attempts"), bool) or not isinstance(e.get("attempts"), int):
                raise ValueError(f"attempts {e.get('attempts')!r}, not an integer")
        except (KeyError, TypeError, ValueError) as err:
            dropped.append(f"fleet manifest entry {jid!r} is malformed ({err}; {path}): left out, its job read from "
                           "its folder")
            continue
        # bookkeeping that is not a time is an unknown one (probe 150: a NaN reached summary.json as a bare NaN)
        kept[jid] = {**e, **{k: None for k in ("wall_s", "cpu_s") if not _seconds(e.get(k))},
                     **({"host": None} if not isinstance(e.get("host"), (str, type(None))) else {})}
    return kept


def _seconds(value) -> bool:
    """Whether ``value`` reads as a time a job took: a finite number >= 0 (bool aside)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value >= 0


# the Job fields a result depends on (not: out, threads, tables_T / design_T, which follow from data)
_RESULT_FIELDS = ("data", "version", "vehicle", "method", "seed", "checkpoint", "calib", "prior", "network",
                  "reference_sha256")


def _changed_options(old: dict, job: Job) -> list[str]:
    """"FIELD: OLD -> NEW" for each result-defining field in which the job recorded in the manifest (``old``,
    a ``Job.to_dict``) differs from ``job``; paths compare resolved, the checkpoint only for network methods."""
    changed = []
    for k in _RESULT_FIELDS:
        a, b = old.get(k), getattr(job, k)
        if k in ("checkpoint", "network") and job.method == "oracle":
            continue
        if k == "network":  # the checkpoint's contents (an older manifest did not record them: not held against it)
            if a is not None and a != b:
                changed.append("the network checkpoint's files (retrained or edited at the same path, or another "
                               "file)")
            continue
        if k == "reference_sha256":  # the export --reference names, by content (its path is in calib)
            if a != b and a is not None and b is not None:  # given, or left off: said by calib's reference
                changed.append("the --reference export's file (exported again at the same path, or another file)")
            continue
        if k in ("data", "checkpoint"):
            same = (a or None) == (b or None) or (bool(a) and bool(b) and os.path.realpath(a) == os.path.realpath(b))
            if k == "checkpoint" and not same and old.get("network") is not None:
                same = old["network"] == job.network  # the default named explicitly: the very same files
        elif k == "calib":  # compared as the config they make: --max-frames 0 is the default, not a change
            same = _effective(job.method, a) == _effective(job.method, b)
        else:
            same = json.loads(json.dumps(a)) == json.loads(json.dumps(b))
        if not same:
            changed.append(f"{k}: {_short(a)} -> {_short(b)}")
    return changed


def _effective(method: str, calib) -> object:
    """The per-vehicle config the ``calib`` overrides make for ``method`` (plain dict), or them as given
    when they do not make one."""
    from hybrid_calib.calib.pipeline import CalibrateConfig
    from hybrid_calib.config import merge, to_dict
    from hybrid_calib.hybrid.loop import HybridConfig

    try:
        return to_dict(merge(CalibrateConfig if method == "oracle" else HybridConfig, calib or {}))
    except (ValueError, TypeError):  # ConfigError is a ValueError
        return json.loads(json.dumps(calib))


def _short(value, limit: int = 80) -> str:
    text = json.dumps(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def rel_path(path: str | Path, base: Path) -> str:
    """``path`` relative to the folder ``base`` (both resolved), or as given when it is not under it."""
    p = Path(path)
    try:
        return str(p.resolve().relative_to(base.resolve()))
    except ValueError:
        return str(p)
