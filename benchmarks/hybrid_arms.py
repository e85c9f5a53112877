"""The hybrid as shipped against one change of its options, paired: the same drives, starts and seeds.

    PYTHONPATH=. .venv/bin/python benchmarks/hybrid_arms.py --data ROOT [ROOT ...] --out OUT \\
        [--against motion.confirm=0 ...] [--starts R1 R2] [--seeds 0 1] [--max-frames 0] [--set KEY=VALUE ...]

Per (root, vehicle, start, seed): ``hybrid.run_vehicle`` as shipped (with ``--set``) and with ``--against`` on top
(default ``motion.confirm=0``: a consensus of agreeing motion residuals beyond the gate admits them whatever the
motion said before, the rule before session 30). Network passes are cached under OUT, so the arms share every pass
until they part. Per arm: the final error against the truth, NEES, whether the truth lies inside the 95 % ellipsoid,
the step alarms, the frames admitted by the motion gate's consensus and those it refused
(``frame_rows[k].motion`` / ``motion_skipped``), and the frames with a motion measurement. Against
``motion.confirm=0`` a trial where no consensus was refused is identical by construction (the arm is not run).

Rows go to ``OUT/trials.jsonl``, one per trial holding every arm run into OUT (resumable: an arm already there is
not run again, so several ``--against`` share the shipped arm); each run prints its summary and writes it to
``OUT/summary-ARM.json``.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybrid_calib.config import deep_update, parse_overrides, save_json_atomic  # noqa: E402
from hybrid_calib.metrics import CHI2_6_95, consistency  # noqa: E402

SHIPPED = "shipped"


def _arm(res) -> dict:
    rows = res.frame_rows
    e = res.error or {}
    return {"yaw_deg": e.get("yaw_deg"), "rot_mean_deg": e.get("rot_mean_deg"), "trans_norm_cm": e.get("trans_norm_cm"),
            "nees": e.get("nees"), "inside95": None if e.get("nees") is None else bool(e["nees"] < CHI2_6_95),
            "alarms": [f.index for f in res.trajectory if f.step_alarm],
            "consensus": sum(r.get("motion", {}).get("admitted") == "consensus" for r in rows),
            "refused": sum("agreeing residuals beyond the gate" in r.get("motion_skipped", "") for r in rows),
            "motion_frames": sum("motion" in r for r in rows), "status": res.final.status}


def _stats(rows: list[dict], arm: str) -> dict:
    yaw = np.abs(np.array([r[arm]["yaw_deg"] for r in rows], float))
    nees = consistency([r[arm]["nees"] for r in rows])
    return {"yaw_abs_mean_deg": float(np.mean(yaw)), "yaw_abs_median_deg": float(np.median(yaw)),
            "yaw_abs_max_deg": float(np.max(yaw)),
            "rot_mean_mean_deg": float(np.mean([r[arm]["rot_mean_deg"] for r in rows])),
            "nees_mean": nees["nees_mean"], "inside95": nees["coverage_95"],
            "alarms": int(sum(len(r[arm]["alarms"]) for r in rows)),
            "consensus_frames": int(sum(r[arm]["consensus"] for r in rows)),
            "motion_frames": int(sum(r[arm].get("motion_frames", 0) for r in rows))}


def main(argv=None) -> int:
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.hybrid import run_vehicle

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True, type=Path)
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--against", nargs="+", default=["motion.confirm=0"], metavar="KEY=VALUE")
    ap.add_argument("--starts", nargs="+", default=["R1", "R2"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--max-frames", type=int, default=0)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE")
    a = ap.parse_args(argv)
    arm = " ".join(a.against)
    gate_only = a.against == ["motion.confirm=0"]
    a.out.mkdir(parents=True, exist_ok=True)
    log = a.out / "trials.jsonl"
    done: dict[str, dict] = {}
    if log.is_file():
        for line in log.read_text().splitlines():
            if line.strip():
                r = json.loads(line)
                done.setdefault(r["key"], {}).update(r)  # later lines add arms
    base = {"method": "hybrid", "progress": False, "threads": 1, "max_frames": a.max_frames,
            "cache_dir": str(a.out / "cache"), **parse_overrides(a.set)}
    keys = []
    for root in a.data:
        vehicles = sorted(NuScenesRadarCamera(root, "v1.0-sim", conf={"check_images": False}).frames_by_vehicle())
        for veh in vehicles:
            for start in a.starts:
                for seed in a.seeds:
                    key = f"{root.name}/{veh}/{start}/{seed}"
                    keys.append(key)
                    row = done.setdefault(key, {"key": key})
                    if SHIPPED in row and arm in row:
                        continue
                    conf = {**base, "start": start, "seed": seed}
                    if SHIPPED not in row:
                        row[SHIPPED] = _arm(run_vehicle(root, "v1.0-sim", veh, conf))
                    if gate_only and row[SHIPPED]["refused"] == 0:
                        row[arm] = row[SHIPPED]  # no consensus refused: every gate decision is the shipped one
                    else:
                        against = deep_update(copy.deepcopy(conf), parse_overrides(a.against))
                        row[arm] = _arm(run_vehicle(root, "v1.0-sim", veh, against))
                    with log.open("a") as f:
                        f.write(json.dumps(row) + "\n")
                    s, o = row[SHIPPED], row[arm]
                    print(f"{key}: shipped yaw {s['yaw_deg']:.2f} deg NEES {s['nees']:.1f} alarms {s['alarms']} "
                          f"motion {s.get('motion_frames')}" + (" (identical)" if s == o else
                          f" | {arm}: yaw {o['yaw_deg']:.2f} deg NEES {o['nees']:.1f} alarms {o['alarms']} "
                          f"motion {o.get('motion_frames')}"), flush=True)
    rows = [done[k] for k in keys]
    summary = {"command": " ".join(sys.argv), "trials": len(rows), "against": arm,
               "differ": sum(r[SHIPPED] != r[arm] for r in rows), SHIPPED: _stats(rows, SHIPPED),
               arm: _stats(rows, arm)}
    name = arm.replace("=", "-").replace(" ", "_").replace("/", "_")
    save_json_atomic(a.out / f"summary-{name}.json", summary)
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
