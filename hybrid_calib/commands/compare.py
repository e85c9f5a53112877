"""``hybrid-calib compare``: pure vs pure-avg vs hybrid (vs oracle) on the same starts and network outputs."""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from hybrid_calib.commands import (
    add_split_arguments,
    given_flags,
    nonnegative_int,
    positive_int,
    reject_set_keys,
    seed_int,
    split_overrides,
    version_name,
)
from hybrid_calib.config import parse_overrides
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.errors import OptionError

HELP = "compare calibration methods on the same starts (tables, NEES, coverage, time per frame)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, nargs="+", required=True,
                   help="nuScenes root(s); their vehicles are the trials' drives (e.g. one root per scenario)")
    p.add_argument("--version", type=version_name,
                   default=SIM_VERSION, help=f"version folder (default: {SIM_VERSION})")
    p.add_argument("--range", default="R1", choices=("R1", "R2"), help="start range of every trial (default: R1)")
    p.add_argument("--trials", type=positive_int, default=20, help="trials (vehicle, start seed) (default: 20)")
    p.add_argument("--methods", default="pure,pure-avg,hybrid",
                   help="comma-separated: pure, pure-avg, hybrid, oracle (default: pure,pure-avg,hybrid)")
    p.add_argument("--checkpoint", default="", help="network checkpoint (default: the shipped one of --range)")
    p.add_argument("--refine", default="", help="refining network after --checkpoint (a cascade): 'shipped' (the "
                   "shipped R0 checkpoint) or a checkpoint path (default: none)")
    p.add_argument("--max-frames", type=nonnegative_int, default=None, help="frames per drive, 0 = all (default: 0)")
    p.add_argument("--seed", type=seed_int, default=0, help="first start seed (default: 0)")
    add_split_arguments(p, "all", "all, or the train / val / test part of the split flags below (e.g. --split test "
                                  "--split-by time: the held-out end of each scene; learned methods only)")
    p.add_argument("--out", type=Path, required=True, help="output folder (resumable: finished trials are kept)")
    p.add_argument("--set", action="extend", nargs="+", metavar="KEY=VALUE", default=[],
                   help="HybridConfig overrides for every method, e.g. threads=1 window.window=30")
    p.add_argument("--overwrite", action="store_true", help="remove the trials, tables and network / depth caches "
                   "an earlier run left in --out and run every trial again from the data as they are now")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.compare import compare, inconclusive_words, trials_not_asked

    hybrid = parse_overrides(args.set)
    # compare sets these per trial from its own flags
    reject_set_keys(hybrid, {"method": "--methods", "start": "--range", "seed": "--seed", "split": "--split"})
    hybrid.update(split=args.split, **given_flags(args, {"max_frames": "max_frames"}, hybrid))
    for key in ("checkpoint", "refine"):
        if getattr(args, key):  # "" = not passed: --set (or the default) stays in charge
            hybrid[key] = getattr(args, key)
    if flags := split_overrides(args):
        hybrid["split_options"] = {**hybrid.get("split_options", {}), **flags}
    named = [m.strip() for m in args.methods.split(",") if m.strip()]
    methods = tuple(dict.fromkeys(named))  # once each, in order
    if twice := [m for m in methods if named.count(m) > 1]:  # it had compared them once in silence
        print(f"note: --methods names {', '.join(twice)} more than once; each method is compared once",
              file=sys.stderr)
    if not methods:
        raise OptionError("--methods", f"{args.methods!r} names no method; pass a comma-separated list of pure, "
                                       "pure-avg, hybrid, oracle")
    network = [flag for flag in ("--checkpoint", "--refine") if getattr(args, flag[2:])]
    if network and set(methods) <= {"oracle"}:  # the oracle runs no network: they were accepted and ignored (p37)
        raise OptionError(network[0], f"is for the learned methods (pure, pure-avg, hybrid); --methods oracle runs no "
                                      f"network: drop {' and '.join(network)}, or add a learned method to --methods")
    conf = {"range": args.range, "trials": args.trials, "seed": args.seed, "hybrid": hybrid, "methods": methods}
    command = " ".join(["hybrid-calib", *map(shlex.quote, getattr(args, "argv", sys.argv[1:]))])
    s = compare(args.data, args.version, args.out, conf, command=command, progress=not args.no_progress,
                overwrite=args.overwrite)
    for note in s.notes:
        print(f"note: {note}")
    for m, r in s.methods.items():
        e, d, c = r.mean, r.median, r.consistency
        print(f"{m:>9}: rot mean {e['rot_mean_deg']:.3f} deg (median {d['rot_mean_deg']:.3f}), trans mean "
              f"{e['trans_mean_cm']:.2f} cm (median {d['trans_mean_cm']:.2f}); NEES {c['nees_mean']:.1f}, "
              f"coverage {100 * c['coverage_95']:.0f} %, not ok {100 * r.not_ok_fraction:.0f} %, inconclusive "
              f"{100 * r.inconclusive_fraction:.0f} %")
    if said := inconclusive_words(s):
        print(f"note: inconclusive trials ({said}): their estimates are in the tables but are not to be trusted, "
              f"whatever their covariance; why, in each trial's status ({args.out / 'trials'})")
    if s.run.trials_kept:  # a rerun: say what it reused (calibrate says so too)
        print(f"kept {s.run.trials_kept} trial(s) an earlier run finished in {args.out / 'trials'} (same data, "
              f"network and options); ran {s.run.trials_run}")
    if more := trials_not_asked(args.out, methods, args.trials):  # an earlier run's: on disk, not in these tables
        print(f"note: {args.out / 'trials'} also holds {len(more)} finished trial(s) this run did not ask for (of "
              f"{', '.join(sorted(set(more)))}); the tables hold --trials {args.trials} of {','.join(methods)} only: "
              "rerun with the earlier --trials and --methods to see them again")
    for name, reason in s.run.vehicles_left_out.items():
        print(f"left out {name}: {reason}", file=sys.stderr)
    for t in s.run.trials_failed:
        print(f"trial {t['trial']} ({t['method']}, {t['vehicle']}) failed: {t['reason']}", file=sys.stderr)
    print(f"wrote {args.out / 'compare.md'}, compare.json and error_vs_frames.png")
    return 1 if s.run.vehicles_left_out or s.run.trials_failed else 0
