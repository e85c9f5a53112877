"""The motion (hand-eye) constraint: camera and radar share one rigid motion between two frames.

Between keyframes a and b the camera's visual odometry gives its rotation ``R_A`` (3, 3) and the
unit direction ``c`` (3,) of its centre's displacement, both in camera frame a
(``sensors.visual_odometry``); the radar's Doppler gives its own velocity in its x-y plane at a
and at b (``sensors.radar_velocity``), whose mean is the direction of the radar's displacement
(the chord of a constant-curvature arc is parallel to the mean of its end tangents; the speed
times ``dt`` its length ``s``). With ``X = T_cam_radar = (R, t)`` the radar's displacement in
radar frame a is (rigid body, lever arm included)::

    d(X) = R^T (s c + (R_A - I) t)            (3,), metres

and the residual is the difference of its azimuth in the radar plane and the Doppler heading
``psi`` (rad)::

    r(X) = wrap(atan2(d_y, d_x) - psi)

Jacobian for the right perturbation ``X exp([phi, rho])`` (GTSAM order, docs/conventions.md):
``dd/dphi = [d]_x``, ``dd/drho = R^T (R_A - I) R``, ``dr/dd = [-d_y, d_x, 0] / (d_x^2 + d_y^2)``.
It observes the rotation about the radar's z axis (yaw of the radar in the camera) in every
frame, and the lateral offset through the lever arm in turns; a 2D radar's Doppler says nothing
about its pitch and roll. VO has no scale: the camera's chord length is taken as the radar's ``s``
(they differ by the lever arm times the turn, a second-order effect: 0.06 deg of heading at 34
deg/s, ``tests/test_motion.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.geometry import skew, so3_log


@dataclass(frozen=True)
class MotionMeasurement:
    """One frame pair's motion constraint (module doc).

    c: (3,) unit, camera a. R_A: (3, 3) camera b in camera a. s: radar chord length, m. psi: Doppler
    chord heading in radar frame a, rad. sigma: its std, rad (Doppler part; the VO part is added by
    the user of the measurement). speed: mean radar speed, m/s. frame_a / frame_b: frame ids.
    """

    c: np.ndarray
    R_A: np.ndarray
    s: float
    psi: float
    sigma: float
    speed: float
    frame_a: str = ""
    frame_b: str = ""
    n_vo_inliers: int = 0
    n_radar_inliers: int = 0

    def __post_init__(self):
        """Probe 118: NaN or inf in any field gave a NaN residual and Jacobian without a word (``heading_residual``)."""
        for name, shape in (("c", (3,)), ("R_A", (3, 3))):
            v = np.asarray(getattr(self, name), np.float64)
            if v.shape != shape or not np.all(np.isfinite(v)):
                raise ValueError(f"MotionMeasurement[{self.frame_a} -> {self.frame_b}].{name} must be a finite "
                                 f"{shape} array, got shape {v.shape}" + ("" if v.shape != shape else " with NaN/inf"))
        for name in ("s", "psi", "sigma", "speed"):
            if not np.isfinite(float(getattr(self, name))):
                raise ValueError(f"MotionMeasurement[{self.frame_a} -> {self.frame_b}].{name} is "
                                 f"{getattr(self, name)}: it must be finite")
        if not (self.sigma > 0 and self.s >= 0):
            raise ValueError(f"MotionMeasurement[{self.frame_a} -> {self.frame_b}]: sigma must be > 0 and the chord s "
                             f">= 0, got sigma {self.sigma:g}, s {self.s:g}")

    def to_dict(self) -> dict:
        return {"c": [float(x) for x in self.c], "R_A": np.asarray(self.R_A).tolist(), "s": float(self.s),
                "psi": float(self.psi), "sigma": float(self.sigma), "speed": float(self.speed),
                "frame_a": self.frame_a, "frame_b": self.frame_b, "n_vo_inliers": int(self.n_vo_inliers),
                "n_radar_inliers": int(self.n_radar_inliers)}

    @classmethod
    def from_dict(cls, d: dict) -> MotionMeasurement:
        return cls(np.asarray(d["c"], np.float64), np.asarray(d["R_A"], np.float64), float(d["s"]),
                   float(d["psi"]), float(d["sigma"]), float(d["speed"]), d.get("frame_a", ""),
                   d.get("frame_b", ""), int(d.get("n_vo_inliers", 0)), int(d.get("n_radar_inliers", 0)))


def wrap(a: float | np.ndarray) -> float | np.ndarray:
    """Angle(s) wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(a, np.float64)))


def chord_heading(v_a: np.ndarray, cov_a: np.ndarray, v_b: np.ndarray, cov_b: np.ndarray, yaw_ab: float
                  ) -> tuple[float, float, float]:
    """(psi rad, sigma rad, mean of the two speeds m/s) of the radar's chord from its velocities at a and b.

    v_*: (2,) m/s in radar frames a and b; cov_*: (2, 2). yaw_ab: the radar's rotation from a to b
    about its z axis (rad), which carries v_b into frame a.
    """
    Rz = np.array([[np.cos(yaw_ab), -np.sin(yaw_ab)], [np.sin(yaw_ab), np.cos(yaw_ab)]])
    v = 0.5 * (v_a + Rz @ v_b)
    C = 0.25 * (cov_a + Rz @ cov_b @ Rz.T)
    norm = float(np.linalg.norm(v))
    n = np.array([-v[1], v[0]]) / max(norm, 1e-9)
    speed = 0.5 * float(np.linalg.norm(v_a) + np.linalg.norm(v_b))
    return float(np.arctan2(v[1], v[0])), float(np.sqrt(n @ C @ n)) / max(norm, 1e-9), speed


def chord_length(speed: float, dt: float, yaw_ab: float) -> float:
    """The chord (m) of an arc of constant curvature travelled at ``speed`` (m/s) for ``dt`` (s) while
    turning by ``yaw_ab`` (rad): ``speed dt sinc(yaw_ab / 2)``."""
    half = 0.5 * yaw_ab
    return float(speed * dt * (np.sin(half) / half if abs(half) > 1e-9 else 1.0))


def radar_yaw_change(R_A: np.ndarray, R_cam_radar: np.ndarray) -> float:
    """The radar's rotation about its own z axis between a and b (rad), from the camera's ``R_A``."""
    return float((R_cam_radar.T @ so3_log(R_A))[2])


def displacement(T: np.ndarray, m: MotionMeasurement) -> np.ndarray:
    """d(X) (3,) metres, radar frame a (module doc)."""
    R, t = T[:3, :3], T[:3, 3]
    return R.T @ (m.s * m.c + (m.R_A - np.eye(3)) @ t)


def heading_residual(T: np.ndarray, m: MotionMeasurement) -> tuple[float, np.ndarray]:
    """(r rad, J (6,) d r / d [phi, rho]) at ``T = T_cam_radar`` (4, 4) (module doc)."""
    R = T[:3, :3]
    d = displacement(T, m)
    rho2 = d[0] ** 2 + d[1] ** 2
    dr_dd = np.array([-d[1], d[0], 0.0]) / max(rho2, 1e-12)
    J = np.concatenate([dr_dd @ skew(d), dr_dd @ (R.T @ (m.R_A - np.eye(3)) @ R)])
    return float(wrap(np.arctan2(d[1], d[0]) - m.psi)), J
