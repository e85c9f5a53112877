"""Covariance of the extrinsic you can trust: marginals, reported std, and degeneracy status.

Conventions (docs/conventions.md): a 6x6 covariance ``C`` of ``T_cam_radar`` is in the RIGHT
tangent ``[omega, v]`` (radar frame), rad^2 and m^2. Reports rotate it into camera axes with
``B = blockdiag(R, R)``: ``C_report = B C B^T`` (rotation error in camera axes, and the translation
vector ``t_cam_radar`` itself); std in degrees and centimetres.

Degeneracy is decided from the 6x6 information matrix (the inverse covariance before any
regularisation), analysed in a *physical* basis: each direction is scaled by the tolerance a user
cares about (``rot_tol_deg`` and ``trans_tol_cm``), so "how well is this direction observed" is
comparable between rotation and translation. A direction whose std exceeds ``weak_factor`` times
its tolerance is named as poorly observed; one whose information is numerically zero is
unobservable and gets its covariance from a weak regularising prior, the status saying so.

The status vocabulary (one home, docs/conventions.md): ``ok`` | ``weak: <why>`` | ``degenerate: <why>``
from the information here, and ``inconclusive: <why>`` (``inconclusive_status``) when the input itself
cannot be trusted: too few of a vehicle's frames are inside the learned network's training domain
(``hybrid.ood``). An inconclusive result is never reported as ``ok``, whatever its information.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.calib.degeneracy import AXIS_WORDS, DegeneracyConfig, RowGeometry, explain
from hybrid_calib.geometry import check_covariance, check_transform, se3_exp

AXES = ("x", "y", "z")
# fleet words of the camera axes (docs/conventions.md): rotation about x, y, z; translation along x, y, z
ROT_WORDS = {"x": "pitch", "y": "yaw", "z": "roll"}
TRANS_WORDS = {"x": "lateral", "y": "vertical", "z": "longitudinal"}


@dataclass(frozen=True)
class CovarianceConfig:
    rot_tol_deg: float = 0.1  # rotation accuracy a user needs (deg); sets the physical scale of rotation
    trans_tol_cm: float = 1.0  # translation accuracy a user needs (cm); sets the physical scale of translation
    weak_factor: float = 10.0  # a direction with std > weak_factor * tolerance is "poorly observed"
    unobservable_rel_eig: float = 1e-9  # scaled-information eigenvalue / largest below this: unobservable
    regularise_rot_deg: float = 30.0  # std of the weak prior that replaces an unobservable rotation (deg)
    regularise_trans_m: float = 5.0  # std of the weak prior that replaces an unobservable translation (m)
    degeneracy: DegeneracyConfig = DegeneracyConfig()  # thresholds of the trade-off / geometry words

    def __post_init__(self):
        from hybrid_calib.config import require_ranges

        # a tolerance of 1e-300 made the scaled covariance overflow (``internal error: LinAlgError``: probe 51); no
        # radar-camera calibration needs its rotation to 1e-4 deg or its translation to 10 um
        require_ranges(self, {"rot_tol_deg": "[1e-4, 90]", "trans_tol_cm": "[1e-3, 1000]", "weak_factor": "[1, 1e6]",
                              "unobservable_rel_eig": "[0, 1)", "regularise_rot_deg": "(0, 180]",
                              "regularise_trans_m": "(0, 1000]"})


@dataclass(frozen=True)
class CovarianceReport:
    """Covariance and its reading.

    cov: (6, 6) right-tangent radar-frame covariance [rot rad, trans m]; never over-confident: an
        unobservable direction carries the regularising prior's variance.
    std_report: (6,) [rot x (pitch), rot y (yaw), rot z (roll) in deg, t x, t y, t z in cm], camera axes
        (``C_report = B C B^T``; rotation components are about camera x, y, z).
    status: "ok", "weak: ...", "degenerate: ..." (see ``analyse_information``; ``inconclusive_status`` is
        the fourth word, set by the learned methods, never here).
    regularised: True when the covariance needed the weak prior (pseudo-inverse fallback).
    weak_directions: human-readable names of the poorly observed directions.
    """

    cov: np.ndarray
    std_report: np.ndarray
    status: str
    regularised: bool
    weak_directions: tuple[str, ...]
    condition: float  # condition number of the scaled information matrix



STATUS_WORDS = ("ok", "weak", "degenerate", "inconclusive")  # what a status opens with (docs/conventions.md)
NOT_CONVERGED = "NOT CONVERGED"  # ``schedule.convergence_note``'s mark in a status: the last solve did not converge


def camera_offset(T_ref: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(6,) offset of ``T`` (4, 4) from ``T_ref`` (4, 4) in camera axes, the one definition of every reported
    change (docs/conventions.md "Metrics"): the rotation ``R_ref w`` [deg x3] with ``w`` the rotation part of
    ``local(T_ref, T)`` (= ``R w``: the same axis in either frame), and the translation ``t - t_ref`` itself [cm x3]
    (not the tangent's, which differs by ~|w| |t|: 0.4 cm at 1.5 deg on a half-metre lever, probe 24)."""
    from hybrid_calib.geometry import local

    T_ref, T = np.asarray(T_ref, np.float64), np.asarray(T, np.float64)
    w = T_ref[:3, :3] @ local(T_ref, T)[:3]
    return np.concatenate([np.degrees(w), (T[:3, 3] - T_ref[:3, 3]) * 100.0])


