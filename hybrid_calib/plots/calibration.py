"""Plots of a calibration run: error and std over frames (+-2 sigma band), step statistic."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np

from hybrid_calib.calib.drift import drift_verdict
from hybrid_calib.calib.result import VehicleResult, truth_at
from hybrid_calib.data.files import file_part
from hybrid_calib.metrics import signed_errors
from hybrid_calib.plots.figure import pyplot, save_figure

LABELS = ("roll (rot z) [deg]", "pitch (rot x) [deg]", "yaw (rot y) [deg]", "x [cm]", "y [cm]", "z [cm]")
# camera-axis Euler order of metrics.signed_errors is [roll, pitch, yaw] = rotation about z, x, y;
# report_std is ordered rotation about x, y, z: map each Euler angle to its std column.
STD_COLUMN = (2, 0, 1, 3, 4, 5)


def trajectory_errors(vr: VehicleResult) -> np.ndarray:
    """(F, 6) signed error of each trajectory frame (camera axes, deg x3 then cm x3; ``metrics.signed_errors``)
    against the true mount of that frame (``calib.result.truth_at``: a knocked radar's frames before the knock
    against the mount before it; probe 54: every frame scored against the end's, a 1.5 deg "error" that was the
    knock), or against the final estimate when the result has no truth."""
    err = np.array([signed_errors(f.T, truth_at(vr, f.index) if vr.truth_T is not None else vr.trajectory[-1].T)
                    for f in vr.trajectory]).reshape(-1, 6)
    err[:, :3] = np.degrees(err[:, :3])
    err[:, 3:] *= 100
    return err


def plot_vehicle(vr: VehicleResult, out_dir: Path) -> list[Path]:
    """Write ``<vehicle>_trajectory.png`` (signed error with the +-2 sigma band, or the estimate
    when there is no truth) and ``<vehicle>_drift.png`` (windowed chi-square vs threshold, inlier
    fraction). Returns the paths written; nothing for batch results (no trajectory)."""
    plt = pyplot()
    if not vr.trajectory:
        return []
    out_dir = Path(out_dir)
    k = np.array([f.index for f in vr.trajectory])
    std = np.array([f.estimate.std for f in vr.trajectory])
    err = trajectory_errors(vr)
    fig, axes = plt.subplots(2, 3, figsize=(13, 6), sharex=True)
    for j, ax in enumerate(axes.ravel()):
        s = std[:, STD_COLUMN[j]]
        ax.fill_between(k, -2 * s, 2 * s, color="tab:blue", alpha=0.2, label="+-2 sigma (reported)")
        ax.plot(k, err[:, j], color="k", lw=1, label="error" if vr.truth_T is not None else "minus final")
        ax.axhline(0, color="gray", lw=0.5)
        ax.set_title(LABELS[j])
        lim = max(4 * np.median(s), np.percentile(np.abs(err[:, j]), 90) * 1.5, 1e-6)
        ax.set_ylim(-lim, lim)
    axes[1, 0].set_xlabel("frame")
    axes[0, 0].legend(fontsize=7)
    against = "the tables" if vr.errors_against == "tables" else "truth"  # a real root's errors: vs its tables
    fig.suptitle(f"{vr.vehicle}: estimate {f'error vs {against}' if vr.truth_T is not None else 'minus final estimate'}"
                 f" (camera axes) with the reported +-2 sigma")
    fig.tight_layout()
    p1 = save_figure(fig, out_dir / f"{file_part(vr.vehicle)}_trajectory.png", dpi=90)

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(10, 5), sharex=True)
    st = np.array([np.nan if f.step_statistic is None else f.step_statistic for f in vr.trajectory])
    thr = next((f.step_threshold for f in vr.trajectory if f.step_threshold is not None), None)
    a1.semilogy(k, np.maximum(st, 1e-3), ".-", lw=0.8, label="windowed chi-square / its running scale")
    if thr is not None:
        a1.axhline(thr, color="r", ls="--", label=f"alarm threshold {thr:.1f}")
    for f in vr.trajectory:
        if f.step_alarm:
            a1.axvline(f.index, color="orange", lw=2, alpha=0.6)
    a1.legend(fontsize=7)
    a1.set_ylabel("statistic")
    if not vr.frame_rows or any(r.get("used") or r.get("rejected") for r in vr.frame_rows):  # learned: rows fused?
        a2.plot(k, [f.inlier_fraction for f in vr.trajectory], color="tab:green")
    else:  # no correspondence rows (a learned method fusing the network's SE(3) alone): no fraction to draw
        a2.text(0.5, 0.5, "no correspondence rows: the network's SE(3) prior only", ha="center", va="center",
                transform=a2.transAxes, fontsize=9)
    a2.set_ylabel("inlier fraction")
    a2.set_xlabel("frame")
    d = vr.drift or {}
    verdict = textwrap.fill(f"vs reference (tables): {drift_verdict(d) or 'no reference test'}", 120)
    fig.suptitle(f"{vr.vehicle}: step detector; chi2 vs reference {d.get('statistic', float('nan')):.1f} "
                 f"(p {d.get('p_value', float('nan')):.2g})\n{verdict}", fontsize=9)
    fig.tight_layout()
    p2 = save_figure(fig, out_dir / f"{file_part(vr.vehicle)}_drift.png", dpi=90)
    return [p1, p2]
