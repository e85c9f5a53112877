"""The error CDFs of a network evaluation (``learned.evaluate.EvalResult``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hybrid_calib.plots.figure import pyplot, save_figure

if TYPE_CHECKING:  # the figure reads only .per_frame and .n_frames; no torch import needed to draw it
    from learned.evaluate import EvalResult


def plot_error_cdf(result: EvalResult, path: str | Path) -> Path:
    """Rotation (geodesic, deg) and translation (norm, cm) error CDFs of every row of ``result``
    (the initial error, each iteration, the final estimate dashed) -> PNG."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name, errs in result.per_frame.items():
        for ax, key in zip(axes, ("geodesic_deg", "trans_norm_cm")):
            v = np.sort([e[key] for e in errs])
            style = dict(color="k", ls="--", lw=1.2) if " iter " not in name and name != "initial" else {}
            ax.plot(v, np.arange(1, len(v) + 1) / len(v), label=name, **style)
    axes[0].set_xlabel("rotation error, geodesic (deg)")
    axes[1].set_xlabel("translation error, norm (cm)")
    for ax in axes:
        ax.set_ylabel("fraction of frames")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8)
    fig.suptitle(f"extrinsic error CDF ({result.n_frames} frames)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=100)
