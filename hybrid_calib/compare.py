"""Pure vs hybrid: every method on the same starts and the same network outputs, then one table.

``compare(roots, version, out, conf)``:

1. Trials. The vehicles of the roots (sorted per root, roots in order) are taken in turn: trial k
   is vehicle ``k mod V`` with start seed ``conf.seed + k // V`` (``perturbation.vehicle_start``:
   the same start for every method).
2. Export once, evaluate many. One ``NetworkRunner`` per root with one output cache
   (``OUT/network-cache``): ``pure`` and ``pure-avg`` read the very same passes, the hybrid's first
   frame too. Each (method, trial) writes ``OUT/trials/<method>/<k>.json`` (a ``VehicleResult``);
   a rerun skips those already there (resumable; a larger ``--trials`` extends a run).
3. ``OUT/compare.json`` / ``compare.md``: per method the paper's table (rotation Mean/Roll/Pitch/Yaw
   deg, translation Mean/X/Y/Z cm, geodesic, norm), means and medians over trials; coverage of the
   95 % ellipsoid and mean NEES (all, and per root = scenario); fraction of trials whose status is
   not ``ok``; time per frame (network + solve). ``OUT/error_vs_frames.png``
   (``plots.compare``): error against frames fused, per method and axis, with the reported 2-sigma.
"""

from __future__ import annotations

import dataclasses
import json
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.atomic import out_dir_lock
from hybrid_calib.calib.covariance import status_kind
from hybrid_calib.calib.result import VehicleResult, failed_vehicles_message
from hybrid_calib.config import (
    changed_options,
    check_seed,
    merge,
    read_out_record,
    save_json_atomic,
    save_text_atomic,
    to_dict,
)
from hybrid_calib.data.files import root_labels, stamps_changed
from hybrid_calib.errors import CheckpointError, DataError, HybridCalibError, check_api_out, check_not_being_written
from hybrid_calib.hybrid.loop import METHODS, HybridConfig, _Session, vehicle_learned, vehicle_oracle
from hybrid_calib.metrics import METRIC_KEYS, consistency


@dataclass(frozen=True)
class CompareConfig:
    range: str = "R1"  # start range of every trial: R1 | R2
    trials: int = 20  # trials (vehicle, start seed), the same for every method
    methods: tuple[str, ...] = ("pure", "pure-avg", "hybrid")  # any of hybrid_calib.hybrid.METHODS
    seed: int = 0  # first start seed
    hybrid: HybridConfig = HybridConfig()  # shared settings (checkpoint, max_frames, window, measurement, ...)

    def __post_init__(self):
        if not self.methods:
            raise ValueError(f"CompareConfig.methods is empty; valid: {METHODS}")
        if bad := [m for m in self.methods if m not in METHODS]:
            raise ValueError(f"CompareConfig.methods: unknown {bad}; valid: {METHODS}")
        if twice := sorted({m for m in self.methods if list(self.methods).count(m) > 1}):
            # probe 106: recorded twice in compare_config.json and run as two to-do lists (the command says it once)
            raise ValueError(f"CompareConfig.methods names {', '.join(twice)} more than once; name each method once")
        if self.range not in ("R1", "R2"):
            raise ValueError(f"CompareConfig.range={self.range!r}; valid: R1, R2")
        if self.trials < 1:
            raise ValueError("CompareConfig.trials must be >= 1")
        check_seed(self)
        if self.trials > MAX_TRIALS:  # each trial is a calibration of seconds to minutes; the list was built first
            raise ValueError(f"CompareConfig.trials={self.trials} (--trials): more than {MAX_TRIALS} trials, each a "
                             "calibration of seconds to minutes, would not finish; pass at most "
                             f"{MAX_TRIALS}, or split the comparison over several --out folders")
        if "oracle" in self.methods and self.hybrid.split != "all":
            raise ValueError(f"CompareConfig: method oracle uses every frame; split={self.hybrid.split!r} is for the "
                             "learned methods (drop oracle or the split)")


MAX_TRIALS = 10_000  # CompareConfig.trials: 20-100 measure a method; 10 000 run for days on a workstation


