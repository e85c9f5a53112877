"""Fleet jobs: one per vehicle (log), plain data, and the one call into the per-vehicle calibration.

A ``Job`` holds only paths, names, numbers and nested lists (``to_dict`` / ``from_dict``), so it
crosses a process pool or a Ray cluster unchanged; what comes back is an outcome dict (``run_job``)
and the result file the job wrote: ``OUT/vehicles/<job id>/result.json`` (``calib.result``
``CalibrationRun`` holding one vehicle) with its plots in ``OUT/vehicles/<job id>/plots/``.

``FLEET.json`` (``--manifest``) lists the roots of a fleet::

    {"version": "v1.0-sim",                       # optional, default the command's --version
     "roots": [ROOT, ...] | [{"data": ROOT, "version": V, "vehicles": [NAME, ...]}, ...]}

(a bare list is read as ``roots``; relative paths are relative to the file; "note", "comment" and keys starting
with "_" are free text; any other key is refused: a typo such as "vehciles" calibrated the whole root).
"""

from __future__ import annotations

import json
import os
import socket
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.data.files import data_stamp, file_part, root_labels
from hybrid_calib.data.tables import version_dir
from hybrid_calib.errors import DataError, HybridCalibError, OptionError

METHODS = ("hybrid", "pure", "pure-avg", "oracle")  # issue 9's methods; "oracle" runs today
RESULT = "result.json"


@dataclass(frozen=True)
class Job:
    """One vehicle of one root. Plain data only (JSON-ready); ``out`` is the vehicle's directory."""

    id: str  # unique in the fleet: the vehicle name (prefixed by its root's folder name on a clash)
    vehicle: str  # the vehicle (log.json ``vehicle``) inside its root
    data: str  # nuScenes root
    version: str  # version folder under data
    method: str  # hybrid | pure | pure-avg | oracle
    out: str  # OUT/vehicles/<id>
    seed: int = 0  # the fleet seed: each vehicle's start (and oracle rows) drawn by (seed, vehicle), as calibrate's
    checkpoint: str | None = None  # network checkpoint (the learned methods)
    calib: dict = field(default_factory=dict)  # CalibrateConfig overrides (mode, window, max_frames, ...)
    prior: dict | None = None  # {"T_cam_radar": 4x4, "cov_right_radar": 6x6} (fleet.prior) or None
    tables_T: list | None = None  # (4, 4) the tables' T_cam_radar (inv(T_ego_cam) T_ego_radar), first frame
    design_T: list | None = None  # (4, 4) the recorded design (nominal) mount, when the root has one
    threads: int = 1  # torch / BLAS threads inside the worker
    # the network methods: the contents of the checkpoints they run (``hybrid.loop.network_identity``), so that a
    # checkpoint retrained or edited at the same path is not taken for the one a done job ran
    network: dict | None = None
    # --reference: the sha256 of the export it names (``data.reference``), so that one re-exported at the same path is
    # not taken for the one a done job was checked against
    reference_sha256: str | None = None

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Job:
        return cls(**d)

    @property
    def result_path(self) -> Path:
        return Path(self.out) / RESULT


FREE_TEXT = {"note", "comment", "description"}  # FLEET.json keys a reader may write anything in