def status_kind(status: str) -> str:
    """The word of ``STATUS_WORDS`` a status opens with ("" for none): the one reading of a status's kind."""
    word = str(status).split(":", 1)[0].split(" ", 1)[0].strip()
    return word if word in STATUS_WORDS else ""


OWN_STATUS = " [the estimate's own status: "  # where an inconclusive status keeps the estimate's own


def inconclusive_status(reason: str, estimate_status: str = "") -> str:
    """``"inconclusive: <reason>"`` with the estimate's own status after it (kept for the record)."""
    return f"inconclusive: {reason}" + (f"{OWN_STATUS}{estimate_status}]" if estimate_status else "")


def inconclusive_why(status: str) -> str:
    """The whole reason of an ``inconclusive_status`` (without the estimate's own status), or "" for another."""
    if status_kind(status) != "inconclusive":
        return ""
    return status[len("inconclusive"):].lstrip(": ").split(OWN_STATUS)[0]


def inconclusive_reason(status: str) -> str:
    """The reason of an ``inconclusive_status`` up to its first ": " (what happened, without the advice after it),
    or "" for another status: a fleet's one-line view names it (a radar knocked 90 deg at the drive's end read only
    "the estimate is not trusted (its status: inconclusive)" there: probe 39)."""
    return inconclusive_why(status).split(": ")[0]


def untrusted_status(status: str) -> str:
    """Why an estimate whose status is ``status`` cannot be trusted, in words ("" when it can): the last solve did
    not converge (``schedule.convergence_note``'s "NOT CONVERGED"), an ``inconclusive_status`` (its reason: the
    network's input out of its domain, a checkpoint without its fitted models, network rows fused without the
    hybrid's model), or the data did not determine it ("degenerate")."""
    if NOT_CONVERGED in status:
        return "the last solve did not converge"
    if status_kind(status) == "inconclusive":
        why = inconclusive_why(status)
        # cut at a word, marked (probe 34: "... check the radar's mount, a)")
        return f"it is not trusted ({why if len(why) <= 300 else why[:300].rsplit(' ', 1)[0] + ' ...'})"
    if status_kind(status) == "degenerate":
        return "the data did not determine it"
    return ""


def report_basis(T_cam_radar: np.ndarray) -> np.ndarray:
    """``B = blockdiag(R, R)`` (6, 6) with R = rotation of ``T_cam_radar`` (radar -> camera axes)."""
    R = np.asarray(T_cam_radar, dtype=np.float64)[:3, :3]
    B = np.zeros((6, 6))
    B[:3, :3] = R
    B[3:, 3:] = R
    return B


