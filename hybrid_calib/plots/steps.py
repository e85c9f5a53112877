"""Step-detector benchmark figure: detection delay curves against step size, false-alarm rate."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.plots.figure import pyplot, save_figure

PANELS = {"rot": "rotation steps (random axis)", "trans": "translation steps (random direction)"}


def plot_step_benchmark(summary: dict, path: str | Path, within: int = 20, horizon: int | None = None,
                        titles: dict | None = None, detector: str = "step detector") -> Path:
    """Fraction of drives whose step was found within k frames, against k, one curve per step size
    (one panel per step kind: rotation, translation); the false-alarm rate in the title. ``summary``:
    the dict of ``benchmarks/bench_steps.py`` (``steps`` -> {kind, size, unit, delays (list, None =
    missed)}); horizon: frames observed after the step (the curves end there; default ``2 within``);
    titles: step kind -> panel title (default ``PANELS``: both kinds); detector: named in the title."""
    plt = pyplot()
    panels = titles or PANELS
    fig, axes = plt.subplots(1, len(panels), figsize=(max(8.0, 5.5 * len(panels)), 4.2), sharey=True, squeeze=False)
    for ax, (kind, title) in zip(axes[0], panels.items()):
        for s in summary.get("steps", {}).values():
            if s["kind"] != kind:
                continue
            d = np.array([np.inf if x is None else x for x in s["delays"]], float)
            k = np.arange(0, (2 * within if horizon is None else horizon) + 1)
            ax.step(k, [np.mean(d <= x) for x in k], where="post", label=f"{s['size']:g} {s['unit']} ({len(d)} drives)")
        ax.axvline(within, color="grey", ls=":", lw=1)
        ax.axhline(0.95, color="grey", ls=":", lw=1)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("frames after the step")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="lower right")
    axes[0][0].set_ylabel("fraction of drives with an alarm")
    axes[0][0].set_ylim(0, 1.02)
    fa = summary.get("false_alarm", {})
    fig.suptitle(f"{detector}: {fa.get('alarms', 0)} false alarm(s) in {fa.get('frames_tested', 0)} frames with no "
                 f"change\n({fa.get('per_1000_frames', float('nan')):.2f} per 1000, 95 % upper bound "
                 f"{fa.get('per_1000_frames_upper95', float('nan')):.2f})", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)
