"""The sliding window's per-frame estimates from the start of a drive: how many frames end far from the truth,
and whether the final estimate moves, with the window's convex-start check on and off.

Per root, start range and seed: ``hybrid_calib.calib.pipeline.calibrate`` with oracle correspondences (the
calibrate command's ``--correspondences oracle``), window mode, once with the default
``window.convex_check_fraction`` and once with it 0 (off). Each frame of the trajectory is scored against the true
mount of that frame (``calib.result.truth_at``); a frame more than ``--far-deg`` from it is "far", and counted
apart when its status does not say NOT CONVERGED. The roots are
made by the caller (``hybrid-calib simulate``); the runs are kept under ``--out`` and a rerun reuses them.

    PYTHONPATH=. .venv/bin/python benchmarks/window_start.py --data SIM_urban SIM_highway SIM_rain --seeds 3 \\
        --out outputs/window_start
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def _arm_runs(roots, seeds: int, fraction: float | None, out: Path) -> list[dict]:
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.calib.result import CalibrationRun, truth_at
    from hybrid_calib.geometry import local
    from hybrid_calib.metrics import extrinsic_error, nees

    rows = []
    for root in roots:
        for start in ("R1", "R2"):
            for seed in range(seeds):
                arm = "default" if fraction is None else f"fraction-{fraction:g}"
                run_dir = out / arm / f"{Path(root).name}-{start}-{seed}"
                if not (run_dir / "result.json").is_file():
                    conf = {"start": start, "seed": seed}
                    if fraction is not None:
                        conf["window"] = {"convex_check_fraction": fraction}
                    t0 = time.perf_counter()
                    calibrate(Path(root), "v1.0-sim", "oracle", run_dir, conf, progress=False)
                    (run_dir / "seconds.txt").write_text(f"{time.perf_counter() - t0:.2f}")
                run = CalibrationRun.load(run_dir / "result.json")
                for vr in run.vehicles.values():
                    per_frame = [extrinsic_error(f.T, truth_at(vr, f.index)).geodesic_deg for f in vr.trajectory]
                    flagged = ["NOT CONVERGED" in f.status for f in vr.trajectory]
                    frame_nees = [nees(local(truth_at(vr, f.index), f.T), f.cov) for f in vr.trajectory]
                    rows.append({"root": Path(root).name, "start": start, "seed": seed, "vehicle": vr.vehicle,
                                 "frames": len(per_frame), "worst_deg": max(per_frame),
                                 "per_frame_deg": per_frame, "flagged": flagged, "frame_nees": frame_nees,
                                 "final_deg": vr.error["geodesic_deg"], "final_nees": vr.error["nees"]})
    return rows


def summary(rows: list[dict], far_deg: float) -> dict:
    from hybrid_calib.metrics import CHI2_6_95

    final = np.array([r["final_deg"] for r in rows])
    final_nees = np.array([r["final_nees"] for r in rows])
    return {"vehicle_runs": len(rows), "frames": int(sum(r["frames"] for r in rows)),
            "frames_far": int(sum(np.sum(np.array(r["per_frame_deg"]) > far_deg) for r in rows)),
            "frames_far_not_flagged": int(sum(np.sum((np.array(r["per_frame_deg"]) > far_deg) & ~np.array(r["flagged"]))
                                              for r in rows)),
            "frames_nees_over_50": int(sum(np.sum(np.array(r["frame_nees"]) > 50) for r in rows)),
            "worst_frame_deg": float(max(r["worst_deg"] for r in rows)),
            "final_geodesic_mean_deg": float(final.mean()), "final_geodesic_median_deg": float(np.median(final)),
            "final_nees_mean": float(final_nees.mean()), "final_inside_95": float(np.mean(final_nees < CHI2_6_95))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", nargs="+", required=True, help="v1.0-sim roots (hybrid-calib simulate)")
    p.add_argument("--seeds", type=int, default=3, help="start seeds per root and start range")
    p.add_argument("--far-deg", type=float, default=5.0, help="a frame this far from its truth (geodesic) is far")
    p.add_argument("--out", type=Path, default=Path("outputs/window_start"))
    args = p.parse_args(argv)
    result = {}
    for name, fraction in (("convex check (default)", None), ("convex check off", 0.0)):
        result[name] = summary(_arm_runs(args.data, args.seeds, fraction, args.out), args.far_deg)
        s = result[name]
        print(f"{name}: {s['vehicle_runs']} vehicle-runs; frames more than {args.far_deg:g} deg off: "
              f"{s['frames_far']} of {s['frames']} ({s['frames_far_not_flagged']} of them not said NOT CONVERGED); "
              f"frames with NEES > 50: {s['frames_nees_over_50']}; worst frame "
              f"{s['worst_frame_deg']:.1f} deg; final geodesic mean {s['final_geodesic_mean_deg']:.4f} deg (median "
              f"{s['final_geodesic_median_deg']:.4f}), NEES mean {s['final_nees_mean']:.2f}, "
              f"{100 * s['final_inside_95']:.0f} % inside the 95 % ellipsoid")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