def read_fleet_file(path: str | Path, version: str) -> list[tuple[str, str, tuple[str, ...] | None]]:
    """``FLEET.json`` (module doc) -> [(root, version, vehicles or None)]; ``DataError`` naming the file."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, RecursionError) as e:  # ValueError: not JSON, or not UTF-8
        why = "nested too deeply" if isinstance(e, RecursionError) else f"{type(e).__name__}: {e}"
        raise DataError(f"fleet manifest unreadable ({why}); pass a UTF-8 JSON file as in hybrid_calib/fleet/jobs.py",
                        path=str(path)) from None

    def unknown(d: dict, allowed: set[str], where: str) -> None:
        bad = sorted(k for k in d if k not in allowed | FREE_TEXT and not str(k).startswith("_"))
        if bad:
            raise DataError(f"fleet manifest {where}: unknown key(s) {bad} (valid: {sorted(allowed)}; free text: "
                            f"{sorted(FREE_TEXT)} or a key starting with '_'); fix the spelling", path=str(path))

    if isinstance(doc, list):
        doc = {"roots": doc}
    if not isinstance(doc, dict) or not isinstance(doc.get("roots"), list) or not doc["roots"]:
        raise DataError('fleet manifest needs a non-empty "roots" list (paths or {"data", "version", '
                        '"vehicles"})', path=str(path))
    unknown(doc, {"roots", "version"}, "top level")
    version = str(doc.get("version", version))
    out = []
    for i, r in enumerate(doc["roots"]):
        r = {"data": r} if isinstance(r, str) else r
        if not isinstance(r, dict) or not isinstance(r.get("data"), str):
            raise DataError(f"fleet manifest roots[{i}] is {r!r}; expected a path or {{\"data\": PATH, ...}}",
                            path=str(path))
        unknown(r, {"data", "version", "vehicles"}, f"roots[{i}]")
        root = Path(r["data"])
        root = root if root.is_absolute() else path.parent / root
        vehicles = r.get("vehicles")
        if vehicles is not None and not (isinstance(vehicles, list) and all(isinstance(v, str) for v in vehicles)):
            raise DataError(f"fleet manifest roots[{i}].vehicles is {vehicles!r}; expected a list of vehicle names",
                            path=str(path))
        if vehicles is not None and not vehicles:  # it read as "every vehicle"
            raise DataError(f"fleet manifest roots[{i}].vehicles is empty; list the vehicles to calibrate, or drop "
                            "the key to calibrate every vehicle of the root", path=str(path))
        v = str(r.get("version", version))
        where = (f"roots[{i}].version" if "version" in r else 'the top-level "version"' if "version" in doc
                 else "the command's --version (or a \"version\" in the manifest)")
        try:
            version_dir(root, v, fix=f"set {where} to one of them")
        except DataError as e:
            raise DataError(f"fleet manifest {path} roots[{i}]: {e}") from None
        out.append((str(root), v, tuple(vehicles) if vehicles else None))
    return out


def _root_vehicles(root: str, version: str, notes: list[str] | None = None, reference: str | None = None
                   ) -> dict[str, dict]:
    """vehicle -> {"tables_T", "design_T"} of one root, from its tables only (no sensor file is read,
    so a vehicle with corrupt data files still becomes a job and fails alone). Samples of no vehicle (a scene or
    log missing from the tables) are said in ``notes``; ``reference``: an earlier export the run checks against
    (``DataConfig.reference``: ``tables_T`` is then its exported extrinsic where it wrote one)."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.data.summary import not_on_disk_note, overlap_note, sim_vehicle_gap_warning, vehicleless_warning

    ds = NuScenesRadarCamera(root, version, conf={"check_images": False, "reference": reference or None})
    if notes is not None and (lost := vehicleless_warning(ds)):
        notes.append(f"root {root}: {lost.removeprefix('warning: ')}")
    if notes is not None:
        notes.extend(f"root {root}: {line.removeprefix('warning: ')}" for line in ds.reference_notes()
                     if line.startswith("warning: ") and line not in notes)
        # a scene left out, a simulated vehicle with no factory record (probe 96: said in a job's stream only)
        notes.extend(f"root {root}: {line.removeprefix('warning: ').removeprefix('note: ')}"
                     for line in (overlap_note(ds), not_on_disk_note(ds), sim_vehicle_gap_warning(ds)) if line)
    out = {}
    for vehicle, idx in ds.frames_by_vehicle().items():
        tables_T = None
        for i in idx:  # the first frame whose mounts read: a corrupt record is the job's to fail on, named there
            ref = ds.frames[i]
            try:
                # the tables the verdict compares with (a simulated vehicle's factory calibration: its
                # calibrated_sensor holds the truth; probe 24 read a 1.53 deg "offset from tables" beside "differs by
                # 1.21 deg in yaw")
                tables_T = ds.reference_T_cam_radar(ref)
                break
            except (DataError, KeyError, TypeError):  # one vehicle's broken calibrated_sensor ended the whole fleet
                continue
        design = _design_T(ds.sim_vehicles.get(ds.frames[idx[0]].log_token))
        out[vehicle] = {"tables_T": None if tables_T is None else tables_T.tolist(),
                        "design_T": None if design is None else design.tolist(),
                        "logs": sorted({ds.frames[i].log_token for i in idx})}
    # a vehicle of the tables with no frame (every sample another's copy, a scene left out): a job that fails with
    # why, as calibrate's ``vehicles_failed`` and rc 1 (it had been a note of a fleet that exited 0)
    for vehicle in ds.frameless_vehicles():
        out.setdefault(vehicle, {"tables_T": None, "design_T": None, "logs": []})
    return out


