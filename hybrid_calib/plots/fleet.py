"""The fleet figure: every vehicle's offset from a reference mount (the fleet's design mount, or
each vehicle's own tables) per camera axis, with error bars, flagged vehicles coloured and named.

One drawing (``draw_fleet``) serves the fleet command (``plot_fleet``, from ``summary.json``) and the
report's fleet page (``hybrid_calib.report.fleet``, from result files)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hybrid_calib.plots.figure import pyplot, save_figure, short_name

AXES = ("rot x [deg]", "rot y [deg]", "rot z [deg]", "t x [cm]", "t y [cm]", "t z [cm]")
# a vehicle's colour: its first flag in this order (a step inside the drive before a mount off its tables: both
# vehicles of a knocked fleet were orange, and purple was never drawn, probe 67)
# every flag ``fleet.summary`` sets has one (probe 69: an inconclusive vehicle, "flagged" on the page, was blue)
COLOURS = {"fleet_outlier": "tab:red", "flagged": "tab:red", "drifted_in_drive": "tab:purple",
           "out_of_tolerance": "tab:orange", "doppler_off_tables": "tab:brown", "inconclusive": "tab:olive",
           "degenerate": "tab:olive"}
LEGEND = ("red: fleet outlier / flagged, purple: drifted in the drive, orange: out of tolerance, brown: the radar's "
          "Doppler puts its yaw off its tables, olive: inconclusive / degenerate (not trusted)")


def vehicle_colour(flags: Sequence[str]) -> str:
    """The colour of a vehicle with ``flags``: its first flag in ``COLOURS``' order; blue for none."""
    return next((c for f, c in COLOURS.items() if f in flags), "tab:blue")


def axis_limits(offsets: np.ndarray, sigmas: np.ndarray, n_sigma: float = 2.0,
                band: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(6,) half-width of each panel's axis: every offset with its +-``n_sigma`` bar, and the band, in view."""
    reach = np.abs(np.asarray(offsets, np.float64).reshape(-1, 6)) + n_sigma * np.nan_to_num(
        np.asarray(sigmas, np.float64).reshape(-1, 6))
    if band is not None:
        reach = np.vstack([reach, np.abs(band[0]) + band[1]])
    return reach.max(axis=0) * 1.1 + 1e-6 if len(reach) else np.ones(6)


def draw_fleet(names: Sequence[str], offsets: np.ndarray, sigmas: np.ndarray, flags: Sequence[Sequence[str]],
               path: str | Path, title: str, n_sigma: float = 2.0,
               band: tuple[np.ndarray, np.ndarray] | None = None) -> Path:
    """Write ``path`` (PNG): six panels (camera axes), one row per vehicle.

    offsets, sigmas: (V, 6) [rot x, y, z deg, t x, y, z cm], camera axes; bars are +-``n_sigma``.
    flags: per vehicle its flag names (keys of ``COLOURS``; the first of them in ``COLOURS``' order colours it, and
    a flagged vehicle's label names its flags). band: optional (mean (6,), spread (6,)) drawn as a grey band. Each
    axis shows every vehicle's bar whole (probe 67: the axis was fitted to the offsets alone and cut the bars)."""
    plt = pyplot()
    off = np.asarray(offsets, np.float64).reshape(-1, 6)
    std = np.asarray(sigmas, np.float64).reshape(-1, 6)
    colour = [vehicle_colour(fl) for fl in flags]
    limits = axis_limits(off, std, n_sigma, band)
    y = np.arange(len(names))
    fig, axes = plt.subplots(1, 6, figsize=(16, 1.5 + 0.28 * max(len(names), 4)), sharey=True)
    for k, ax in enumerate(axes):
        if band is not None:
            ax.axvspan(band[0][k] - band[1][k], band[0][k] + band[1][k], color="gray", alpha=0.2)
        ax.axvline(0, color="k", lw=0.6)
        for i in range(len(names)):
            ax.errorbar(off[i, k], y[i], xerr=n_sigma * std[i, k], fmt="o", ms=3, color=colour[i], lw=1, capsize=2)
        ax.set_xlim(-limits[k], limits[k])  # every vehicle (outliers too) and its bar in view
        ax.set_title(AXES[k], fontsize=9)
    labels = [f"{short_name(n)} ({', '.join(f.replace('_', ' ') for f in fl if f in COLOURS)})" if c != "tab:blue"
              else short_name(n) for n, c, fl in zip(names, colour, flags)]
    axes[0].set_yticks(y, labels, fontsize=7)
    axes[0].invert_yaxis()
    grey = "; grey: the fleet's mean +- its spread (1 sigma)" if band is not None else ""
    text = textwrap.fill(f"{title}; +-{n_sigma:g} sigma (camera axes); {LEGEND}{grey}", 190)
    fig.suptitle(text, fontsize=9)  # wrapped: one line ran off both edges
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.17 * (text.count("\n") + 1) / fig.get_figheight()))
    return save_figure(fig, path, dpi=90)


def plot_fleet(summary: dict, path: str | Path) -> Path:
    """The fleet command's figure from ``summary.json``: each done vehicle's "offset_from_design"
    with +-2 sigma ("std_cam"), coloured by its flags, and the fleet mean +- 1 sigma spread (grey)
    when a fleet prior was fitted."""
    done = [(jid, r) for jid, r in summary["vehicles"].items() if r["state"] == "done"]
    off = np.array([list(r["offset_from_design"].values()) for _, r in done]).reshape(-1, 6)
    std = np.array([list(r["std_cam"].values()) for _, r in done]).reshape(-1, 6)
    band = None
    fp = summary.get("fleet_prior")
    if fp:
        from hybrid_calib.calib.covariance import camera_offset

        mean = camera_offset(np.asarray(summary["design_mount"]["T_cam_radar"]), np.asarray(fp["T_mean"]))
        band = (mean, np.array(list(fp["spread_std_cam"].values())))
    c = summary["counts"]
    title = (f"offsets from the design mount ({summary['design_mount']['source']}); {c['done']} done, "
             f"{c['failed']} failed")
    return draw_fleet([jid for jid, _ in done], off, std, [r["flags"] for _, r in done], path, title, band=band)
