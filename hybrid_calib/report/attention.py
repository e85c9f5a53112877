"""The network's cross-attention on one frame of the drive (``plots.network.plot_frame``), when a
checkpoint is named (``ReportConfig.checkpoint``, or ``network["checkpoint"]`` in the result) and the
data root is there. The network runs once, on the middle shown frame, from the dataset's fixed R1
evaluation start (the same start ``hybrid-calib evaluate`` uses), on the CPU: a second or two for
the shipped small checkpoints."""

from __future__ import annotations

import os
from pathlib import Path

from hybrid_calib.calib.result import VehicleResult
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.report.evidence import Evidence, frame_words
from hybrid_calib.report.html import esc, img_tag


def attention_figure(checkpoint: str | Path, data: str | Path, version: str, frame_index: int, path: Path,
                     depth: str = "") -> tuple[Path, str]:
    """Run the network of ``checkpoint`` on dataset frame ``frame_index`` and draw its attention maps
    (``plots.network.plot_frame``) to ``path``; returns (path, the depth spec it read). ``depth``: the run's
    (its result's ``config.depth_effective``), or "" for the rule calibrate applies (``hybrid.drives.effective_depth``:
    lidar-densified on a real root with LiDAR, else the checkpoint's training depth), with the training run's
    depth options as the hybrid reads them (``hybrid.network.network_depth``)."""
    import torch

    from hybrid_calib.hybrid.drives import effective_depth
    from hybrid_calib.hybrid.loop import HybridConfig
    from hybrid_calib.hybrid.network import network_depth
    from hybrid_calib.plots.network import plot_frame
    from learned.checkpoint import load_model
    from learned.dataset import CalibDataset, DatasetConfig, collate, open_frames
    from learned.train import model_inputs

    model, ckpt = load_model(checkpoint)
    depth = depth or effective_depth(data, version, HybridConfig(checkpoint=str(checkpoint)))
    name, estimator = network_depth(ckpt.train_config, ckpt.path, depth)
    frames = open_frames(data, version)
    H, W = (int(v) for v in model.cfg.input_hw)
    dconf = DatasetConfig(height=H, width=W, max_lidar_points=0, seed=1000, variant=model.cfg.variant)
    sample = CalibDataset(frames, dconf, estimator, indices=[frame_index], train=False)[0]
    if sample is None:
        raise HybridCalibError(f"frame {frame_index} of {data} could not be loaded for the network")
    batch = collate([sample])
    with torch.no_grad():
        out = model(model_inputs(batch))
    return plot_frame(out, batch, 0, path), name


def attention_html(vr: VehicleResult, ev: Evidence, data, version: str, checkpoint: str, tmp: Path) -> str:
    """The attention section: the figure, or one line saying why it is absent."""
    # the network methods name theirs in ``vr.checkpoint`` (a cascade: "A -> B", the first stage's attention is
    # drawn); a run on exported correspondences in ``network["checkpoint"]``
    named = str(vr.checkpoint or (vr.network or {}).get("checkpoint") or "").split(" -> ")[0].strip()
    ckpt = checkpoint or named
    head = "<h3>Cross-attention on one frame</h3>"
    if not ckpt:
        return head + ("<p class=note>Absent: the result names no network checkpoint (a run on oracle or plain "
                       "correspondences) and none was given (--checkpoint).</p>")
    if not ev.frames:
        return head + f"<p class=note>Absent: checkpoint {esc(ckpt)} is named but no camera frame is available.</p>"
    frame = ev.frames[len(ev.frames) // 2]
    try:
        own = ckpt == named or _same_file(ckpt, named)  # the run's own network: the depth it read (a learned
        # method's config; the exporting run's, for rows an evaluate export gave calibrate --correspondences)
        ran = str((vr.config or {}).get("depth_effective") or (vr.network or {}).get("depth") or "") if own else ""
        png, depth = attention_figure(ckpt, data, version, frame.index, tmp / "attention.png", ran)
    except (HybridCalibError, OSError) as e:
        return head + f"<p class=note>Absent: the network could not run ({esc(e)}).</p>"
    other = ""  # --checkpoint given, another than the result's: the figure is not of the network that calibrated
    if checkpoint and named and not _same_file(checkpoint, named):
        other = (f" <b>The result was calibrated with {esc(named)}</b>; this figure is of the checkpoint given with "
                 "--checkpoint, which is not that file.")
    where = frame_words(frame)
    read = ("as the run read it" if ran else "as calibrate would choose it" if not own else
            "the result does not say which depth its network read: the one calibrate would choose")
    return (head + f"<p class=meta>Checkpoint {esc(ckpt)} on {where}, from the fixed R1 evaluation start, with "
            f"depth {esc(depth)} ({read})."
            f"{other} "
            "Top: points projected with the start (red) and the network's estimate (green; white: truth, or on a "
            "real root its tables). Middle: "
            "which image regions the radar points attend to and back. Bottom: the bird's-eye views.</p>"
            + img_tag(png, "network cross-attention"))


def _same_file(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one is not there (a path relative to where calibrate ran)
        return False