def _design_T(rec: dict | None) -> np.ndarray | None:
    """The nominal (design) T_cam_radar of a simulated vehicle record (``sim_vehicle.json``), read
    defensively: ``nominal_T_cam_radar`` (4x4) if recorded, else inv(nominal_T_ego_cam) nominal_T_ego_radar
    from {"rotation" (w, x, y, z), "translation"}; None when absent or malformed."""
    from hybrid_calib.geometry import pose_from_nuscenes, se3_inverse

    if not isinstance(rec, dict):
        return None
    try:
        if "nominal_T_cam_radar" in rec:
            T = np.asarray(rec["nominal_T_cam_radar"], np.float64)
            return T if T.shape == (4, 4) and np.all(np.isfinite(T)) else None
        cam, rad = rec.get("nominal_T_ego_cam"), rec.get("nominal_T_ego_radar")
        if cam is None or rad is None:
            return None
        Tc, Tr = (pose_from_nuscenes(p["rotation"], p["translation"]) for p in (cam, rad))
        return se3_inverse(Tc) @ Tr
    except (KeyError, TypeError, ValueError):
        return None


def check_fleet_roots(sources: list[tuple[str, str, tuple[str, ...] | None]], manifest: str | Path) -> None:
    """``DataError`` naming the manifest and the entry when a root it lists (``read_fleet_file``) is not a
    directory on this machine."""
    for i, (root, _, _) in enumerate(sources):
        if not Path(root).is_dir():
            raise DataError(f"fleet manifest roots[{i}]: {root} is not a directory (a relative path is read from the "
                            "manifest's folder); fix the path", path=str(manifest))


def _check_root(root: str, version: str, method: str, calib: dict, checkpoint: str | None) -> None:
    """``OptionError`` when ``method`` cannot run on any vehicle of the root, as calibrate says before reading a frame:
    the oracle on a root without the simulator's truth, a learned method whose depth the root cannot give (its LiDAR
    files absent). Checked once per root: each job had indexed the whole root and failed alike, a line per vehicle
    (probe 124: 5 vehicles, 10 lines of "use --method hybrid", rc 1)."""
    if method == "oracle":
        from hybrid_calib.calib.pipeline import require_oracle_truth

        require_oracle_truth(root)
        return
    from hybrid_calib.config import merge
    from hybrid_calib.hybrid.drives import checked_depth
    from hybrid_calib.hybrid.loop import HybridConfig

    checked_depth(root, version, merge(HybridConfig, {**calib, "method": method, "checkpoint": checkpoint or ""}),
                  option="--set depth")  # fleet has no --depth


def discover_jobs(roots: list[tuple[str, str, tuple[str, ...] | None]], method: str, out: str | Path,
                  seed: int = 0, checkpoint: str | None = None, calib: dict | None = None,
                  priors: dict | None = None, threads: int = 1, notes: list[str] | None = None,
                  left_out: dict[str, str] | None = None) -> list[Job]:
    """One job per vehicle of every root ([(root, version, vehicles or None)]), sorted by id. A vehicle
    name found in two roots gets its root's folder name as a prefix (``<folder>-<vehicle>``).
    ``left_out``: given, a root of several whose tables cannot be read is recorded there (root -> why) and the
    others go on (as compare does); without it, or when no root reads, the ``DataError`` stops the fleet.
    ``priors``: ``fleet.prior.load_priors`` (job id -> prior dict or None; "*" for any other job), matched by
    ``fleet.prior.match_prior``; what it says about the match is appended to ``notes``."""
    from hybrid_calib.config import merge
    from hybrid_calib.fleet.prior import match_prior
    from hybrid_calib.hybrid.loop import HybridConfig, network_identity

    if method not in METHODS:
        raise HybridCalibError(f"--method {method!r}; valid: {METHODS}")
    network = None
    if method != "oracle":  # the checkpoint the jobs run (the shipped one of the start range by default)
        keys = {k: v for k, v in (calib or {}).items() if k in ("start", "refine")}
        network = network_identity(merge(HybridConfig, {"method": method, "checkpoint": checkpoint or "", **keys}))
        network = network.get("network")
    from hybrid_calib.data.reference import reference_identity

    reference = (calib or {}).get("reference")
    reference_sha256 = reference_identity(reference).get("reference_sha256")
    found = []
    for root, version, wanted in roots:
        try:
            vs = _root_vehicles(root, version, notes, reference)
            _check_root(root, version, method, calib or {}, checkpoint)
        except (DataError, OptionError) as e:  # one root that cannot run: its vehicles are no jobs, the others can
            if left_out is None or len(roots) == 1:
                raise
            left_out[str(root)] = str(e)
            continue
        missing = sorted(set(wanted or ()) - set(vs))
        if missing:
            raise DataError(f"vehicles {missing} not in this root (it has {sorted(vs)})", path=str(root))
        found += [(root, version, v, info) for v, info in sorted(vs.items()) if wanted is None or v in wanted]
    if not found and left_out:
        raise DataError("no root of the fleet can be read: " + "; ".join(f"{r}: {why}" for r, why in left_out.items()))
    names = [v for _, _, v, _ in found]
    labels = root_labels([root for root, _, _, _ in found])
    holders: dict[str, set[str]] = {}  # log token -> the roots holding it
    for root, _, _, info in found:
        for log in info.get("logs", ()):
            holders.setdefault(log, set()).add(str(root))
    if (shared := sorted({tuple(sorted(r)) for r in holders.values() if len(r) > 1})) and notes is not None:
        notes.append(f"roots {' and '.join(shared[0])} hold the same log(s) (a copy of one root?): those drives are "
                     "calibrated and counted in the fleet view and prior once per root; pass one of them")
    jobs = []
    stamps: dict[tuple[str, str], str] = {}  # (root, version) -> its data's digest, read only when a prior asks

    def digest_of(root: str, version: str) -> Callable[[], str]:
        return lambda: stamps.setdefault((root, version), data_stamp(root, version)["digest"])

    for root, version, v, info in found:
        jid = v if names.count(v) == 1 else f"{labels[root]}-{v}"
        prior, note = match_prior(priors or {}, jid, str(root), version, v, digest_of(str(root), version))
        if note is not None and notes is not None and note not in notes:
            notes.append(note)
        # the folder is named after the vehicle of the tables, encoded (a name "../../x" escaped --out)
        # resolved, as the root below: a worker (a Ray node, a process started elsewhere) writes where the driver
        # meant whatever its own working folder (it was stored as typed; probe 33)
        folder = str(Path(out).resolve() / "vehicles" / file_part(jid))
        # the root resolved: a rerun from another folder, or naming it by its absolute path, is the same fleet (the
        # manifest held it as typed, and a resume from elsewhere was refused as "other options"; probe 31)
        jobs.append(Job(jid, v, str(Path(root).resolve()), version, method, folder, seed, checkpoint,
                        dict(calib or {}), prior,
                        info["tables_T"], info["design_T"], threads, network, reference_sha256))
    ids = [j.id for j in jobs]
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        twice = ", ".join(sorted({j.data for j in jobs if j.id in dup}))
        raise DataError(f"job ids {dup} repeat: a root is given twice ({twice}); pass each root once")
    return sorted(jobs, key=lambda j: j.id)


