"""Elevation model study: which radar-pixel residual is unbiased when the reflectors' elevation
really varies inside the vertical beam (the radar records z = 0)?

For every seed: a drive of ``--frames`` frames with ``--points`` oracle correspondences each
(``factors.synthetic``: elevation uniform in mean +- beam, 2 px noise, 20 % gross outliers), solved
from the true extrinsic (to isolate bias from convergence) with each elevation model
(``calib.batch.solve_batch``, GTSAM, ``SCHEDULE``: Cauchy after a Huber start, no gated stage).
Reported per model and axis: the mean signed error over seeds, its
standard error (std / sqrt(seeds)), the spread (std), the t-statistic mean / standard error
(|t| > 3: biased), and covariance consistency (mean NEES, ideal 6; fraction of runs inside the
95 % ellipsoid, ideal 0.95).

    PYTHONPATH=. .venv/bin/python benchmarks/elevation_models.py --seeds 30 --frames 20 \
        --out outputs/bench/elevation_models
    PYTHONPATH=. .venv/bin/python benchmarks/elevation_models.py --kernel-study --seeds 30 --frames 20 \
        --out outputs/bench/kernels

Writes ``results.json`` (schema: {"config": {...}, "scenarios": {name: {model: {"mean": [6],
"sem": [6], "std": [6], "t": [6], "nees_mean": float, "inside95": float, "n": int}}}}; axes
[roll_deg, pitch_deg, yaw_deg, x_cm, y_cm, z_cm] signed, camera axes) and ``errors.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from factors.config import ELEVATION_MODELS, RadarPixelFactorConfig
from factors.synthetic import synthetic_correspondences
from hybrid_calib.calib.batch import BatchConfig, solve_batch
from hybrid_calib.calib.schedule import ScheduleConfig
from hybrid_calib.config import save_json_atomic
from hybrid_calib.geometry import R_AXES_CAM_FROM_RADAR, local, make_T
from hybrid_calib.metrics import consistency, signed_errors
from hybrid_calib.metrics import nees as nees_of

AXES = ("roll_deg", "pitch_deg", "yaw_deg", "x_cm", "y_cm", "z_cm")


def nominal_extrinsic() -> np.ndarray:
    """RADAR_FRONT 1.7 m ahead of and 1.0 m below CAM_FRONT (tests.helpers.nominal_T_cam_radar)."""
    return make_T(R_AXES_CAM_FROM_RADAR, np.array([0.0, 1.0, 1.7]))


# The study's schedule: the convex start (Huber 1.345), then the model's kernel, LM to convergence;
# no gated least-squares stage (the robust estimate itself is measured).
SCHEDULE = ScheduleConfig(max_iterations=100, relative_error_tol=1e-10, final_gate=0.0)
# The synthetic elevation distribution is the one the model assumes: no prior-pinned inflation of
# radar z / pitch (as ``bench_oracle.py --elevation model``), so NEES reads the data's covariance.
KNOWN_HEIGHTS = dict(reflector_height_mean_std_m=0.0, reflector_tilt_std_deg=0.0)
# Robust schedules of the kernel study: (kernel, scale); the convex start is skipped for Huber itself.
KERNEL_VARIANTS = {
    "huber alone": ("huber", 1.345),
    "huber -> cauchy": ("cauchy", 2.5),
    "huber -> tukey": ("tukey", 4.685),
    "huber -> geman_mcclure": ("geman_mcclure", 2.5),
}


def run_scenario(name: str, true_mean_deg: float, model_mean_deg: float, args, kernel_study: bool = False) -> dict:
    """Solve every seed's drive with every variant (elevation models, or kernels with the default
    anisotropic model when ``kernel_study``); returns the per-variant statistics."""
    T = nominal_extrinsic()
    variants = list(KERNEL_VARIANTS) if kernel_study else list(ELEVATION_MODELS)
    errs = {m: [] for m in variants}
    nees = {m: [] for m in variants}
    for seed in tqdm(range(args.seeds), desc=name, file=sys.stderr):
        g = np.random.default_rng(1000 + seed)
        frames = [synthetic_correspondences(T, n=args.points, rng=g, sigma_px=args.sigma, outlier_frac=args.outliers,
                                            elevation_beam_deg=args.beam, elevation_mean_deg=true_mean_deg)[0]
                  for _ in range(args.frames)]
        for variant in variants:
            if kernel_study:
                kernel, scale = KERNEL_VARIANTS[variant]
                conf = RadarPixelFactorConfig(kernel=kernel, kernel_scale=scale, elevation_model="anisotropic",
                                              elevation_beam_deg=args.beam, elevation_mean_deg=model_mean_deg,
                                              **KNOWN_HEIGHTS)
            else:
                conf = RadarPixelFactorConfig(kernel=args.kernel, elevation_model=variant, elevation_beam_deg=args.beam,
                                              elevation_mean_deg=model_mean_deg, **KNOWN_HEIGHTS)
            res = solve_batch(frames, T, BatchConfig(factor=conf, schedule=SCHEDULE)).estimate
            s = signed_errors(res.T, T)
            errs[variant].append(np.concatenate([np.rad2deg(s[:3]), 100 * s[3:]]))
            if not res.regularised:
                xi = local(res.T, T)
                nees[variant].append(nees_of(xi, res.cov))
    out = {}
    for model in variants:
        E = np.array(errs[model])
        mean, std = E.mean(0), E.std(0, ddof=1)
        sem = std / np.sqrt(len(E))
        summary = consistency(nees[model])  # None where every solve was regularised
        out[model] = dict(mean=mean.tolist(), sem=sem.tolist(), std=std.tolist(), t=(mean / sem).tolist(),
                          nees_mean=summary["nees_mean"], inside95=summary["coverage_95"], n=len(E),
                          errors=E.tolist())
    return out


def format_scenario(name: str, res: dict) -> str:
    lines = [f"### {name}", "",
             "| model | " + " | ".join(f"{a} mean +- sem (std) [t]" for a in AXES) + " | NEES | in 95 % |",
             "|---|" + "---|" * (len(AXES) + 2)]
    for model, r in res.items():
        stats = zip(r["mean"], r["sem"], r["std"], r["t"], strict=True)
        cells = [f"{m:+.3f} +- {s:.3f} ({sd:.3f}) [{t:+.1f}]" for m, s, sd, t in stats]
        lines.append(f"| {model} | " + " | ".join(cells) + " | " + " | ".join(
            "-" if v is None else f"{v:{f}}" for v, f in ((r["nees_mean"], ".1f"), (r["inside95"], ".2f"))) + " |")
    return "\n".join(lines)


def plot(results: dict, path: Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scen = list(results)
    fig, axes = plt.subplots(len(scen), 6, figsize=(18, 3.2 * len(scen)), squeeze=False)
    for i, sname in enumerate(scen):
        for j, axis in enumerate(AXES):
            ax = axes[i, j]
            names = list(results[sname])
            data = [np.array(results[sname][m]["errors"])[:, j] for m in names]
            ax.boxplot(data, tick_labels=[m.replace(" -> ", ">") for m in names], showmeans=True)
            ax.axhline(0.0, color="k", lw=0.5)
            ax.set_title(f"{sname}: {axis}", fontsize=8)
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=40)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--points", type=int, default=100)
    p.add_argument("--sigma", type=float, default=2.0, help="pixel noise, px")
    p.add_argument("--outliers", type=float, default=0.2, help="fraction of gross outliers")
    p.add_argument("--beam", type=float, default=7.0, help="elevation half-beam, degrees")
    p.add_argument("--offset", type=float, default=2.0, help="true mean elevation of the 'offset' scenarios, degrees")
    p.add_argument("--kernel", default="cauchy")
    p.add_argument("--centred-only", action="store_true", help="only the centred-beam scenario")
    p.add_argument("--kernel-study", action="store_true",
                   help="compare robust schedules (anisotropic model, centred beam) instead of elevation models")
    p.add_argument("--out", type=Path, default=Path("outputs/bench/elevation_models"))
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.kernel_study:
        name = f"robust schedules, anisotropic model, {args.outliers:.0%} outliers"
        results = {name: run_scenario(name, 0.0, 0.0, args, kernel_study=True)}
    else:
        scenarios = {
            f"centred beam +-{args.beam:g} deg": (0.0, 0.0),
            f"mean elevation +{args.offset:g} deg, model assumes 0": (args.offset, 0.0),
            f"mean elevation +{args.offset:g} deg, known to the model": (args.offset, args.offset),
        }
        if args.centred_only:
            scenarios = dict(list(scenarios.items())[:1])
        results = {name: run_scenario(name, tm, mm, args) for name, (tm, mm) in scenarios.items()}
    text = "\n\n".join(format_scenario(n, r) for n, r in results.items())
    print(text)
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    config["factor_defaults"] = dataclasses.asdict(RadarPixelFactorConfig())
    config["schedule"] = dataclasses.asdict(SCHEDULE)
    save_json_atomic(args.out / "results.json", {"config": config, "scenarios": results})
    (args.out / "table.md").write_text(text + "\n")
    plot(results, args.out / "errors.png")
    print(f"\nwrote {args.out / 'results.json'}, {args.out / 'errors.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
