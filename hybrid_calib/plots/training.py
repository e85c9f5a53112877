"""The training history of a network run: losses and validation errors per epoch."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from hybrid_calib.plots.figure import pyplot, save_figure


def plot_history(csv_path: str | Path, png_path: str | Path) -> Path | None:
    """Losses (train / val) and validation errors per epoch from a run's ``epochs.csv``
    (``learned.train``) -> PNG. Returns None (and writes nothing) when the CSV has no epoch yet."""
    plt = pyplot()
    with Path(csv_path).open(newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return None

    def col(name):
        return [float(r[name]) if r.get(name) not in (None, "") else np.nan for r in rows]

    epochs = col("epoch")
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    for k in ("total", "calib", "matching"):
        axes[0].plot(epochs, col(f"train_{k}"), "-o", ms=3, label=f"train {k}")
        axes[0].plot(epochs, col(f"val_{k}"), "--", label=f"val {k}")
    axes[0].set_yscale("log")
    axes[0].set_title("losses")
    axes[1].plot(epochs, col("val_rot_mean_deg"), "-o", ms=3, label="rotation mean")
    axes[1].plot(epochs, col("val_rot_geodesic_deg"), "-o", ms=3, label="geodesic")
    axes[1].set_title("validation rotation error (deg)")
    axes[2].plot(epochs, col("val_trans_mean_cm"), "-o", ms=3, label="translation mean")
    axes[2].plot(epochs, col("val_trans_norm_cm"), "-o", ms=3, label="norm")
    axes[2].set_title("validation translation error (cm)")
    for ax in axes:
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, png_path, dpi=90)
