"""What the hybrid does not measure: its roll and pitch on drives whose radar is tilted, against the same drives
untilted (docs/benchmarks.md, "What the hybrid does not measure").

    PYTHONPATH=. .venv/bin/python benchmarks/unseen_tilt.py --out OUT [--scenarios urban:86107 highway:86122]
        [--tilts roll:2,0,0 pitch:0,2,0] [--vehicles 3] [--frames 40] [--start-seed 86201] [--set KEY=VALUE ...]

Per scenario (``NAME:SEED``) one root with no change and one per tilt (``NAME:ROLL,PITCH,YAW`` in degrees about the
radar's x, y, z, at the first frame: the mount the whole drive has), all simulated from the same seed (so the same
world, trajectory and mounts but the tilt; reused when present), ``--vehicles`` x ``--frames`` keyframes at
``image_scale`` 0.25; every vehicle calibrated with ``--method hybrid`` from an R1 start (``--start-seed``; the same
start on every root). Printed per vehicle: its roll and pitch against its tables (``drift.delta_camera``: rotation
about camera z and x, deg) on each root, their errors against the truth, and the largest move of the estimate's
roll and pitch between a tilted root and the untilted one. ``OUT/unseen_tilt.json`` holds it all with the command.
A method that saw the tilt would move by it (1.5-2 deg); the hybrid moved by at most 0.14 deg on urban and 0.29 deg on
highway (session 35, the defaults; docs/benchmarks.md, "What the hybrid does not measure").
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybrid_calib.config import merge, parse_overrides, save_json_atomic  # noqa: E402


def _named(items: list[str], what: str) -> list[tuple[str, str]]:
    out = []
    for item in items:
        name, sep, value = item.partition(":")
        if not sep or not name or not value:
            raise SystemExit(f"{what}: expected NAME:VALUE, got {item!r}")
        out.append((name, value))
    return out


def main(argv=None) -> int:
    from hybrid_calib.hybrid import HybridConfig, run_calibration
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--scenarios", nargs="+", default=["urban:86107", "highway:86122"], metavar="PRESET:SEED")
    ap.add_argument("--tilts", nargs="+", default=["roll:2,0,0", "pitch:0,2,0"], metavar="NAME:ROLL,PITCH,YAW")
    ap.add_argument("--vehicles", type=int, default=3)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--start-seed", type=int, default=86201)
    ap.add_argument("--set", nargs="*", default=[], help="HybridConfig overrides")
    a = ap.parse_args(argv)
    tilts = [(n, [float(x) for x in v.split(",")]) for n, v in _named(a.tilts, "--tilts")]
    if any(len(r) != 3 for _, r in tilts):
        raise SystemExit("--tilts: three angles each (roll, pitch, yaw about the radar's x, y, z, deg)")
    hconf = merge(HybridConfig, {"method": "hybrid", "start": "R1", "seed": a.start_seed, "threads": 1,
                                 "progress": False, **parse_overrides(a.set)})
    rows, t0 = [], time.perf_counter()
    for scen, seed in _named(a.scenarios, "--scenarios"):
        for tilt, rot in [("none", None), *tilts]:
            o = {"scenario": scen, "vehicles": a.vehicles, "frames": a.frames, "seed": int(seed), "image_scale": 0.25}
            if rot is not None:
                o["extrinsic_change"] = {"kind": "step", "frame": 0, "rotation_deg": tuple(rot),
                                         "translation_m": (0.0, 0.0, 0.0)}
            name = f"{scen}-{seed}-{tilt}"
            root = simulate(merge(SimConfig, o), a.out / "data" / name, progress=False, workers=1)
            run = run_calibration(root, "v1.0-sim", a.out / "cal" / name, hconf)
            for v, vr in sorted(run.vehicles.items()):
                d = vr.drift["delta_camera"]
                rows.append({"scenario": scen, "seed": int(seed), "tilt": tilt, "tilt_deg": rot, "vehicle": v,
                             "roll_from_tables_deg": d["rot_z_deg"], "pitch_from_tables_deg": d["rot_x_deg"],
                             "roll_error_deg": vr.error["roll_deg"], "pitch_error_deg": vr.error["pitch_deg"],
                             "nees": vr.error["nees"], "verdict": vr.drift["verdict_kind"]})
                r = rows[-1]
                print(f"{name:28s} {v}: roll {r['roll_from_tables_deg']:+.2f} pitch {r['pitch_from_tables_deg']:+.2f} "
                      f"deg from tables; errors {r['roll_error_deg']:.2f} / {r['pitch_error_deg']:.2f} deg, NEES "
                      f"{r['nees']:.1f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    base = {(r["scenario"], r["seed"], r["vehicle"]): r for r in rows if r["tilt"] == "none"}
    moves = {}
    for r in rows:
        b = base.get((r["scenario"], r["seed"], r["vehicle"]))
        if r["tilt"] != "none" and b is not None:
            m = max(abs(r["roll_from_tables_deg"] - b["roll_from_tables_deg"]),
                    abs(r["pitch_from_tables_deg"] - b["pitch_from_tables_deg"]))
            moves.setdefault(f"{r['scenario']} {r['tilt']}", []).append(m)
    summary = {k: max(v) for k, v in moves.items()}
    for k, m in summary.items():
        print(f"{k}: the hybrid's roll and pitch moved by at most {m:.2f} deg")
    save_json_atomic(a.out / "unseen_tilt.json", {"command": " ".join(sys.argv), "max_move_deg": summary,
                                                  "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