def report_cov(T_cam_radar: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """``C_report = B C B^T`` (6, 6): rotation error in camera axes (rad^2) and t_cam_radar (m^2)."""
    B = report_basis(T_cam_radar)
    return B @ _check_cov(cov) @ B.T


def report_std(T_cam_radar: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Per-axis std in the camera frame, (6,): rotation about camera x, y, z in degrees, then
    translation along camera x, y, z in centimetres (docs/conventions.md). A negative variance (a covariance
    that is not positive semidefinite) reads as 0: check a covariance a caller gives with
    ``geometry.check_covariance`` first."""
    # a negative variance is clipped to 0, never raised: raising here ended whole runs in "internal error" on a
    # singular bound (probe 36); the covariances reported are made positive where they are computed
    # (``analyse_information`` reads negative information as unobservable) and checked where a caller gives one
    d = np.sqrt(np.clip(np.diag(report_cov(T_cam_radar, cov)), 0.0, None))
    return np.concatenate([np.degrees(d[:3]), d[3:] * 100.0])


def fold_scalar(T: np.ndarray, cov: np.ndarray, h: np.ndarray, z: float, var: float) -> tuple[np.ndarray, np.ndarray]:
    """(T', cov'): one scalar measurement ``z = h @ xi + n`` (``n`` of variance ``var``) of the right
    perturbation ``xi`` at ``T`` (4, 4), ``cov`` (6, 6) [rotation, translation], folded in by a Kalman update;
    correlated directions move with it. Used by the hybrid's Doppler alignment (``fold_linear`` with one row)."""
    return fold_linear(T, cov, np.asarray(h, np.float64)[None, :], np.array([z], np.float64), np.array([[var]]))


def fold_linear(T: np.ndarray, cov: np.ndarray, H: np.ndarray, z: np.ndarray, R: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(T', cov'): measurements ``z = H xi + n`` (H (k, 6), z (k,), ``n`` of covariance R (k, k)) of the right
    perturbation ``xi`` at ``T`` (4, 4), ``cov`` (6, 6) [rotation, translation], folded in by one Kalman update
    (Joseph form: the covariance stays symmetric and positive); correlated directions move with them."""
    H, z, R = (np.atleast_1d(np.asarray(a, np.float64)) for a in (H, z, R))
    cov = check_covariance(cov, "fold_linear cov", semidefinite=True)
    k = len(z)  # probe 112: a variance of 0, -1e-4 or NaN, or a NaN measurement, gave a NaN extrinsic or a covariance
    # with a negative variance
    if H.shape != (k, 6) or R.shape != (k, k) or not (np.isfinite(H).all() and np.isfinite(z).all()):
        raise ValueError(f"fold_linear: need finite H (k, 6) and z (k,) with R (k, k); got H {H.shape}, z {z.shape}, "
                         f"R {R.shape}")
    if not np.isfinite(R).all() or not np.allclose(R, R.T) or np.linalg.eigvalsh(R).min() <= 0:
        raise ValueError(f"fold_linear: the measurement noise R must be a finite positive definite matrix, got "
                         f"{str(R.tolist())[:60]}")
    S = H @ cov @ H.T + R
    K = np.linalg.solve(0.5 * (S + S.T), H @ cov).T  # (6, k) = cov H^T S^-1
    IKH = np.eye(6) - K @ H
    cov2 = IKH @ cov @ IKH.T + K @ R @ K.T
    return T @ se3_exp(K @ np.asarray(z, np.float64)), 0.5 * (cov2 + cov2.T)


def _check_cov(cov: np.ndarray) -> np.ndarray:
    cov = np.asarray(cov, dtype=np.float64)
    if cov.shape != (6, 6):
        raise ValueError(f"covariance must be (6, 6), got {cov.shape}")
    if not np.all(np.isfinite(cov)):
        raise ValueError("covariance has NaN/inf entries")
    return cov


def _scale(conf: CovarianceConfig) -> np.ndarray:
    """(6,) physical unit of each report axis: tolerance in rad and in m."""
    return np.array([np.radians(conf.rot_tol_deg)] * 3 + [conf.trans_tol_cm / 100.0] * 3)


# (6,) the basis the rank decision ("unobservable") is made in: the default tolerances, whatever the user's. Made in
# the user's, a rotation tolerance of 1e-5 deg against 1 cm called a roll measured to 0.155 deg "unobservable" and
# regularised it (probe 51): what the data cannot see does not depend on the accuracy a user needs
RANK_SCALE = _scale(CovarianceConfig())


def _name_direction(vec_report: np.ndarray) -> str:
    """A unit direction (6,) in the scaled report basis -> "translation along camera z" etc."""
    v = vec_report / np.linalg.norm(vec_report)
    rot, tr = v[:3], v[3:]
    parts = []
    for label, block in (("rotation about", rot), ("translation along", tr)):
        w = block**2
        if w.sum() < 0.15:
            continue
        order = np.argsort(-w)
        axes = [AXES[i] for i in order if w[i] > 0.25 * w.sum()]
        words = "/".join((ROT_WORDS if label == "rotation about" else TRANS_WORDS)[a] for a in axes)
        words += "" if label == "rotation about" else " offset"
        parts.append(f"{words} ({label} camera {'/'.join(axes)})")
    return " coupled with ".join(parts) if parts else "mixed direction"


def _fmt_std(std_scaled: float, vec_report: np.ndarray, conf: CovarianceConfig, Cz: np.ndarray | None = None) -> str:
    """Std of a scaled direction in the unit of its dominant block. A direction that is (90 % or more) one camera
    axis is said with that axis' own std (``Cz``: the scaled report covariance), so the status reads as the axis' std
    of the result and the verdict (probe 24: "pitch ... (std 1.03 deg)" beside the axis' 1.04); a mixed one's std is
    said to be along it."""
    v = vec_report / np.linalg.norm(vec_report)
    i = int(np.argmax(v**2))
    along = ""
    if Cz is not None and v[i] ** 2 >= 0.9:
        std_scaled = float(np.sqrt(max(Cz[i, i], 0.0)))
    elif Cz is not None:
        along = " along that direction"
    if np.sum(v[:3] ** 2) >= np.sum(v[3:] ** 2):
        deg = std_scaled * conf.rot_tol_deg
        return f"std {deg:.3g} deg{along}"
    cm = std_scaled * conf.trans_tol_cm
    return (f"std {cm / 100:.3g} m" if cm >= 100 else f"std {cm:.3g} cm") + along


RADAR_PITCH, RADAR_Z = 1, 5  # right-tangent [omega, v] indices: rotation about radar y, translation along radar z


def prior_pinned_std(factor_conf) -> np.ndarray:
    """(6,) std of the right-tangent directions that only the elevation prior pins (rad, m).

    Under the ``height`` elevation model (``RadarPixelFactorConfig``) two properties of the world
    are assumed, not measured, and the correspondences cannot see them:
    - a common offset ``dh`` of every reflector height: ``p + dh e_z`` is EXACTLY
      ``T Exp([0, dh e_z])`` applied to ``p``, a translation along radar z (index 5), std
      ``reflector_height_mean_std_m``;
    - a tilt ``beta`` of the plane the heights are measured from (the radar's pitch against the
      road, and a height that grows with range because tall objects are only inside the beam far
      away): ``p + beta x e_z`` is, to first order, ``T Exp([-beta e_y, 0])`` applied to ``p`` (the
      remainder ``beta z`` along x is second order), a rotation about radar y (index 1), std
      ``reflector_tilt_std_deg``.
    They are nuisance parameters of the DATA: ``marginalise_prior_pinned`` removes them from the
    correspondences' information (Woodbury), and external priors on ``T_cam_radar`` (e.g. the
    network's) are added afterwards, so such a prior can still pin those directions. Without
    external priors this equals adding their variances to the covariance. Zeros for the other
    models (they fix the elevation distribution by assumption; the elevation study measures the
    cost of that).
    """
    std = np.zeros(6)
    if getattr(factor_conf, "elevation_model", None) == "height":
        std[RADAR_PITCH] = np.radians(factor_conf.reflector_tilt_std_deg)
        std[RADAR_Z] = factor_conf.reflector_height_mean_std_m
    return std


def inflate_prior_pinned(cov: np.ndarray, pinned_std=None) -> np.ndarray:
    """``cov + diag(pinned_std^2)`` (6, 6): the prior-pinned directions of ``prior_pinned_std``."""
    cov = np.array(cov, dtype=np.float64)
    if pinned_std is None:
        return cov
    return cov + np.diag(_checked_pinned_std(pinned_std) ** 2)


def _checked_pinned_std(pinned_std) -> np.ndarray:
    std = np.asarray(pinned_std, dtype=np.float64)
    if std.shape != (6,) or np.any(std < 0) or not np.all(np.isfinite(std)):
        raise ValueError(f"pinned_std must be a finite (6,) vector >= 0, got {std}")
    return std


def marginalise_prior_pinned(info: np.ndarray, pinned_std=None, external_info: np.ndarray | None = None) -> np.ndarray:
    """Information (6, 6) with the prior-pinned nuisance directions marginalised out of the data part.

    info: total information (data + external priors), right tangent [rad, m].
    pinned_std: (6,) std of the nuisance along each right-tangent axis (``prior_pinned_std``).
    external_info: (6, 6) information of priors that do NOT come from the correspondences (the
        network's SE(3), a reference); None = all of ``info`` is data.

    With ``H_d = info - external_info`` and E the pinned axes, the data see ``T Exp(E d)`` with
    ``d ~ N(0, S)``: ``H_d' = H_d - H_d E (S^-1 + E^T H_d E)^-1 E^T H_d`` (Woodbury; valid for a
    singular ``H_d``), and the result is ``H_d' + external_info``. For ``external_info = 0`` its
    inverse is exactly ``inv(info) + E S E^T``.
    """
    info = np.asarray(info, dtype=np.float64)
    if pinned_std is None:
        return info
    std = _checked_pinned_std(pinned_std)
    axes = np.flatnonzero(std > 0)
    if len(axes) == 0:
        return info
    ext = np.zeros((6, 6)) if external_info is None else np.asarray(external_info, dtype=np.float64)
    Hd = info - ext
    HE = Hd[:, axes]
    inner = np.diag(1.0 / std[axes] ** 2) + HE[axes, :]
    Hd_marg = Hd - HE @ np.linalg.solve(inner, HE.T)
    out = Hd_marg + ext
    return 0.5 * (out + out.T)


def marginalise_scene_nuisance(info: np.ndarray, cross: np.ndarray | None = None, prior_std=None,
                               pinned_std=None, external_info: np.ndarray | None = None) -> np.ndarray:
    """Information (6, 6) whose inverse is the covariance of an estimate that held the per-drive scene
    nuisance (``factors.scene``) at its prior mean, after ``marginalise_prior_pinned``.

    info: total information (data + external priors), right tangent [rad, m].
    cross: (6, K) ``J^T W G`` summed over the data rows (``calib.schedule.frame_scene_cross``).
    prior_std: (K,) nuisance std (``factors.scene.scene_prior_std``); None / empty = no scene nuisance.
    pinned_std, external_info: as ``marginalise_prior_pinned``.

    Linearised, the estimate's error is ``info^-1 (J^T W n + cross c)`` with ``c ~ N(0, P)``,
    ``P = diag(prior_std^2)``: the covariance is ``C_pinned + A P A^T`` with ``A = info^-1 cross``
    (Schmidt "consider" covariance; ``info^-1`` the pseudo-inverse on a singular problem, so an
    unobservable direction stays unobservable and is named by ``analyse_information``). Returned in
    information form by Woodbury: ``H - H A (P^-1 + A^T H A)^-1 A^T H``, ``H`` the pinned-marginalised
    information (valid for a singular ``H``). Pass the result to ``analyse_information`` without
    ``pinned_std``.
    """
    H = marginalise_prior_pinned(info, pinned_std, external_info)
    std = np.zeros(0) if prior_std is None else np.asarray(prior_std, dtype=np.float64).reshape(-1)
    if cross is None or not np.any(std > 0):
        return H
    cross = np.asarray(cross, dtype=np.float64)
    if cross.shape != (6, len(std)) or not np.all(np.isfinite(cross)) or np.any(std < 0):
        raise ValueError(f"scene nuisance: cross must be a finite (6, {len(std)}) matrix and prior_std >= 0, "
                         f"got {cross.shape}")
    keep = std > 0
    A = np.linalg.pinv(0.5 * (info + info.T), rcond=1e-12, hermitian=True) @ cross[:, keep]
    HA = H @ A
    inner = np.diag(1.0 / std[keep] ** 2) + A.T @ HA
    out = H - HA @ np.linalg.solve(0.5 * (inner + inner.T), HA.T)
    return 0.5 * (out + out.T)


def scene_config_for(factor_conf, geometry: RowGeometry | None, conf=None):
    """The factor configuration whose scene nuisance (``factors.scene``) holds for these rows: the lateral slope's
    std widened for the few keyframes the rows come from, ``sqrt(s^2 + s_f^2 / n)`` (``scene_lateral_slope_std``,
    ``scene_lateral_slope_frame_std``, ``n = geometry.n_frames``: a short stretch of road sees one roadside, its
    slope has not averaged over a drive), then the three scene stds times ``scene_along_road_factor`` when the rows
    lie along the road (``degeneracy.along_road`` with ``conf.degeneracy``; a straight road); ``factor_conf``
    itself when neither applies (a config it returned stays as it is). The covariance
    (``analyse_drive_information``) and the Cramer-Rao bound of the model used (``crb.oracle_crb``) take the same
    one."""
    import dataclasses

    from hybrid_calib.calib.degeneracy import along_road
    from hybrid_calib.config import merge

    s = float(getattr(factor_conf, "scene_lateral_slope_std", 0.0))
    per_frame = float(getattr(factor_conf, "scene_lateral_slope_frame_std", 0.0))
    n = geometry.n_frames if geometry is not None else 0
    slope = float(np.hypot(s, per_frame / np.sqrt(n))) if s > 0 and per_frame > 0 and n > 0 else s
    k = float(getattr(factor_conf, "scene_along_road_factor", 1.0))
    if k != 1.0 and along_road(geometry, merge(CovarianceConfig, conf).degeneracy) is None:
        k = 1.0
    if k == 1.0 and slope == s:
        return factor_conf
    # both applied: a second call leaves it as it is
    return dataclasses.replace(factor_conf, scene_height_std_m=k * factor_conf.scene_height_std_m,
                               scene_height_sq_std_m2=k * factor_conf.scene_height_sq_std_m2,
                               scene_lateral_slope_std=k * slope, scene_lateral_slope_frame_std=0.0,
                               scene_along_road_factor=1.0)


def analyse_drive_information(
    T_cam_radar: np.ndarray, info: np.ndarray, conf, factor_conf, cov_hint: np.ndarray | None = None,
    external_info: np.ndarray | None = None, scene_cross: np.ndarray | None = None,
    geometry: RowGeometry | None = None,
) -> CovarianceReport:
    """``analyse_information`` with the nuisance of the factor's elevation model removed from the data:
    the prior-pinned directions (``prior_pinned_std(factor_conf)``) and, when enabled and
    ``scene_cross`` (6, K) is given, the per-drive scene nuisance (``marginalise_scene_nuisance``).
    ``geometry``: the rows' ``degeneracy.RowGeometry`` for the status words and the scene prior
    (``scene_config_for``: wider along a straight road). The one entry point of the window and the
    batch solve."""
    from factors.scene import scene_prior_std

    pinned = prior_pinned_std(factor_conf)
    std = scene_prior_std(scene_config_for(factor_conf, geometry, conf))
    if scene_cross is None or not np.any(std > 0):
        return analyse_information(T_cam_radar, info, conf, cov_hint=cov_hint, pinned_std=pinned,
                                   external_info=external_info, geometry=geometry)
    info_n = marginalise_scene_nuisance(info, scene_cross, std, pinned, external_info)
    return analyse_information(T_cam_radar, info_n, conf, pinned_std=pinned, geometry=geometry,
                               pinned_marginalised=True)


def analyse_information(
    T_cam_radar: np.ndarray, info: np.ndarray, conf: CovarianceConfig | None = None,
    cov_hint: np.ndarray | None = None, pinned_std: np.ndarray | None = None,
    external_info: np.ndarray | None = None, geometry: RowGeometry | None = None,
    pinned_marginalised: bool = False,
) -> CovarianceReport:
    """Information (6, 6) in the right/radar tangent -> trustworthy covariance and status.

    info: Gauss-Newton information of the whole problem at the estimate (J^T W J summed, plus
        priors), right tangent, [rad, m] units.
    cov_hint: optional covariance computed elsewhere (e.g. ``gtsam.Marginals``); used when the
        information is well conditioned, so the two agree by construction.

    pinned_std: optional (6,) std (rad, m) of directions only the elevation prior pins
        (``prior_pinned_std``); marginalised out of the data information
        (``marginalise_prior_pinned``) before the directions are read, so a large value is named
        as a poorly observed direction unless an external prior pins it.
    external_info: optional (6, 6) information of the external priors included in ``info``.
    pinned_marginalised: ``info`` already has the ``pinned_std`` nuisance marginalised (e.g. with
        the scene nuisance, ``marginalise_scene_nuisance``); ``pinned_std`` then only names the
        prior-pinned directions in the status.
    geometry: optional ``degeneracy.RowGeometry`` of the rows behind ``info``; its causes (a single
        frame, few rows, one range, one direction, along the road) make the status at least "weak"
        and, with the trade-off pairs of the covariance, are the words after the colon
        (``degeneracy.explain``; thresholds in ``conf.degeneracy``).

    The analysis is done in the scaled report basis ``S^-1 B`` (B = blockdiag(R, R), S = the
    tolerances): eigenvectors of the scaled covariance name the poorly observed directions.
    """
    from hybrid_calib.config import merge

    conf = merge(CovarianceConfig, conf)
    info = np.asarray(info, dtype=np.float64)
    if info.shape != (6, 6) or not np.all(np.isfinite(info)):
        raise ValueError(f"information must be a finite (6, 6) matrix, got "
                         f"{'shape ' + str(info.shape) if info.shape != (6, 6) else 'non-finite entries'}")
    check_transform(T_cam_radar, "analyse_information T_cam_radar", atol=1e-4)  # probe 112: a NaN one was a bare
    # LinAlgError, a scaled one accepted; an information that is not symmetric (beyond rounding) is not one
    if not np.allclose(info, info.T, rtol=1e-6, atol=1e-9 * max(float(np.abs(info).max()), 1e-300)):
        raise ValueError("information must be symmetric (J^T W J is): check its order and frame")
    info = 0.5 * (info + info.T)
    pinned = pinned_std is not None and np.any(np.asarray(pinned_std) > 0)
    if pinned and not pinned_marginalised:
        info = marginalise_prior_pinned(info, pinned_std, external_info)
    if pinned:
        cov_hint = None  # a solver's marginal does not know the nuisance: invert the marginalised information
    B = report_basis(T_cam_radar)
    s = _scale(conf)
    # xi_report = B xi ; scaled z = xi_report / s -> xi = B^T diag(s) z ; info_z = D B info B^T D; the rank decision
    # in RANK_SCALE, the words (weak directions) in the user's tolerances s
    M = np.diag(RANK_SCALE) @ B @ info @ B.T @ np.diag(RANK_SCALE)
    evals, evecs = np.linalg.eigh(M)
    if evals[0] < 0:  # M is congruent to ``info``: the same signs, found without a second decomposition
        # negative information is none: an indefinite matrix (a Schur complement or a subtracted term gone past zero
        # on rows that fit nothing) had its inverse reported as a covariance with a negative variance (probe 36: a
        # rear radar paired with the front camera ended in "internal error"); such directions are unobservable below
        w, V = np.linalg.eigh(info)
        if w[0] < -1e-12 * max(float(np.max(np.abs(w))), 1e-300):
            info = (V * np.clip(w, 0.0, None)) @ V.T
            cov_hint = None
            M = np.diag(RANK_SCALE) @ B @ info @ B.T @ np.diag(RANK_SCALE)
            evals, evecs = np.linalg.eigh(M)
    lam_max = max(float(evals[-1]), 1e-300)
    unobs = evals < conf.unobservable_rel_eig * lam_max
    if not np.any(evals > 0):
        unobs[:] = True
    condition = float(lam_max / max(float(evals[0]), 1e-300))
    regularised = bool(np.any(unobs))
    if regularised:
        # weak prior in the report basis: replaces the unobservable part, leaves the rest unchanged
        prior_std = np.array([np.radians(conf.regularise_rot_deg)] * 3 + [conf.regularise_trans_m] * 3)
        prior_info_report = np.diag(1.0 / prior_std**2)
        info_reg = info + B.T @ prior_info_report @ B
        cov = np.linalg.inv(0.5 * (info_reg + info_reg.T))
    elif cov_hint is not None and np.linalg.eigvalsh(0.5 * ((hint := _check_cov(cov_hint)) + hint.T))[0] >= 0:
        cov = hint  # a solver's marginal, when it is a covariance (else the information's inverse)
    else:
        cov = np.linalg.inv(info)
    cov = 0.5 * (cov + cov.T)
    # directions of large std: eigen-decomposition of the scaled covariance
    Cz = np.diag(1 / s) @ B @ cov @ B.T @ np.diag(1 / s)
    cevals, cevecs = np.linalg.eigh(0.5 * (Cz + Cz.T))
    names, details = [], []
    # the unobservable subspace in the user's scaled coordinates (z_user = z_rank * RANK_SCALE / s), orthonormal
    null = np.linalg.qr(np.diag(RANK_SCALE / s) @ evecs[:, unobs])[0] if regularised else np.zeros((6, 0))
    pinned_axes = pinned_camera_axes(B, pinned_std) if pinned else np.zeros(6, bool)
    for k in range(5, -1, -1):
        std_scaled = float(np.sqrt(max(cevals[k], 0.0)))
        if std_scaled <= conf.weak_factor:
            break
        vec = cevecs[:, k]
        name = _name_direction(vec)
        # is this direction (mostly) in the unobservable subspace?
        in_null = regularised and float(np.sum((null.T @ vec) ** 2)) > 0.5
        names.append(name)
        on_pinned = float(np.sum(vec[pinned_axes] ** 2)) > 0.5
        how = "unobservable" if in_null else "prior-pinned, not measured" if on_pinned else "poorly observed"
        details.append(f"{name} is {how} ({_fmt_std(std_scaled, vec, conf, Cz)})")
    cov_t, observed = _without_pinned(cov, B, pinned_std if pinned else None)
    why, weak = explain(B @ cov_t @ B.T, geometry, conf.degeneracy, regularised or bool(details), observed)
    std = report_std(T_cam_radar, cov)
    if not regularised and (tiny := implausibly_precise(std)):
        why, weak = [*why, tiny], True
    if regularised:
        status = "degenerate: " + "; ".join(why + (details or ["information matrix is singular"]))
        status += " [covariance regularised with a weak prior: those directions are not calibrated]"
    elif weak:
        status = "weak: " + "; ".join(why + details)
    else:
        status = "ok"
    return CovarianceReport(cov, std, status, regularised, tuple(names), condition)


# the smallest 1-sigma any radar-camera calibration can measure (the bounds of CovarianceConfig's tolerances): a
# covariance below it comes from inputs that claim too much (sigma_px in other units, a producer's covariance 1e-30)
MIN_PLAUSIBLE_STD = (1e-4, 1e-3)  # deg, cm


def implausibly_precise(std_report: np.ndarray) -> str:
    """Words when a (6,) ``report_std`` (deg, cm) claims a std below ``MIN_PLAUSIBLE_STD`` on some axis, else "": an
    information matrix of 1e300 * I read "ok" with stds of 1e-148 deg."""
    rot, trans = MIN_PLAUSIBLE_STD
    low = [(AXIS_WORDS[k], float(v), unit) for k, (v, unit) in enumerate(zip(std_report, ["deg"] * 3 + ["cm"] * 3))
           if v < (rot if k < 3 else trans)]
    if not low:
        return ""
    axis, v, unit = low[0]
    return (f"the covariance claims a {axis} std of {v:.2g} {unit}, below what any radar-camera calibration measures "
            f"({rot:g} deg, {trans:g} cm): the inputs claim too much (rows' sigma_px or a network covariance too "
            "small: check their units)")


def _without_pinned(cov: np.ndarray, B: np.ndarray, pinned_std) -> tuple[np.ndarray, np.ndarray]:
    """The covariance (6, 6, radar tangent) conditioned on the prior-pinned directions, and the (6,)
    mask of camera axes that are not mostly prior-pinned: the trade-offs worth naming are between
    the observed axes, not the prior's leakage into them through the mount rotation."""
    if pinned_std is None:
        return cov, np.ones(6, bool)
    std = np.asarray(pinned_std, np.float64)
    E = np.flatnonzero(std > 0)
    cond = cov - cov[:, E] @ np.linalg.pinv(cov[np.ix_(E, E)], hermitian=True) @ cov[E, :]
    return 0.5 * (cond + cond.T), ~pinned_camera_axes(B, std)


def pinned_camera_axes(B: np.ndarray, pinned_std) -> np.ndarray:
    """(6,) bool: the camera report axes (pitch, yaw, roll, lateral, vertical, longitudinal) that a
    prior-pinned right-tangent direction maps to (``report_basis`` B; per pinned direction the axis
    of its largest component: pitch and vertical offset for a forward-looking radar)."""
    out = np.zeros(6, bool)
    if pinned_std is None:
        return out
    for k in np.flatnonzero(_checked_pinned_std(pinned_std) > 0):
        out[int(np.argmax(np.abs(B[:, k])))] = True
    return out


def marginal_covariance(graph, values, key: int) -> tuple[np.ndarray | None, str]:
    """``gtsam.Marginals`` covariance of ``key`` (6, 6), or (None, reason) when GTSAM refuses.

    Catches GTSAM's ``IndeterminantLinearSystemException`` (a ``RuntimeError`` in Python) so a
    degenerate problem never escapes as an unhandled exception.
    """
    import gtsam

    if key not in graph.keys():
        return None, "no factor on the extrinsic (no correspondences, no prior)"
    try:
        m = gtsam.Marginals(graph, values)
        return np.asarray(m.marginalCovariance(key), dtype=np.float64), ""
    except RuntimeError as e:  # gtsam::IndeterminantLinearSystemException and friends
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        return None, f"gtsam.Marginals failed ({first}); using the regularised pseudo-inverse"


def information_from_graph(graph, values, key: int) -> np.ndarray:
    """Gauss-Newton information (6, 6) of ``key`` from the linearised graph (single-key graphs),
    without any Cholesky (so it works on singular problems)."""
    import gtsam

    if key not in graph.keys():  # no factor on the extrinsic (no correspondences, no prior): no information
        return np.zeros((6, 6))
    lin = graph.linearize(values)
    ordering = gtsam.Ordering()
    ordering.push_back(key)
    A, b = lin.jacobian(ordering)
    A = np.asarray(A, dtype=np.float64)
    return A.T @ A


def graph_covariance(graph, values, key: int) -> tuple[np.ndarray, np.ndarray | None, str]:
    """What ``analyse_information`` reads from a solved GTSAM graph: the information (6, 6) of
    ``key`` (``information_from_graph``), its ``gtsam.Marginals`` covariance (6, 6) or None, and
    why that is None ("" otherwise; ``marginal_covariance``)."""
    cov, why = marginal_covariance(graph, values, key)
    return information_from_graph(graph, values, key), cov, why
