"""The motion constraint's noise on simulated drives with ground truth: residuals at the truth, and
the fitted ``MotionConfig.sigma_vo_deg`` / ``drive_std_deg`` (fit on validation drives only).

    PYTHONPATH=. .venv/bin/python benchmarks/motion_fit.py --data ROOT [ROOT ...] --version v1.0-sim \
        --out OUT [--set velocity.min_inliers=8 vo.min_inliers=30 ...]

Per consecutive frame pair of every vehicle (``hybrid.motion.MotionSource``): the heading residual
of ``factors.motion`` at the true ``T_cam_radar_static``, the Doppler part of its std, the VO
inliers and the radar speed. The fit: ``sigma_vo_deg`` such that the median of the whitened
residual ``|r| / sqrt(sigma_doppler^2 + sigma_vo^2)`` of the pairs with at least ``vo_inliers_full`` VO
inliers is the Gaussian's 0.674 (the tails are left to the Huber weight), ``vo_inliers_power`` the same
for the pairs with fewer (their VO std ``sigma_vo * (full / n) ** power``), ``vo_inliers_full`` the
candidate of ``FULL_GRID`` whose fit whitens each quartile of the inlier counts closest to 0.674;
``vo_chord_power`` the same for the pairs whose radar chord (their travel) is below ``vo_chord_full_m``, the
candidate of ``CHORD_GRID`` that whitens each quartile of those chords closest to 0.674 (``--hold`` keeps
``sigma_vo_deg`` and the inlier terms at the config's values and fits the chord's alone);
``drive_std_deg``: the spread of the per-drive mean residuals beyond what
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
                         "speed_mps": m.speed, "chord_m": float(m.s)})
    return rows


FULL_GRID = (12, 15, 20, 25, 30, 40)  # candidate vo_inliers_full
CHORD_GRID = (3.0, 4.0, 5.0, 6.0, 8.0, 10.0)  # candidate vo_chord_full_m, metres


def _median_fit(f, hi: float) -> float:
    """The root of the decreasing ``f`` on [0, hi] (0 when f(0) <= 0 already: no growth needed)."""
    from scipy.optimize import brentq

    return 0.0 if f(0.0) <= 0 else (hi if f(hi) > 0 else float(brentq(f, 0.0, hi)))


def fit_vo_sigma(r: np.ndarray, sd: np.ndarray, n: np.ndarray, full: int) -> tuple[float, float]:
    """``(sigma_vo_deg, vo_inliers_power)`` for one ``vo_inliers_full``: the base std such that the whitened
    residuals of the pairs with at least ``full`` inliers have the Gaussian's median 0.674, then the power such
    that those of the pairs with fewer do too. r, sd: (P,) deg; n: (P,) VO inliers."""
    rich = n >= full
    if rich.sum() < 5:
        return float("nan"), float("nan")
    base = _median_fit(lambda s: float(np.median(np.abs(r[rich]) / np.hypot(sd[rich], s))) - 0.6745, 50.0)
    poor = ~rich
    if poor.sum() < 5:
        return base, 0.0
    grow = full / n[poor]
    power = _median_fit(lambda q: float(np.median(np.abs(r[poor]) / np.hypot(sd[poor], base * grow ** q)))
                        - 0.6745, 10.0)
    return base, power


def fit_chord(r: np.ndarray, sd: np.ndarray, s_inl: np.ndarray, chord: np.ndarray, full: float) -> float:
    """``vo_chord_power`` for one ``vo_chord_full_m`` = ``full``: the power such that the whitened residuals of the
    pairs whose chord is below ``full`` have the Gaussian's median 0.674, their VO std ``s_inl (full / chord) **
    power``. r, sd, s_inl: (P,) deg (``s_inl``: the VO std with the inlier terms); chord: (P,) m."""
    short = (chord > 0) & (chord < full)
    if short.sum() < 5:
        return float("nan")
    grow = full / chord[short]
    return _median_fit(lambda q: float(np.median(np.abs(r[short]) / np.hypot(sd[short], s_inl[short] * grow ** q)))
                       - 0.6745, 10.0)


def inlier_bins(r: np.ndarray, sig: np.ndarray, n: np.ndarray, key: str = "inliers") -> list[dict]:
    """The whitened residuals ``r / sig`` by VO inlier count (quartile bins; or by any ``n``, named ``key``): their
    median (0.674 when the std is right) and the fraction inside 1.96."""
    if not len(n):
        return []
    edges = np.unique(np.quantile(n, [0, 0.25, 0.5, 0.75, 1.0]).round(1 if key != "inliers" else 0))
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = (n >= lo) & ((n < hi) if hi < edges[-1] else (n <= hi))
        if sel.any():
            z = np.abs(r[sel]) / sig[sel]
            out.append({key: [float(lo), float(hi)], "pairs": int(sel.sum()), "median_whitened": float(np.median(z)),
                        "inside_95": float(np.mean(z < 1.96)), "robust_std_deg": float(1.4826 * np.median(
                            np.abs(r[sel] - np.median(r[sel]))))})
    return out


def fit(rows: list[dict], hold: MotionConfig | None = None) -> dict:
    ok = [r for r in rows if "residual_deg" in r]
    r = np.array([x["residual_deg"] for x in ok])
    sd = np.array([x["sigma_doppler_deg"] for x in ok])
    n = np.array([x["vo_inliers"] for x in ok], np.float64)
    chord = np.array([x.get("chord_m", 0.0) for x in ok], np.float64)
    # vo_inliers_full: the candidate whose fitted std whitens every inlier bin closest to the Gaussian's median;
    # fitted on the pairs of long chords (each chord candidate's), or held at the config's (``hold``)
    best = None
    for cf in CHORD_GRID:
        long = ~((chord > 0) & (chord < cf))
        for full in ((hold.vo_inliers_full,) if hold is not None else FULL_GRID):
            if hold is not None:
                base, power = hold.sigma_vo_deg, hold.vo_inliers_power
            else:
                base, power = fit_vo_sigma(r[long], sd[long], n[long], full)
            if not np.isfinite(base):
                continue
            s_inl = base * np.where(n < full, full / np.maximum(n, 1), 1.0) ** power
            q = fit_chord(r, sd, s_inl, chord, cf)
            q = 0.0 if not np.isfinite(q) else q
            sig = np.hypot(sd, s_inl * np.where(~long, cf / np.maximum(chord, 1e-3), 1.0) ** q)
            bins = inlier_bins(r[long], sig[long], n[long]) + inlier_bins(r[~long], sig[~long], chord[~long], "chord")
            score = float(sum(np.log(b["median_whitened"] / 0.6745) ** 2 for b in bins))
            if best is None or score < best[0]:
                best = (score, full, base, power, sig, cf, q)
    _, full, sigma_vo, power, sig, chord_full, chord_power = best
    sig_no_chord = np.hypot(sd, sigma_vo * np.where(n < full, full / np.maximum(n, 1), 1.0) ** power)
    w = 1 / sig ** 2
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
            "inside_95_whitened": float(np.mean(np.abs(r) / sig < 1.96)),
            "sigma_vo_deg": float(sigma_vo), "vo_inliers_full": int(full), "vo_inliers_power": float(power),
            "vo_chord_full_m": float(chord_full), "vo_chord_power": float(chord_power), "held": hold is not None,
            "inlier_bins": inlier_bins(r, sig, n), "inlier_bins_one_std": inlier_bins(r, np.hypot(sd, sigma_vo), n),
            "chord_bins": inlier_bins(r, sig, chord, "chord"),
            "chord_bins_no_chord_term": inlier_bins(r, sig_no_chord, chord, "chord"),
            "drive_means_deg": means, "drive_std_deg": drive_std,
            "median_drive_mean_deg": float(np.median(means)) if means else float("nan")}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True)
    ap.add_argument("--version", default="v1.0-sim")
    ap.add_argument("--out", required=True)
    ap.add_argument("--set", nargs="*", default=[], help="MotionConfig overrides (key=value)")
    ap.add_argument("--hold", action="store_true", help="keep sigma_vo_deg and the inlier terms at the config's "
                    "values (--set); fit the chord's term alone")
    a = ap.parse_args(argv)
    conf = merge(MotionConfig, parse_overrides(a.set))
    out = Path(a.out)
    t0 = time.perf_counter()
    rows = []
    for root in a.data:
        rows += residuals(root, a.version, conf, str(out / "cache"))
        print(f"{root}: {sum('residual_deg' in r for r in rows)} pairs so far ({time.perf_counter() - t0:.0f} s)",
              flush=True)
    f = fit(rows, conf if a.hold else None)
    reasons = {}
    for r in rows:
        if "skipped" in r:
            key = r["skipped"].split(":")[0]
            reasons[key] = reasons.get(key, 0) + 1
    print(f"pairs {f['pairs']}, used {f['used']}, skipped {f['skipped']} {reasons}")
    print(f"residual at the truth: median |r| {f['median_abs_residual_deg']:.3f} deg, "
          f"mean {f['mean_residual_deg']:+.3f}, MAD {f['mad_residual_deg']:.3f}")
    for name, key, by in (("fitted std", "inlier_bins", "inliers"), ("sigma_vo_deg alone", "inlier_bins_one_std",
                                                                       "inliers"),
                          ("fitted std", "chord_bins", "chord"), ("without the chord term", "chord_bins_no_chord_term",
                                                                  "chord")):
        print(f"by {'VO inliers' if by == 'inliers' else 'radar chord (m)'}, {name}: " + "; ".join(
            f"{b[by][0]:g}-{b[by][1]:g}: {b['pairs']} pairs, robust std {b['robust_std_deg']:.2f} deg, "
            f"median |r|/std {b['median_whitened']:.2f}, inside 1.96 {b['inside_95']:.0%}" for b in f[key]))
    print(f"fit{' (inlier terms held)' if f['held'] else ''}: sigma_vo_deg {f['sigma_vo_deg']:.3f}, vo_inliers_full "
          f"{f['vo_inliers_full']}, vo_inliers_power {f['vo_inliers_power']:.2f}, vo_chord_full_m "
          f"{f['vo_chord_full_m']:g}, vo_chord_power {f['vo_chord_power']:.2f}, drive_std_deg {f['drive_std_deg']:.3f} "
          f"(per-drive means {np.round(f['drive_means_deg'], 3).tolist()}); whitened inside 1.96: "
          f"{f['inside_95_whitened']:.1%}")
    save_json_atomic(out / "motion_fit.json", {"command": " ".join(sys.argv), "fit": f, "reasons": reasons,
                                               "rows": rows, "seconds": time.perf_counter() - t0})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
