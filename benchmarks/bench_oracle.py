"""Oracle-correspondence calibration on simulated drives: accuracy, Cramer-Rao ratio, consistency.

Per Monte Carlo run: one simulated drive (``hybrid-calib simulate``; the runs cycle through the
vehicles of one root), oracle correspondences per frame (``hybrid_calib.calib.oracle``: up to
``--per-frame`` real reflectors that project into the image, ``--sigma-px`` pixel noise,
``--outliers`` gross outliers, elevation redrawn from the factor's model unless
``--elevation world``), a start sampled uniformly in R1 or R2 (docs/conventions.md), then the
sliding window (``--window``) frame by frame and the batch solve of the whole drive. Noise,
outliers, elevations, subsampling and the start are drawn independently per run.

Reported: per-axis and mean absolute errors (``metrics.extrinsic_error``), the ratio of the
per-axis RMSE to the per-axis Cramer-Rao std (``calib.crb``, camera axes), the CRB-normalised
error ``E[e^T F e] / 6`` (1 = efficient), covariance consistency (fraction of runs with NEES below
the chi2(6) 95 % quantile 12.59; mean NEES, ideal 6), false step alarms, and time per frame.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_oracle.py --runs 100 --frames 200 --out outputs/bench_oracle

With the per-drive scene nuisance on (``RadarPixelFactorConfig.scene_*``, the default; ``--scene-*``
override it) every run is also read WITHOUT it (modes ``window_noscene`` / ``batch_noscene``: the
same estimates, today's covariance and bound), and the NEES of the four directions the data observe
(rotation about radar x and z, translation along radar x and y) is reported next to the six-direction
one. A frame with no real reflector in view is skipped (``skipped_frames``).

Elevation models on the simulator's real reflector heights, paired runs (same seeds), one table:

    PYTHONPATH=. .venv/bin/python benchmarks/bench_oracle.py --elevation world --ranges R1 --runs 20 \
        --elevation-models anisotropic height
"""

from __future__ import annotations

import argparse
import hashlib
import json
import multiprocessing as mp
import sys
import time
from pathlib import Path

import numpy as np

CHI2_4_95 = 9.487729036781154  # scipy.stats.chi2.ppf(0.95, 4): the four observable directions' 95 % bound
MODES = ("window", "batch", "window_noscene", "batch_noscene")  # *_noscene: same solve, no scene nuisance
OBS = [0, 2, 3, 4]  # right-tangent axes the data observe: rotation about radar x and z, translation along x and y
AXES = ("rot_x", "rot_y", "rot_z", "t_x", "t_y", "t_z")

_DATA: dict = {}