def set_threads(n: int) -> None:
    """Torch / BLAS threads of this worker process (set before torch is imported where possible)."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(int(n))
    import sys

    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(int(n))


def calibrate_job(job: Job) -> Path:
    """THE per-vehicle calibration of the fleet: calibrate ``job.vehicle`` of ``job.data`` with
    ``job.method`` and write ``job.out/result.json`` (one vehicle's ``CalibrationRun``, atomic),
    its ``config.json`` and plots; returns the result path. ``oracle`` runs the factor graph on the
    simulator's rows (``calib.pipeline``); the network methods (``hybrid``, ``pure``, ``pure-avg``) run
    ``hybrid_calib.hybrid.run_calibration``. Every method draws a vehicle's start (and oracle rows) from the
    fleet seed and the vehicle's name alone (``perturbation.vehicle_rng``): the same as ``calibrate --seed``
    of that vehicle, whatever the engine, the worker or the order of the jobs. ``DataError`` for a vehicle whose
    data cannot be calibrated."""
    from functools import partial

    from hybrid_calib.plots.calibration import plot_vehicle

    out = Path(job.out)
    if out.exists() and not out.is_dir():  # an OSError here was retried as a system failure, to no avail
        raise HybridCalibError(f"{out} is a file, not this vehicle's folder of the fleet run; move it away and rerun")
    if (out / "result.json").is_file():  # an earlier run's, superseded (the data changed): kept aside, so that a
        os.replace(out / "result.json", out / "result.stale.json")  # failure now leaves no result at that path
    plots = partial(plot_vehicle, out_dir=out / "plots")
    if job.method == "oracle":
        from hybrid_calib.calib.pipeline import calibrate
        from hybrid_calib.calib.schedule import GaussianPrior

        prior = None if job.prior is None else {job.vehicle: GaussianPrior(
            np.asarray(job.prior["T_cam_radar"], np.float64), np.asarray(job.prior["cov_right_radar"], np.float64))}
        conf = {**job.calib, "vehicles": (job.vehicle,), "seed": job.seed}
        _resuming(job, lambda overwrite: calibrate(job.data, job.version, "oracle", out, conf, overwrite=overwrite,
                                                   priors=prior, progress=False, on_vehicle=plots))
        return _plotted(job)
    from hybrid_calib.hybrid import run_calibration

    if job.prior is not None:
        raise HybridCalibError(f"--prior (the fleet prior) is applied by method oracle only; method {job.method} "
                               "fuses the network's own prior: rerun without --prior")
    unsupported = sorted(set(job.calib) & {"mode", "batch"})
    if unsupported:
        raise HybridCalibError(f"--set {', '.join(unsupported)}: method {job.method} runs the sliding window only")
    conf = {**job.calib, "method": job.method, "checkpoint": job.checkpoint or "", "seed": job.seed,
            "vehicles": (job.vehicle,), "threads": job.threads, "progress": False}
    _resuming(job, lambda overwrite: run_calibration(job.data, job.version, out, conf, overwrite=overwrite,
                                                     on_vehicle=plots))
    return _plotted(job)


JOB_RECORD = "job.json"  # beside a finished job's result: the job it is the result of (``Manifest.open`` adopts it)


def _plotted(job: Job) -> Path:
    """The job's result path, after drawing its vehicle's plots when they are missing: a vehicle a resumed attempt
    kept (probe 90: its result came back without the plots, and summary.json listed none, without a word). Writes
    ``JOB_RECORD``, so that a manifest lost or damaged since still knows the result for this job's."""
    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.config import save_json_atomic
    from hybrid_calib.plots.calibration import draw_missing

    draw_missing(CalibrationRun.load(job.result_path), Path(job.out) / "plots")
    save_json_atomic(Path(job.out) / JOB_RECORD, job.to_dict())
    return job.result_path


def _resuming(job: Job, run: Callable[[bool], object]) -> None:
    """``run(overwrite)``, the job's calibration, resuming an interrupted attempt in its folder where the data are as
    they were (its ``vehicles-done`` stamp records the data's stamp of today): the vehicle it finished and its network
    and depth caches are kept (a vehicle finished with other options, which the manifest runs again with this run's,
    is recomputed; the caches are keyed by checkpoint, frame and start); otherwise afresh, discarding them (they are
    keyed by frame token, which a root re-made at the same path keeps). Probe 84: every retried job (after a Ctrl-C, a
    kill, a full disk) started afresh, its finished vehicle and caches deleted and recomputed."""
    import shutil

    from hybrid_calib.calib.result import OtherConfiguration
    from hybrid_calib.data.files import data_stamp

    done = Path(job.out) / "vehicles-done"
    try:
        old = json.loads((done / "stamp.json").read_text())
        same_data = old["config"]["data_stamp"] == data_stamp(job.data, job.version)["digest"]
    except (OSError, ValueError, KeyError, TypeError, HybridCalibError):  # none, damaged, another layout: afresh
        same_data = False
    if not same_data:
        run(True)
        return
    try:
        run(False)
    except OtherConfiguration:
        shutil.rmtree(done, ignore_errors=True)
        run(False)


def _where(e: BaseException) -> str:
    """The innermost frame of ``e``'s traceback as "file:line in function" (the traceback itself stays out of the
    manifest; this line is what a bug report needs first)."""
    import traceback

    frames = traceback.extract_tb(e.__traceback__)
    return f"{Path(frames[-1].filename).name}:{frames[-1].lineno} in {frames[-1].name}" if frames else "?"


def run_job(job: dict) -> dict:
    """Run one job (a ``Job.to_dict``) in whatever process this is; returns its outcome as plain data:
    {"id", "state": "done" | "failed", "reason", "file", "wall_s", "cpu_s" (this process's CPU time),
    "host", "pid", "result"}.
    A ``HybridCalibError`` (corrupt data, a method not available) is the job's failure; so is an unexpected
    error (a bug met by this vehicle's data: the fleet goes on and the reason says "internal error"); an
    ``OSError`` propagates, so the engine can retry system failures."""
    j = Job.from_dict(job)
    set_threads(j.threads)
    t0, c0 = time.perf_counter(), time.process_time()
    base = {"id": j.id, "host": socket.gethostname(), "pid": os.getpid()}
    try:
        path = calibrate_job(j)
    except OSError:
        raise
    except Exception as e:  # noqa: BLE001 - one vehicle's failure, never the fleet's
        what = "" if isinstance(e, HybridCalibError) else "internal error (please report it with this vehicle's data): "
        where = "" if isinstance(e, HybridCalibError) else f" [at {_where(e)}]"  # a bug: where it was met
        return {**base, "state": "failed", "reason": f"{what}{type(e).__name__}: {e}{where}",
                "file": getattr(e, "path", None),
                "wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "result": None}
    return {**base, "state": "done", "reason": None, "file": None, "wall_s": time.perf_counter() - t0,
            "cpu_s": time.process_time() - c0, "result": str(path)}
