"""The motion gate's consensus rule, paired: the hybrid with ``motion.confirm`` as shipped against
``motion.confirm=0`` (a consensus of agreeing residuals beyond the gate admits them whatever the motion
said before), on the same drives and starts.

    PYTHONPATH=. .venv/bin/python benchmarks/motion_gate.py --data ROOT [ROOT ...] --out OUT \\
        [--starts R1 R2] [--seeds 0 1] [--max-frames 0] [--set KEY=VALUE ...]

Per (root, vehicle, start, seed): ``hybrid.run_vehicle`` twice (network passes cached under OUT, so the
two arms share every pass until they part); per arm the final error against the truth, NEES, whether the
truth lies inside the 95 % ellipsoid, the step alarms, and the frames admitted by consensus and refused
by the confirmation (``frame_rows[k].motion``/``motion_skipped``). Trials where no consensus was refused
are identical in both arms by construction (printed as such; the second arm is not run). Rows go to
``OUT/trials.jsonl`` (resumable); the summary is printed and written to ``OUT/summary.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybrid_calib.config import parse_overrides, save_json_atomic  # noqa: E402

ARMS = {"shipped": {}, "confirm=0": {"motion": {"confirm": 0}}}
CHI2_6_95 = 12.592


def _arm(res) -> dict:
    rows = res.frame_rows
    e = res.error or {}
    return {"yaw_deg": e.get("yaw_deg"), "rot_mean_deg": e.get("rot_mean_deg"), "trans_norm_cm": e.get("trans_norm_cm"),
            "nees": e.get("nees"), "inside95": None if e.get("nees") is None else bool(e["nees"] <= CHI2_6_95),
            "alarms": [f.index for f in res.trajectory if f.step_alarm],
            "consensus": sum(r.get("motion", {}).get("admitted") == "consensus" for r in rows),
            "refused": sum("agreeing residuals beyond the gate" in r.get("motion_skipped", "") for r in rows),
            "status": res.final.status}


def main(argv=None) -> int:
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.hybrid import run_vehicle

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--starts", nargs="+", default=["R1", "R2"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--max-frames", type=int, default=0)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    log = a.out / "trials.jsonl"
    done = {}
    if log.is_file():
        for line in log.read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                done[r["key"]] = r
    base = {"method": "hybrid", "progress": False, "threads": 1, "max_frames": a.max_frames,
            "cache_dir": str(a.out / "cache"), **parse_overrides(a.set)}
    for root in a.data:
        vehicles = sorted(NuScenesRadarCamera(root, "v1.0-sim", conf={"check_images": False}).frames_by_vehicle())
        for veh in vehicles:
            for start in a.starts:
                for seed in a.seeds:
                    key = f"{root.name}/{veh}/{start}/{seed}"
                    if key in done:
                        continue
                    row = {"key": key}
                    for arm, over in ARMS.items():
                        if arm != "shipped" and row["shipped"]["refused"] == 0:
                            # no consensus refused: every gate decision of confirm=0 is the shipped one
                            row[arm] = row["shipped"]
                            continue
                        conf = {**base, "start": start, "seed": seed,
                                "motion": {**base.get("motion", {}), **over.get("motion", {})}}
                        row[arm] = _arm(run_vehicle(root, "v1.0-sim", veh, conf))
                    done[key] = row
                    with log.open("a") as f:
                        f.write(json.dumps(row) + "\n")
                    s, o = row["shipped"], row["confirm=0"]
                    same = s == o
                    print(f"{key}: shipped yaw {s['yaw_deg']:.2f} deg NEES {s['nees']:.1f} alarms {s['alarms']} "
                          f"refused {s['refused']}" + (" (identical)" if same else
                          f" | confirm=0 yaw {o['yaw_deg']:.2f} deg NEES {o['nees']:.1f} alarms {o['alarms']} "
                          f"consensus {o['consensus']}"), flush=True)
    rows = list(done.values())
    summary = {"command": " ".join(sys.argv), "trials": len(rows),
               "differ": sum(r["shipped"] != r["confirm=0"] for r in rows)}
    for arm in ARMS:
        yaw = np.array([r[arm]["yaw_deg"] for r in rows], float)
        rot = np.array([r[arm]["rot_mean_deg"] for r in rows], float)
        nees = np.array([r[arm]["nees"] for r in rows], float)
        summary[arm] = {"yaw_abs_mean_deg": float(np.mean(np.abs(yaw))),
                        "yaw_abs_median_deg": float(np.median(np.abs(yaw))),
                        "yaw_abs_max_deg": float(np.max(np.abs(yaw))), "rot_mean_mean_deg": float(np.mean(rot)),
                        "nees_mean": float(np.mean(nees)), "inside95": float(np.mean(nees <= CHI2_6_95)),
                        "alarms": int(sum(len(r[arm]["alarms"]) for r in rows)),
                        "consensus_frames": int(sum(r[arm]["consensus"] for r in rows))}
    save_json_atomic(a.out / "summary.json", summary)
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