def _load(root: str, vehicle_frames: dict) -> None:
    """Per worker: every frame of every vehicle (loaded once)."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    if _DATA:
        return
    # an empty radar sweep (a highway gap) is kept: the oracle finds no reflector in it and skips the frame
    ds = NuScenesRadarCamera(root, "v1.0-sim", conf={"check_images": False, "skip_empty_radar": False})
    for v, idx in vehicle_frames.items():
        _DATA[v] = [ds[i] for i in idx]


def run_one(job: dict) -> dict:
    """One Monte Carlo run; an exception is recorded (``error``) and the benchmark goes on."""
    import traceback

    try:
        return _run_one(job)
    except Exception as e:  # noqa: BLE001 - a long benchmark records a failed run and continues
        return {"range": job["range"], "seed": job["seed"], "vehicle": job["vehicle"],
                "error": f"{type(e).__name__}: {e}", "traceback": traceback.format_exc()[-2000:]}


SCENE_KEYS = ("scene_height_std_m", "scene_lateral_slope_std", "scene_height_sq_std_m2",
              "scene_lateral_slope_frame_std")


def factor_config(model: str, elevation: str, height_mean_m: float | None = None,
                  height_std_m: float | None = None, scene: dict | None = None) -> dict:
    """Factor overrides of one benchmark variant. With ``--elevation model`` the oracle draws from the
    factor's own model, so the mean height is known exactly: no height-offset inflation (0), and the
    drive has no scene structure: no scene nuisance (0). ``scene``: overrides of ``SCENE_KEYS``."""
    from factors.config import RadarPixelFactorConfig

    d = RadarPixelFactorConfig()
    out = {"elevation_model": model,
           "reflector_height_mean_m": d.reflector_height_mean_m if height_mean_m is None else height_mean_m,
           "reflector_height_std_m": d.reflector_height_std_m if height_std_m is None else height_std_m,
           "reflector_height_mean_std_m": d.reflector_height_mean_std_m,
           "reflector_tilt_std_deg": d.reflector_tilt_std_deg}
    out.update({k: getattr(d, k) for k in SCENE_KEYS})
    out.update({k: v for k, v in (scene or {}).items() if v is not None})
    if elevation == "model":
        out.update(reflector_height_mean_std_m=0.0, reflector_tilt_std_deg=0.0, **{k: 0.0 for k in SCENE_KEYS})
    return out


def on_road(factor: dict, frames: list, elevation: str) -> dict:
    """``factor`` (overrides) with the heights measured from the road as calibrate does (``pipeline.on_road_plane``:
    the vehicle's reference radar mount, from its first frame), for the world's heights; the oracle's model draw is
    from the radar's own plane."""
    from factors.config import RadarPixelFactorConfig
    from hybrid_calib.calib.pipeline import road_factor, road_normal
    from hybrid_calib.config import merge

    if elevation != "world" or not frames:
        return dict(factor)
    fc = road_factor(merge(RadarPixelFactorConfig, factor), road_normal(frames[0].extras["reference_T_ego_radar"]))
    return {**factor, "height_plane_normal": fc.height_plane_normal}


def _run_one(job: dict) -> dict:
    import dataclasses

    from factors.config import RadarPixelFactorConfig
    from factors.scene import scene_prior_std
    from hybrid_calib.calib.batch import solve_batch
    from hybrid_calib.calib.covariance import analyse_drive_information, report_basis
    from hybrid_calib.calib.crb import oracle_crb
    from hybrid_calib.calib.oracle import OracleConfig, oracle_from_frame
    from hybrid_calib.calib.window import SlidingWindowCalibrator
    from hybrid_calib.config import merge
    from hybrid_calib.errors import DataError
    from hybrid_calib.geometry import local
    from hybrid_calib.metrics import extrinsic_error
    from hybrid_calib.perturbation import perturbed_start

    _load(job["root"], job["vehicle_frames"])
    frames_in = _DATA[job["vehicle"]][: job["frames"]]
    g = np.random.default_rng(job["seed"])
    factor = on_road(job["factor"], frames_in, job["elevation"])
    fconf = merge(RadarPixelFactorConfig, factor)
    oconf = OracleConfig(n_per_frame=job["per_frame"], sigma_px=job["sigma_px"], outlier_frac=job["outliers"],
                         elevation=job["elevation"], elevation_model=fconf.elevation_model,
                         elevation_beam_deg=fconf.elevation_beam_deg, elevation_mean_deg=fconf.elevation_mean_deg,
                         reflector_height_mean_m=fconf.reflector_height_mean_m,
                         reflector_height_std_m=fconf.reflector_height_std_m)
    frames, truths, skipped = [], [], 0
    for f in frames_in:
        try:
            c, t = oracle_from_frame(f, oconf, g)
        except DataError as e:  # a frame with no real reflector in view (a highway gap): no rows, as on a real drive
            if "no real radar reflector" not in str(e):
                raise
            skipped += 1
            continue
        frames.append(c)
        truths.append(t)
    T = truths[-1].T_cam_radar
    T0 = perturbed_start(T, g, job["range"])
    # + the prior-pinned height offset and tilt ("height") and the per-drive scene nuisance (factors.scene)
    fconf_base = dataclasses.replace(fconf, **{k: 0.0 for k in SCENE_KEYS})
    # the bound of the model used: with the scene prior the covariance takes for these rows (scene_config_for: wider
    # on a straight road and for few frames)
    crb = oracle_crb(T, frames, truths, job["sigma_px"], fconf)
    crb_base = oracle_crb(T, frames, truths, job["sigma_px"], fconf_base)  # the same without the scene nuisance
    F_crb, F_crb_base = np.linalg.inv(crb), np.linalg.inv(crb_base)
    B = report_basis(T)
    out = {"vehicle": job["vehicle"], "range": job["range"], "seed": job["seed"],
           "n_rows": int(sum(len(c) for c in frames)), "skipped_frames": skipped,
           "crb_var_report": np.diag(B @ crb @ B.T).tolist(),
           "crb_var_report_noscene": np.diag(B @ crb_base @ B.T).tolist()}
    scene_on = len(scene_prior_std(fconf)) > 0
    wconf = {"window": job["window"], "schedule": {"final_gate": job["gate"]}, "factor": factor}
    cal = SlidingWindowCalibrator(T0, wconf)
    ms, alarms = [], 0
    for c in frames:
        o = cal.update(c)
        ms.append(o.solve_ms + o.cov_ms)
        alarms += int(o.step_alarm)
    modes = {"window": (o.T, o.cov, o.status, F_crb)}
    t0 = time.perf_counter()
    b = solve_batch(frames, T0, {"schedule": {"final_gate": job["gate"]}, "factor": factor})
    batch_s = time.perf_counter() - t0
    modes["batch"] = (b.estimate.T, b.estimate.cov, b.estimate.status, F_crb)
    if scene_on:  # paired: the same estimates read without the scene nuisance (today's covariance)
        for name, est in (("window", o.estimate), ("batch", b.estimate)):
            rep = analyse_drive_information(est.T, est.info, None, fconf_base)
            modes[f"{name}_noscene"] = (est.T, rep.cov, rep.status, F_crb_base)
    for name, (Te, C, status, F_crb) in modes.items():
        e = local(T, Te)
        err = extrinsic_error(Te, T)
        out[name] = {
            "err_report": (B @ e).tolist(),  # camera axes, rad and m
            "metrics": err.as_dict(),
            "nees": float(e @ np.linalg.solve(C, e)),
            "nees_obs": float(e[OBS] @ np.linalg.solve(np.asarray(C)[np.ix_(OBS, OBS)], e[OBS])),
            "crb_norm": float(e @ F_crb @ e),
            "status": status,
            "cov": np.asarray(C).tolist(),  # reported covariance: NEES under other inflations offline
        }
    out.update(window_ms_mean=float(np.mean(ms)), window_ms_median=float(np.median(ms)), false_alarms=alarms,
               batch_s=batch_s)
    return out


def summarise(results: list[dict], mode: str) -> dict:
    from hybrid_calib.metrics import CHI2_6_95, METRIC_KEYS

    E = np.array([r[mode]["err_report"] for r in results])
    V = np.array([r["crb_var_report_noscene" if mode.endswith("_noscene") else "crb_var_report"] for r in results])
    nees = np.array([r[mode]["nees"] for r in results])
    crbn = np.array([r[mode]["crb_norm"] for r in results])
    nobs = np.array([r[mode].get("nees_obs", np.nan) for r in results])  # nan: a run stored before it existed
    return {
        "runs": len(results),
        "metrics_mean": {k: float(np.mean([r[mode]["metrics"][k] for r in results])) for k in METRIC_KEYS},
        "rmse_over_crb": {a: float(np.sqrt(np.mean(E[:, i] ** 2) / np.mean(V[:, i]))) for i, a in enumerate(AXES)},
        # signed mean error over the runs (deg / cm, camera axes) and that mean over the runs' std:
        # |bias/std| >> 2 / sqrt(runs) means a systematic error
        "mean_err": {a: float(np.mean(E[:, i]) * (np.degrees(1) if i < 3 else 100.0)) for i, a in enumerate(AXES)},
        # undefined for one run (probe 117: a 300-digit number): NaN, printed as such
        "bias_over_std": {a: float(np.mean(E[:, i]) / np.std(E[:, i])) if len(E) > 1 and np.std(E[:, i]) > 0
                          else float("nan") for i, a in enumerate(AXES)},
        "crb_efficiency_ratio": float(np.sqrt(np.mean(crbn) / 6.0)),
        "inside_95": float(np.mean(nees < CHI2_6_95)),
        "nees_mean": float(np.mean(nees)),
        "nees_median": float(np.median(nees)),
        # the four directions the correspondences observe (the other two are prior-pinned, "height")
        "inside_95_obs": float(np.mean(nobs < CHI2_4_95)),
        "nees_obs_mean": float(np.mean(nobs)),
        "crb_std_mean": {a: float(np.sqrt(np.mean(V[:, i])) * (np.degrees(1) if i < 3 else 100.0))
                         for i, a in enumerate(AXES)},
        "statuses": sorted({r[mode]["status"].split(":")[0] for r in results}),
    }


def main(argv=None) -> int:
    from factors.config import ELEVATION_MODELS, RadarPixelFactorConfig

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, default=Path("outputs/bench_oracle/sim"), help="v1.0-sim root (made if absent)")
    p.add_argument("--vehicles", type=int, default=4, help="vehicles (drives) to simulate when --data is absent")
    p.add_argument("--scenario", default="urban")
    p.add_argument("--runs", type=int, default=100, help="Monte Carlo runs per start range")
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--per-frame", type=int, default=100)
    p.add_argument("--sigma-px", type=float, default=2.0)
    p.add_argument("--outliers", type=float, default=0.2)
    p.add_argument("--window", type=int, default=20)
    p.add_argument("--gate", type=float, default=3.0, help="final inlier gate (0 = redescending kernel only)")
    p.add_argument("--elevation", default="model", choices=("model", "world"))
    p.add_argument("--elevation-models", nargs="+", default=[RadarPixelFactorConfig().elevation_model],
                   choices=[m for m in ELEVATION_MODELS if m != "zero"],
                   help="factor elevation models to compare (same seeds: paired runs); one table per model")
    p.add_argument("--height-mean", type=float, default=None, help="reflector_height_mean_m (default: the config's)")
    p.add_argument("--height-std", type=float, default=None, help="reflector_height_std_m (default: the config's)")
    p.add_argument("--scene-height-std", type=float, default=None, help="scene_height_std_m (default: the config's)")
    p.add_argument("--scene-lateral-std", type=float, default=None,
                   help="scene_lateral_slope_std (default: the config's)")
    p.add_argument("--scene-sq-std", type=float, default=None, help="scene_height_sq_std_m2 (default: the config's)")
    p.add_argument("--scene-frame-std", type=float, default=None,
                   help="scene_lateral_slope_frame_std (default: the config's)")
    p.add_argument("--ranges", nargs="+", default=["R1", "R2"])
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=10_000,
                   help="run k of start range i draws its noise, outliers and start from seed * (1 + i) + k "
                        "(default 10000: the published tables' draws)")
    p.add_argument("--summary-only", action="store_true", help="summarise the runs already in the .jsonl, run nothing")
    p.add_argument("--out", type=Path, default=Path("outputs/bench_oracle"))
    a = p.parse_args(argv)
    from tqdm import tqdm

    from hybrid_calib.config import merge, save_json_atomic
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    if not (a.data / "v1.0-sim").is_dir():
        if a.summary_only:  # probe 136: it simulated a new root there and printed an empty table
            print(f"bench_oracle.py: --summary-only summarises the runs on --data {a.data}, which holds no v1.0-sim "
                  "root (moved or deleted?): pass the root the runs were measured on", file=sys.stderr)
            return 2
        from hybrid_calib.sim.drive import SimConfig
        from hybrid_calib.sim.simulate import simulate

        simulate(merge(SimConfig, {"scenario": a.scenario, "vehicles": a.vehicles, "frames": a.frames,
                                   "image_scale": 0.25}), a.data, overwrite=False, workers=a.workers)
    ds = NuScenesRadarCamera(a.data, "v1.0-sim", conf={"check_images": False})
    vf = {v: idx[: a.frames] for v, idx in sorted(ds.frames_by_vehicle().items())}
    vehicles = sorted(vf)
    a.out.mkdir(parents=True, exist_ok=True)
    summaries = {}
    for model in a.elevation_models:
        fc = factor_config(model, a.elevation, a.height_mean, a.height_std,
                           dict(zip(SCENE_KEYS, (a.scene_height_std, a.scene_lateral_std, a.scene_sq_std,
                                             a.scene_frame_std))))
        jobs = [dict(root=str(a.data), vehicle_frames=vf, vehicle=vehicles[k % len(vehicles)], range=rg,
                     seed=a.seed * (1 + i) + k, frames=a.frames, per_frame=a.per_frame, sigma_px=a.sigma_px,
                     outliers=a.outliers, window=a.window, gate=a.gate, elevation=a.elevation, factor=fc)
                for k in range(a.runs) for i, rg in enumerate(a.ranges)]  # R1 and R2 interleaved
        # "anisotropic" keeps the tag of the runs measured before the height model existed
        htag = "" if model == "anisotropic" else \
            f"_{model}_h{fc['reflector_height_mean_m']:g}_s{fc['reflector_height_std_m']:g}" \
            f"_m{fc['reflector_height_mean_std_m']:g}_t{fc['reflector_tilt_std_deg']:g}" + \
            ("" if not any(fc[k] for k in SCENE_KEYS) else
             f"_scene{fc['scene_height_std_m']:g}_{fc['scene_lateral_slope_std']:g}_{fc['scene_height_sq_std_m2']:g}"
             + (f"_f{fc['scene_lateral_slope_frame_std']:g}" if fc["scene_lateral_slope_frame_std"] else ""))
        # what else decides a run: kept runs of other data, noise, outliers or draws are not this table's (probe 134:
        # a new --data or --sigma-px printed the old runs' table under the new arguments); heights from the road
        opts = {"data": str(a.data.resolve()), "tables": _tables_digest(a.data), "per_frame": a.per_frame,
                "sigma_px": a.sigma_px, "outliers": a.outliers, "seed": a.seed, "plane": "road"}
        digest = hashlib.sha256(json.dumps(opts, sort_keys=True).encode()).hexdigest()[:10]
        tag = f"{a.elevation}{htag}_gate{a.gate:g}_w{a.window}_f{a.frames}_{digest}"
        summaries[model] = summary = _run_variant(a, jobs, tag, tqdm, save_json_atomic)
        summary["factor"] = fc
        save_json_atomic(a.out / f"summary_{tag}.json", summary)
        print(json.dumps(summary, indent=1))
    print(comparison_table(summaries, a.ranges))
    return 0


