"""``hybrid-calib train``: train RC-AutoCalib on a nuScenes-format root (default: the simulator's).

Writes the run folder described in ``learned.train`` (checkpoints with their configs, steps.csv,
epochs.csv, train_config.json) and draws ``history.png`` (``hybrid_calib.plots.training``). Running
the same command again resumes after the last checkpoint; raising ``--epochs`` continues a finished
run.

Splits (docs/conventions.md, "Splits"): whole scenes by default; ``--set split.by=time`` trains on the
first keyframes of each scene and keeps a val and a test part at its end behind a guard gap (one real
scene: ``benchmarks/real_finetune.py`` is the fine-tuning recipe), and ``evaluate --split test`` then
holds out the same frames.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hybrid_calib.commands import positive_int, version_name
from hybrid_calib.config import parse_overrides
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.errors import OptionError
from hybrid_calib.perturbation import RANGES

HELP = "train the RC-AutoCalib network (resumable; presets small / paper)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, type=Path, nargs="+",
                        help="nuScenes root(s) (each holds VERSION/ and samples/); several are trained on together")
    parser.add_argument("--version", type=version_name,
                        default=SIM_VERSION, help=f"version folder (default {SIM_VERSION})")
    parser.add_argument("--preset", default="small", choices=("small", "paper"),
                        help="small: 2 CPU cores, well under two hours; paper: 400x192, 50 epochs, Adam 1e-4 "
                             "(its image context net starts from ImageNet weights only with --set "
                             "context_weights=FILE, a local ResNet-18 state dict: README)")
    parser.add_argument("--out", required=True, type=Path, help="run folder (checkpoints, logs, configs)")
    parser.add_argument("--range", dest="perturbation", default=None, choices=tuple(RANGES),
                        help="perturbation range of the training starts (default R1)")
    parser.add_argument("--epochs", type=positive_int, default=None, help="number of epochs (overrides the preset)")
    parser.add_argument("--depth", default=None,
                        help="depth estimator: corrupted-truth (default on simulated roots), lidar-densified (the "
                             "default on a real root) or "
                             "depth-anything:/local/model/dir")
    parser.add_argument("--init", default=None, metavar="CKPT",
                        help="start a new run from this checkpoint's weights (fine-tuning; same model config)")
    parser.add_argument("--nsweeps", type=positive_int, default=1, help="radar sweeps accumulated per frame")
    parser.add_argument("--set", dest="overrides", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
                        help="TrainConfig override, e.g. --set batch_size=4 --set model.feat_dim=32 (repeatable)")
    parser.add_argument("--no-resume", action="store_true", help="fail instead of resuming an existing run")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def _real_root_depth(roots, version: str) -> str:
    """The depth a run without --depth trains with when a root is real (no simulator truth): lidar-densified, as
    calibrate picks (said); "" when every root is simulated (the preset's corrupted-truth). The default failed on
    every frame of a real root, after loading them all. ``OptionError`` for a real root without LiDAR."""
    import sys

    from hybrid_calib.data.nuscenes import simulated_root
    from hybrid_calib.data.tables import sensor_channels

    real = [r for r in roots if not simulated_root(r, version)]
    if not real:
        return ""
    blind = [str(r) for r in real if "LIDAR_TOP" not in sensor_channels(r, version)]
    if blind:
        raise OptionError("--depth", f"{', '.join(blind)} is a real root without LIDAR_TOP, and the default depth "
                                     "(corrupted-truth) needs the simulator's: pass --depth "
                                     "depth-anything:/local/model/dir")
    print(f"note: {', '.join(map(str, real))} is a real root: training on lidar-densified depth (the LiDAR through the "
          "tables), as calibrate uses there; pass --depth to choose", file=sys.stderr)
    return "lidar-densified"


def run(args: argparse.Namespace) -> int:
    import sys

    from hybrid_calib.data.files import data_stamp
    from hybrid_calib.data.nuscenes import simulated_root
    from hybrid_calib.plots.training import plot_history
    from learned.checkpoint import latest_checkpoint
    from learned.dataset import open_roots
    from learned.train import train, train_config

    overrides = parse_overrides(args.overrides)
    for key in ("perturbation", "epochs", "depth"):
        if getattr(args, key) is not None:
            overrides[key] = getattr(args, key)
    if args.init is not None:
        overrides["init_weights"] = args.init
    given_depth = "depth" in overrides
    if "depth" not in overrides and (depth := _real_root_depth(args.data, args.version)):
        overrides["depth"] = depth
    if args.init is not None and not given_depth:  # fine-tuning goes on with the input the weights learned (probe 56:
        from hybrid_calib.hybrid.drives import trained_depth  # a shipped lidar-densified network fine-tuned on
        from learned.depth import CorruptedTruthDepth  # corrupted-truth depth, silently)

        learned_on, default = trained_depth(args.init), overrides.get("depth", CorruptedTruthDepth.name)
        if learned_on != default and "depth" in overrides and learned_on == CorruptedTruthDepth.name:
            print(f"note: --init {args.init} was trained on {learned_on} depth, which a real root cannot give: the "
                  f"run trains on {default} (--depth to choose)", file=sys.stderr)
        elif learned_on != default:
            overrides["depth"] = learned_on
            print(f"note: --init {args.init} was trained on {learned_on} depth: the run goes on with it, not "
                  f"{default} (--depth to choose)", file=sys.stderr)
    conf = train_config(args.preset, overrides)
    resolved = [Path(d).resolve() for d in args.data]
    if twice := sorted({str(d) for d in resolved if resolved.count(d) > 1}):
        raise OptionError("--data", f"{', '.join(twice)} is given twice (every frame would count twice); pass each "
                                    "root once")
    frames = open_roots(args.data, args.version, options={"nsweeps": args.nsweeps})
    if real := [str(d) for d in args.data if not simulated_root(d, args.version)]:
        print(f"note: {', '.join(real)} holds no simulator truth ({args.version}): its calibrated_sensor tables "
              "are the training truth (themselves a few tenths of a degree off); label figures on its frames as "
              "training figures and keep some frames out (docs/benchmarks.md: benchmarks/real_finetune.py)")
    # the data stamps: the frames themselves, so that other frames at the same path (re-simulated, re-downloaded) are
    # not resumed as these, and a copy of these at another path is known as trained on (probe 55)
    source = {"roots": [str(Path(d).resolve()) for d in args.data], "version": args.version, "nsweeps": args.nsweeps,
              "stamps": [data_stamp(d, args.version)["digest"] for d in args.data]}
    if not args.no_resume and (found := latest_checkpoint(args.out / "checkpoints")) is not None:
        # said as a condition: a run of other options or data is refused next (probe 45: "resumes" then the refusal)
        print(f"note: {args.out} holds {found.name}: the run resumes after it if its options and data are the ones "
              "it was trained with (checked next: otherwise refused), its earlier epochs kept", file=sys.stderr)
    last = train(conf, frames, args.out, resume=not args.no_resume, progress=not args.no_progress, source=source)
    plot_history(args.out / "epochs.csv", args.out / "history.png")
    print(f"last checkpoint: {last}")
    return 0
