"""Batch mode's fit-change test (``calib.batch.fit_change``) on simulated drives: how often a drive of one mount is
marked inconclusive (false), and whether a radar turned in yaw inside the drive is (found, and at which frame).

    PYTHONPATH=. .venv/bin/python benchmarks/batch_fit_change.py --out OUT [--seed 4901] [--frames 30]
        [--vehicles 2] [--scenarios urban highway] [--rot 0 0.5 1 3] [--start R1]

Per scenario and turn size one root of ``--vehicles`` drives (``hybrid-calib simulate``, image scale 0.25, reused
when present; a turn about the radar's z axis at the middle frame: the simulator's ``extrinsic_change`` step; 0: no
change), seeds ``--seed + 10 * scenario + step``. Each vehicle: oracle rows, the batch solve from its ``--start``
(``calib.pipeline.calibrate_vehicle``, mode batch). Prints one line per vehicle (the test's finding, the status's
first word, the NEES against the truth at the drive's end) and a summary: false findings on unchanged drives, found
turns and their frame against the true one. ``OUT/summary.json`` holds the lines.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

SCENARIOS = ("urban", "highway", "rain", "straight")


def simulate(root: Path, scenario: str, seed: int, frames: int, vehicles: int, rot: float) -> None:
    if (root / "v1.0-sim" / "sample.json").is_file():
        return
    change = (["--extrinsic-change", "step", "--set", f"extrinsic_change.rotation_deg=[0,0,{rot}]",
               "extrinsic_change.translation_m=[0,0,0]"] if rot else [])
    subprocess.run([sys.executable, "-m", "hybrid_calib.cli", "simulate", "--scenario", scenario, "--vehicles",
                    str(vehicles), "--frames", str(frames), "--seed", str(seed), "--no-progress", "--out", str(root),
                    "--set", "image_scale=0.25", *change], check=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--seed", type=int, default=4901)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--vehicles", type=int, default=2)
    p.add_argument("--scenarios", nargs="+", default=["urban", "highway"], choices=SCENARIOS)
    p.add_argument("--rot", nargs="+", type=float, default=[0.0, 0.5, 1.0, 3.0])
    p.add_argument("--start", default="R1")
    args = p.parse_args()
    from hybrid_calib.calib.pipeline import CalibrateConfig, calibrate_vehicle, load_oracle
    from hybrid_calib.config import merge

    conf = merge(CalibrateConfig, {"mode": "batch", "start": args.start})
    rows = []
    for scenario in args.scenarios:
        for j, rot in enumerate(args.rot):
            seed = args.seed + 10 * SCENARIOS.index(scenario) + j
            # the drive's own options in its name: a rerun with other --frames / --vehicles simulates its own drives
            # (probe 134: it reused the earlier ones and dated them against the new --frames)
            root = args.out / f"{scenario}-{rot:g}deg-{seed}-{args.frames}f{args.vehicles}v"
            simulate(root, scenario, seed, args.frames, args.vehicles, rot)
            for v, vi in load_oracle(root, "v1.0-sim", conf, progress=False, say=False).items():
                res = calibrate_vehicle(vi, conf, progress=False)
                change = (res.drift or {}).get("fit_change")
                row = {"root": root.name, "vehicle": v, "rot_deg": rot, "true_frame": args.frames // 2 if rot else None,
                       "found_frame": None if change is None else change["frame"],
                       "z": None if change is None else change["z"],
                       "status": "NOT CONVERGED" if "NOT CONVERGED" in res.final.status else
                       res.final.status.split(":")[0],
                       "nees": (res.error or {}).get("nees")}
                rows.append(row)
                found = ("no change" if not change else f"found at frame {change['frame']} (z {change['z']:.1f})"
                         if change["z"] is not None else f"found: a compromise of the two sides of frame "
                         f"{change['frame']} (each side alone fits {change['gain']:.0%} more of its rows)")
                print(f"{root.name} {v}: {found}, {row['status']}, NEES {row['nees']:.1f}", flush=True)
    clean = [r for r in rows if not r["rot_deg"]]
    turned = [r for r in rows if r["rot_deg"]]
    print(f"unchanged drives: {sum(r['found_frame'] is not None for r in clean)} of {len(clean)} marked; turned: "
          + ", ".join(f"{rot:g} deg {sum(r['found_frame'] is not None for r in turned if r['rot_deg'] == rot)} of "
                      f"{sum(r['rot_deg'] == rot for r in turned)}" for rot in sorted({r['rot_deg'] for r in turned}))
          + (f"; frame found minus true: median {np.median(d):+.0f}, max |.| {np.abs(d).max():.0f}"
             if (d := np.array([r['found_frame'] - r['true_frame'] for r in turned if r['found_frame'] is not None]))
             .size else ""))
    (args.out / "summary.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