def _tables_digest(root: Path) -> str:
    """SHA-256 of the root's tables (a root simulated again at the same path is other data: probe 135)."""
    h = hashlib.sha256()
    for p in sorted((root / "v1.0-sim").glob("*.json")):
        h.update(p.name.encode() + p.read_bytes())
    return h.hexdigest()[:16]


def _run_variant(a, jobs: list[dict], tag: str, tqdm, save_json_atomic) -> dict:
    runs_path = a.out / f"runs_{tag}.jsonl"  # one line per finished run: the benchmark resumes
    results = [json.loads(line) for line in runs_path.read_text().splitlines()] if runs_path.is_file() else []
    done = {(r["range"], r["seed"]) for r in results}
    todo = [] if a.summary_only else [j for j in jobs if (j["range"], j["seed"]) not in done]
    t0 = time.time()
    if todo:
        with mp.get_context("fork").Pool(a.workers) as pool, runs_path.open("a") as fh:
            for r in tqdm(pool.imap_unordered(run_one, todo), total=len(todo), desc=f"oracle MC {tag}"):
                fh.write(json.dumps(r) + "\n")
                fh.flush()
                results.append(r)
    wall = time.time() - t0
    results = [r for r in results if (r["range"], r["seed"]) in {(j["range"], j["seed"]) for j in jobs}]
    failed = [r for r in results if "error" in r]
    results = [r for r in results if "error" not in r]
    summary = {"args": {k: str(v) for k, v in vars(a).items()}, "wall_s_this_invocation": wall,
               "failed_runs": [{k: r[k] for k in ("range", "seed", "vehicle", "error")} for r in failed]}
    if not results:
        return summary
    summary.update({"mean_rows_per_frame": float(np.mean([r["n_rows"] for r in results]) / a.frames),
                    "false_alarms_total": int(sum(r["false_alarms"] for r in results)),
                    "window_ms_per_frame_mean": float(np.mean([r["window_ms_mean"] for r in results])),
                    "window_ms_per_frame_median": float(np.median([r["window_ms_median"] for r in results])),
                    "batch_s_mean": float(np.mean([r["batch_s"] for r in results]))})
    for rg in a.ranges:
        sub = [r for r in results if r["range"] == rg]
        if sub:
            summary[rg] = {m: summarise(sub, m) for m in MODES if all(m in r for r in sub)}
    summary["wall_s_per_run_x_workers"] = wall * a.workers / max(1, len(todo))
    return summary


