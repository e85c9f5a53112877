"""Fine-tune a shipped network on the training part of a real scene (time split), then fit its
exported covariance on the validation part: the recipe of issue 11's "use the real data you have".

    PYTHONPATH=. python benchmarks/real_finetune.py --data ROOT --version V --range R1|R2 --out OUT \
        [--init CKPT] [--epochs 40] [--fit-seeds 10] [--split-by time] [--test-fraction 0.2] \
        [--val-fraction 0.1] [--gap-frames 3] [--set KEY=VALUE ...]

1. ``hybrid-calib train --preset small --range R --init CKPT --depth lidar-densified --set
   split.by=time lr=1e-4 lr_halve_every=15 samples_per_epoch=0 val_samples=0 threads=1`` on ROOT
   (``learned.train.train``): perturbations drawn in the range around the tables' extrinsic, a new
   one per epoch and frame, on the TRAIN part of the time split only (docs/conventions.md, "Splits";
   scene-0916 with the defaults: keyframes 0-22). ``--init`` defaults to the shipped checkpoint of
   the range. Run folder ``OUT/run`` (resumable, as ``train``).
2. The exported covariance of the last checkpoint: per-axis ``cov_scale``
   (``learned.export.calibrate_cov_scale``) fitted on the VAL part (keyframes 26-29 with the
   defaults) from ``--fit-seeds`` starts per frame, floored at 1 (four frames cannot justify
   claiming more than the network does), written into the checkpoint with a note. The
   hybrid's measurement block (``export.hybrid``) is carried over from the init checkpoint with a
   note saying so: it was fitted on simulated validation drives for the init network and is not refit
   here (too few real frames).
3. Prints the checkpoint path. The TEST part stays untouched: measure it with
   ``benchmarks/real_scene.py --split test --split-by time`` (the same split flags).

The checkpoint lands in OUT (never in ``learned/checkpoints``: shipping is a separate decision).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

RECIPE = {"lr": 1e-4, "lr_halve_every": 15, "samples_per_epoch": 0, "val_samples": 0, "threads": 1}


def fit_cov_scale(ckpt: Path, data: Path, version: str, rng: str, split_options: dict, seeds: int, out: Path):
    """Per-axis cov_scale on the val part, ``seeds`` starts per frame; returns (scale, n, NEES before/after)."""
    from learned.checkpoint import load_model
    from learned.dataset import open_frames
    from learned.evaluate import evaluate, tangent_errors
    from learned.export import calibrate_cov_scale

    model, meta = load_model(ckpt)
    frames = open_frames(data, version, lidar=True)
    xi, covs = [], []
    for k in range(seeds):
        conf = {"method": "pure", "perturbation": rng, "split": "val", "split_options": split_options,
                "seed": 2000 + k, "depth": "lidar-densified", "threads": 1, "export": {"cov_scale": 1.0},
                "depth_cache": str(out / "run" / "depth-cache")}
        d = out / "fit" / f"seed-{2000 + k}"
        evaluate(model, frames, conf, d, checkpoint=ckpt, progress=False)
        e, c = tangent_errors(d)
        xi.append(e)
        covs.append(c)
    xi, covs = np.concatenate(xi), np.concatenate(covs)
    # a few frames only: the fit may inflate an axis, never shrink one below the network's own covariance
    scale = [max(1.0, v) for v in calibrate_cov_scale(xi, covs, per_axis=True)]

    from hybrid_calib.metrics import nees

    s = np.sqrt(np.asarray(scale))
    return scale, len(xi), float(np.mean(nees(xi, covs))), float(np.mean(nees(xi, s[:, None] * covs * s[None, :])))


def main(argv=None) -> int:
    from hybrid_calib.commands import add_split_arguments, split_overrides
    from hybrid_calib.config import parse_overrides

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--version", default="v1.0-mini")
    p.add_argument("--range", required=True, choices=("R1", "R2"))
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--init", type=Path, default=None, help="checkpoint to start from (default: the shipped one)")
    p.add_argument("--epochs", type=int, default=40)
    p.add_argument("--fit-seeds", type=int, default=10, help="starts per val frame for the covariance fit")
    p.add_argument("--set", dest="overrides", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
                   help="further TrainConfig overrides (e.g. device=cuda batch_size=16)")
    add_split_arguments(p, None)  # the split options; training always uses the train part
    a = p.parse_args(argv)

    from hybrid_calib.hybrid.network import shipped_checkpoint
    from hybrid_calib.plots.training import plot_history
    from learned.checkpoint import load_checkpoint, set_export_overrides
    from learned.dataset import open_roots
    from learned.train import train, train_config

    init = a.init or shipped_checkpoint(a.range)
    split_options = {"by": "time", **split_overrides(a)}
    overrides = {**RECIPE, "perturbation": a.range, "epochs": a.epochs, "depth": "lidar-densified",
                 "init_weights": str(init), "split": split_options, **parse_overrides(a.overrides)}
    conf = train_config("small", overrides)
    frames = open_roots([a.data], a.version)
    last = Path(train(conf, frames, a.out / "run", progress=False))
    plot_history(a.out / "run" / "epochs.csv", a.out / "run" / "history.png")

    scale, n, before, after = fit_cov_scale(last, a.data, a.version, a.range, split_options, a.fit_seeds, a.out)
    command = "PYTHONPATH=. python benchmarks/real_finetune.py " + " ".join(sys.argv[1:] if argv is None else argv)
    set_export_overrides(last, {"cov_scale": scale},
                         f"per-axis fit (floored at 1) on {n} starts ({a.fit_seeds} per frame) of the val part of "
                         f"{a.data} (split {split_options}), range {a.range}, by {command}")
    hybrid = load_checkpoint(init).export.get("hybrid")
    if hybrid:
        set_export_overrides(last, {"hybrid": hybrid},
                             f"carried over from {init} (fitted on simulated validation drives for that network; "
                             "not refit for this fine-tuned one)")
    print(f"cov_scale {', '.join(f'{v:.3g}' for v in scale)} fitted on {n} val starts: mean NEES {before:.1f} "
          f"raw -> {after:.1f}")
    print(f"checkpoint: {last}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
