"""How one drive's reflector heights differ from the radar-pixel factor's height model, measured.

The per-drive scene nuisance of the factor (``factors.scene``; ``RadarPixelFactorConfig.scene_*``)
stands for three deviations a drive's reflectors share: a height offset per range knot ``a`` (m), a
left/right height slope ``c_y`` (m per m of lateral position) and an offset of the mean squared
height per knot ``q`` (m^2), each with a prior std (0.25 m, 0.005 m/m, 0.35 m^2 by default). This
benchmark measures those deviations on simulated drives, where every reflector's true height is
known, so the priors can be checked against the world instead of only against NEES:

1. per frame, the real reflectors that project into the image (``calib.oracle``, true positions,
   no noise, no outliers), radar frame: slant range ``r``, lateral ``y``, height ``h``;
2. per reflector, the factor's expectation under its fixed model (``factors.projection``: ``h ~
   N(mean, std^2)`` truncated to the beam): ``d = h - E[h | r]``, ``s = h^2 - E[h^2 | r]``;
3. per drive, least squares ``d = B(r) a + c_y y`` and ``s = B(r) q`` (``B``: the scene's range hats).

``--lidar-radius R`` also asks whether the LiDAR could measure ``c_y`` (issue 10's option of per-row height
priors from what the other sensors see): per reflector, the mean height of the LiDAR points within R metres
of its radar position (r cos az, r sin az) horizontally and inside the radar's elevation field of view
(radar frame, through the true extrinsic: the best case), and the same fit on those heights; reported is
the RMS of ``c_y(LiDAR) - c_y(true)`` over the drives against the RMS of ``c_y(true)`` (what a zero-mean
prior already errs by).

Reported per preset: the RMS over drives of ``c_y`` (and as an angle: a height slope across the
road is what a roll of the radar about its forward axis looks like), of ``a`` and ``q`` per knot, and
per drive ``c_y`` with the number of reflectors. The per-drive values include the drive's own
sampling (the reflectors it happened to see), which is what the estimate of that drive meets.

    PYTHONPATH=. .venv/bin/python benchmarks/scene_profiles.py --data SIM_urban SIM_highway SIM_rain SIM_straight \
        --frames 60 --out OUT
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np


def drive_rows(frames, conf, lidar_radius: float = 0.0) -> tuple[np.ndarray, np.ndarray | None]:
    """(N, 3) slant range, lateral y, height (metres, radar frame) of the real reflectors in view, and with
    ``lidar_radius`` > 0 the same rows with the LiDAR's height at each (module doc; None otherwise; reflectors
    with fewer than 2 LiDAR points near them are left out of both)."""
    from hybrid_calib.calib.oracle import OracleConfig, oracle_from_frame
    from hybrid_calib.errors import DataError

    oconf = OracleConfig(n_per_frame=100000, sigma_px=1e-6, outlier_frac=0.0, elevation="world")
    g = np.random.default_rng(0)
    out, lidar = [], []
    for f in frames:
        try:
            _, truth = oracle_from_frame(f, oconf, g)
        except DataError as e:
            if "no real radar reflector" in str(e):
                continue
            raise
        p = truth.points_true[truth.inlier]
        rows = np.stack([np.linalg.norm(p, axis=1), p[:, 1], p[:, 2]], 1)
        if lidar_radius > 0:
            keep, h = _lidar_heights(f, rows, p, lidar_radius)
            rows = rows[keep]
            lidar.append(np.concatenate([rows[:, :2], h[:, None]], 1))
        out.append(rows)
    empty = np.zeros((0, 3))
    return (np.concatenate(out) if out else empty,
            None if lidar_radius <= 0 else np.concatenate(lidar) if lidar else empty)


def frame_rows_on_road(frames) -> list[np.ndarray]:
    """Per frame (N, 3): slant range, lateral y, height above the road plane through the radar (m; the plane the
    vehicle's reference mount puts the radar on, as the factor measures heights since 2026-12-07:
    ``calib.pipeline.road_normal``) of the real reflectors in view (step 1 of the module doc)."""
    from hybrid_calib.calib.oracle import OracleConfig, oracle_from_frame
    from hybrid_calib.calib.pipeline import road_normal
    from hybrid_calib.errors import DataError

    oconf = OracleConfig(n_per_frame=100000, sigma_px=1e-6, outlier_frac=0.0, elevation="world")
    g = np.random.default_rng(0)
    out = []
    for f in frames:
        try:
            _, truth = oracle_from_frame(f, oconf, g)
        except DataError as e:
            if "no real radar reflector" not in str(e):
                raise
            out.append(np.zeros((0, 3)))
            continue
        p = truth.points_true[truth.inlier]
        n = road_normal(f.extras["reference_T_ego_radar"])
        h = p @ n if n is not None else p[:, 2]
        out.append(np.stack([np.linalg.norm(p, axis=1), p[:, 1], h], 1))
    return out


def window_slopes(per_frame: list[np.ndarray], conf, lengths) -> dict[int, list[float]]:
    """``c_y`` (m/m) of each run of L consecutive frames (non-overlapping) of one drive, for each L of ``lengths``
    (runs of fewer than 20 reflectors left out)."""
    out = {}
    for L in lengths:
        out[L] = [fit_drive(rows, conf)["c_y"] for s in range(0, len(per_frame) - L + 1, L)
                  if len(rows := np.concatenate(per_frame[s:s + L])) >= 20]
    return out


def _lidar_heights(f, rows: np.ndarray, p: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(mask of the reflectors with >= 2 LiDAR points near them, the mean LiDAR height at each kept one, m)."""
    from hybrid_calib.geometry import se3_inverse

    T = se3_inverse(f.T_cam_radar) @ f.T_cam_lidar  # LiDAR -> radar through the true extrinsic
    L = f.lidar_points[:, :3].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    az = np.arctan2(p[:, 1], p[:, 0])
    xy = rows[:, :1] * np.stack([np.cos(az), np.sin(az)], 1)
    keep, h = np.zeros(len(rows), bool), []
    for k in range(len(rows)):
        m = ((np.linalg.norm(L[:, :2] - xy[k], axis=1) < radius)
             & (np.abs(L[:, 2]) < rows[k, 0] * np.tan(np.deg2rad(7.0)) + 0.3))
        if m.sum() >= 2:
            keep[k] = True
            h.append(float(np.mean(L[m, 2])))
    return keep, np.asarray(h)


