"""The motion constraint in the closed loop: what the camera's and the radar's own motion say about
the extrinsic, independent of the network.

Per pair of consecutive frames of a drive (``factors.motion``): the camera's two-view visual
odometry (``sensors.visual_odometry``) and the radar's Doppler velocity at both frames
(``sensors.radar_velocity``) give one scalar measurement of the radar's heading in the camera's
motion, i.e. mainly the extrinsic's yaw (rotation about the radar's z axis), plus the lateral
offset through the lever arm in turns. It uses no ego pose, no tables and no network, so it does not
share the network's drive-dependent bias, the error that no number of frames averages out of the
network-only methods.

Noise model (``MotionConfig``): the Doppler heading's own std (from the inliers' residuals) and a VO heading
std in quadrature (``sigma_vo_deg``, larger for a pair of few image matches: ``vo_sigma_rad``); a Huber weight
at ``huber`` sigma on the residual at the frame's start (VO fails on moving traffic, repetitive texture and
turns); and an error common to a drive ``drive_std_deg`` (a radar azimuth misalignment inside the sensor, a VO
bias of the scene; on a real root at least ``real_drive_std_deg``: sideslip and the ego poses' heading bias,
which the simulator does not have), which the loop adds to the reported covariance through the motion's share
of the estimate (``loop``). The pair is skipped (and why recorded) when the radar is slower than
``min_speed_mps``, the frames are more than ``max_gap_s`` apart, either sensor cannot tell, or VO's rotation
angle disagrees with the vehicle's (the ego poses' rotation angle between the two frames: the angle of a rigid
rotation is the same in every frame on the vehicle, so no tables enter; it catches two-view VO trading
rotation for a sideways travel in turns).

How it enters the window: the window takes one Gaussian prior per frame. The network's SE(3) prior
and the linearised motion residual (at the frame's start, the fused estimate) are combined in
information form (``fold``): ``L = L_net + w J^T J``, mean moved by the Gauss-Newton step. The
measurements are cached per frame pair as JSON under the network cache (``motion/``), so trials of
``compare`` pay for them once.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.motion import MotionMeasurement, chord_heading, chord_length, heading_residual, radar_yaw_change
from factors.robust import weight
from hybrid_calib.atomic import write_bytes_atomic
from hybrid_calib.calib.ego_doppler import pose_doppler_conflict, scene_break, sensor_travel
from hybrid_calib.calib.schedule import GaussianPrior
from hybrid_calib.data.files import NPZ_ERRORS, file_part, file_stamp
from hybrid_calib.errors import DataError, HybridCalibError
from hybrid_calib.geometry import retract, so3_exp, so3_log
from hybrid_calib.sensors.radar_velocity import RadarVelocityConfig, estimate_velocity
from hybrid_calib.sensors.visual_odometry import (
    CameraMotion,
    VisualOdometryConfig,
    match_features,
    motion_from_matches,
    travel_given_rotation,
)


@dataclass(frozen=True)
class MotionConfig:
    enabled: bool = True  # the motion constraint in the hybrid (off: the network's SE(3) alone)
    sigma_vo_deg: float = 0.69  # VO heading std of a well-supported pair, deg (fitted: benchmarks/motion_fit.py, docs)
    # a pair with fewer essential-matrix inliers than ``vo_inliers_full`` has the std ``sigma_vo_deg * (full / n) **
    # vo_inliers_power`` (``vo_sigma_rad``): the VO heading's robust std is 2.0 deg on 10-16 inliers, 0.7 deg on 35
    # or more (fitted with sigma_vo_deg on 53 validation drives, plain and randomised; power 0: one std for all)
    vo_inliers_full: int = 40
    vo_inliers_power: float = 0.9
    # and a pair whose radar chord (the travel between its keyframes) is shorter than ``vo_chord_full_m`` has it grown
    # by ``(full / chord) ** vo_chord_power`` too: a short baseline's translation direction is poorer (probe 48: at
    # 5 m/s, 2.5 m chords, residuals of 2-4 deg against a std of 0.75; benchmarks/motion_fit.py --hold on 15 slow
    # validation drives, 519 pairs of 1.1-5.6 m chords: docs/benchmarks.md "The visual odometry's std by its chord")
    vo_chord_full_m: float = 6.0
    vo_chord_power: float = 0.40
    # on a real root the VO std is at least this, deg: the fit rests on the simulator's images, and on the real
    # scene-0916 its pairs of 150-760 inliers, at 0.7 deg, pulled the yaw 1.3 deg further off the tables from one
    # start of three (the single std fitted before, 1.13 deg, kept there; ``vo_sigma_rad``)
    real_sigma_vo_deg: float = 1.13
    huber: float = 2.0  # Huber threshold on the whitened residual at the frame's start
    gate: float = 3.0  # innovation gate: |r| > gate * sqrt(sigma^2 + J C J^T) (C: the estimate's covariance) -> dropped
    drive_std_deg: float = 0.29  # error common to a drive's motion measurements, deg (added to the covariance)
    # the same on a real root, at least: the simulator has no sideslip, no heading bias of the ego poses against the
    # vehicle's body and no azimuth misalignment inside the radar, which a real drive has and no data here measures
    # (the one real drive, scene-0916: the radar's Doppler against its ego poses 0.93 deg from the tables' radar yaw,
    # and the hybrid's yaw 1.2 deg off at a 0.26 deg 1-sigma, 3.5-5.8 sigma on its consistent variants: probe 26)
    real_drive_std_deg: float = 1.0
    # this many gated-out residuals in a row that agree with each other (within gate x their own std)
    # and lie on one side: the estimate is off, not the measurements; they are admitted (Huber-weighted)
    # until the residuals fall inside the gate again (0: never; ``MotionGate``)
    consensus: int = 3
    # once this many residuals since the window last restarted lay inside their own Huber band (the motion
    # confirmed the estimate), a consensus beyond the gate is admitted only when the network's outputs of those
    # frames moved toward it too (``MotionGate``; 0: never required, the consensus alone admits)
    confirm: int = 3
    # the motion's lever-arm term also moves the translation (off: it updates the rotation only). Off
    # by default: measured on 200-frame R2 test drives (urban), the folds' small translation Jacobian
    # against the network's weak translation prior walked the lateral offset 1.8-3.8 m away with a
    # reported std of 70 cm (NEES 13-37); rotation only, the same drive ends 48 cm off (NEES 3.4)
    translation: bool = False
    min_speed_mps: float = 2.0  # slower: the Doppler heading is too noisy, the pair is skipped
    max_gap_s: float = 1.5  # frames further apart are not a pair
    # a frame is paired with the latest earlier frame at least this far back along the camera's path (its poses), within
    # max_gap_s, else with the one before it (0: always the one before). A slow drive's VO carried biases of 1.3-1.7
    # deg at 1.5 m chords (probe 48's 3 m/s drive), beyond what the chord's std (above) covers there; paired further
    # back on the real scene-0916 (keyframes 1.8-3.1 m apart, 4 m: two back) its yaw moved 0.6-1.3 deg further from
    # the tables from 2 of 3 starts, so only chords under 2 m are paired back (``pair_partner``, docs/benchmarks.md)
    min_chord_m: float = 2.0
    # VO's rotation angle must match the vehicle's own (ego poses: odometry, mount-independent) within
    # this, deg; two-view VO in turns and on repetitive texture trades rotation for a sideways travel
    max_rotation_mismatch_deg: float = 1.0
    # the camera's rotation between frames: "ego" = the ego poses' turn about the radar's up axis
    # (only the direction of travel is estimated from the images; falls back to "vo" without ego
    # poses) | "vo" = the five-point essential matrix (checked against the ego poses' angle)
    rotation: str = "ego"
    velocity: RadarVelocityConfig = RadarVelocityConfig()
    vo: VisualOdometryConfig = VisualOdometryConfig()

    def __post_init__(self):
        if self.rotation not in ("ego", "vo"):
            raise ValueError(f"MotionConfig.rotation={self.rotation!r}; valid: ego, vo")
        if self.consensus < 0:
            raise ValueError(f"MotionConfig.consensus must be >= 0 (0: off), got {self.consensus}")
        if self.sigma_vo_deg < 0 or self.drive_std_deg < 0 or self.huber <= 0 or self.min_speed_mps < 0:
            raise ValueError("MotionConfig: sigma_vo_deg, drive_std_deg, min_speed_mps must be >= 0 and huber > 0 "
                             f"(got {self.sigma_vo_deg}, {self.drive_std_deg}, {self.min_speed_mps}, {self.huber})")
        from hybrid_calib.config import require_ranges

        require_ranges(self, {"sigma_vo_deg": "(0, 90]", "huber": "(0, 100]", "gate": "(0, 1000]",
                              "vo_inliers_full": "[1, 1e6]", "vo_inliers_power": "[0, 10]",
                              "vo_chord_full_m": "(0, 1000]", "vo_chord_power": "[0, 10]",
                              "real_sigma_vo_deg": "[0, 90]",
                              "drive_std_deg": "[0, 90]", "real_drive_std_deg": "[0, 90]", "consensus": "[0, 1e6]",
                              "confirm": "[0, 1e6]", "min_speed_mps": "[0, 100]",
                              "max_gap_s": "(0, 3600]", "max_rotation_mismatch_deg": "(0, 180]",
                              "min_chord_m": "[0, 1000]"})


def vo_sigma_rad(conf: MotionConfig, n_inliers: int, simulated: bool = True, chord_m: float = 0.0) -> float:
    """The VO heading std (rad) of a pair whose essential matrix had ``n_inliers`` inliers and whose radar travelled
    ``chord_m`` metres: ``sigma_vo_deg``, grown by ``(vo_inliers_full / n) ** vo_inliers_power`` below
    ``vo_inliers_full`` (0 or less: not recorded, the base) and by ``(vo_chord_full_m / chord) ** vo_chord_power``
    below ``vo_chord_full_m`` (0 or less: not known, none); on a real root (``simulated`` False) at least
    ``real_sigma_vo_deg`` (fitted on scene-0916, whose keyframes are 1.8-3.1 m apart: its chords are in it)."""
    n, chord = int(n_inliers), float(chord_m)
    grow = (conf.vo_inliers_full / n) ** conf.vo_inliers_power if 0 < n < conf.vo_inliers_full else 1.0
    if 0 < chord < conf.vo_chord_full_m:
        grow *= (conf.vo_chord_full_m / chord) ** conf.vo_chord_power
    s = float(np.radians(conf.sigma_vo_deg) * grow)
    return s if simulated else max(s, float(np.radians(conf.real_sigma_vo_deg)))


def pair_partner(history: list, p: np.ndarray | None, t: float | None, conf: MotionConfig) -> int | None:
    """The frame a new frame (the ego at ``p`` (3,) m, time ``t`` s: ``MotionSource.where``) is paired with: the
    latest of ``history`` ([(index, p, t)], oldest first) at least ``conf.min_chord_m`` back within ``max_gap_s``,
    else the latest one (None: no history)."""
    if not history:
        return None
    if conf.min_chord_m > 0 and p is not None and t is not None:
        for j, pj, tj in reversed(history):
            if tj is None or pj is None or t - tj > conf.max_gap_s:
                break
            if float(np.linalg.norm(p - pj)) >= conf.min_chord_m:
                return j
    return history[-1][0]


def drive_std_rad(conf: MotionConfig, simulated: bool) -> float:
    """The error common to a drive's motion measurements (rad): ``drive_std_deg``, and on a real root at least
    ``real_drive_std_deg`` (the module doc)."""
    return float(np.radians(conf.drive_std_deg if simulated else max(conf.drive_std_deg, conf.real_drive_std_deg)))


@dataclass
class MotionSource:
    """Motion measurements of one root's frames (``learned.dataset`` frames or any sequence of
    ``RadarCameraFrame``), cached in memory and, with ``cache_dir``, on disk."""

    frames: object
    conf: MotionConfig = MotionConfig()
    cache_dir: str = ""
    _velocity: dict = field(default_factory=dict)
    # the frames' radar sweeps (``calib.ego_doppler.frame_sweeps``' cache): the mount monitor and the lever arm
    # read and fit each sweep once
    sweeps: dict = field(default_factory=dict)
    _cache_warned: bool = False  # an image-match cache entry that could not be written: said once
    _identity: str | None = None  # the frames' data identity (``NuScenesRadarCamera.identity``), read once

    def _frame(self, i: int):
        return self.frames[i]

    def where(self, i: int) -> tuple[np.ndarray | None, float | None]:
        """(the camera's position (3,) m, the camera keyframe's time s) of frame ``i`` from the tables (no file read),
        or (None, None) where the frames do not say (``pair_partner`` then takes the frame before). The camera's, not
        the ego origin's: the chord the images see, whatever origin a root gives its ego frame (probe 94: scene-0916
        with its ego origin moved to the camera paired other frames in its turns and ended 1.15 deg / 54 cm apart)."""
        try:
            (T,) = self.frames.camera_poses([i])
            t = self.frames.frames[i].camera_sd["timestamp"] * 1e-6
        except (AttributeError, KeyError, TypeError, ValueError, IndexError):
            return None, None
        return (None, None) if T is None else (np.asarray(T, np.float64)[:3, 3], float(t))

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
        # of these images of this root: the tokens alone gave a cache shared by two roots whose tokens coincide (an
        # edited copy of a scene; compare's one cache for all its roots) the other root's matches (probe 140: yaw
        # 1.72 deg where its own read 12.64), and a root re-made at its path its old images' matches
        if self._identity is None:
            self._identity = str(getattr(self.frames, "identity", "") or "")
        stamps = [file_stamp(f.image_path) if getattr(f, "image_path", None) is not None else "" for f in (fa, fb)]
        seen = hashlib.sha1(json.dumps([self._identity, *stamps]).encode()).hexdigest()[:12]
        pair = f"{file_part(fa.camera_token)}__{file_part(fb.camera_token)}-{seen}.npz"
        return Path(self.cache_dir) / "motion" / f"matches-{key}" / pair

    def _matches(self, fa, fb) -> tuple[tuple | None, str]:
        """The image matches a -> b ((pa, pb, K) or None, why), cached as ``.npz``."""
        import io

        path = self._cache(fa, fb)
        if path is not None and path.is_file():
            try:
                with np.load(path, allow_pickle=False) as z:
                    if "pa" in z:
                        return (z["pa"], z["pb"], z["K"]), ""
                    return None, str(z["reason"])
            except NPZ_ERRORS:
                pass  # a damaged cache entry (truncated, not a zip, a missing key) is recomputed
        m, why = match_features(fa.load_image(), fb.load_image(), fa.camera, self.conf.vo)
        if path is not None:
            buf = io.BytesIO()
            if m is None:
                np.savez(buf, reason=np.array(why))
            else:
                np.savez(buf, pa=m[0], pb=m[1], K=m[2])
            try:
                write_bytes_atomic(path, buf.getvalue())
            except (OSError, HybridCalibError) as e:  # as the network cache: said once, the run goes on (probe 131: a
                # cache_dir that cannot be created stopped a whole compare, "No such file or directory")
                if not self._cache_warned:
                    self._cache_warned = True
                    print(f"motion cache: {path} could not be written ({e}); going on without caching image matches "
                          "(and saying so once)", file=sys.stderr)
        return m, why

    def camera(self, fa, fb, R_cam_radar: np.ndarray, speed_mps: float | None = None, ego: bool = True
               ) -> tuple[CameraMotion | None, str]:
        """The camera's motion a -> b (module doc): with ego poses, the rotation is the vehicle's
        rotation angle about the radar's up axis (the current estimate's; a 2D radar is mounted level)
        and only the direction of travel is estimated (``travel_given_rotation``); without them, or when
        their travel contradicts the radar's Doppler speed ``speed_mps`` (``ego_doppler.pose_doppler_conflict``:
        frozen or foreign poses), or when ``ego`` is False (their headings are known to be wrong: the radar
        mount monitor's implausible level), the five-point essential matrix."""
        m, why = self._matches(fa, fb)
        if m is None:
            return None, why
        omega = ego_rotation(fa, fb) if ego else None
        if omega is not None and speed_mps is not None and ego_conflict(fa, fb, speed_mps):
            omega = None
        if omega is None or self.conf.rotation == "vo":
            cm, why = motion_from_matches(*m, self.conf.vo)
            if cm is not None and omega is not None:
                vo_deg = float(np.degrees(np.linalg.norm(so3_log(cm.R_ab))))
                ego_deg = float(np.degrees(np.linalg.norm(omega)))
                if abs(vo_deg - ego_deg) > self.conf.max_rotation_mismatch_deg:
                    return None, (f"its rotation {vo_deg:.1f} deg disagrees with the ego poses' {ego_deg:.1f} deg "
                                  f"(more than {self.conf.max_rotation_mismatch_deg:g}): a wrong two-view solution")
            return cm, why
        up = np.asarray(R_cam_radar, np.float64)[:, 2]
        return travel_given_rotation(*m, so3_exp(omega[2] * up), self.conf.vo)

    def measurement(self, ia: int, ib: int, R_cam_radar: np.ndarray, ego: bool = True
                    ) -> tuple[MotionMeasurement | None, str]:
        """The motion constraint between frames ``ia`` and ``ib`` (indices into ``frames``), or (None,
        why not). ``R_cam_radar`` (3, 3): the current estimate; it gives the rotation axis (with ego
        poses) and carries the radar velocity at b into frame a, both first-order insensitive to it.
        ``ego`` False: the ego poses' rotation is not used (``camera``)."""
        try:
            fa, fb = self._frame(ia), self._frame(ib)
        except DataError as e:
            return None, f"frame unreadable: {e}"
        if why := scene_break(fa, fb):
            return None, why
        dt = (fb.timestamp_radar_us - fa.timestamp_radar_us) * 1e-6
        if not 0 < dt <= self.conf.max_gap_s:
            return None, f"frames {dt:.2f} s apart (a pair needs 0 < dt <= {self.conf.max_gap_s:g} s)"
        (va, wa), (vb, wb) = self.velocity(ia), self.velocity(ib)
        if va is None or vb is None:
            return None, f"radar velocity: {wa or wb}"
        if min(va.speed, vb.speed) < self.conf.min_speed_mps:
            return None, f"radar speed {min(va.speed, vb.speed):.1f} m/s (need {self.conf.min_speed_mps:g})"
        try:
            cm, why = self.camera(fa, fb, R_cam_radar, 0.5 * (va.speed + vb.speed), ego)
        except DataError as e:
            return None, f"image unreadable: {e}"
        if cm is None:
            return None, f"visual odometry: {why}"
        # the sign of two-view translation rests on cheirality, fragile with far points (a highway's):
        # the radar says which way the vehicle moves; the current estimate carries it to the camera
        ahead = np.asarray(R_cam_radar, np.float64) @ np.array([va.v[0], va.v[1], 0.0])
        c = cm.c if cm.c @ ahead >= 0 else -cm.c
        R_A = cm.R_ab
        yaw_ab = radar_yaw_change(R_A, R_cam_radar)
        psi, sig, speed = chord_heading(va.v, va.cov, vb.v, vb.cov, yaw_ab)
        # the Doppler chord is centred on the radar's mid-time, the camera's on the camera's: carry
        # the heading over the offset at the pair's turn rate (the radar sweeps lag the images)
        dt_cam = (fb.timestamp_camera_us - fa.timestamp_camera_us) * 1e-6
        lag = 0.5 * (fa.timestamp_radar_us + fb.timestamp_radar_us - fa.timestamp_camera_us - fb.timestamp_camera_us)
        if dt_cam > 0:
            psi -= yaw_ab * lag * 1e-6 / dt_cam
        s = chord_length(speed, dt, yaw_ab)
        if not np.all(np.isfinite([s, psi, sig, speed])) or not sig > 0:
            return None, "the radar's Doppler chord is not finite"
        return MotionMeasurement(c, R_A, s, psi, sig, speed, fa.camera_token, fb.camera_token, cm.n_inliers,
                                 min(va.n_inliers, vb.n_inliers)), ""


def ego_conflict(fa, fb, speed_mps: float) -> str:
    """Why the frames' ego poses (at the camera's timestamps) contradict the radar's Doppler speed, or "": the
    radar's travel by them (its mount ``extras["T_ego_radar"]``), whatever origin the root gives its ego frame."""
    Ta, Tb = fa.extras.get("T_global_ego_cam"), fb.extras.get("T_global_ego_cam")
    dt = (fb.timestamp_camera_us - fa.timestamp_camera_us) * 1e-6
    if Ta is None or Tb is None or dt <= 0:
        return ""
    return pose_doppler_conflict(sensor_travel(Ta, Tb, fa.extras.get("T_ego_radar")), dt, speed_mps)


def ego_rotation(fa, fb) -> np.ndarray | None:
    """The vehicle's rotation vector between the two camera timestamps (3,) rad, in the ego frame at
    a (``extras["T_global_ego_cam"]``), or None when the frames have none. Its angle is the same in
    every frame attached to the vehicle, and its z part is the turn, so no mount (no tables) enters."""
    Ta, Tb = fa.extras.get("T_global_ego_cam"), fb.extras.get("T_global_ego_cam")
    if Ta is None or Tb is None:
        return None
    return so3_log(np.asarray(Ta, np.float64)[:3, :3].T @ np.asarray(Tb, np.float64)[:3, :3])


@dataclass(frozen=True)
class Innovation:
    """One motion measurement at the estimate ``T`` before its frame: residual ``r`` (rad), its
    Jacobian ``J`` (6,), the measurement's own std ``sigma`` (rad: Doppler and VO) and the
    innovation std ``std = sqrt(sigma^2 + J C J^T)`` (rad) with ``C`` the uncertainty of ``T``: what
    the gate and the fold use (and the frame's record, ``z``)."""

    r: float
    J: np.ndarray
    sigma: float
    std: float
    # the std the pair would have with a well-supported VO (``sigma_vo_deg``; None: ``sigma``): what confirms an
    # estimate (``MotionGate``) is a residual as small as a good pair's, whatever the pair's own std
    sigma_base: float | None = None

    @property
    def band(self) -> float:
        """The std a residual is judged by for confirming an estimate: ``sigma_base`` (``sigma`` without one)."""
        return self.sigma if self.sigma_base is None else self.sigma_base

    @property
    def few_matches(self) -> bool:
        """Its VO std is grown beyond a well-supported pair's (``vo_sigma_rad``: fewer than ``vo_inliers_full``)."""
        return self.sigma > 1.05 * self.band

    @property
    def z(self) -> float:
        return self.r / self.std

    def inside(self, gate: float) -> bool:
        """The innovation gate: ``|r| <= gate * std`` (the one rule of ``fold`` and ``MotionGate``)."""
        return abs(self.r) <= gate * self.std


def innovation(T: np.ndarray, m: MotionMeasurement, conf: MotionConfig, cov: np.ndarray,
               simulated: bool = True) -> Innovation:
    """The ``Innovation`` of ``m`` at ``T`` (4, 4); cov: (6, 6) the uncertainty of T."""
    return gated_innovation(T, m, conf, (cov,), simulated)


def gated_innovation(T: np.ndarray, m: MotionMeasurement, conf: MotionConfig, covs,
                     simulated: bool = True) -> Innovation:
    """``innovation`` of ``m`` at ``T`` against the tightest of ``covs`` ((6, 6) each, None skipped): each is
    an upper bound on the uncertainty of ``T`` (the window's reported covariance; the frame's own network
    pass with its drive-common error), so the smallest innovation std is the honest gate. The hybrid's
    window weights its network priors with ``C + N D`` (generalised least squares for a shared bias):
    used as the gate, that covariance is ~sqrt(N) too wide in the first frames, and one failed VO pair
    (a 21 deg heading on a rainy validation drive) passed it and set the yaw for the whole drive."""
    r, J = heading_residual(T, m)
    if not conf.translation:
        J = np.concatenate([J[:3], np.zeros(3)])
    sigma = float(np.hypot(m.sigma, vo_sigma_rad(conf, m.n_vo_inliers, simulated, m.s)))
    spread = min(float(J @ c @ J) for c in covs if c is not None)
    return Innovation(r, J, sigma, float(np.sqrt(sigma ** 2 + spread)),
                      float(np.hypot(m.sigma, vo_sigma_rad(conf, 0, simulated, m.s))))


class MotionGate:
    """The innovation gate of one drive, with re-admission by consensus.

    ``admit(inn, r_net)``: True when ``|r| <= gate * std`` (the innovation's std: measurement and estimate).
    Otherwise the residual is remembered; once the last ``consensus`` remembered residuals (in a row)
    lie on one side and within ``gate`` of their median by their own measurement std, the estimate is
    what is off (the tight gate protects a good estimate from a failed VO pair, but it would also lock
    a network estimate that starts beyond it out of every correction), and they are admitted, Huber-
    weighted by ``fold``, until a residual passes the gate again. ``admitted_by_consensus`` tells the
    caller which way the last one went in.

    Once the motion has confirmed the estimate (``confirm`` residuals inside the Huber band of a well-supported
    pair, ``|r| <= huber * sigma_base``, since the window last restarted: ``reset``), agreeing residuals beyond
    the gate are a stretch of drive where visual odometry fails the same way frame after frame (a
    highway curve with a few far matches: 10 deg for 8 frames), not proof that the estimate is off:
    the estimate did not move and the motion agreed with it. They are admitted only when the network's
    own outputs moved toward them too (``r_net``: the residuals at the network's outputs of those frames;
    their median at most half the estimate's), which a sensor that really moved gives; ``refused`` says
    why a consensus was not taken. After a restart, until the motion has confirmed the new estimate, a pair of few
    image matches (its std grown beyond the base, ``vo_sigma_rad``) is taken only inside a good pair's Huber band:
    the restarted window's gate is wide open, and one failed pair set the yaw for the rest of the drive."""

    def __init__(self, conf: MotionConfig):
        self.conf = conf
        self.recent: list[float] = []
        self.recent_net: list[float] = []
        self.agreed = 0  # residuals inside their own Huber band since the last reset
        self.admitted_by_consensus = False
        self.refused = ""
        self.restarted = False  # the window restarted at a mount step (``reset``)

    def reset(self) -> None:
        """The window restarted (a step alarm): the estimate is a new one, not confirmed by any motion yet."""
        self.recent, self.recent_net, self.agreed, self.restarted = [], [], 0, True

    def admit(self, inn: Innovation, r_net: float | None = None) -> bool:
        c = self.conf
        self.admitted_by_consensus, self.refused = False, ""
        if self.restarted and self.agreed < max(c.confirm, 1) and inn.few_matches and abs(inn.r) > c.huber * inn.band:
            # probe 46: after a restart the window's yaw std is 10-13 deg, the gate is wide open, and the first pairs
            # it took were failed ones of 10-16 matches that set the yaw 6-9 deg off; until the motion confirms the
            # restarted estimate, a pair of few matches is taken only when it agrees as a good pair would
            self.refused = (f"a pair of few image matches (VO std {np.degrees(inn.sigma):.1f} deg) "
                            f"{np.degrees(inn.r):+.1f} deg from an estimate the window restarted at a mount step "
                            "and the motion has not confirmed yet: left out until it has")
            return False
        if inn.inside(c.gate):
            self.recent, self.recent_net = [], []
            # within a well-supported pair's band, whatever this pair's own std (grown for few matches: a residual
            # of 4 deg on 10 matches is inside its Huber band but confirms no estimate to a degree)
            self.agreed += int(abs(inn.r) <= c.huber * inn.band)
            return True
        keep = max(c.consensus, 1)
        self.recent = (self.recent + [inn.r])[-keep:]
        self.recent_net = (self.recent_net + [np.nan if r_net is None else r_net])[-keep:]
        if c.consensus == 0 or len(self.recent) < c.consensus:
            return False
        r = np.asarray(self.recent)
        one_side = bool(np.all(r > 0) or np.all(r < 0))
        agree = bool(np.all(np.abs(r - np.median(r)) <= c.gate * inn.sigma))
        if not (one_side and agree):
            return False
        if c.confirm and self.agreed >= c.confirm:
            net = np.asarray(self.recent_net)
            moved = bool(np.all(np.isfinite(net)) and abs(np.median(net)) <= 0.5 * abs(np.median(r)))
            if not moved:
                self.refused = (f"{len(r)} agreeing residuals beyond the gate (median {np.degrees(np.median(r)):+.1f} "
                                f"deg), but the motion agreed with this estimate at {self.agreed} frames since the "
                                "window last restarted and the network's outputs did not move toward them: visual "
                                "odometry failing on a stretch of road, not a moved sensor")
                return False
        self.admitted_by_consensus = True
        return True


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


def fold(prior: GaussianPrior, T0: np.ndarray, inn: Innovation, conf: MotionConfig,
         gated: bool = True) -> Folded | None:
    """The network prior (``prior``) and the motion residual linearised at ``T0`` (4, 4) (``inn``,
    ``innovation`` at T0) in one Gaussian (module doc), or None when it fails the innovation gate
    ``|r| > gate * std`` (``gated=False``: the caller's ``MotionGate`` decided). ``prior.cov``: (6, 6)
    right tangent, radar frame [rad, m]."""
    from hybrid_calib.geometry import local

    r, J, sigma = inn.r, inn.J, inn.sigma
    if gated and not inn.inside(conf.gate):
        return None
    z = abs(r) / max(sigma, 1e-12)
    w_huber = float(weight("huber", z, conf.huber))
    w = w_huber / sigma ** 2
    L_p = np.linalg.inv(prior.cov)
    mu_p = local(T0, prior.T)
    L_m = w * np.outer(J, J)
    L = L_p + L_m
    L = 0.5 * (L + L.T)
    mu = np.linalg.solve(L, L_p @ mu_p - w * J * r)
    cov = np.linalg.inv(L)
    return Folded(GaussianPrior(retract(T0, mu), 0.5 * (cov + cov.T)), L_m, w * J, float(np.degrees(r)), w_huber)