def _trial_file(out: Path, method: str, k: int) -> Path:
    return out / "trials" / method / f"{k:04d}.json"


def trials_not_asked(out: Path, methods: tuple[str, ...], trials: int) -> list[str]:
    """The method of each trial file in ``out`` outside ``methods`` x ``range(trials)`` (an earlier run of more
    trials or other methods: kept on disk, not in this run's tables), sorted."""
    asked = {(m, k) for m in methods for k in range(trials)}
    return sorted(p.parent.name for p in (Path(out) / "trials").glob("*/[0-9]*.json")
                  if p.stem.isdigit() and (p.parent.name, int(p.stem)) not in asked)


@dataclass(frozen=True)
class TrialsRun:
    """What ``run_trials`` did. Bad data does not stop the comparison: a failed trial writes no file, so a rerun
    tries it again."""

    vehicles_left_out: dict[str, str]  # vehicle (or "every vehicle of ROOT") -> why none of its frames reads
    trials_failed: tuple[dict, ...]  # {"trial", "method", "vehicle", "reason"}
    trials_kept: int  # finished by an earlier run (same data, network and options)
    trials_run: int


@dataclass(frozen=True)
class MethodSummary:
    """The table row of one method over its trials (module doc, step 3). Errors: ``metrics.METRIC_KEYS`` (deg, cm)."""

    trials: int
    mean: dict[str, float]
    median: dict[str, float]
    consistency: dict  # {"n", "nees_mean", "nees_median", "coverage_95"} of the final estimates (dof 6)
    consistency_per_root: dict[str, dict]  # the same per root (scenario), by its label
    not_ok_fraction: float  # trials whose status is not "ok"
    inconclusive_fraction: float
    ms_per_frame: float | None  # CPU wall time per frame (hybrid: network + window)
    frames_mean: float
    # the errors' std over the trials (ddof 1; 0 for one trial): how far a mean of so few trials can move
    std: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class CompareResult:
    """What ``compare`` returns; ``to_dict`` is ``OUT/compare.json``."""

    range: str
    trials: int
    roots: tuple[str, ...]
    command: str
    config: dict  # compare_config.json: the data, network and options the trials ran with
    methods: dict[str, MethodSummary]  # the methods with at least one finished trial
    run: TrialsRun
    # what the trials say of the run as a whole, once (a start range wider than the checkpoint's: its rows are of a
    # network outside what it learned; probe 45 found it said only in a failed trial's reason)
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict:
        return {"range": self.range, "trials": self.trials, "roots": list(self.roots), "command": self.command,
                "config": self.config, "notes": list(self.notes),
                "methods": {m: s.to_dict() for m, s in self.methods.items()},
                "vehicles_left_out": self.run.vehicles_left_out, "trials_failed": list(self.run.trials_failed),
                "trials_kept": self.run.trials_kept, "trials_run": self.run.trials_run}


