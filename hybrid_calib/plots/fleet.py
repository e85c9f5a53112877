"""The fleet figure: every vehicle's offset from the fleet's design mount with +-2 sigma bars."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.plots.figure import pyplot, save_figure

AXES = ("rot x [deg]", "rot y [deg]", "rot z [deg]", "t x [cm]", "t y [cm]", "t z [cm]")
COLOURS = {"fleet_outlier": "tab:red", "out_of_tolerance": "tab:orange", "drifted_in_drive": "tab:purple"}


def plot_fleet(summary: dict, path: str | Path) -> Path:
    """Write ``path`` (PNG): six panels (camera axes), one row per done vehicle: its offset from the
    design mount (``summary.json`` "offset_from_design") with +-2 sigma error bars ("std_cam"),
    coloured by its first flag (outlier red, out of tolerance orange, drifted in the drive purple),
    and the fleet mean +- 1 sigma spread when a fleet prior was fitted."""
    plt = pyplot()
    done = [(jid, r) for jid, r in summary["vehicles"].items() if r["state"] == "done"]
    off = np.array([list(r["offset_from_design"].values()) for _, r in done]).reshape(-1, 6)
    std = np.array([list(r["std_cam"].values()) for _, r in done]).reshape(-1, 6)
    colour = [next((COLOURS[f] for f in COLOURS if f in r["flags"]), "tab:blue") for _, r in done]
    y = np.arange(len(done))
    fig, axes = plt.subplots(1, 6, figsize=(16, 1.5 + 0.28 * max(len(done), 4)), sharey=True)
    fp = summary.get("fleet_prior")
    mean = spread = None
    if fp:
        from hybrid_calib.fleet.summary import camera_offset

        mean = camera_offset(np.asarray(summary["design_mount"]["T_cam_radar"]), np.asarray(fp["T_mean"]))
        spread = np.array(list(fp["spread_std_cam"].values()))
    for k, ax in enumerate(axes):
        if mean is not None:
            ax.axvspan(mean[k] - spread[k], mean[k] + spread[k], color="gray", alpha=0.2, label="fleet mean +-1 sigma")
        ax.axvline(0, color="k", lw=0.6)
        for i in range(len(done)):
            ax.errorbar(off[i, k], y[i], xerr=2 * std[i, k], fmt="o", ms=3, color=colour[i], lw=1)
        lim = np.max(np.abs(off[:, k])) * 1.2 + 1e-6 if len(done) else 1  # every vehicle (outliers too) in view
        ax.set_xlim(-lim, lim)
        ax.set_title(AXES[k], fontsize=9)
    axes[0].set_yticks(y, [jid for jid, _ in done], fontsize=7)
    axes[0].invert_yaxis()
    c = summary["counts"]
    fig.suptitle(f"offsets from the design mount ({summary['design_mount']['source']}), +-2 sigma; {c['done']} done, "
                 f"{c['failed']} failed; red: fleet outlier, orange: out of tolerance, purple: drifted in the drive",
                 fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, dpi=90)