def fit_drive(rows: np.ndarray, conf) -> dict:
    """The drive's scene deviations from the factor's model (module doc, step 2-3)."""
    from factors.projection import truncated_normal_moments
    from factors.scene import range_hats

    r, y, h = rows.T
    beam, centre = np.deg2rad(conf.elevation_beam_deg), np.deg2rad(conf.elevation_mean_deg)
    mean_h, std_h = truncated_normal_moments(conf.reflector_height_mean_m, conf.reflector_height_std_m,
                                             r * np.sin(centre - beam), r * np.sin(centre + beam))
    d, s = h - mean_h, h ** 2 - (mean_h ** 2 + std_h ** 2)
    B = range_hats(r, conf.scene_knots_m)
    seen = B.sum(0) > 1.0  # knots with reflectors near them
    A = np.concatenate([B[:, seen], y[:, None]], 1)
    coef = np.linalg.lstsq(A, d, rcond=None)[0]
    a = np.full(B.shape[1], np.nan)
    a[seen] = coef[:-1]
    q = np.full(B.shape[1], np.nan)
    q[seen] = np.linalg.lstsq(B[:, seen], s, rcond=None)[0]
    return {"reflectors": int(len(r)), "c_y": float(coef[-1]), "a": a.tolist(), "q": q.tolist(),
            "knot_weight": B.sum(0).tolist(), "lateral_std_m": float(np.std(y)),
            "mean_d": float(np.mean(d)), "mean_s": float(np.mean(s))}


