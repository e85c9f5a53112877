"""What ``hybrid-calib evaluate`` runs, decided from a checkpoint and the options asked for: the model (a cascade
with ``--refine``), the effective ``EvalConfig`` overrides (the checkpoint's split, depth and export block, what was
asked over them), the radar sweeps per frame and whether LiDAR is read. The notes are sentences the command prints
on stderr (a range or sweep count the checkpoint was not trained on)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from hybrid_calib.config import deep_update
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.perturbation import RANGES
from learned.checkpoint import Checkpoint


@dataclass(frozen=True)
class EvalSetup:
    model: torch.nn.Module  # eval mode; a ``learned.cascade.Cascade`` with refine stages
    conf: dict  # ``learned.evaluate.EvalConfig`` overrides, complete for ``evaluate``
    stage_paths: tuple[Path, ...]  # the checkpoints, first to last stage
    last: Checkpoint  # the last stage's: its export block, the fit's target
    nsweeps: int  # radar sweeps accumulated per frame
    lidar: bool  # the frames must read LiDAR (the lidar variant, or lidar-densified depth)
    notes: tuple[str, ...]


def setup_evaluation(checkpoint: str | Path, refine: list, *, method: str, perturbation: str, split: str,
                     max_frames: int, depth: str | None, nsweeps: int | None, split_flags: dict, overrides: dict,
                     given: dict, fit_uncertainty: bool, data: list, version: str) -> EvalSetup:
    """The evaluation ``checkpoint`` (and the ``refine`` checkpoints after it) runs with these options.

    ``overrides``: ``--set`` (checked); ``given``: the flags passed, which win over ``--set``; ``split_flags``: the
    split flags passed (``SplitConfig`` keys). Defaults come from the checkpoint's training run: its split and depth
    (``--depth`` drops the checkpoint's depth options), its sweeps per frame; the export block is the last stage's
    (``cov_scale`` 1 when ``fit_uncertainty``: the fit is against the raw covariance, ``uncertainty_fit.check_fit``
    first)."""
    from learned.checkpoint import load_model, trained_data
    from learned.depth import needs_lidar
    from learned.uncertainty_fit import check_fit

    notes = []
    model, ckpt = load_model(checkpoint)
    trained = ckpt.train_config or {}
    if (rng := trained.get("perturbation")) in RANGES and rng != perturbation:
        notes.append(f"note: {ckpt.path.name} was trained on {rng} starts and is evaluated on {perturbation} starts: "
                     f"outside the range it was fitted for, its errors and covariance are not its {rng} figures (the "
                     f"shipped learned/checkpoints/small-sim-{perturbation.lower()}.json fits {perturbation})")
    last, stage_paths = ckpt, [ckpt.path]
    if refine:
        from learned.cascade import Cascade

        stages = [model]
        for path in refine:
            m, last = load_model(path)
            stages.append(m)
            stage_paths.append(last.path)
        try:
            model = Cascade(stages).eval()
        except ValueError as e:
            raise HybridCalibError(f"--refine: {e}") from None
    conf = {"method": method, "perturbation": perturbation, "split": split, "max_frames": max_frames}
    for key, src in (("split_options", "split"), ("depth", "depth"), ("depth_options", "depth_options")):
        if src in trained:
            conf[key] = trained[src]
    if split_flags:
        conf["split_options"] = {**conf.get("split_options", {}), **split_flags}
    if depth is not None:
        conf["depth"] = depth
        if depth != trained.get("depth"):
            conf["depth_options"] = {}  # the checkpoint's options belong to its own estimator
    conf["export"] = dict(last.export)
    if fit_uncertainty:
        check_fit(last.path, data, split, version, bool(refine), perturbation)
        conf["export"]["cov_scale"] = 1.0  # fit against the raw covariance
    deep_update(conf, overrides)  # --set export.KEY=... changes that value and keeps the checkpoint's others
    deep_update(conf, {**given, **({"split_options": split_flags} if split_flags else {})})  # a flag wins over --set
    # the LiDAR-camera variant calibrates T_cam_lidar from LiDAR points; lidar-densified depth reads them too
    lidar = model.cfg.variant == "lidar" or needs_lidar(str(conf.get("depth", "")))
    sweeps_trained = trained_data(last.path).get("nsweeps")
    if nsweeps is None:
        nsweeps = int(sweeps_trained) if isinstance(sweeps_trained, int) and sweeps_trained >= 1 else 1
        if nsweeps != 1:
            notes.append(f"note: {nsweeps} radar sweeps per frame, as the checkpoint's training run read (--nsweeps "
                         "to change)")
    elif isinstance(sweeps_trained, int) and sweeps_trained != nsweeps:
        notes.append(f"note: --nsweeps {nsweeps}, but the checkpoint was trained on {sweeps_trained} sweeps per "
                     "frame: its inputs differ from what it learned")
    return EvalSetup(model, conf, tuple(stage_paths), last, nsweeps, lidar, tuple(notes))