def run_trials(roots: list, version: str, out: Path, conf: CompareConfig, progress: bool = True) -> TrialsRun:
    """Step 1-2 of the module doc."""
    from tqdm import tqdm

    hconf = dataclasses.replace(conf.hybrid, start=conf.range, progress=False,
                                cache_dir=conf.hybrid.cache_dir or str(out.resolve() / "network-cache"),
                                depth_cache=conf.hybrid.depth_cache or str(out.resolve() / "depth-cache"))
    learned = any(m != "oracle" for m in conf.methods)
    sessions, left_out = [], {}
    for r in roots:
        try:
            sessions.append(_Session(r, version, dataclasses.replace(hconf, method="hybrid" if learned else "oracle"),
                                     depth_option="--set depth"))  # compare has no --depth (probe 130)
        except CheckpointError:  # the network's file, not this root: no root can be compared (it read "no vehicle")
            raise
        except DataError as e:  # no vehicle of this root reads: the other roots are compared
            left_out[f"every vehicle of {r}"] = str(e)
    vehicles = [(s, name) for s in sessions for name in s.drives]
    left_out.update({name: reason for s in sessions for name, reason in s.unreadable.items()})
    if not vehicles:
        raise HybridCalibError(f"no vehicle in {roots}" + (f": {failed_vehicles_message(left_out)}" if left_out
                                                          else ""))
    failed = []
    # a kept trial must be this trial's: its vehicle, root and start seed (probe 131: a trial file of another seed or
    # of a root left out since was kept, one (vehicle, start) counted twice and a left-out root's trials in the tables)
    todo = [(k, m) for k in range(conf.trials) for m in conf.methods
            if _read_trial(_trial_file(out, m, k), m, k, vehicles[k % len(vehicles)][1],
                           str(Path(vehicles[k % len(vehicles)][0].data).resolve()),
                           conf.seed + k // len(vehicles)) is None]
    for k, method in tqdm(todo, desc="compare trials", disable=not progress):
        s, name = vehicles[k % len(vehicles)]
        c = dataclasses.replace(hconf, method=method, seed=conf.seed + k // len(vehicles))
        drive = s.drives[name]
        try:
            vr = (vehicle_oracle(s.data, version, drive, c) if method == "oracle"
                  else vehicle_learned(s.runner, drive, c, s.note, s.motion, s.frames))
        except DataError as e:  # this drive's data: recorded, the other trials go on
            failed.append({"trial": k, "method": method, "vehicle": name, "reason": str(e)})
            continue
        vr.config = {**(vr.config or {}), "trial": k, "root": str(Path(s.data).resolve())}  # one spelling per root
        path = _trial_file(out, method, k)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_json_atomic(path, vr.to_dict())
        except (OSError, HybridCalibError) as e:  # the trial is computed: the comparison goes on without keeping it
            failed.append({"trial": k, "method": method, "vehicle": name,
                           "reason": f"computed, but its trial file could not be written ({e}); rerun to compute it "
                                     "again once the path is free"})
    kept = conf.trials * len(conf.methods) - len(todo)
    return TrialsRun(left_out, tuple(failed), kept, len(todo) - len(failed))


def load_trials(out: Path, method: str, trials: int) -> list[VehicleResult]:
    return [r for k in range(trials) if (r := _read_trial(_trial_file(out, method, k), method, k)) is not None]


def _read_trial(path: Path, method: str, k: int, vehicle: str | None = None, root: str | None = None,
                seed: int | None = None) -> VehicleResult | None:
    """Trial ``k`` of ``method`` (on ``vehicle`` of ``root`` from start seed ``seed``, when given) from ``path``, or
    None when there is none yet. A file that does not read back as that trial (cut short by a crash, edited, another
    schema, or another method's, trial's, vehicle's, root's or seed's result there) is reported on stderr and counts
    as not done, so it is rerun."""
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text())
        if not isinstance(doc, dict):
            raise TypeError(f"a JSON {type(doc).__name__}, not an object")
        vr = VehicleResult.from_dict(doc)
        if vr.error is None:  # every trial is scored (probe 45: an internal error); the loader checks the block whole
            raise ValueError("it holds no error against the truth or the tables (its 'error' block is missing)")
        holds = {"method": vr.method, "trial": (vr.config or {}).get("trial"), "vehicle": vr.vehicle,
                 "root": (vr.config or {}).get("root"), "seed": (vr.start or {}).get("seed")}
        wanted = {"method": method, "trial": k, **({"vehicle": vehicle} if vehicle is not None else {}),
                  **({"root": root} if root is not None else {}), **({"seed": seed} if seed is not None else {})}
        if wrong := [f"{key} {holds[key]!r}" for key, want in wanted.items() if holds[key] != want]:
            raise ValueError(f"it holds the result of {', '.join(wrong)}, not trial {k} of {method}"
                             + (f" on {vehicle}" if vehicle else ""))
        return vr
    except (OSError, ValueError, KeyError, TypeError, AttributeError, RecursionError) as e:
        print(f"compare: trial file {path} is unreadable ({type(e).__name__}: {str(e)[:200]}); running that trial "
              "again",
              file=sys.stderr)
        return None


def summarize_method(results: list[VehicleResult], labels: dict[str, str] | None = None) -> MethodSummary:
    """The table row of one method over its trials (module doc, step 3); ``labels``: root (as its trials record it)
    -> its name in the per-root rows (``data.files.root_labels``; default the folder name)."""
    errs = [r.error for r in results]
    nees = np.array([e["nees"] for e in errs])
    per_root: dict[str, list[float]] = {}
    # by the root itself, not its spelling: a run resumed with the roots typed otherwise put one root's kept trials
    # under another of the same folder name (probe 113); a trial recorded before holds the spelling of its run
    named = {str(Path(k).resolve()): v for k, v in (labels or {}).items()}
    for r in results:
        root = str((r.config or {}).get("root", ""))
        per_root.setdefault(named.get(str(Path(root).resolve()), Path(root).name), []).append(r.error["nees"])
    ms = []
    for r in results:
        net = {row["frame_id"]: row.get("network_ms", 0.0) for row in r.frame_rows}
        ms += [f.solve_ms + f.cov_ms + (net.get(f.frame_id, 0.0) if r.method == "hybrid" else 0.0)
               for f in r.trajectory]
    return MethodSummary(
        trials=len(results),
        mean={k: float(np.mean([e[k] for e in errs])) for k in METRIC_KEYS},
        median={k: float(np.median([e[k] for e in errs])) for k in METRIC_KEYS},
        consistency=consistency(nees),
        consistency_per_root={k: consistency(np.array(v)) for k, v in sorted(per_root.items())},
        not_ok_fraction=float(np.mean([status_kind(r.final.status) != "ok" for r in results])),
        inconclusive_fraction=float(np.mean([status_kind(r.final.status) == "inconclusive" for r in results])),
        ms_per_frame=float(np.mean(ms)) if ms else None,
        frames_mean=float(np.mean([r.n_frames for r in results])),
        std={k: float(np.std([e[k] for e in errs], ddof=1)) if len(errs) > 1 else 0.0 for k in METRIC_KEYS},
    )


def inconclusive_words(summary: CompareResult) -> str:
    """"hybrid: 2 of 2; pure-avg: 1 of 2" for the methods with inconclusive trials ("" when none is)."""
    return "; ".join(f"{m}: {round(s.inconclusive_fraction * s.trials)} of {s.trials}"
                     for m, s in summary.methods.items() if s.inconclusive_fraction > 0)


def _markdown(summary: CompareResult, conf: CompareConfig, command: str) -> str:
    # called from Python, no command line: said so, not an empty "Command: ``" (probe 51)
    said = f"Command: `{command}`" if command else "Called from Python (hybrid_calib.compare.compare), no command line"
    lines = [f"# compare: range {conf.range}, {conf.trials} trials", "", said, "",
             *[f"**Note:** {n}\n" for n in summary.notes],
             "Errors against the truth (simulated) or the tables (real roots); rotation in degrees, translation "
             "in cm. Time per frame (ms/frame): CPU wall time, the network pass included for every learned "
             "method (hybrid: network + window; pure, pure-avg: the network pass; oracle: the window).", ""]
    for stat in ("mean", "median"):
        lines += [f"## {stat} over trials", "",
                  "| method | R.Mean | Roll | Pitch | Yaw | Geodesic | T.Mean | X | Y | Z | Norm |",
                  "|---|---|---|---|---|---|---|---|---|---|---|"]
        for m, s in summary.methods.items():
            e = getattr(s, stat)
            lines.append(f"| {m} | {e['rot_mean_deg']:.3f} | {e['roll_deg']:.3f} | {e['pitch_deg']:.3f} | "
                         f"{e['yaw_deg']:.3f} | {e['geodesic_deg']:.3f} | {e['trans_mean_cm']:.2f} | {e['x_cm']:.2f} | "
                         f"{e['y_cm']:.2f} | {e['z_cm']:.2f} | {e['trans_norm_cm']:.2f} |")
        lines.append("")
    lines += ["## covariance and status", "",
              "| method | trials | mean NEES (6 if honest) | median NEES | coverage of the 95 % ellipsoid | not ok "
              "(weak or inconclusive) | inconclusive | ms/frame | frames |", "|---|---|---|---|---|---|---|---|---|"]
    for m, s in summary.methods.items():
        c = s.consistency
        ms = "-" if s.ms_per_frame is None else f"{s.ms_per_frame:.0f}"
        lines.append(f"| {m} | {s.trials} | {c['nees_mean']:.2f} | {c['nees_median']:.2f} | "
                     f"{100 * c['coverage_95']:.0f} % | {100 * s.not_ok_fraction:.0f} % | "
                     f"{100 * s.inconclusive_fraction:.0f} % | {ms} | {s.frames_mean:.1f} |")
    # how far a mean of so few trials moves, and which methods look for a step (probe 131: 0.545 against 0.544 deg
    # over 4 trials read as a table of winners, with no spread beside it)
    spread = "; ".join(f"{m} {s.std['rot_mean_deg']:.3f} deg, {s.std['trans_mean_cm']:.2f} cm"
                       for m, s in summary.methods.items() if s.std)
    if spread:
        lines += ["", f"Spread over the trials (std of R.Mean, T.Mean): {spread}. Two methods' means closer than about "
                      "twice that over the square root of the trials are within the trials' noise (the same starts: "
                      "compare them trial by trial in trials/)."]
    steps = [m for m in summary.methods if m in ("hybrid", "oracle")]
    lines += ["", "Step tests: " + (f"{' and '.join(steps)} look{'s' if len(steps) == 1 else ''} for a step inside the "
                                    "drive (hybrid: the radar mount monitor, turns in yaw; oracle: the window's test)"
                                    if steps else "none of these methods looks for a step inside the drive")
              + ("; pure and pure-avg look for none" if any(m in ("pure", "pure-avg") for m in summary.methods)
                 else "") + "."]
    if said := inconclusive_words(summary):  # read where the figures are (probe 54: said in compare.json alone)
        lines += ["", f"**Inconclusive trials** ({said}): their estimates are in the tables above but are not to be "
                      "trusted, whatever their covariance; why, in each trial's status (trials/)."]
    done = {m: s.trials for m, s in summary.methods.items()}
    short = [f"{m}: {done.get(m, 0)} of {conf.trials}" for m in conf.methods if done.get(m, 0) < conf.trials]
    if short:  # the rows are then not over the same trials: said where they are read
        lines += ["", f"**Not every trial finished** ({'; '.join(short)}): those rows are over fewer trials than the "
                      "others; why each failed is in compare.json (trials_failed), and a rerun tries them again."]
    if summary.run.vehicles_left_out:  # the trials then went to the other vehicles: said where they are read
        lines += ["", f"**Left out** (none of their frames reads; the trials went to the other vehicles): "
                      f"{', '.join(sorted(summary.run.vehicles_left_out))}; why, in compare.json (vehicles_left_out)."]
    lines += ["", "Per root (scenario): mean NEES / coverage", ""]
    for m, s in summary.methods.items():
        parts = [f"{k}: {c['nees_mean']:.1f} / {100 * c['coverage_95']:.0f} %" for k, c in
                 s.consistency_per_root.items()]
        lines.append(f"- {m}: " + "; ".join(parts))
    return "\n".join(lines) + "\n"


# keys of compare_config.json that do not change what a trial gives: how the run ran, the trial count (more trials
# extend a run), the methods (each has its own trial files) and the checkpoint paths (their contents are "network")
_NOT_OF_A_TRIAL = ("trials", "methods", "hybrid.threads", "hybrid.progress", "hybrid.cache_dir", "hybrid.depth_cache",
                   "hybrid.checkpoint", "hybrid.refine",
                   "hybrid.start")  # = range, compared as "range" (records before 2026-12-04 hold "reference")


_WHOLE = ("data", "network", "hybrid.data", "hybrid.measurement", "hybrid.split_options")  # compared as one value


def _record(roots: list, version: str, conf: CompareConfig) -> dict:
    """What the trials of ``conf`` on ``roots`` depend on (``compare_config.json``): the config, the roots (resolved:
    "./sim" and "sim" are one) with their data stamps (``data.files.data_stamp``: a re-simulated or re-downloaded
    root is other data) and, for the learned methods, the checkpoints' contents (``hybrid.loop.network_identity``)."""
    from hybrid_calib.data.files import data_stamp
    from hybrid_calib.hybrid.loop import network_identity

    learned = any(m != "oracle" for m in conf.methods)
    hconf = dataclasses.replace(conf.hybrid, start=conf.range, method="hybrid" if learned else "oracle")
    # the trials' hybrid block as they ran it: from the range's starts (not the default "reference"); the method and
    # the seed are each trial's own (``methods``, ``seed``), so not recorded as one value
    record = to_dict(dataclasses.replace(conf, hybrid=dataclasses.replace(conf.hybrid, start=conf.range)))
    for key in ("method", "seed"):
        record["hybrid"].pop(key, None)
    return {**record, **network_identity(hconf),
            "data": {"roots": [str(Path(r).resolve()) for r in roots], "version": version,
                     "stamps": [data_stamp(r, version)["digest"] for r in roots]}}


def _differences(previous: dict, record: dict) -> list[str]:
    """What differs between the record of the kept trials and this run's, in words (``_NOT_OF_A_TRIAL`` aside; a
    key the earlier record lacks is not held against it)."""
    words = []
    was, now = previous.get("data"), record["data"]
    if isinstance(was, dict):
        if [was.get("roots"), was.get("version")] != [now["roots"], now["version"]]:
            words.append(f"other roots or --version ({', '.join(map(str, was.get('roots') or []))}; "
                         f"{was.get('version')})")
        elif changed := stamps_changed(was, now):
            words.append(changed)
    if "network" in previous and "network" in record and previous["network"] != record["network"]:
        was_h, now_h = previous.get("hybrid") or {}, record.get("hybrid") or {}
        if not (was_h.get("checkpoint") or now_h.get("checkpoint")) and previous.get("range") != record.get("range"):
            # no --checkpoint either time: the range chose the shipped checkpoint (probe 45: this read "another
            # network checkpoint ... retrained or edited" to a user who passed none)
            words.append(f"another --range ({previous.get('range')} -> {record.get('range')}), and with it the shipped "
                         "network checkpoint of that range")
        else:
            words.append("another network checkpoint (the checkpoint's files differ: another file, or retrained or "
                         "edited at the same path)")
    options = changed_options(previous, record, skip=("data", "network") + _NOT_OF_A_TRIAL, whole=_WHOLE)
    return words + ([f"another configuration ({'; '.join(options)})"] if options else [])


def _check_roots(roots: list, version: str, methods) -> tuple[list, dict[str, str]]:
    """(the roots to compare, {"every vehicle of ROOT": why} of those left out). A root without the version folder is
    left out when another root has it (as ``fleet`` does; with one root, or none that has it, the first one's error
    is raised); a root named twice, and oracle on a real root, are refused. All before any trial is run or any file
    written (a root whose vehicles do not read is left out later, and the others compared)."""
    from hybrid_calib.data.tables import version_dir

    seen: dict[str, str] = {}
    kept, left_out, first = [], {}, None
    for r in roots:
        if (key := str(Path(r).resolve())) in seen:  # its trials would be counted twice as independent ones
            raise HybridCalibError(f"--data names the root {key} twice ({seen[key]} and {r}); give each root once")
        seen[key] = str(r)
        try:
            version_dir(r, version)
        except DataError as e:
            first = first or e
            left_out[f"every vehicle of {r}"] = str(e)
            continue
        kept.append(r)
    if not kept:
        raise first
    if "oracle" not in methods:
        return kept, left_out
    from hybrid_calib.data.nuscenes import simulated_root

    real = [str(r) for r in roots if (Path(r) / version).is_dir() and not simulated_root(r, version)]
    if real:
        raise HybridCalibError(f"method oracle needs simulated roots (the true reflectors); {', '.join(real)} "
                               f"{'is a real root' if len(real) == 1 else 'are real roots'}: drop oracle from "
                               "--methods (hybrid, pure and pure-avg run on real data)")
    return kept, left_out


def compare(roots: list | str, version: str, out: str | Path, conf: CompareConfig | dict | None = None,
            command: str = "", progress: bool = True, overwrite: bool = False) -> CompareResult:
    """Run (or resume) every trial, then write compare.json, compare.md and the plot; returns their summary.
    ``overwrite``: the kept trials, tables and own caches of ``out`` are removed first."""
    conf = merge(CompareConfig, conf)
    out = Path(out)
    if isinstance(roots, (str, os.PathLike)):  # one root: "sim" was read as the roots "s", "i", "m" (probe 51)
        roots = [roots]
    check_api_out(out, "compare", roots[0] if len(roots) == 1 else None, version)
    check_not_being_written(roots, "data")  # each root (probe 142: the command checked its --data only)
    roots, roots_left_out = _check_roots(roots, version, conf.methods)
    with out_dir_lock(out, "compare", reentrant=True):  # probe 140: a library run and a command in one folder
        return _compare_into(roots, roots_left_out, version, out, conf, command, progress, overwrite)


def _compare_into(roots: list, roots_left_out: dict, version: str, out: Path, conf: CompareConfig, command: str,
                  progress: bool, overwrite: bool) -> CompareResult:
    """``compare`` once its folder and roots are checked and its folder locked."""
    import shutil

    from hybrid_calib.plots.compare import plot_error_vs_frames

    cfg_path = out / "compare_config.json"
    record = _record(roots, version, conf)
    if overwrite:
        from hybrid_calib.hybrid.network import clear_own_caches

        clear_own_caches(out, conf.hybrid.cache_dir, conf.hybrid.depth_cache)
        shutil.rmtree(out / "trials", ignore_errors=True)
        for name in ("compare_config.json", "compare.json", "compare.md", "error_vs_frames.png"):
            (out / name).unlink(missing_ok=True)
    previous = read_out_record(cfg_path, "compare config", "the configuration its trials were run with: pass "
                               "--overwrite to start over, or use another --out")
    if previous is not None and not any((out / "trials").glob("*/*.json")):
        previous = None  # a run that stopped before its first trial (a broken checkpoint): nothing to keep or refuse
    if previous is not None and "data" not in previous:  # written before the roots were recorded
        previous = {**previous, "data": record["data"]}
    if previous is not None and (changed := _differences(previous, record)):
        raise HybridCalibError(f"{out} holds trials of {'; '.join(changed)} ({cfg_path}), which this run would "
                               "report as its own; pass the same options, --overwrite to start over, or another --out")
    if previous is not None and "network" in previous and "network" not in record:  # an oracle-only rerun: the kept
        record["network"] = previous["network"]  # learned trials keep the identity of the network that made them
    first = previous is None and not cfg_path.exists()
    save_json_atomic(cfg_path, record)
    try:
        problems = run_trials([str(r) for r in roots], version, out, conf, progress)
    except HybridCalibError:  # refused before a trial ran (a split that holds no vehicle): leave the folder as it was
        if first and not any((out / "trials").glob("*/*.json")):
            cfg_path.unlink(missing_ok=True)
        raise
    if roots_left_out:  # said with the vehicles that do not read (compare.json, compare.md, the terminal)
        problems = dataclasses.replace(problems, vehicles_left_out={**roots_left_out, **problems.vehicles_left_out})
    results = {m: load_trials(out, m, conf.trials) for m in conf.methods}
    labels = root_labels([str(r) for r in roots], "/")
    if not any(results.values()):
        first = problems.trials_failed[0]["reason"] if problems.trials_failed else "-"
        raise DataError(f"no trial finished ({len(problems.trials_failed)} failed; first: {first})",
                        path=str(roots[0]))
    notes = tuple(dict.fromkeys(n for rs in results.values() for r in rs if (n := (r.config or {}).get("range_note"))))
    summary = CompareResult(conf.range, conf.trials, tuple(str(r) for r in roots), command, record,
                            {m: summarize_method(rs, labels) for m, rs in results.items() if rs}, problems, notes)
    save_json_atomic(out / "compare.json", summary.to_dict())
    save_text_atomic(out / "compare.md", _markdown(summary, conf, command))
    plot_error_vs_frames(results, out / "error_vs_frames.png")
    return summary
