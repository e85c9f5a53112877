"""The comparison plot: error against frames fused, per method and axis, with the reported 2-sigma."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.calib.result import VehicleResult
from hybrid_calib.plots.calibration import LABELS, STD_COLUMN, trajectory_errors
from hybrid_calib.plots.figure import pyplot, save_figure


def _series(results: list[VehicleResult]) -> tuple[np.ndarray, np.ndarray]:
    """(T, F, 6) |signed error| and (T, F, 6) reported std (camera axes, deg / cm) after each number of frames fused;
    a trial that fused fewer frames than the longest (a frame left out) keeps its last estimate to the end, so the
    last point is the median of every trial's end, as compare.md's table (probe 67: it was the longer trials' alone,
    one trial's at worst); NaN for a trial without truth."""
    F = max((len(r.trajectory) for r in results), default=0)
    err = np.full((len(results), F, 6), np.nan)
    std = np.full((len(results), F, 6), np.nan)
    for t, r in enumerate(results):
        if r.truth_T is None or not r.trajectory:
            continue
        n = len(r.trajectory)
        err[t, :n] = np.abs(trajectory_errors(r))  # each frame against the mount of that frame (a knock moved it)
        std[t, :n] = [np.asarray(f.estimate.std)[list(STD_COLUMN)] for f in r.trajectory]
        err[t, n:], std[t, n:] = err[t, n - 1], std[t, n - 1]
    return err, std


def plot_error_vs_frames(results: dict[str, list[VehicleResult]], path: Path) -> Path:
    """Per axis: the median over trials of |error| (solid) and of the reported 2-sigma (dashed)
    against frames fused, one colour per method."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 3, figsize=(14, 7), sharex=True)
    for c, (method, rs) in enumerate(results.items()):
        if not rs:
            continue
        err, std = _series(rs)
        k = np.arange(1, err.shape[1] + 1)
        for j, ax in enumerate(axes.ravel()):
            with np.errstate(all="ignore"):
                ax.plot(k, np.nanmedian(err[:, :, j], axis=0), color=f"C{c}", lw=1.2, label=f"{method} |error|")
                ax.plot(k, 2 * np.nanmedian(std[:, :, j], axis=0), color=f"C{c}", lw=1, ls="--",
                        label=f"{method} 2-sigma")
            ax.set_title(LABELS[j])
            ax.set_yscale("log")
    for ax in axes[1]:
        ax.set_xlabel("frames fused")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("error against frames fused (median over trials; a trial that fused fewer frames keeps its last "
                 "estimate) and the reported 2-sigma (median)")
    fig.tight_layout()
    return save_figure(fig, Path(path), dpi=90)
