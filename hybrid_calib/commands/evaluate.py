"""``hybrid-calib evaluate``: the paper's error table for a checkpoint on a held-out split.

Export-then-evaluate (``learned.evaluate``): per-frame predictions go to ``OUT/frames/*.npz`` (rerun
skips frames already there), then the table (rotation Mean/Roll/Pitch/Yaw in degrees, translation
Mean/X/Y/Z in cm, geodesic angle and translation norm; the initial error, every iteration and the
final estimate) is printed and written to ``OUT/results.json`` (schema in
``learned.evaluate.write_report``), ``OUT/results.md`` and ``OUT/errors_cdf.png``. The split and the
depth estimator default to the checkpoint's training config, so ``--split test`` holds out the same
scenes training did.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hybrid_calib.config import parse_overrides

HELP = "evaluate a trained network on held-out frames (paper table: rotation deg, translation cm)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, type=Path, help="nuScenes root (holds VERSION/ and samples/)")
    parser.add_argument("--version", default="v1.0-sim", help="version folder (default v1.0-sim)")
    parser.add_argument("--range", dest="perturbation", default="R1", choices=("R1", "R2"),
                        help="perturbation range of the starts (fixed per frame)")
    parser.add_argument("--method", default="pure", help="pure = the network alone")
    parser.add_argument("--checkpoint", required=True, type=Path,
                        help="ckpt-NNNN.json / .safetensors, or a run folder (its last checkpoint)")
    parser.add_argument("--out", required=True, type=Path, help="output folder (predictions, results.json/.md)")
    parser.add_argument("--split", default="test",
                        help="test (default; scenes held out in training), val, train, or all (a separate root)")
    parser.add_argument("--max-frames", type=int, default=0, help="evaluate at most this many frames (0 = all)")
    parser.add_argument("--depth", default=None,
                        help="depth estimator (default: the checkpoint's; real data: depth-anything:/local/model/dir)")
    parser.add_argument("--nsweeps", type=int, default=1, help="radar sweeps accumulated per frame")
    parser.add_argument("--set", dest="overrides", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
                        help="EvalConfig override, e.g. --set batch_size=8 --set device=cuda (repeatable)")
    parser.add_argument("--overwrite", action="store_true", help="recompute predictions already in --out")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(args: argparse.Namespace) -> int:
    from learned.checkpoint import load_model
    from learned.dataset import open_frames
    from learned.evaluate import evaluate

    model, ckpt = load_model(args.checkpoint)
    trained = ckpt.train_config or {}
    conf = {"method": args.method, "perturbation": args.perturbation, "split": args.split,
            "max_frames": args.max_frames}
    for key, src in (("split_options", "split"), ("depth", "depth"), ("depth_options", "depth_options")):
        if src in trained:
            conf[key] = trained[src]
    if args.depth is not None:
        conf["depth"] = args.depth
        if args.depth != trained.get("depth"):
            conf["depth_options"] = {}  # the checkpoint's options belong to its own estimator
    conf.update(parse_overrides(args.overrides))
    lidar = model.cfg.variant == "lidar"  # the LiDAR-camera variant calibrates T_cam_lidar from LiDAR points
    frames = open_frames(args.data, args.version, lidar=lidar, options={"nsweeps": args.nsweeps})
    result = evaluate(model, frames, conf, args.out, checkpoint=ckpt.path, overwrite=args.overwrite,
                      progress=not args.no_progress)
    print(result.table())
    print(f"wrote {Path(args.out) / 'results.json'} and results.md")
    return 0
