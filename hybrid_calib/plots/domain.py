"""Simulated against real data: the statistics of ``hybrid_calib.data.domain_stats`` as figures
(``benchmarks/sim_vs_real.py``, docs/sim_vs_real.md).

Every function takes ``groups``: label -> a dict of plain arrays (one value per frame, point or
vehicle), draws each group in its own colour and writes one small PNG.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.plots.figure import pyplot, save_figure

COLOURS = ("black", "tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple")


def _hist(ax, groups: dict, key: str, bins, title: str, xlabel: str) -> None:
    for (label, g), c in zip(groups.items(), COLOURS):
        v = np.asarray(g.get(key, []), float)
        v = v[np.isfinite(v)]
        if len(v):
            ax.hist(v, bins=bins, density=True, histtype="step", lw=1.6 if c == "black" else 1.2, color=c,
                    label=f"{label} (n={len(v)})")
    ax.set_title(title, fontsize=9)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)


def plot_radar(groups: dict, path: str | Path) -> Path:
    """Radar after the devkit filters: points per sweep (``n``), range (``range_m``), azimuth
    (``azimuth_deg``) and RCS (``rcs_dbsm``) histograms, normalised to densities."""
    plt = pyplot()
    fig, ax = plt.subplots(1, 4, figsize=(13, 3.0))
    _hist(ax[0], groups, "n", np.arange(0, 131, 5), "radar points per sweep", "points")
    _hist(ax[1], groups, "range_m", np.arange(0, 251, 10), "range", "m")
    _hist(ax[2], groups, "azimuth_deg", np.arange(-60, 61, 5), "azimuth", "deg")
    _hist(ax[3], groups, "rcs_dbsm", np.arange(-30, 41, 2.5), "RCS", "dBsm")
    ax[0].legend(fontsize=6)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def plot_image(groups: dict, path: str | Path) -> Path:
    """Per-frame image statistics: luminance against contrast, saturation against sharpness."""
    plt = pyplot()
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.3))
    for (label, g), c in reversed(list(zip(groups.items(), COLOURS))):  # the first group on top
        kw = dict(s=14 if c == "black" else 7, color=c, alpha=0.9 if c == "black" else 0.5, label=label)
        ax[0].scatter(g["luminance"], g["contrast"], **kw)
        ax[1].scatter(g["saturation"], g["sharpness"], **kw)
        ax[2].scatter(np.asarray(g["mean_r"]) - np.asarray(g["mean_b"]), np.asarray(g["mean_g"]) - 0.5 * (
            np.asarray(g["mean_r"]) + np.asarray(g["mean_b"])), **kw)
    names = (("mean luminance", "contrast (luminance std)"), ("saturation", "sharpness (Laplacian std)"),
             ("R - B (colour cast)", "G - (R + B) / 2"))
    for a, (x, y) in zip(ax, names):
        a.set_xlabel(x, fontsize=8)
        a.set_ylabel(y, fontsize=8)
        a.tick_params(labelsize=7)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=6)
    fig.suptitle("camera images at 400 x 225, one point per frame", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def plot_depth(groups: dict, path: str | Path) -> Path:
    """The lidar-densified depth map per frame: density, error against held-out LiDAR points
    (``lidar_abs_rel``) and, for simulated frames, against the true depth (``truth_abs_rel``)."""
    plt = pyplot()
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.0))
    _hist(ax[0], groups, "density", np.linspace(0, 1, 26), "depth map density", "share of pixels with depth")
    _hist(ax[1], groups, "lidar_abs_rel", np.linspace(0, 0.3, 31), "vs held-out LiDAR points", "mean abs. rel. error")
    _hist(ax[2], groups, "truth_abs_rel", np.linspace(0, 0.3, 31), "vs true depth (simulator only)",
          "mean abs. rel. error")
    ax[0].legend(fontsize=6)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def plot_mounts(groups: dict, path: str | Path) -> Path:
    """Mounts and intrinsics per vehicle: camera yaw / pitch / roll, radar yaw, camera x, focal
    length and principal point (1600 x 900). ``weight`` (optional) sizes the markers, e.g. scenes
    per real fleet mount."""
    plt = pyplot()
    fig, ax = plt.subplots(1, 4, figsize=(13, 3.2))
    for (label, g), c in reversed(list(zip(groups.items(), COLOURS))):  # the first group on top
        w = np.asarray(g.get("weight", np.ones(len(g["cam_yaw_deg"]))), float)
        s = 8 + 60 * w / max(w.max(), 1e-9) if "weight" in g else 10
        kw = dict(s=s, color=c, alpha=0.8 if c == "black" else 0.5, label=label)
        ax[0].scatter(g["cam_yaw_deg"], g["cam_pitch_deg"], **kw)
        ax[1].scatter(g["cam_roll_deg"], g["radar_yaw_deg"], **kw)
        ax[2].scatter(g["cam_x_m"], g["cam_z_m"], **kw)
        ax[3].scatter(g["cx"], g["cy"], **kw)
    for a, (x, y) in zip(ax, (("camera yaw (deg)", "camera pitch (deg)"), ("camera roll (deg)", "radar yaw (deg)"),
                              ("camera x (m)", "camera z (m)"), ("cx at 1600 px (px)", "cy at 900 px (px)"))):
        a.set_xlabel(x, fontsize=8)
        a.set_ylabel(y, fontsize=8)
        a.tick_params(labelsize=7)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=6)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def plot_examples(images: dict, path: str | Path, width: int = 200) -> Path:
    """One camera image per label (label -> (H, W, 3) uint8 RGB), side by side, ``width`` px each."""
    import cv2

    plt = pyplot()
    n = len(images)
    cols = min(n, 4)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(2.6 * cols, 1.6 * rows), squeeze=False)
    for a in axes.ravel():
        a.axis("off")
    for a, (label, img) in zip(axes.ravel(), images.items()):
        h = int(round(img.shape[0] * width / img.shape[1]))
        a.imshow(cv2.resize(np.asarray(img), (width, h), interpolation=cv2.INTER_AREA))
        a.set_title(label, fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)
