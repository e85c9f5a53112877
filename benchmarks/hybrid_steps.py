"""Step alarms of the hybrid (the radar mount monitor, calib.mount_monitor, and the window's own test) on
knocked and unchanged simulated drives: detection delay and false alarms per 1000 frames.

    PYTHONPATH=. .venv/bin/python benchmarks/hybrid_steps.py --out OUT [--seed 601] [--frames 40]
        [--knock-deg 1.0] [--vehicles 3] [--set mount.threshold=6 ...]

Simulates (reused when present) ``knock-urban`` (``--vehicles`` urban drives whose radar turns by
``--knock-deg`` about its z axis at the middle frame), ``knock-highway`` (one), and unchanged
``urban`` (``--vehicles``), ``highway`` and ``straight`` (one each), ``--frames`` keyframes at
``image_scale`` 0.5, seeds from ``--seed``; calibrates every vehicle with ``--method hybrid`` from
an R1 start (``--set``: HybridConfig overrides), and prints per drive the alarm frames, the delay
of the first alarm after the knock (frames; a miss when none within the drive), the yaw error at the
end (against the mount at the last frame: the knocked one), and the false
alarms (before the knock, or anywhere on an unchanged drive) per 1000 frames tested.
``OUT/steps.json`` holds it all with the command.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybrid_calib.config import merge, parse_overrides, save_json_atomic  # noqa: E402

DRIVES = (("knock-urban", "urban", True), ("knock-highway", "highway", True), ("urban", "urban", False),
          ("highway", "highway", False), ("straight", "straight", False))


def main(argv=None) -> int:
    from hybrid_calib.hybrid import HybridConfig, run_calibration
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--seed", type=int, default=601)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--vehicles", type=int, default=3)
    ap.add_argument("--knock-deg", type=float, default=1.0)
    ap.add_argument("--set", nargs="*", default=[])
    a = ap.parse_args(argv)
    hconf = merge(HybridConfig, {"method": "hybrid", "start": "R1", "threads": 1, "progress": False,
                                 **parse_overrides(a.set)})
    rows, t0 = [], time.perf_counter()
    for k, (name, scen, knocked) in enumerate(DRIVES):
        n = a.vehicles if scen == "urban" else 1
        o = {"scenario": scen, "vehicles": n, "frames": a.frames, "seed": a.seed + k, "image_scale": 0.5}
        if knocked:
            o["extrinsic_change"] = {"kind": "step", "rotation_deg": (0.0, 0.0, a.knock_deg),
                                     "translation_m": (0.0, 0.0, 0.0)}
        root = simulate(merge(SimConfig, o), a.out / "data" / name, progress=False)
        run = run_calibration(root, "v1.0-sim", a.out / "cal" / name, hconf)
        change = a.frames // 2 if knocked else None
        for v, vr in run.vehicles.items():
            alarms = [f.index for f in vr.trajectory if f.step_alarm]  # drive frames (hybrid.drives.Drive.positions)
            after = [i for i in alarms if change is not None and i >= change]
            false = [i for i in alarms if change is None or i < change]
            rows.append({"drive": name, "vehicle": v, "knocked": knocked, "frames": len(vr.trajectory),
                         "alarms": alarms, "delay": (after[0] - change) if after else None, "false_alarms": len(false),
                         "frames_tested": len(vr.trajectory) if change is None else change,
                         "yaw_error_deg": vr.error["yaw_deg"]})
            r = rows[-1]
            print(f"{name:14s} {v}: alarms {alarms}, delay {r['delay']}, false {r['false_alarms']}, "
                  f"yaw error {r['yaw_error_deg']:.2f} deg ({time.perf_counter() - t0:.0f} s)", flush=True)
    kn = [r for r in rows if r["knocked"]]
    found = [r for r in kn if r["delay"] is not None]
    fa = sum(r["false_alarms"] for r in rows)
    tested = sum(r["frames_tested"] for r in rows)
    summary = {"knocked": len(kn), "found": len(found), "delays": [r["delay"] for r in found],
               "false_alarms": fa, "frames_tested": tested, "false_per_1000": 1000.0 * fa / max(tested, 1)}
    print(f"knocked drives: {len(found)} of {len(kn)} found, delays {summary['delays']} frames; false alarms "
          f"{fa} in {tested} frames ({summary['false_per_1000']:.2f} per 1000)")
    save_json_atomic(a.out / "steps.json", {"command": " ".join(sys.argv), "summary": summary, "rows": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
