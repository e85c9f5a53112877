"""Plots of a calibration run: error and std over frames (+-2 sigma band), step statistic."""

from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybrid_calib.calib.drift import drift_verdict
from hybrid_calib.calib.result import VehicleResult, truth_at
from hybrid_calib.data.files import file_part
from hybrid_calib.metrics import signed_errors
from hybrid_calib.plots.figure import pyplot, save_figure, short_name

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


@dataclass(frozen=True)
class StepPanel:
    """One step test's series over the drive's frames (``values`` (F,), NaN where not tested), as drawn."""

    title: str
    label: str
    ylabel: str
    values: np.ndarray
    threshold: float | None
    alarms: tuple[int, ...]  # frames where this test alarmed
    changes: tuple[int, ...] = ()  # the frames its steps began (the monitor's change points)
    note: str = ""  # why nothing is drawn, when nothing is
    log: bool = False


def step_panels(vr: VehicleResult) -> list[StepPanel]:
    """The step tests of ``vr`` as they decided its alarms: the radar mount monitor's CUSUM against its threshold
    (the hybrid's alarms; ``calib.mount_monitor``), then the window's chi-square of the rows (when it tested any
    frame). The hybrid's figure drew only the window's statistic, which never raised its alarm, and its axis shrank
    to the few frames that statistic had (probe 67)."""
    k = [f.index for f in vr.trajectory]
    panels = []
    monitor = vr.mount or {}
    if monitor.get("threshold") is not None:
        by_id = {r.get("frame_id"): (r.get("mount") or {}) for r in vr.frame_rows or []}
        cusum = np.array([np.nan if (v := by_id.get(f.frame_id, {}).get("statistic")) is None else float(v)
                          for f in vr.trajectory])
        steps = monitor.get("steps") or []
        note = "" if np.isfinite(cusum).any() else (
            f"no frame tested ({monitor.get('pairs_tested') or 0} sweep pairs read): the monitor needs "
            "pairs of radar sweeps while the vehicle drives on, not too slowly and not turning hard")
        panels.append(StepPanel(
            "radar mount monitor (the radar's Doppler heading against the ego poses: yaw steps)",
            "CUSUM of the heading residual (noise sigmas)", "CUSUM", cusum, float(monitor["threshold"]),
            tuple(int(s["at"]) for s in steps if s.get("at") is not None),
            tuple(int(s["change"]) for s in steps if s.get("change") is not None), note))
    st = np.array([np.nan if f.step_statistic is None else f.step_statistic for f in vr.trajectory])
    thr = next((f.step_threshold for f in vr.trajectory if f.step_threshold is not None), None)
    if np.isfinite(st).any() or not panels:
        by_monitor = set(panels[0].alarms) if panels else set()
        alarms = tuple(i for i, f in zip(k, vr.trajectory) if f.step_alarm and i not in by_monitor)
        note = "" if np.isfinite(st).any() else (
            "no frame tested: the window's step test needs a history of frames first (a drive this short, or rows "
            "too few, gives it none)")
        panels.append(StepPanel("sliding window (the rows' windowed chi-square)",
                                "windowed chi-square / its running scale", "statistic", st, thr, alarms, note=note,
                                log=True))
    return panels


def vehicle_plot_paths(vr: VehicleResult, out_dir: Path) -> list[Path]:
    """The files ``plot_vehicle`` writes for ``vr`` into ``out_dir`` (none for a batch result)."""
    if not vr.trajectory:
        return []
    return [Path(out_dir) / f"{file_part(vr.vehicle)}_{what}.png" for what in ("trajectory", "drift")]


def draw_missing(run, out_dir: Path) -> list[str]:
    """Draw the plots of each vehicle of ``run`` (a ``CalibrationRun``) that lacks some in ``out_dir``: a vehicle an
    interrupted run kept, whose plots were not written, or a reused result whose plots were removed. Returns their
    names."""
    drawn = [name for name, vr in run.vehicles.items() if not all(p.is_file() for p in vehicle_plot_paths(vr, out_dir))]
    for name in drawn:
        plot_vehicle(run.vehicles[name], out_dir)
    return drawn


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
    shown = f"error vs {against}" if vr.truth_T is not None else "minus final estimate"
    fig.suptitle(f"{short_name(vr.vehicle)}: estimate {shown} (camera axes) with the reported +-2 sigma")
    fig.tight_layout()
    path_trajectory, path_drift = vehicle_plot_paths(vr, out_dir)
    p1 = save_figure(fig, path_trajectory, dpi=90)

    panels = step_panels(vr)
    fig, axes = plt.subplots(len(panels) + 1, 1, figsize=(10, 2.2 * (len(panels) + 1) + 0.6), sharex=True)
    for ax, pan in zip(axes, panels):
        if pan.log:
            ax.semilogy(k, np.maximum(pan.values, 1e-3), ".-", lw=0.8, label=pan.label)
        else:
            ax.plot(k, pan.values, ".-", lw=0.8, label=pan.label)
        if pan.threshold is not None:
            ax.axhline(pan.threshold, color="r", ls="--", label=f"alarm threshold {pan.threshold:.1f}")
        for i, c in enumerate(pan.changes):
            ax.axvline(c, color="purple", ls=":", lw=1.5,
                       label="change point (the step's first frame)" if i == 0 else None)
        for i, a in enumerate(pan.alarms):
            ax.axvline(a, color="orange", lw=2, alpha=0.6, label="alarm" if i == 0 else None)
        if pan.note:
            ax.text(0.5, 0.5, textwrap.fill(pan.note, 90), ha="center", va="center", transform=ax.transAxes, fontsize=8)
        ax.set_ylabel(pan.ylabel)
        ax.set_title(pan.title, fontsize=9, loc="left")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="upper left")
    a2 = axes[-1]
    if not vr.frame_rows or any(r.get("used") or r.get("rejected") for r in vr.frame_rows):  # learned: rows fused?
        a2.plot(k, [f.inlier_fraction for f in vr.trajectory], color="tab:green")
    else:  # no correspondence rows (a learned method fusing the network's SE(3) alone): no fraction to draw
        a2.text(0.5, 0.5, "no correspondence rows: the network's SE(3) prior only", ha="center", va="center",
                transform=a2.transAxes, fontsize=9)
    a2.set_ylabel("inlier fraction")
    a2.set_xlabel("frame of the drive")
    a2.set_xlim(k.min() - 0.5, k.max() + 0.5)  # the whole drive, whatever a panel has to draw (probe 67)
    d = vr.drift or {}
    verdict = textwrap.fill(f"vs reference (tables): {drift_verdict(d) or 'no reference test'}", 120)
    fig.suptitle(f"{short_name(vr.vehicle)}: step detectors; chi2 vs reference {d.get('statistic', float('nan')):.1f} "
                 f"(p {d.get('p_value', float('nan')):.2g})\n{verdict}", fontsize=9)
    fig.tight_layout()
    p2 = save_figure(fig, path_drift, dpi=90)
    return [p1, p2]
