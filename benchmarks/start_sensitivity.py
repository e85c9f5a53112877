"""Where the network's roll, pitch and yaw come from: how its output depends on the start it runs from, and what it
returns on each vehicle (issue 9: "measure the fixed point against the truth"; docs/benchmarks.md, "What the
network's roll and pitch are").

    PYTHONPATH=. .venv/bin/python benchmarks/start_sensitivity.py --data ROOT [ROOT ...] --out OUT.json
        [--checkpoint CKPT] [--deltas 0.3 1 3] [--starts 4] [--range R1] [--every 1] [--threads 1]

Per simulated vehicle and kept frame the network (``hybrid.network.mount_pass``, the pass every learned method makes)
runs from: the truth; the truth turned by +-``--deltas`` deg about one radar axis at a time (x roll, y pitch, z yaw);
``--starts`` starts drawn in ``--range`` (start seeds 0.., ``perturbation.vehicle_start``: the pure and pure-avg
regime); and a start near the truth (0.3 deg, 2 cm normal per axis: the closed loop's regime once it has converged).
Its output error about each radar axis (``local(truth, out)``, deg) gives, per vehicle:

- the slope of the output's error on an axis against the start's error on that axis (0: the output does not depend
  on where the pass started, 1: the start is returned), the intercept (the pass from the truth) and the closed
  loop's fixed point ``intercept / (1 - slope)`` (a loop that restarts the network from its own estimate settles
  there);
- the mean output error from the truth, from near it and from the ``--range`` starts;
- against the vehicle's design mounts (``sim_vehicle.json``): the error the output would have if it returned the
  fleet's design pair (``nominal_T_ego_cam``, ``nominal_T_ego_radar``), or the design radar seen through the true
  camera (``inv(true_T_ego_cam) nominal_T_ego_radar``); the slope, correlation and rms of the output's error
  against each, over vehicles.

``OUT.json`` holds every pass's start and output error, the per-vehicle figures and the command.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybrid_calib.config import save_json_atomic  # noqa: E402

AXES = ("roll", "pitch", "yaw")  # rotation about radar x, y, z: the first three of the right tangent


def _design(rec: dict, key_cam: str) -> np.ndarray:
    """(4, 4) ``inv(rec[key_cam]) rec["nominal_T_ego_radar"]``: the design radar seen through that camera mount."""
    from hybrid_calib.geometry import pose_from_nuscenes, se3_inverse

    cam, rad = (pose_from_nuscenes(rec[k]["rotation"], rec[k]["translation"]) for k in (key_cam, "nominal_T_ego_radar"))
    return se3_inverse(cam) @ rad


def _starts(X: np.ndarray, drive, deltas: list[float], n_starts: int, rng_name: str) -> dict[str, np.ndarray]:
    from hybrid_calib.geometry import se3_exp
    from hybrid_calib.perturbation import vehicle_start

    out = {"truth": X}
    for a, axis in enumerate(AXES):
        for d in sorted({*deltas, *(-d for d in deltas)}):
            xi = np.zeros(6)
            xi[a] = np.radians(d)
            out[f"{axis}{d:+g}"] = X @ se3_exp(xi)
    for s in range(n_starts):
        out[f"{rng_name}-{s}"] = vehicle_start(X, rng_name, s, drive.vehicle)
    return out


def _mean_out(passes: list[dict], pick) -> list[float]:
    """(3,) the mean output error (deg) of the passes whose start kind ``pick`` accepts."""
    return np.mean([p["out_deg"] for p in passes if pick(p["start"])], axis=0).tolist()


def _fit(x: list[float], y: list[float]) -> dict:
    slope, icpt = np.polyfit(x, y, 1)
    return {"slope": float(slope), "intercept_deg": float(icpt),
            "fixed_point_deg": float(icpt / (1.0 - slope)) if slope < 1 else float("nan")}


def measure(roots: list[Path], version: str, checkpoint: str, deltas: list[float], n_starts: int, rng_name: str,
            every: int, threads: int) -> dict:
    """Every pass and the per-vehicle figures (module doc) of the drives of ``roots``."""
    from tqdm import tqdm

    from hybrid_calib.geometry import local, se3_exp
    from hybrid_calib.hybrid.loop import HybridConfig, _Session
    from hybrid_calib.hybrid.network import mount_pass

    rng = np.random.default_rng(0)
    passes, vehicles = [], []
    for root in roots:
        s = _Session(root, version, HybridConfig(method="pure", start=rng_name, checkpoint=checkpoint, progress=False,
                                                 threads=threads))
        for name, drive in s.drives.items():
            rec = s.frames.sim_vehicles.get(s.frames[drive.indices[0]].log_token)
            if rec is None:
                raise SystemExit(f"{root}: {name} has no sim_vehicle.json record; this benchmark needs simulated "
                                 "drives")
            X = drive.base
            starts = _starts(X, drive, deltas, n_starts, rng_name)
            mine = []
            for i in tqdm(drive.indices[::every], desc=f"{root.name} {name}", leave=False):
                near = X @ se3_exp(np.concatenate([np.radians(rng.normal(0, 0.3, 3)), rng.normal(0, 0.02, 3)]))
                for kind, S in {**starts, "near": near}.items():
                    o = mount_pass(s.runner, i, S)
                    if o is not None:
                        mine.append({"root": str(root), "vehicle": name, "index": int(i), "start": kind,
                                     "start_deg": np.degrees(local(X, S)[:3]).tolist(),
                                     "out_deg": np.degrees(local(X, o.T)[:3]).tolist()})
            if not mine:
                continue
            passes += mine
            v = {"root": str(root), "vehicle": name, "frames": len({p["index"] for p in mine}),
                 "out_at_truth_deg": _mean_out(mine, lambda k: k == "truth"),
                 "out_near_deg": _mean_out(mine, lambda k: k == "near"),
                 "out_at_range_deg": _mean_out(mine, lambda k: k.startswith(rng_name + "-")),
                 "design_pair_deg": np.degrees(local(X, _design(rec, "nominal_T_ego_cam"))[:3]).tolist(),
                 "design_radar_true_camera_deg": np.degrees(local(X, _design(rec, "true_T_ego_cam"))[:3]).tolist()}
            for a, axis in enumerate(AXES):
                on_axis = [p for p in mine if p["start"] == "truth" or p["start"].startswith(axis)]
                v[axis] = _fit([p["start_deg"][a] for p in on_axis], [p["out_deg"][a] for p in on_axis])
            vehicles.append(v)
            print(f"{root.name} {name}: " + "; ".join(
                f"{axis} slope {v[axis]['slope']:+.3f}, from truth {v['out_at_truth_deg'][a]:+.2f}, near "
                f"{v['out_near_deg'][a]:+.2f}, {rng_name} {v['out_at_range_deg'][a]:+.2f} (design radar via true "
                f"camera {v['design_radar_true_camera_deg'][a]:+.2f})" for a, axis in enumerate(AXES)), flush=True)
    return {"passes": passes, "vehicles": vehicles, "summary": summarise(vehicles, rng_name)}


def summarise(vehicles: list[dict], rng_name: str) -> dict:
    """Per axis over vehicles: slope range, and the output error from the truth against each design reading."""
    out = {}
    for a, axis in enumerate(AXES):
        slopes = [v[axis]["slope"] for v in vehicles]
        y = np.array([v["out_at_truth_deg"][a] for v in vehicles])
        row = {"slope_min": min(slopes), "slope_max": max(slopes),
               "mean_abs_out_at_truth_deg": float(np.abs(y).mean()),
               "mean_abs_out_at_range_deg": float(np.mean([abs(v["out_at_range_deg"][a]) for v in vehicles])),
               "range_minus_truth_deg": [v["out_at_range_deg"][a] - v["out_at_truth_deg"][a] for v in vehicles],
               "near_minus_truth_deg": [v["out_near_deg"][a] - v["out_at_truth_deg"][a] for v in vehicles]}
        for key in ("design_pair_deg", "design_radar_true_camera_deg"):
            x = np.array([v[key][a] for v in vehicles])
            fit = np.polyfit(x, y, 1) if len(x) > 1 and np.ptp(x) > 0 else [float("nan")] * 2
            row[key] = {"slope": float(fit[0]), "corr": float(np.corrcoef(x, y)[0, 1]) if len(x) > 2 else float("nan"),
                        "rms_deg": float(np.sqrt(np.mean((y - x) ** 2)))}
        out[axis] = row
        via = row["design_radar_true_camera_deg"]
        print(f"{axis}: slope on its own start {row['slope_min']:+.3f} .. {row['slope_max']:+.3f}; mean |error| from "
              f"the truth {row['mean_abs_out_at_truth_deg']:.3f} deg, from {rng_name} starts "
              f"{row['mean_abs_out_at_range_deg']:.3f}; {rng_name} minus truth "
              f"{' '.join(f'{d:+.2f}' for d in row['range_minus_truth_deg'])}; against the design radar seen through "
              f"the true camera: slope {via['slope']:.2f}, corr {via['corr']:.2f}, rms {via['rms_deg']:.2f}"
              f" deg (the design pair: slope {row['design_pair_deg']['slope']:.2f}, corr "
              f"{row['design_pair_deg']['corr']:.2f}, rms {row['design_pair_deg']['rms_deg']:.2f})")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True, type=Path, help="simulated roots")
    ap.add_argument("--version", default="v1.0-sim")
    ap.add_argument("--out", required=True, type=Path, help="OUT.json")
    ap.add_argument("--checkpoint", default="", help="default: the shipped checkpoint of --range")
    ap.add_argument("--deltas", type=float, nargs="+", default=[0.3, 1.0, 3.0], help="start turns per axis, deg")
    ap.add_argument("--starts", type=int, default=4, help="--range starts per vehicle (seeds 0..)")
    ap.add_argument("--range", default="R1", choices=("R0", "R1", "R2"))
    ap.add_argument("--every", type=int, default=1, help="every Nth frame of each drive")
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    if a.every < 1 or a.starts < 0 or not a.deltas or min(a.deltas) <= 0:
        ap.error("--every >= 1, --starts >= 0 and positive --deltas")
    res = measure(a.data, a.version, a.checkpoint, a.deltas, a.starts, a.range, a.every, a.threads)
    save_json_atomic(a.out, {"command": " ".join(sys.argv), **res})
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
