"""``hybrid-calib calibrate``: sliding-window (or batch) calibration of every vehicle of a dataset."""

from __future__ import annotations

import argparse
from functools import partial
from pathlib import Path

from hybrid_calib.commands import nonnegative_int, positive_int
from hybrid_calib.config import parse_overrides
from hybrid_calib.perturbation import RANGES

HELP = "calibrate T_cam_radar per vehicle from oracle or exported correspondences (window or batch)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, required=True, help="nuScenes root (e.g. written by hybrid-calib simulate)")
    p.add_argument("--version", default="v1.0-sim", help="version folder under --data (default: v1.0-sim)")
    p.add_argument("--correspondences", default="oracle",
                   help="'oracle' (simulated roots: from the ground truth) or a directory of measurement files "
                        "(factors.io *.npz: the --out of hybrid-calib evaluate, flat, or one sub-directory per "
                        "vehicle)")
    p.add_argument("--mode", default="window", choices=("window", "batch"), help="default: window")
    p.add_argument("--window", type=positive_int, default=20, help="sliding-window length in frames (default: 20)")
    p.add_argument("--backend", default="gtsam", choices=("gtsam", "ceres"), help="batch back end (default: gtsam)")
    p.add_argument("--start", default="reference", choices=("reference", *RANGES),
                   help="initial extrinsic: the vehicle's tables, or a perturbed truth (default: reference)")
    p.add_argument("--max-frames", type=nonnegative_int, default=0, help="frames per vehicle, 0 = all (default: 0)")
    p.add_argument("--seed", type=int, default=0, help="oracle noise and start seed (default: 0)")
    p.add_argument("--out", type=Path, default=Path("outputs/calibrate"),
                   help="run directory (default: outputs/calibrate)")
    p.add_argument("--overwrite", action="store_true", help="recompute even if RUN/result.json exists")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--set", action="extend", nargs="+", metavar="KEY=VALUE", default=[],
                   help="CalibrateConfig overrides, e.g. window.factor.kernel=tukey oracle.outlier_frac=0.3")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.calib.drift import drift_verdict
    from hybrid_calib.calib.pipeline import CalibrateConfig, calibrate
    from hybrid_calib.calib.result import STD_FRAME
    from hybrid_calib.config import merge
    from hybrid_calib.metrics import std_dict
    from hybrid_calib.plots.calibration import plot_vehicle

    overrides = parse_overrides(args.set)
    overrides.update(mode=args.mode, start=args.start, seed=args.seed, max_frames=args.max_frames)
    overrides.setdefault("window", {})["window"] = args.window
    overrides.setdefault("batch", {})["backend"] = args.backend
    conf = merge(CalibrateConfig, overrides)  # ConfigError (unknown key, wrong type, bad value) names the option
    if (args.out / "result.json").is_file() and not args.overwrite:
        print(f"{args.out / 'result.json'} exists; pass --overwrite to recompute")
    result = calibrate(args.data, args.version, args.correspondences, args.out, conf, overwrite=args.overwrite,
                       on_vehicle=None if args.no_plots else partial(plot_vehicle, out_dir=args.out / "plots"))
    for name, v in result.vehicles.items():
        s = std_dict(v.final.std, STD_FRAME)
        line = (f"{name}: {v.final.status}; std (camera axes) rot {s['rot_x_cam_deg']:.3f}/{s['rot_y_cam_deg']:.3f}/"
                f"{s['rot_z_cam_deg']:.3f} deg, t {s['t_x_cam_cm']:.2f}/{s['t_y_cam_cm']:.2f}/{s['t_z_cam_cm']:.2f} cm")
        if v.error:
            line += f"; error {v.error['rot_mean_deg']:.3f} deg, {v.error['trans_norm_cm']:.2f} cm"
        if v.drift:
            line += f"; vs reference (tables): {drift_verdict(v.drift)} (chi2 p {v.drift['p_value']:.2g})"
        if v.skipped:
            line += f"; {len(v.skipped)} frame(s) skipped (bad files; listed in result.json)"
        print(line)
    print(f"wrote {args.out / 'result.json'}")
    return 0