def comparison_table(summaries: dict, ranges) -> str:
    """Markdown: per model, range and mode, signed mean error and bias/std per axis, RMSE/CRB, NEES."""
    head = ("| model | start | mode | runs | mean err rot x,y,z (deg) | mean err t x,y,z (cm) | bias/std rot x,y,z | "
            "bias/std t x,y,z | RMSE/CRB rot x,y,z | RMSE/CRB t x,y,z | sqrt(E[e'Fe]/6) | inside 95 % | mean NEES | "
            "4 observable: inside 95 % | 4 observable: mean NEES |")
    lines = [head, "|" + "---|" * 15]
    for model, summ in summaries.items():
        for rg in ranges:
            for mode in MODES:
                s = summ.get(rg, {}).get(mode)
                if not s:
                    continue
                def f(d, keys, fmt):
                    return ", ".join(fmt % d[k] for k in keys)
                lines.append(
                    f"| {model} | {rg} | {mode} | {s['runs']} | {f(s['mean_err'], AXES[:3], '%.3f')} | "
                    f"{f(s['mean_err'], AXES[3:], '%.2f')} | {f(s['bias_over_std'], AXES[:3], '%.1f')} | "
                    f"{f(s['bias_over_std'], AXES[3:], '%.1f')} | {f(s['rmse_over_crb'], AXES[:3], '%.2f')} | "
                    f"{f(s['rmse_over_crb'], AXES[3:], '%.2f')} | {s['crb_efficiency_ratio']:.3f} | "
                    f"{100 * s['inside_95']:.1f} % | {s['nees_mean']:.2f} | "
                    f"{100 * s['inside_95_obs']:.1f} % | {s['nees_obs_mean']:.2f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