def rms(x) -> float:
    x = np.asarray(x, np.float64)
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if len(x) else float("nan")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", nargs="+", required=True, type=Path, help="v1.0-sim roots (one preset each)")
    p.add_argument("--frames", type=int, default=60, help="keyframes per drive (the first N)")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--lidar-radius", type=float, default=0.0,
                   help="also fit c_y on the LiDAR's heights at the reflectors (this radius, m; module doc)")
    p.add_argument("--windows", type=int, nargs="+", default=None, metavar="L",
                   help="instead: c_y of runs of L consecutive keyframes, heights from the road (how the slope of a "
                        "short stretch of road exceeds a drive's: scene_lateral_slope_frame_std)")
    a = p.parse_args(argv)
    if a.windows:
        return _windows(a)

    from factors.config import RadarPixelFactorConfig
    from hybrid_calib.config import save_json_atomic
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    conf = RadarPixelFactorConfig()
    a.out.mkdir(parents=True, exist_ok=True)
    result = {"command": "PYTHONPATH=. python benchmarks/scene_profiles.py " + " ".join(sys.argv[1:] if argv is None
                                                                                          else argv),
              "knots_m": list(conf.scene_knots_m),
              "priors": {"scene_height_std_m": conf.scene_height_std_m,
                         "scene_lateral_slope_std": conf.scene_lateral_slope_std,
                         "scene_height_sq_std_m2": conf.scene_height_sq_std_m2},
              "roots": {}}
    for root in a.data:
        ds = NuScenesRadarCamera(root, "v1.0-sim", conf={"check_images": False, "skip_empty_radar": False,
                                                          "load_lidar": a.lidar_radius > 0})
        drives = {}
        for scene, idx in ds.frames_by_vehicle().items():
            idx = idx[: a.frames]
            rows, lidar = drive_rows([ds[i] for i in idx], conf, a.lidar_radius)
            if len(rows) < 20:
                print(f"{root.name} {scene}: {len(rows)} reflectors, skipped")
                continue
            drives[scene] = fit_drive(rows, conf)
            extra = ""
            if lidar is not None:
                drives[scene]["c_y_lidar"] = fit_drive(lidar, conf)["c_y"]
                drives[scene]["height_corr_lidar"] = float(np.corrcoef(rows[:, 2], lidar[:, 2])[0, 1])
                extra = (f", from the LiDAR {drives[scene]['c_y_lidar']:+.4f} (height correlation "
                         f"{drives[scene]['height_corr_lidar']:.2f})")
            print(f"{root.name} {scene}: {len(rows)} reflectors, c_y {drives[scene]['c_y']:+.4f} m/m{extra}",
                  flush=True)
        c = [v["c_y"] for v in drives.values()]
        A = np.array([v["a"] for v in drives.values()])
        Q = np.array([v["q"] for v in drives.values()])
        result["roots"][str(root)] = {
            "drives": drives,
            "c_y_rms": rms(c), "c_y_rms_deg": float(np.degrees(np.arctan(rms(c)))),
            "c_y_mean": float(np.mean(c)),
            "a_rms_per_knot": [rms(A[:, k]) for k in range(A.shape[1])],
            "q_rms_per_knot": [rms(Q[:, k]) for k in range(Q.shape[1])]}
        if a.lidar_radius > 0:
            err = rms([v["c_y_lidar"] - v["c_y"] for v in drives.values()])
            result["roots"][str(root)]["c_y_lidar_error_rms"] = err
            print(f"{root.name}: c_y from the LiDAR errs by {err:.4f} m/m RMS over {len(drives)} drives; a zero-mean "
                  f"prior by {rms(c):.4f}")
    save_json_atomic(a.out / "scene_profiles.json", result)
    knots = ", ".join(f"{k:g}" for k in conf.scene_knots_m)
    print(f"\n| root | drives | c_y RMS m/m (deg) | c_y mean | a RMS per knot ({knots} m), m | q RMS per knot, m^2 |")
    print("|---|---|---|---|---|---|")
    for root, v in result["roots"].items():
        print(f"| {Path(root).name} | {len(v['drives'])} | {v['c_y_rms']:.4f} ({v['c_y_rms_deg']:.2f}) | "
              f"{v['c_y_mean']:+.4f} | {', '.join(f'{x:.2f}' for x in v['a_rms_per_knot'])} | "
              f"{', '.join(f'{x:.2f}' for x in v['q_rms_per_knot'])} |")
    pr = result["priors"]
    print(f"(priors: a {pr['scene_height_std_m']} m, c_y {pr['scene_lateral_slope_std']} m/m, "
          f"q {pr['scene_height_sq_std_m2']} m^2; wrote {a.out / 'scene_profiles.json'})")
    return 0


def _windows(a) -> int:
    """``--windows``: per root and L, the RMS of c_y over runs of L frames, its mean, and the excess variance over the
    drive-level prior times L, ``(var - s^2) L`` (var about the mean: a preset's own mean slope is not a short
    stretch's), which ``scene_lateral_slope_frame_std^2`` stands for."""
    from factors.config import RadarPixelFactorConfig
    from hybrid_calib.config import save_json_atomic
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    conf = RadarPixelFactorConfig()
    s2 = conf.scene_lateral_slope_std ** 2
    a.out.mkdir(parents=True, exist_ok=True)
    result, rows = {"command": "PYTHONPATH=. python benchmarks/scene_profiles.py " + " ".join(sys.argv[1:]),
                    "roots": {}}, []
    for root in a.data:
        ds = NuScenesRadarCamera(root, "v1.0-sim", conf={"check_images": False, "skip_empty_radar": False,
                                                          "load_lidar": False})
        per = {L: [] for L in a.windows}
        for idx in ds.frames_by_vehicle().values():
            for L, c in window_slopes(frame_rows_on_road([ds[i] for i in idx[: a.frames]]), conf, a.windows).items():
                per[L] += c
        result["roots"][str(root)] = {str(L): v for L, v in per.items()}
        for L, v in per.items():
            v = np.asarray(v)
            excess = (float(np.var(v)) - s2) * L if len(v) else float("nan")
            rows.append(f"| {Path(root).name} | {L} | {len(v)} | {rms(v):.4f} | {np.mean(v):+.4f} | "
                        f"{np.sqrt(max(excess, 0.0)):.3f} |")
            print(rows[-1], flush=True)
    save_json_atomic(a.out / "window_slopes.json", result)
    print("\n| root | L frames | runs | c_y RMS m/m | mean | sqrt((var - s^2) L) |\n|---|---|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
