"""The motion constraint in the closed loop: what the camera's and the radar's own motion say about
the extrinsic, independent of the network.

Per pair of consecutive frames of a drive (``factors.motion``): the camera's two-view visual
odometry (``sensors.visual_odometry``) and the radar's Doppler velocity at both frames
(``sensors.radar_velocity``) give one scalar measurement of the radar's heading in the camera's
motion, i.e. mainly the extrinsic's yaw (rotation about the radar's z axis), plus the lateral
offset through the lever arm in turns. It uses no ego pose, no tables and no network, so it does not
share the network's drive-dependent bias, the error that no number of frames averages out of the
network-only methods.

Noise model (``MotionConfig``): the Doppler heading's own std (from the inliers' residuals) and a
VO heading std ``sigma_vo_deg`` in quadrature; a Huber weight at ``huber`` sigma on the residual at
the frame's start (VO fails on moving traffic, repetitive texture and turns); and an error common to
a drive ``drive_std_deg`` (a radar azimuth misalignment inside the sensor, a VO bias of the
scene), which the loop adds to the reported covariance through the motion's share of the estimate
(``loop``). The pair is skipped (and why recorded) when the radar is slower than
``min_speed_mps``, the frames are more than ``max_gap_s`` apart, either sensor cannot tell, or VO's
rotation angle disagrees with the vehicle's (the ego poses' rotation angle between the two frames:
the angle of a rigid rotation is the same in every frame on the vehicle, so no tables enter; it
catches two-view VO trading rotation for a sideways travel in turns).

How it enters the window: the window takes one Gaussian prior per frame. The network's SE(3) prior
and the linearised motion residual (at the frame's start, the fused estimate) are combined in
information form (``fold``): ``L = L_net + w J^T J``, mean moved by the Gauss-Newton step. The
measurements are cached per frame pair as JSON under the network cache (``motion/``), so trials of
``compare`` pay for them once.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.motion import MotionMeasurement, chord_heading, chord_length, heading_residual, radar_yaw_change
from hybrid_calib.atomic import write_bytes_atomic
from hybrid_calib.calib.schedule import GaussianPrior
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import retract, so3_log
from hybrid_calib.sensors.radar_velocity import RadarVelocityConfig, estimate_velocity
from hybrid_calib.sensors.visual_odometry import VisualOdometryConfig, camera_motion


@dataclass(frozen=True)
class MotionConfig:
    enabled: bool = True  # the motion constraint in the hybrid (off: the network's SE(3) alone)
    sigma_vo_deg: float = 1.16  # VO heading std, deg (fitted on validation drives: benchmarks/motion_fit.py, docs)
    huber: float = 2.0  # Huber threshold on the whitened residual at the frame's start
    gate: float = 3.0  # innovation gate: |r| > gate * sqrt(sigma^2 + J C J^T) (C: the estimate's covariance) -> dropped
    drive_std_deg: float = 0.16  # error common to a drive's motion measurements, deg (added to the covariance)
    min_speed_mps: float = 2.0  # slower: the Doppler heading is too noisy, the pair is skipped
    max_gap_s: float = 1.5  # frames further apart are not a pair
    # VO's rotation angle must match the vehicle's own (ego poses: odometry, mount-independent) within
    # this, deg; two-view VO in turns and on repetitive texture trades rotation for a sideways travel
    max_rotation_mismatch_deg: float = 1.0
    velocity: RadarVelocityConfig = RadarVelocityConfig()
    vo: VisualOdometryConfig = VisualOdometryConfig()

    def __post_init__(self):
        if self.sigma_vo_deg < 0 or self.drive_std_deg < 0 or self.huber <= 0 or self.min_speed_mps < 0:
            raise ValueError("MotionConfig: sigma_vo_deg, drive_std_deg, min_speed_mps must be >= 0 and huber > 0 "
                             f"(got {self.sigma_vo_deg}, {self.drive_std_deg}, {self.min_speed_mps}, {self.huber})")


@dataclass
class MotionSource:
    """Motion measurements of one root's frames (``learned.dataset`` frames or any sequence of
    ``RadarCameraFrame``), cached in memory and, with ``cache_dir``, on disk."""

    frames: object
    conf: MotionConfig = MotionConfig()
    cache_dir: str = ""
    _velocity: dict = field(default_factory=dict)

    def _frame(self, i: int):
        return self.frames[i]

    def velocity(self, i: int):
        if i not in self._velocity:
            f = self._frame(i)
            self._velocity[i] = estimate_velocity(f.radar_points, f.radar_fields, self.conf.velocity,
                                                  f.extras.get("radar_sweep_index"))
        return self._velocity[i]

    def _cache(self, fa, fb) -> Path | None:
        if not self.cache_dir:
            return None
        import hashlib

        from hybrid_calib.config import to_dict

        key = hashlib.sha1(json.dumps(to_dict(self.conf.vo), sort_keys=True).encode()).hexdigest()[:10]
        return Path(self.cache_dir) / "motion" / f"vo-{key}" / f"{fa.camera_token}__{fb.camera_token}.json"

    def _vo(self, fa, fb) -> tuple[dict | None, str]:
        """Camera motion a -> b as plain data (cached), or (None, why)."""
        path = self._cache(fa, fb)
        if path is not None and path.is_file():
            try:
                d = json.loads(path.read_text())
                return (d["motion"], d["reason"])
            except (OSError, ValueError, KeyError):
                pass  # a damaged cache entry is recomputed
        cm, why = camera_motion(fa.load_image(), fb.load_image(), fa.camera, self.conf.vo)
        d = None if cm is None else {"R_ab": cm.R_ab.tolist(), "c": cm.c.tolist(), "n_inliers": cm.n_inliers,
                                      "parallax_px": cm.parallax_px}
        if path is not None:
            write_bytes_atomic(path, json.dumps({"motion": d, "reason": why}).encode())
        return d, why

    def measurement(self, ia: int, ib: int, R_cam_radar: np.ndarray) -> tuple[MotionMeasurement | None, str]:
        """The motion constraint between frames ``ia`` and ``ib`` (indices into ``frames``), or (None,
        why not). ``R_cam_radar`` (3, 3): the current estimate, used only to carry the radar velocity
        at b into frame a (a second-order effect)."""
        try:
            fa, fb = self._frame(ia), self._frame(ib)
        except DataError as e:
            return None, f"frame unreadable: {e}"
        dt = (fb.timestamp_radar_us - fa.timestamp_radar_us) * 1e-6
        if not 0 < dt <= self.conf.max_gap_s:
            return None, f"frames {dt:.2f} s apart (a pair needs 0 < dt <= {self.conf.max_gap_s:g} s)"
        (va, wa), (vb, wb) = self.velocity(ia), self.velocity(ib)
        if va is None or vb is None:
            return None, f"radar velocity: {wa or wb}"
        if min(va.speed, vb.speed) < self.conf.min_speed_mps:
            return None, f"radar speed {min(va.speed, vb.speed):.1f} m/s (need {self.conf.min_speed_mps:g})"
        try:
            vo, why = self._vo(fa, fb)
        except DataError as e:
            return None, f"image unreadable: {e}"
        if vo is None:
            return None, f"visual odometry: {why}"
        R_A = np.asarray(vo["R_ab"], np.float64)
        ego = ego_rotation_deg(fa, fb)
        vo_deg = float(np.degrees(np.linalg.norm(so3_log(R_A))))
        if ego is not None and abs(vo_deg - ego) > self.conf.max_rotation_mismatch_deg:
            return None, (f"visual odometry: its rotation {vo_deg:.1f} deg disagrees with the ego poses' {ego:.1f} deg "
                          f"(more than {self.conf.max_rotation_mismatch_deg:g}): a wrong two-view solution")
        yaw_ab = radar_yaw_change(R_A, R_cam_radar)
        psi, sig, speed = chord_heading(va.v, va.cov, vb.v, vb.cov, yaw_ab)
        # the Doppler chord is centred on the radar's mid-time, the camera's on the camera's: carry
        # the heading over the offset at the pair's turn rate (the radar sweeps lag the images)
        dt_cam = (fb.timestamp_camera_us - fa.timestamp_camera_us) * 1e-6
        lag = 0.5 * (fa.timestamp_radar_us + fb.timestamp_radar_us - fa.timestamp_camera_us - fb.timestamp_camera_us)
        if dt_cam > 0:
            psi -= yaw_ab * lag * 1e-6 / dt_cam
        return MotionMeasurement(np.asarray(vo["c"], np.float64), R_A, chord_length(speed, dt, yaw_ab), psi, sig, speed,
                                 fa.camera_token, fb.camera_token, int(vo["n_inliers"]),
                                 min(va.n_inliers, vb.n_inliers)), ""


def ego_rotation_deg(fa, fb) -> float | None:
    """The vehicle's rotation angle between the two camera timestamps (deg), from the ego poses
    (``extras["T_global_ego_cam"]``), or None when the frames have none. The angle of a rotation is
    the same in every frame attached to the vehicle, so no mount (no tables) enters."""
    Ta, Tb = fa.extras.get("T_global_ego_cam"), fb.extras.get("T_global_ego_cam")
    if Ta is None or Tb is None:
        return None
    R = np.asarray(Ta, np.float64)[:3, :3].T @ np.asarray(Tb, np.float64)[:3, :3]
    return float(np.degrees(np.linalg.norm(so3_log(R))))


@dataclass(frozen=True)
class Folded:
    """A frame's prior with the motion folded in. prior: the combined Gaussian. info_motion: (6, 6)
    the motion's information ``w J^T J``. gain_motion: (6,) ``w J`` (the motion's pull per unit of
    a common heading bias, before the fused covariance). residual_deg: at the frame's start.
    weight: the Huber weight (1 = inlier)."""

    prior: GaussianPrior
    info_motion: np.ndarray
    gain_motion: np.ndarray
    residual_deg: float
    weight: float


def fold(prior: GaussianPrior, T0: np.ndarray, m: MotionMeasurement, conf: MotionConfig,
         cov_T0: np.ndarray | None = None) -> Folded | None:
    """The network prior (``prior``) and the motion residual linearised at ``T0`` (4, 4) in one
    Gaussian (module doc), or None when the residual fails the innovation gate against ``cov_T0``
    (6, 6), the uncertainty of ``T0`` (default: the prior's). ``prior.cov``: (6, 6) right tangent,
    radar frame [rad, m]."""
    from hybrid_calib.geometry import local

    r, J = heading_residual(T0, m)
    sigma = float(np.hypot(m.sigma, np.radians(conf.sigma_vo_deg)))
    C = prior.cov if cov_T0 is None else cov_T0
    if abs(r) > conf.gate * np.sqrt(sigma ** 2 + float(J @ C @ J)):
        return None
    z = abs(r) / max(sigma, 1e-12)
    w = min(1.0, conf.huber / z) / sigma ** 2 if z > 0 else 1.0 / sigma ** 2
    L_p = np.linalg.inv(prior.cov)
    mu_p = local(T0, prior.T)
    L_m = w * np.outer(J, J)
    L = L_p + L_m
    L = 0.5 * (L + L.T)
    mu = np.linalg.solve(L, L_p @ mu_p - w * J * r)
    cov = np.linalg.inv(L)
    return Folded(GaussianPrior(retract(T0, mu), 0.5 * (cov + cov.T)), L_m, w * J, float(np.degrees(r)),
                  float(min(1.0, conf.huber / z)) if z > 0 else 1.0)
