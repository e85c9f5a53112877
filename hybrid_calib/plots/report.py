"""Figures of the uncertainty report (``hybrid_calib.report``): before / after projections with the
correspondences, estimate with its 3-sigma band per axis, residual histograms, the fleet plot.

Each function writes one PNG atomically (``figure.save_figure``) and returns its path.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hybrid_calib.calib.result import VehicleResult, extrinsic_report, truth_at
from hybrid_calib.plots.figure import pyplot, save_figure

# (label, unit, std column in camera axes [rot x, y, z deg, t x, y, z cm])
AXES = (("rotation about camera x (pitch)", "deg", 0), ("rotation about camera y (yaw)", "deg", 1),
        ("rotation about camera z (roll)", "deg", 2), ("translation along camera x", "cm", 3),
        ("translation along camera y", "cm", 4), ("translation along camera z", "cm", 5))


def report_values(T_cam_radar: np.ndarray) -> np.ndarray:
    """(6,) [pitch, yaw, roll deg (rotation about camera x, y, z), t x, y, z cm] of an extrinsic,
    i.e. ``calib.result.extrinsic_report`` in the column order of the camera-axis std."""
    r = extrinsic_report(T_cam_radar)
    return np.array([r["pitch_deg"], r["yaw_deg"], r["roll_deg"], *(100 * np.asarray(r["t_m"]))])


def plot_estimate_bands(vr: VehicleResult, path: str | Path) -> Path:
    """Per axis (2 x 3 panels): the window's estimate after every frame with its +-3 sigma band
    (reported std, camera axes), the truth when the result has one, and the frames with a step alarm
    (orange lines). Needs a trajectory (window mode)."""
    plt = pyplot()
    traj = vr.trajectory
    k = np.array([f.index for f in traj])
    est = np.array([report_values(f.T) for f in traj])
    std = np.array([f.estimate.std for f in traj])
    # the mount of each frame (a knock moves it: drawn as a step, not the end's mount throughout; probe 54)
    truth = None if vr.truth_T is None else np.array([report_values(truth_at(vr, f.index)) for f in traj])
    fig, axes = plt.subplots(2, 3, figsize=(11, 5), sharex=True)
    for ax, (label, unit, j) in zip(axes.ravel(), AXES):
        # a drive of a few frames (one kept: a vehicle that stood still) draws its points and bands as markers and
        # error bars: a line and a fill of one point are empty (probe 88)
        few = len(k) < 3
        ax.fill_between(k, est[:, j] - 3 * std[:, j], est[:, j] + 3 * std[:, j], color="tab:blue", alpha=0.2,
                        label="+-3 sigma")
        if few:
            ax.errorbar(k, est[:, j], yerr=3 * std[:, j], color="tab:blue", alpha=0.5, fmt="none", capsize=4)
        ax.plot(k, est[:, j], color="tab:blue", lw=1.2, label="estimate", marker="o" if few else None, ms=4)
        if truth is not None:
            ax.step(k, truth[:, j], where="post", color="k", ls="--", lw=0.8,  # a real root's: its tables (probe 67)
                    label="the tables" if vr.errors_against == "tables" else "truth")
        for f in traj:
            if f.step_alarm:
                ax.axvline(f.index, color="orange", lw=1.5, alpha=0.8)
        # the band of the first frames (start-up) may be metres wide: zoom on the settled half
        tail = slice(len(k) // 2, None)
        lo = np.min(est[tail, j] - 3 * std[tail, j])
        hi = np.max(est[tail, j] + 3 * std[tail, j])
        if truth is not None:
            lo, hi = min(lo, truth[:, j].min()), max(hi, truth[:, j].max())
        pad = 0.15 * max(hi - lo, 1e-3)
        ax.set_ylim(lo - pad, hi + pad)
        ax.set_title(f"{label} [{unit}]", fontsize=9)
        ax.tick_params(labelsize=7)
    for ax in axes[1]:
        ax.set_xlabel("frame", fontsize=8)
    # one legend below the panels: inside the first one it sat on its band (probe 88)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=len(labels), frameon=False)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return save_figure(fig, path, dpi=80)


def plot_residual_histograms(residual_px: np.ndarray, inlier: np.ndarray, gate_px: float | None,
                             path: str | Path, title: str = "") -> Path:
    """Histogram of per-row residuals in pixels, inliers and rejected rows stacked.

    residual_px: (N,) pixels. inlier: (N,) bool. gate_px: the inlier gate in pixels (a vertical line)
    or None."""
    plt = pyplot()
    r = np.asarray(residual_px, np.float64)
    inl = np.asarray(inlier, bool)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.2))
    hi = max(float(np.percentile(r[inl], 99.5)) if inl.any() else 1.0, gate_px or 0.0) * 1.3
    a1.hist(r[inl & (r <= hi)], bins=40, range=(0, hi), color="tab:green", alpha=0.8,
            label=f"inliers ({int(inl.sum())})")
    a1.hist(r[~inl & (r <= hi)], bins=40, range=(0, hi), color="tab:red", alpha=0.6,
            label=f"rejected ({int((~inl).sum())}, {int((~inl & (r > hi)).sum())} beyond the axis)")
    a2.hist(np.log10(np.maximum(r, 1e-3)), bins=50, color="gray")
    a2.hist(np.log10(np.maximum(r[~inl], 1e-3)), bins=50, range=a2.get_xlim(), color="tab:red", alpha=0.6,
            label="rejected")
    for a, g in ((a1, gate_px), (a2, None if gate_px is None else np.log10(gate_px))):
        if g is not None:
            a.axvline(g, color="k", ls="--", lw=1, label="inlier gate")
    a1.set_xlabel("residual (px)")
    a2.set_xlabel("log10 residual (px), all rows")
    a1.set_ylabel("rows")
    a1.legend(fontsize=7)
    a2.legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)


def draw_before_after(image_rgb: np.ndarray, panels: Sequence[dict], path: str | Path, title: str = "") -> Path:
    """Side-by-side panels of one camera image with radar points projected.

    image_rgb: (H, W, 3) uint8. Each panel: ``{"title": str, "uv": (N, 2) px, "depth": (N,) m}``
    (the frame's radar points, coloured by depth) and optionally ``"pairs": (obs (M, 2) px, pred
    (M, 2) px, inlier (M,) bool)``: the correspondences, the observed pixel (ring) joined to the
    radar point projected with the panel's extrinsic (green inlier, red rejected)."""
    plt = pyplot()
    H, W = image_rgb.shape[:2]
    n = len(panels)
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 5.2 * H / W + 0.45), squeeze=False)
    for ax, p in zip(axes[0], panels):
        ax.imshow(image_rgb)
        uv, z = np.asarray(p["uv"], float).reshape(-1, 2), np.asarray(p["depth"], float).reshape(-1)
        ok = np.isfinite(uv).all(1) & (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H)
        if ok.any():
            ax.scatter(uv[ok, 0], uv[ok, 1], c=z[ok], cmap="turbo", s=9, vmin=0,
                       vmax=max(float(np.percentile(z[ok], 95)), 1.0), edgecolors="k", linewidths=0.2)
        if p.get("pairs") is not None:
            obs, pred, inl = (np.asarray(a) for a in p["pairs"])
            for mask, color in ((inl, "lime"), (~inl, "red")):
                ax.scatter(obs[mask, 0], obs[mask, 1], s=14, facecolors="none", edgecolors=color, linewidths=0.7)
                seg = np.stack([obs[mask], pred[mask]], 1)
                seg = seg[np.isfinite(seg).all((1, 2))]
                if len(seg):
                    from matplotlib.collections import LineCollection

                    ax.add_collection(LineCollection(seg, colors=color, linewidths=0.6))
        ax.set_xlim(-0.5, W - 0.5)
        ax.set_ylim(H - 0.5, -0.5)
        ax.set_axis_off()
        ax.set_title(p["title"] + f" ({int(ok.sum())} points in image)", fontsize=8)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=80)
