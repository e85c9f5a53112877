"""The motion constraint's noise on simulated drives with ground truth: residuals at the truth, and
the fitted ``MotionConfig.sigma_vo_deg`` / ``drive_std_deg`` (fit on validation drives only).

    PYTHONPATH=. .venv/bin/python benchmarks/motion_fit.py --data ROOT [ROOT ...] --version v1.0-sim \
        --out OUT [--set velocity.min_inliers=8 vo.min_inliers=30 ...]

Per consecutive frame pair of every vehicle (``hybrid.motion.MotionSource``): the heading residual
of ``factors.motion`` at the true ``T_cam_radar_static``, the Doppler part of its std, the VO
inliers and the radar speed. The fit: ``sigma_vo_deg`` such that the median of the whitened
residual ``|r| / sqrt(sigma_doppler^2 + sigma_vo^2)`` is the Gaussian's 0.674 (the tails are left
to the Huber weight); ``drive_std_deg``: the spread of the per-drive mean residuals beyond what
their within-drive scatter explains: the second moment of the drive means about zero (a bias
shared by all drives counts: its sign on a new drive is unknown) less their mean variance, >= 0.
Prints a table and writes
``OUT/motion_fit.json`` (every residual, the fit, the command).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from factors.motion import heading_residual  # noqa: E402
from hybrid_calib.config import merge, parse_overrides, save_json_atomic  # noqa: E402
from hybrid_calib.hybrid.motion import MotionConfig, MotionSource  # noqa: E402


def residuals(root: str, version: str, conf: MotionConfig, cache: str) -> list[dict]:
    from learned.dataset import open_frames

    frames = open_frames(root, version, lidar=False)
    src = MotionSource(frames, conf, cache)
    rows = []
    for vehicle, idx in sorted(frames.frames_by_vehicle().items()):
        for a, b in zip(idx[:-1], idx[1:]):
            T = np.asarray(frames[a].extras["T_cam_radar_static"], np.float64)
            m, why = src.measurement(a, b, T[:3, :3])
            if m is None:
                rows.append({"root": root, "vehicle": vehicle, "pair": [a, b], "skipped": why})
                continue
            r, _ = heading_residual(T, m)
            rows.append({"root": root, "vehicle": vehicle, "pair": [a, b], "residual_deg": float(np.degrees(r)),
                         "sigma_doppler_deg": float(np.degrees(m.sigma)), "vo_inliers": m.n_vo_inliers,
                         "speed_mps": m.speed})
    return rows


def fit(rows: list[dict]) -> dict:
    from scipy.optimize import brentq

    ok = [r for r in rows if "residual_deg" in r]
    r = np.array([x["residual_deg"] for x in ok])
    sd = np.array([x["sigma_doppler_deg"] for x in ok])

    def med(s):
        return float(np.median(np.abs(r) / np.hypot(sd, s))) - 0.6745

    sigma_vo = 0.0 if med(0.0) <= 0 else brentq(med, 0.0, 50.0)
    w = 1 / (sd ** 2 + sigma_vo ** 2)
    drives = sorted({(x["root"], x["vehicle"]) for x in ok})
    means, vars_ = [], []
    for d in drives:
        k = [i for i, x in enumerate(ok) if (x["root"], x["vehicle"]) == d]
        if len(k) < 3:
            continue
        rk, wk = r[k], w[k]
        # robust per-drive mean (inside 3 MAD) and its variance from the within-drive scatter
        c = np.median(rk)
        keep = np.abs(rk - c) <= 3 * 1.4826 * np.median(np.abs(rk - c)) + 1e-9
        means.append(float(np.sum(wk[keep] * rk[keep]) / np.sum(wk[keep])))
        vars_.append(float(1.0 / np.sum(wk[keep])))
    # second moment about ZERO: a bias shared by every drive is unknown on a new drive, so it is part
    # of the drive-common error, not subtracted
    second = float(np.mean(np.square(means))) if means else 0.0
    drive_std = float(np.sqrt(max(0.0, second - np.mean(vars_)))) if means else 0.0
    return {"pairs": len(rows), "used": len(ok), "skipped": len(rows) - len(ok),
            "median_abs_residual_deg": float(np.median(np.abs(r))), "mean_residual_deg": float(np.mean(r)),
            "mad_residual_deg": float(1.4826 * np.median(np.abs(r - np.median(r)))),
            "inside_95_whitened": float(np.mean(np.abs(r) / np.hypot(sd, sigma_vo) < 1.96)),
            "sigma_vo_deg": float(sigma_vo), "drive_means_deg": means, "drive_std_deg": drive_std,
            "median_drive_mean_deg": float(np.median(means)) if means else float("nan")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--version", default="v1.0-sim")
    ap.add_argument("--out", required=True)
    ap.add_argument("--set", nargs="*", default=[], help="MotionConfig overrides (key=value)")
    a = ap.parse_args(argv)
    conf = merge(MotionConfig, parse_overrides(a.set))
    out = Path(a.out)
    t0 = time.perf_counter()
    rows = []
    for root in a.data:
        rows += residuals(root, a.version, conf, str(out / "cache"))
        print(f"{root}: {sum('residual_deg' in r for r in rows)} pairs so far ({time.perf_counter() - t0:.0f} s)",
              flush=True)
    f = fit(rows)
    reasons = {}
    for r in rows:
        if "skipped" in r:
            key = r["skipped"].split(":")[0]
            reasons[key] = reasons.get(key, 0) + 1
    print(f"pairs {f['pairs']}, used {f['used']}, skipped {f['skipped']} {reasons}")
    print(f"residual at the truth: median |r| {f['median_abs_residual_deg']:.3f} deg, "
          f"mean {f['mean_residual_deg']:+.3f}, MAD {f['mad_residual_deg']:.3f}")
    print(f"fit: sigma_vo_deg {f['sigma_vo_deg']:.3f}, drive_std_deg {f['drive_std_deg']:.3f} "
          f"(per-drive means {np.round(f['drive_means_deg'], 3).tolist()}); whitened inside 1.96: "
          f"{f['inside_95_whitened']:.1%}")
    save_json_atomic(out / "motion_fit.json", {"command": " ".join(sys.argv), "fit": f, "reasons": reasons,
                                               "rows": rows, "seconds": time.perf_counter() - t0})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
