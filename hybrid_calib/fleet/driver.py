"""``run_fleet``: discover the jobs, open the manifest, run what is left on an engine, write the fleet view.

Resumable by construction (``manifest`` module doc): every job writes its result atomically, the
manifest is rewritten atomically on every change, so a driver killed at any moment (SIGINT,
SIGKILL) or a killed worker leaves a state the next run completes without losing or repeating a
finished vehicle.
"""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from pathlib import Path

from hybrid_calib.atomic import out_dir_lock
from hybrid_calib.errors import check_api_out, check_not_being_written
from hybrid_calib.fleet.engines import ENGINES, run_engine
from hybrid_calib.fleet.jobs import check_fleet_roots, discover_jobs, read_fleet_file
from hybrid_calib.fleet.manifest import Manifest
from hybrid_calib.fleet.prior import MIN_PRIOR_VEHICLES


@dataclass(frozen=True)
class FleetOptions:
    """How ``run_fleet`` runs (the command's options)."""

    engine: str = "local"  # local | process | ray
    workers: int = 1  # parallel jobs (process pool size, local Ray CPUs)
    address: str | None = None  # Ray cluster to join (None: start a local one)
    ray_temp: str | None = None  # Ray temp dir for a local cluster (default OUT/ray)
    object_store_mb: int = 200  # local Ray object store cap
    retries: int = 2  # system-failure retries per job (a killed worker, an OSError)
    threads: int = 1  # torch / BLAS threads per worker
    plots: bool = True  # fleet.png
    alpha: float = 1e-3  # fleet outlier test level

    def __post_init__(self):
        from hybrid_calib.config import require, require_ranges

        require_ranges(self, {"workers": "[1, 1e5]", "threads": "[1, 256]", "retries": "[0, 100]",
                              "object_store_mb": "[50, 1e6]", "alpha": "(0, 1)"})
        require(self, {f"engine in {ENGINES}": self.engine in ENGINES})  # was refused inside run_fleet as '--engine'


def run_fleet(roots: list[str] | str | None, manifest: str | None, version: str, method: str, out: str | Path,
              seed: int = 0, checkpoint: str | None = None, calib: dict | None = None, priors: dict | None = None,
              options: FleetOptions = FleetOptions(), on_outcome=None) -> dict:
    """Calibrate every vehicle of ``roots`` (or of the ``FLEET.json`` ``manifest``) into
    ``out/vehicles/<id>/`` and write ``out/manifest.json`` and the fleet view (``summary``);
    returns the summary dict. Done vehicles are skipped, failed ones retried. ``on_outcome(entry,
    counts)`` is called in the driver after each job (the command's progress bar)."""

    out = Path(out)
    if isinstance(roots, (str, os.PathLike)):  # one root: "sim" was read as the roots "s", "i", "m" (probe 51)
        roots = [roots]
    check_api_out(out, "fleet", roots[0] if roots and len(roots) == 1 else None, version)
    with out_dir_lock(out, "fleet", reentrant=True):  # probe 140: a library run and a command in one folder
        return _fleet_into(roots, manifest, version, method, out, seed, checkpoint, calib, priors, options,
                           on_outcome)


def _fleet_into(roots, manifest, version: str, method: str, out: Path, seed: int, checkpoint, calib, priors,
                options: FleetOptions, on_outcome) -> dict:
    """``run_fleet`` once its folder is checked and locked."""
    from hybrid_calib.fleet.summary import write_summary

    sources = read_fleet_file(manifest, version) if manifest else [(str(r), version, None) for r in roots or []]
    # each root, a manifest's too (probe 142: the command checked its --data only)
    check_not_being_written([src[0] for src in sources], "data" if not manifest else f"fleet manifest {manifest}")
    if manifest:
        check_fleet_roots(sources, manifest)
    notes: list[str] = []
    left_out: dict[str, str] = {}  # roots whose tables cannot be read: recorded, the other roots go on
    jobs = discover_jobs(sources, method, out, seed, checkpoint, calib, priors, options.threads, notes, left_out)
    if priors is not None and not any(j.prior is not None for j in jobs):
        named = sorted(k for k in priors if k != "*")
        star = priors.get("*")  # load_priors: a dict, {"outlier": True} for a named outlier's None
        why = ("and no new-vehicle prior '*'" if not isinstance(star, dict) or star.get("outlier") else
               "each of these vehicles is named in it without one: an outlier of its fit, or an inlier whose "
               f"leave-one-out prior rests on fewer than {MIN_PRIOR_VEHICLES} other vehicles; its new-vehicle prior "
               "'*' is for vehicles it does not name")
        notes.append(f"the fleet prior holds no prior for any of the {len(jobs)} vehicle(s) (its vehicles: "
                     f"{named[:6]}{', ...' if len(named) > 6 else ''}; {why}): none is applied")
    m = Manifest.open(out / "manifest.json", jobs, method, seed)
    notes += m.recovered
    if m.stale:
        notes.append(f"{len(m.stale)} vehicle(s) done by an earlier run are calibrated again: their root's data "
                     f"changed since ({', '.join(m.stale[:4])}{', ...' if len(m.stale) > 4 else ''})")
    if m.renamed:
        notes.append(f"{len(m.renamed)} vehicle(s) of an earlier run into this --out have a new id now that the roots "
                     f"differ ({', '.join(f'{a} -> {b}' for a, b in sorted(m.renamed.items())[:4])}): their results "
                     "moved with them, unless said otherwise")
    if earlier := sorted(set(m.jobs) - {j.id for j in jobs}):
        notes.append(f"the fleet view also holds {len(earlier)} vehicle(s) of earlier runs into this --out that this "
                     f"command did not list ({', '.join(earlier[:4])}{', ...' if len(earlier) > 4 else ''}): pass "
                     "another --out for a fleet of these roots alone")
    todo = m.todo()
    if kept := sum(m.jobs[j.id]["state"] == "done" for j in jobs if j.id in m.jobs):  # a rerun: say what it keeps
        notes.append(f"kept {kept} vehicle(s) an earlier run into this --out finished (same data and options); "
                     f"{len(todo)} to run")
    host = socket.gethostname()

    def record(o: dict) -> None:
        e = m.record(o)
        if on_outcome is not None:
            on_outcome({"id": o["id"], **e}, m.counts())

    try:
        run_engine(options.engine, todo, lambda ids: m.mark_running(ids, host), record, options.workers,
                   options.address, options.ray_temp or out / "ray", options.retries, None, options.object_store_mb)
    finally:  # also when interrupted: the bookkeeping of every finished job reaches the file, the others are pending
        m.release_running()
        m.flush()
    summary = write_summary(m, plot=options.plots, alpha=options.alpha, notes=notes, roots_left_out=left_out)
    return summary
