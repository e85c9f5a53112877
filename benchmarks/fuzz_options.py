"""Bad-input fuzz of the command line: every ``--set`` option of a command, or its flags, set to odd values.

A serious tool meets a bad option with one line naming it (exit 2), never with an internal error (exit 3, a bug),
a hang or a runaway: this script finds the values that end otherwise. Each run is a real command, in-process
(``hybrid_calib.cli.main``), on a tiny root the script simulates (2 vehicles x 6 frames, image_scale 0.125), with a
per-run time limit.

- ``--mode set``: every numeric / string / list leaf of the command's config (``CalibrateConfig`` for
  ``--method oracle``, ``HybridConfig`` for the network methods) set to -1, 0, 1e-9, 1e6, 1e300, 1e12 (ints), "zzz",
  [] ... The values ``merge`` refuses are counted as refused (exit 2 at start, the intended answer); the others run.
- ``--mode flags``: each command's count and fraction flags (``--workers``, ``--trials``, ``--max-frames``,
  ``--window``, ...) set to -1, 0, 999999999, 1e9, nan, "", 0.5, 1, 2. ``--workers`` values above the machine's
  limit are refused by argparse; a value that is accepted runs (``--workers 999999999`` forked until the machine
  stopped before session 21: run this only where that cannot hurt).

Prints one line per run that ended with exit 3 or a hang, and a summary: runs, refused at start, ran, bad.

    PYTHONPATH=. .venv/bin/python benchmarks/fuzz_options.py --mode set --method oracle --out outputs/fuzz
    PYTHONPATH=. .venv/bin/python benchmarks/fuzz_options.py --mode set --method hybrid --out outputs/fuzz
    PYTHONPATH=. .venv/bin/python benchmarks/fuzz_options.py --mode flags --out outputs/fuzz
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import shutil
import signal
from pathlib import Path

CHECKPOINT = Path(__file__).resolve().parents[1] / "learned" / "checkpoints" / "small-sim-r1.json"
SKIP_SET = ("checkpoint", "refine", "cache_dir", "depth_cache", "vehicles", "data.vehicles", "data.scenes", "method",
            "split", "start", "depth", "progress", "max_frames", "seed")  # flags' own keys, or paths
FLAG_VALUES = ["-1", "0", "999999999", "1e9", "nan", "", "0.5", "1", "2"]


class _Hang(BaseException):
    pass


def _alarm(*_):
    raise _Hang()


def leaves(cls, prefix: str = ""):
    """(dotted key, default) of every non-config field of the config class ``cls``, depth first."""
    default = cls()
    for f in dataclasses.fields(cls):
        value = getattr(default, f.name)
        if dataclasses.is_dataclass(value):
            yield from leaves(type(value), f"{prefix}{f.name}.")
        else:
            yield f"{prefix}{f.name}", value


def odd_values(default) -> list:
    if isinstance(default, bool):
        return ["maybe"]
    if isinstance(default, int):
        return [-1, 0, 10**6, 10**12]
    if isinstance(default, float):
        return [-1.0, 0.0, 1e-9, 1e6, 1e300]
    if isinstance(default, str):
        return ["zzz", ""]
    if isinstance(default, tuple):
        return [[], [0] * max(len(default), 1), [1e300] * max(len(default), 1)]
    return []


def nest(key: str, value) -> dict:
    out: dict = {}
    cur = out
    *parents, last = key.split(".")
    for p in parents:
        cur = cur.setdefault(p, {})
    cur[last] = value
    return out


def run(argv: list[str], limit_s: int) -> object:
    """The exit status of ``hybrid-calib ARGV`` ("HANG" past ``limit_s``), its output swallowed."""
    from hybrid_calib.cli import main

    signal.alarm(limit_s)
    try:
        with contextlib.redirect_stderr(io.StringIO()) as err, contextlib.redirect_stdout(io.StringIO()):
            try:
                rc = main([str(a) for a in argv])
            except SystemExit as e:
                rc = e.code
    except _Hang:
        return "HANG", ""
    finally:
        signal.alarm(0)
    return rc, err.getvalue().strip().splitlines()[-1:] if err.getvalue().strip() else []


def fuzz_set(root: Path, out: Path, method: str, limit_s: int) -> dict:
    from hybrid_calib.calib.pipeline import CalibrateConfig
    from hybrid_calib.config import merge
    from hybrid_calib.hybrid.loop import HybridConfig

    cls = CalibrateConfig if method == "oracle" else HybridConfig
    base = ["calibrate", "--data", root, "--version", "v1.0-sim", "--method", method, "--max-frames", "2",
            "--no-plots", "--start", "R1", "--out", out / "run"]
    counts = {"runs": 0, "refused_at_start": 0, "ran": 0, "bad": []}
    for key, default in leaves(cls):
        if key.startswith(SKIP_SET):
            continue
        for value in odd_values(default):
            counts["runs"] += 1
            try:
                merge(cls, nest(key, value))
            except Exception:  # noqa: BLE001 - refused at start: the intended answer
                counts["refused_at_start"] += 1
                continue
            shutil.rmtree(out / "run", ignore_errors=True)
            rc, last = run([*base, "--set", f"{key}={json.dumps(value)}"], limit_s)
            counts["ran"] += 1
            if rc not in (0, 1, 2):
                counts["bad"].append(f"{key}={value!r}: exit {rc} {last}")
                print(counts["bad"][-1], flush=True)
    return counts


def fuzz_flags(root: Path, out: Path, limit_s: int) -> dict:
    o = out / "run"
    base = {
        "simulate": ["simulate", "--vehicles", "1", "--frames", "2", "--set", "image_scale=0.125", "--out", o],
        "inspect": ["inspect", "--data", root, "--version", "v1.0-sim", "--out", o, "--no-progress"],
        "calibrate": ["calibrate", "--data", root, "--version", "v1.0-sim", "--max-frames", "2", "--no-plots", "--out",
                      o],
        "evaluate": ["evaluate", "--data", root, "--version", "v1.0-sim", "--checkpoint", CHECKPOINT, "--max-frames",
                     "2", "--split", "all", "--out", o, "--no-progress"],
        "compare": ["compare", "--data", root, "--version", "v1.0-sim", "--methods", "oracle", "--trials", "1",
                    "--max-frames", "2", "--out", o, "--no-progress"],
        "fleet": ["fleet", "--data", root, "--version", "v1.0-sim", "--max-frames", "2", "--no-plots", "--no-report",
                  "--out", o],
    }
    flags = {"simulate": ["--vehicles", "--frames", "--seed", "--change-frame", "--workers"],
             "inspect": ["--nsweeps", "--frame"],
             "calibrate": ["--window", "--max-frames", "--seed", "--test-fraction", "--val-fraction", "--gap-frames"],
             "evaluate": ["--max-frames", "--nsweeps", "--test-fraction", "--gap-frames"],
             "compare": ["--trials", "--max-frames", "--seed", "--test-fraction"],
             "fleet": ["--workers", "--threads", "--retries", "--seed", "--max-frames"]}
    counts = {"runs": 0, "bad": []}
    for cmd, names in flags.items():
        for flag in names:
            for value in FLAG_VALUES:
                argv = list(base[cmd])
                if flag in argv:
                    argv[argv.index(flag) + 1] = value
                else:
                    argv += [flag, value]
                shutil.rmtree(o, ignore_errors=True)
                rc, last = run(argv, limit_s)
                counts["runs"] += 1
                if rc not in (0, 1, 2):
                    counts["bad"].append(f"{cmd} {flag} {value!r}: exit {rc} {last}")
                    print(counts["bad"][-1], flush=True)
    return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mode", choices=("set", "flags"), required=True)
    ap.add_argument("--method", choices=("oracle", "hybrid", "pure", "pure-avg"), default="oracle",
                    help="--mode set: the method whose config is fuzzed")
    ap.add_argument("--out", type=Path, required=True, help="work folder (the tiny root and each run's output)")
    ap.add_argument("--limit-s", type=int, default=120, help="per-run time limit (a run past it is a hang)")
    args = ap.parse_args()
    from hybrid_calib.config import merge
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    signal.signal(signal.SIGALRM, _alarm)
    root = args.out / "tiny"
    if not (root / "v1.0-sim").is_dir():
        simulate(merge(SimConfig, {"vehicles": 2, "frames": 6, "image_scale": 0.125, "seed": 55}), root, workers=1)
    counts = (fuzz_set(root, args.out, args.method, args.limit_s) if args.mode == "set"
              else fuzz_flags(root, args.out, args.limit_s))
    print(json.dumps({**counts, "bad": len(counts["bad"])}))


if __name__ == "__main__":
    main()
