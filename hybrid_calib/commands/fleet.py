"""``hybrid-calib fleet``: calibrate every vehicle of a fleet (resumable; local, process pool or Ray)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hybrid_calib.commands import (
    MAX_PROCESSES,
    cluster_workers,
    given_flags,
    nonnegative_int,
    process_count,
    reject_learned_keys,
    reject_set_keys,
    reject_unused_batch,
    reject_unused_blocks,
    reject_unused_oracle,
    reject_unused_window,
    retry_count,
    seed_int,
    version_name,
)
from hybrid_calib.config import parse_overrides
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.errors import OptionError
from hybrid_calib.words import n_vehicles

HELP = "calibrate every vehicle of one or more roots as resumable jobs (local | process | ray) + fleet view"


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--data", type=Path, nargs="+", help="nuScenes root(s); one job per vehicle (log) of each")
    src.add_argument("--manifest", type=Path, help='FLEET.json: {"roots": [ROOT | {"data", "version", "vehicles"}]}; '
                     "a relative ROOT or data path is read from the manifest's folder (not the current one)")
    p.add_argument("--version", type=version_name,
                   default=SIM_VERSION, help=f"version folder under each root (default: {SIM_VERSION})")
    p.add_argument("--method", default="oracle", choices=("hybrid", "pure", "pure-avg", "oracle"),
                   help="per-vehicle method (default: oracle; the network methods come with the hybrid package)")
    p.add_argument("--checkpoint", type=Path, help="network checkpoint (network methods)")
    p.add_argument("--engine", default="local", choices=("local", "process", "ray"), help="default: local")
    p.add_argument("--address", help="Ray cluster to join, e.g. HEAD:6379 (every node: this package, and the roots "
                                     "and --out on a shared file system at the same paths; default: start a local "
                                     "Ray of --workers CPUs)")
    p.add_argument("--workers", type=cluster_workers, default=1,
                   help="parallel jobs (default: 1; with --address: at least the cluster's CPUs / --threads)")
    p.add_argument("--threads", type=process_count, default=1, help="torch / BLAS threads per worker (default: 1)")
    p.add_argument("--ray-temp", type=Path, help="temp dir of a local Ray (default: OUT/ray; keep it short)")
    p.add_argument("--retries", type=retry_count, default=2,
                   help="retries of a system failure (default: 2, at most 100)")
    p.add_argument("--prior", type=Path, help="fleet_prior.json of an earlier fleet run: each vehicle's prior "
                                              "(leave-one-out; the fleet's for a new vehicle; none for an outlier)")
    p.add_argument("--seed", type=seed_int, default=0,
                   help="fleet seed; each job seeds from (seed, vehicle) (default: 0)")
    p.add_argument("--max-frames", type=nonnegative_int, default=None, help="frames per vehicle, 0 = all (default: 0)")
    p.add_argument("--reference", default=None, metavar="EXPORT",
                   help="check each vehicle against the mount an earlier hybrid-calib export wrote for it (its --out "
                        "folder, or its export.json), not its tables: later drives after a recalibration (default: "
                        "the tables; a vehicle the export did not replace keeps them)")
    p.add_argument("--out", type=Path, required=True, help="fleet run directory (rerun the same command to resume)")
    p.add_argument("--no-plots", action="store_true", help="skip the fleet plot")
    p.add_argument("--no-report", action="store_true",
                   help="skip the HTML pages (OUT/fleet.html and a report.html beside each vehicle's result)")
    p.add_argument("--set", action="extend", nargs="+", metavar="KEY=VALUE", default=[],
                   help="overrides for every vehicle: CalibrateConfig keys for --method oracle (e.g. window.window=10 "
                        "mode=batch), HybridConfig keys for hybrid / pure / pure-avg (e.g. measurement.rows=none); "
                        "threads, seed, method and checkpoint are this command's flags")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hybrid_calib.calib.pipeline import CalibrateConfig
    from hybrid_calib.config import merge
    from hybrid_calib.fleet.driver import FleetOptions, run_fleet
    from hybrid_calib.fleet.prior import load_priors
    from hybrid_calib.fleet.summary import drifted_words
    from hybrid_calib.report import write_fleet_pages

    check_options(args)
    calib = parse_overrides(args.set)
    # each job's seed comes from the fleet seed and its vehicle; each job is one vehicle (probe 103: --set vehicles
    # was accepted, and every vehicle ran)
    reject_set_keys(calib, {"seed": "--seed", "vehicles": "a --manifest whose roots name their \"vehicles\""})
    # --max-frames wins over --set max_frames, --reference over --set reference
    calib.update(given_flags(args, {"max_frames": "max_frames", "reference": "reference"}, calib))
    if calib.get("reference"):  # read once here (a DataError naming the file), absolute: every worker reads it
        from hybrid_calib.data.reference import absolute_reference, load_export_reference

        calib["reference"] = absolute_reference(str(calib["reference"]))
        load_export_reference(calib["reference"])
    if args.method == "oracle":
        reject_learned_keys(calib)
        reject_unused_batch(calib, batch_flag="--set mode=batch")
        reject_unused_window(calib, batch_flag="--set mode=batch")
        reject_unused_oracle(calib)
        merge(CalibrateConfig, {**calib, "seed": args.seed})  # ConfigError names a bad option before any job runs
    else:  # the network methods' jobs merge --set into HybridConfig (fleet.jobs.calibrate_job): checked alike
        from hybrid_calib.hybrid import HybridConfig

        reject_set_keys(calib, {"method": "--method", "checkpoint": "--checkpoint", "threads": "--threads"})
        if unsupported := sorted(set(calib) & {"mode", "batch"}):  # every job would fail alike
            raise OptionError("--set", f"{', '.join(unsupported)}: --method {args.method} runs the sliding window "
                                       "(or the network alone), not a batch solve; drop it, or use --method oracle")
        reject_unused_blocks(args.method, calib)  # accepted, and without effect (probe 100), as calibrate
        merge(HybridConfig, {**calib, "method": args.method, "seed": args.seed})
    if args.checkpoint is not None and args.method != "oracle":  # one bad checkpoint would fail every job alike
        from learned.checkpoint import load_model

        load_model(args.checkpoint)  # CheckpointError naming the file: its metadata, export block and weights
    options = FleetOptions(args.engine, args.workers, args.address, None if args.ray_temp is None else
                           str(args.ray_temp), threads=args.threads, retries=args.retries, plots=not args.no_plots)
    bar = None  # made at the first finished vehicle (bad input fails before, without a bar)

    def progress(e: dict, counts: dict) -> None:
        nonlocal bar
        # no rate: its count is set by hand, as vehicles end (probe 119: "36792.14vehicle/s" in a log)
        bar = bar or tqdm(desc="fleet", unit="vehicle", bar_format="{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/"
                          "{total_fmt} [{elapsed}{postfix}]")
        bar.total = sum(counts.values())
        bar.n = counts["done"] + counts["failed"]
        bar.set_postfix(done=counts["done"], failed=counts["failed"])
        bar.refresh()
        what = e["reason"] if e["state"] == "failed" else e["result"]
        bar.write(f"{e['id']}: {e['state']} in {e['wall_s'] or 0:.1f} s on {e['host']}: {what}")

    summary = run_fleet(None if args.data is None else [str(d) for d in args.data],
                        None if args.manifest is None else str(args.manifest), args.version, args.method, args.out,
                        args.seed, None if args.checkpoint is None else str(args.checkpoint), calib,
                        None if args.prior is None else load_priors(args.prior), options, on_outcome=progress)
    if bar is not None:
        bar.close()
    c = summary["counts"]
    print(f"{n_vehicles(c['vehicles'])}: {c['done']} done, {c['failed']} failed; {c['out_of_tolerance']} out of "
          f"tolerance, {drifted_words(summary)}, {c['fleet_outliers']} fleet outlier(s)"
          + (f" ({', '.join(summary['fleet_prior']['outliers'])})" if c["fleet_outliers"] else "")
          + (f"; {c['doppler_off_tables']} whose radar's Doppler puts its yaw off its tables (check their yaw)"
             if c.get("doppler_off_tables") else "")
          + "".join(f"; {c[k]} {k} (not trusted: see their status)" for k in ("inconclusive", "degenerate")
                    if c.get(k)))
    for note in summary.get("notes") or []:
        print(f"  note: {note}")
    for root, why in (summary.get("roots_left_out") or {}).items():
        print(f"  left out root {root}: {why}")
    for jid, r in summary["vehicles"].items():
        if r["state"] == "failed":
            print(f"  failed {jid}: {r['reason']}")
    print(f"wrote {args.out / 'summary.md'}, {args.out / 'summary.json'}, {args.out / 'manifest.json'}; "
          f"per vehicle: {args.out / 'vehicles'}/<job>/result.json")
    if not args.no_report:
        page = write_fleet_pages(summary, args.out)
        if page is not None:
            print(f"fleet page: {page} (one report.html beside each vehicle's result.json)")
    return 0 if c["failed"] == 0 and not summary.get("roots_left_out") else 1


def check_options(args: argparse.Namespace) -> None:
    """``OptionError`` for an option the chosen --method / --engine would ignore, or (--prior with a network
    method) one that would fail every job alike."""
    if args.method == "oracle" and args.checkpoint is not None:
        raise OptionError("--checkpoint", "is for the network methods (--method hybrid, pure or pure-avg); --method "
                                          "oracle runs no network: drop --checkpoint, or pass a network --method")
    if args.method != "oracle" and args.prior is not None:
        raise OptionError("--prior", f"the fleet prior is applied by --method oracle only; --method {args.method} "
                                     "fuses the network's own prior: drop --prior, or use --method oracle")
    for flag, value in (("--address", args.address), ("--ray-temp", args.ray_temp)):
        if value is not None and args.engine != "ray":
            raise OptionError(flag, f"is for --engine ray; --engine {args.engine} starts no Ray: drop {flag}, or pass "
                                    "--engine ray")
    if args.engine == "ray" and args.address is None:  # before the manifest is written (probe 66)
        from hybrid_calib.fleet.engines import check_ray_temp

        check_ray_temp(args.ray_temp or args.out / "ray")
    if args.workers > 1 and args.engine == "local":
        raise OptionError("--workers", f"{args.workers} parallel jobs need --engine process or ray; --engine local "
                                       "runs one job at a time: pass --engine process, or drop --workers")
    if args.workers > MAX_PROCESSES and args.address is None:  # a cluster's CPUs may be more than one machine's
        raise OptionError("--workers", f"{args.workers} processes on this machine: at most {MAX_PROCESSES} (pass the "
                                       "cores to use); more only with --engine ray --address (a cluster)")
