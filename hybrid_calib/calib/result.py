"""Result objects of the calibrator and the JSON schema of ``RUN/result.json``.

``result.json`` (schema ``hybrid-calib/calibrate-result/v1``)::

    {
      "schema": "hybrid-calib/calibrate-result/v1",
      "data": str, "version": str, "correspondences": "oracle" | DIR, "mode": "window" | "batch",
      "vehicles": {
        VEHICLE: {
          "n_frames": int, "frames_skipped": [{"index", "token", "reason"}],
          "final": EXTRINSIC,              # the estimate after the last frame (window) / of the batch
          "truth": EXTRINSIC-lite | null,  # "T_cam_radar" + "report" when the data has ground truth
          "error": {metrics.ExtrinsicError fields..., "nees": float} | null,
          "crb_std_camera": {rot_x_deg, ..., t_z_cm} | null,   # oracle data only (docs: crb.py)
          "drift": DriftDecision.to_dict() | null,           # vs the vehicle's reference extrinsic
          "step_alarms": [frame index, ...],
          "trajectory": [FrameEstimate.to_dict(), ...]      # window mode: one per frame
        }
      }
    }

EXTRINSIC = {"T_cam_radar": 4x4 list, "report": {"roll_deg", "pitch_deg", "yaw_deg" (camera-axis Euler
angles of R_delta with R = R_delta R_axes), "t_m": [x, y, z]}, "cov_right_radar": 6x6 (right tangent,
radar frame, [rad, m]), "std_camera": {"rot_x_deg", "rot_y_deg", "rot_z_deg", "t_x_cm", "t_y_cm",
"t_z_cm"} (C_report = B C B^T), "status": str, "regularised": bool, "weak_directions": [...]}.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hybrid_calib.calib.covariance import CovarianceReport
from hybrid_calib.geometry import R_AXES_CAM_FROM_RADAR, camera_euler_from_rotation

SCHEMA = "hybrid-calib/calibrate-result/v1"
STD_KEYS = ("rot_x_deg", "rot_y_deg", "rot_z_deg", "t_x_cm", "t_y_cm", "t_z_cm")


def extrinsic_report(T_cam_radar: np.ndarray) -> dict:
    """Euler/translation report of an extrinsic (docs/conventions.md "Report parametrisation")."""
    T = np.asarray(T_cam_radar, np.float64)
    rpy = np.degrees(camera_euler_from_rotation(T[:3, :3] @ R_AXES_CAM_FROM_RADAR.T))
    return {"roll_deg": float(rpy[0]), "pitch_deg": float(rpy[1]), "yaw_deg": float(rpy[2]),
            "t_m": [float(x) for x in T[:3, 3]]}


def std_dict(std: np.ndarray) -> dict[str, float]:
    return {k: float(v) for k, v in zip(STD_KEYS, std)}


@dataclass(frozen=True)
class Estimate:
    """An extrinsic with its trustworthy covariance.

    T: (4, 4) T_cam_radar. cov: (6, 6) right tangent, radar frame [rad, m]. std: (6,) camera axes
    [deg x3, cm x3]. status: "ok" | "weak: ..." | "degenerate: ..." (+ notes).
    """

    T: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    status: str
    regularised: bool = False
    weak_directions: tuple[str, ...] = ()
    info: np.ndarray | None = None  # (6, 6) information before regularisation (for tests/NEES)

    @classmethod
    def from_report(cls, T: np.ndarray, rep: CovarianceReport, info: np.ndarray | None = None,
                    note: str = "") -> Estimate:
        status = rep.status + (f" ({note})" if note else "")
        return cls(np.asarray(T, np.float64), rep.cov, rep.std_report, status, rep.regularised,
                   rep.weak_directions, info)

    def to_dict(self) -> dict:
        return {
            "T_cam_radar": np.asarray(self.T).tolist(), "report": extrinsic_report(self.T),
            "cov_right_radar": np.asarray(self.cov).tolist(), "std_camera": std_dict(self.std),
            "status": self.status, "regularised": bool(self.regularised),
            "weak_directions": list(self.weak_directions),
        }


@dataclass(frozen=True)
class FrameEstimate:
    """What the sliding window outputs after one frame."""

    index: int  # running frame number in this calibrator (0-based)
    frame_id: str
    timestamp_us: int
    estimate: Estimate
    n_window: int  # frames currently in the window
    n_total: int  # frames whose information the estimate holds (window + marginalised)
    inlier_fraction: float  # mean robust weight > 0.5 over the window's rows
    step_statistic: float | None  # windowed chi-square (None when not tested yet)
    step_threshold: float | None
    step_alarm: bool
    solve_ms: float  # wall time of the window solve (incl. the step test), ms
    cov_ms: float  # wall time of the covariance, ms
    events: tuple[str, ...] = ()  # e.g. "step change detected: window reset, convex restart"

    @property
    def T(self) -> np.ndarray:
        return self.estimate.T

    @property
    def cov(self) -> np.ndarray:
        return self.estimate.cov

    @property
    def status(self) -> str:
        return self.estimate.status

    def to_dict(self) -> dict:
        return {
            "index": self.index, "frame_id": self.frame_id, "timestamp_us": int(self.timestamp_us),
            "T_cam_radar": np.asarray(self.T).tolist(), "std_camera": std_dict(self.estimate.std),
            "status": self.status, "n_window": self.n_window, "n_total": self.n_total,
            "inlier_fraction": float(self.inlier_fraction),
            "step_statistic": None if self.step_statistic is None else float(self.step_statistic),
            "step_threshold": None if self.step_threshold is None else float(self.step_threshold),
            "step_alarm": bool(self.step_alarm), "solve_ms": float(self.solve_ms), "cov_ms": float(self.cov_ms),
            "events": list(self.events),
        }


@dataclass
class VehicleResult:
    """Everything ``calibrate`` produces for one vehicle (log)."""

    vehicle: str
    final: Estimate
    trajectory: list[FrameEstimate] = field(default_factory=list)
    truth_T: np.ndarray | None = None
    error: dict | None = None
    crb_std: np.ndarray | None = None
    drift: dict | None = None
    skipped: list[dict] = field(default_factory=list)
    n_frames: int = 0

    def to_dict(self) -> dict:
        return {
            "n_frames": self.n_frames, "frames_skipped": self.skipped, "final": self.final.to_dict(),
            "truth": None if self.truth_T is None else {
                "T_cam_radar": np.asarray(self.truth_T).tolist(), "report": extrinsic_report(self.truth_T)},
            "error": self.error, "crb_std_camera": None if self.crb_std is None else std_dict(self.crb_std),
            "drift": self.drift,
            "step_alarms": [f.index for f in self.trajectory if f.step_alarm],
            "trajectory": [f.to_dict() for f in self.trajectory],
        }
