"""Figures of one frame of the network (paper Fig. 4 and supplement Figs. 8-9): radar projections and attention maps.

``plot_frame(out, batch, index, path)`` writes a PNG with
- top: the RGB image with the points projected by T_init (red), by the final estimate (green) and, when
  the batch has it, by T_gt (white);
- middle: the FV cross-attention maps I_{I<-R} (image attending radar) and I_{R<-I} (radar attending
  image) of the chosen iteration, upsampled to the image, with the iteration's radar projections;
- bottom: the pseudo-BEV image and the radar BEV map of that iteration.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from hybrid_calib.plots.figure import pyplot, save_figure


def _project(T: torch.Tensor, pts: np.ndarray, K: np.ndarray, hw: tuple) -> np.ndarray:
    T = T.detach().double().cpu().numpy()
    pc = pts @ T[:3, :3].T + T[:3, 3]
    ok = pc[:, 2] > 0.5
    uv = (pc[ok] @ K.T)[:, :2] / pc[ok, 2:3]
    inside = (uv[:, 0] >= -0.5) & (uv[:, 0] < hw[1] - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] < hw[0] - 0.5)
    return uv[inside]


def plot_frame(out: dict, batch: Mapping, index: int, path: str | Path, iteration: int = -1) -> Path:
    """Save the figure of sample ``index`` of a forward pass to ``path`` (PNG, written atomically)."""
    plt = pyplot()
    H, W = out["image_hw"]
    img = batch["image"][index].detach().permute(1, 2, 0).cpu().numpy().clip(0, 1)
    mask = batch["radar_mask"][index].cpu().numpy().astype(bool)
    pts = batch["radar"][index].detach().double().cpu().numpy()[mask]
    K = batch["K"][index].detach().double().cpu().numpy()
    fig, axes = plt.subplots(3, 2, figsize=(10, 7.5))
    ax = axes[0, 0]
    ax.imshow(img)
    uv = _project(batch["T_init"][index], pts, K, (H, W))
    ax.scatter(uv[:, 0], uv[:, 1], s=6, c="red", label="T_init")
    ax.set_title("initial projection")
    ax = axes[0, 1]
    ax.imshow(img)
    uv = _project(out["T_iters"][-1][index], pts, K, (H, W))
    ax.scatter(uv[:, 0], uv[:, 1], s=6, c="lime", label="estimate")
    if "T_gt" in batch:
        uv = _project(batch["T_gt"][index], pts, K, (H, W))
        ax.scatter(uv[:, 0], uv[:, 1], s=3, c="white", edgecolors="k", linewidths=0.3, label="truth")
    # the legend on a grey box: its white "truth" marker was white on white (probe 88)
    ax.legend(loc="upper right", fontsize=6, facecolor="0.6", framealpha=0.8)
    ax.set_title(f"after {len(out['T_iters'])} iterations")
    attn = out["attention"][iteration].get("fv") if out["attention"] else None
    render = out["render"][iteration]
    valid = render["fv_valid"][index].cpu().numpy()
    pix = render["fv_pix"][index].detach().cpu().numpy()[valid]
    for k, key in enumerate(("attn_I_from_R", "attn_R_from_I")):
        ax = axes[1, k]
        if attn is None:
            ax.text(0.5, 0.5, "no MCA in this model", ha="center", va="center")
        else:
            a = attn[key][index, 0].cpu().numpy()
            ax.imshow(a, cmap="jet", extent=(-0.5, W - 0.5, H - 0.5, -0.5), interpolation="bilinear")
            ax.scatter(pix[:, 0], pix[:, 1], s=4, c="white")
        ax.set_title({"attn_I_from_R": "I(I<-R): image attends radar",
                      "attn_R_from_I": "I(R<-I): radar attends image"}[key], fontsize=9)
    for k, (name, m) in enumerate((("pseudo-BEV (camera)", out.get("pseudo_bev")), ("radar BEV", render["bev"]))):
        ax = axes[2, k]
        if m is None:
            ax.text(0.5, 0.5, "no BEV view in this model", ha="center", va="center")
        else:
            ax.imshow(m[index, 0].detach().cpu().numpy(), cmap="viridis")
        ax.set_title(f"{name}: Y + h (m)", fontsize=9)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)


def attention_numpy(out: dict, view: str = "fv", iteration: int = -1) -> dict[str, np.ndarray]:
    """The attention maps of one view and iteration as numpy arrays (B, h, w)."""
    maps = out["attention"][iteration].get(view)
    if maps is None:
        raise ValueError(f"no attention maps for view {view!r} (use_mca off or view absent)")
    return {k: v[:, 0].cpu().numpy() for k, v in maps.items()}
