"""Extrinsic error metrics (the paper's table plus geodesic angle and translation norm).

Definitions (docs/conventions.md, "Error metrics"):
- Rotation error ``dR = R_est @ R_gt.T`` (a left error, in camera axes). Its camera Euler angles
  ``[roll, pitch, yaw]`` (see ``geometry.camera_euler_from_rotation``) are reported as absolute
  values in degrees; "Mean" is the mean of the three per-axis absolute errors. The geodesic angle
  is ``|log(dR)|``.
- Translation error ``dt = t_est - t_gt`` (translation of ``T_cam_radar``, camera axes) reported as
  absolute values in centimetres; "Mean" is the mean of |dx|, |dy|, |dz|; "norm" is ``|dt|``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from hybrid_calib.geometry import camera_euler_from_rotation, check_transform, is_symmetric, so3_log

CHI2_6_95 = 12.591587243743977  # scipy.stats.chi2.ppf(0.95, 6): NEES below it is inside the 95 % ellipsoid


def mad_scale(x: np.ndarray, floor: float = 0.0) -> float:
    """Robust std of the values ``x`` (any shape): 1.4826 x their median absolute deviation (the std of a Gaussian),
    at least ``floor``; ``floor`` for no values. The scale of every IRLS fit's residuals (same unit as ``x``)."""
    x = np.asarray(x, np.float64).ravel()
    if not len(x):
        return float(floor)
    return max(1.4826 * float(np.median(np.abs(x - np.median(x)))), float(floor))


def nees(xi: np.ndarray, cov: np.ndarray) -> np.ndarray | float:
    """Normalised estimation error squared ``xi^T C^-1 xi`` (6 on average when ``cov`` is honest). ``xi``: (6,) or
    (F, 6) errors in the right tangent [rad, m] of ``T_cam_radar`` (``local(T_true, T_est)``); ``cov``: (6, 6) or
    (F, 6, 6) in the same tangent. A float for one error, (F,) for F."""
    xi, cov = np.asarray(xi, np.float64), np.asarray(cov, np.float64)
    if xi.ndim not in (1, 2) or xi.shape[-1] != 6 or cov.shape != (*xi.shape[:-1], 6, 6):
        raise ValueError(f"nees: xi (6,) or (F, 6) with cov (6, 6) or (F, 6, 6), got xi {xi.shape} and cov {cov.shape}")
    if not (np.isfinite(xi).all() and np.isfinite(cov).all()):
        raise ValueError("nees: xi or cov holds NaN/inf values (probe 67: a NaN error gave NaN, read as no verdict)")
    if not xi.size:
        raise ValueError("nees: no errors given (xi of shape (0, 6))")
    if not is_symmetric(cov):
        raise ValueError("nees: cov is not symmetric (a covariance is; check its order and frame)")
    low = np.linalg.eigvalsh(cov).min(axis=-1) / np.maximum(np.abs(cov).max(axis=(-2, -1)), 1e-300)
    if len(bad := np.flatnonzero(np.atleast_1d(low) < -1e-9)):  # probe 112: a negative variance the error avoided
        which = "" if xi.ndim == 1 else f" (estimate {int(bad[0])} of {len(xi)})"  # gave a plausible NEES of 1
        raise ValueError(f"nees: cov is not positive definite{which} (a negative eigenvalue): not a covariance")
    try:
        if xi.ndim == 1:
            v = np.array([xi @ np.linalg.solve(cov, xi)])
        else:
            v = np.einsum("fi,fi->f", xi, np.linalg.solve(cov, xi[..., None])[..., 0])
    except np.linalg.LinAlgError:  # was a bare "Singular matrix" (probe 51)
        raise ValueError("NEES of a singular covariance: a direction it gives zero variance has no error scale; "
                         "regularise the covariance (calib.covariance.analyse_information) first") from None
    if len(bad := np.flatnonzero(v < 0)):  # a NEES of -3 read as "inside the ellipsoid" (probe 31)
        which = "" if xi.ndim == 1 else f" (estimate {int(bad[0])} of {len(v)})"
        raise ValueError(f"NEES is negative{which}: its covariance is not positive definite")
    return float(v[0]) if xi.ndim == 1 else v


def consistency(nees_values) -> dict:
    """How honest covariances were over a set of estimates, from their NEES (``nees``), the one summary every
    command reports (docs/conventions.md "Error metrics"): ``{"n", "nees_mean" (6 if honest), "nees_median",
    "coverage_95" (the fraction inside the 95 % ellipsoid, NEES < ``CHI2_6_95``; 0.95 if honest)}``."""
    v = np.asarray(nees_values, np.float64).reshape(-1)
    if not len(v):
        return {"n": 0, "nees_mean": None, "nees_median": None, "coverage_95": None}
    if not (np.isfinite(v).all() and (v >= 0).all()):  # a NEES of -5 was "inside the ellipsoid" (probe 67)
        raise ValueError(f"consistency: NEES values must be finite and >= 0 (as ``nees`` returns them), got "
                         f"{v[~(np.isfinite(v) & (v >= 0))][:3].tolist()}")
    return {"n": int(len(v)), "nees_mean": float(v.mean()), "nees_median": float(np.median(v)),
            "coverage_95": float(np.mean(v < CHI2_6_95))}


@dataclass(frozen=True)
class ExtrinsicError:
    """Errors of one estimate. Angles in degrees, translations in centimetres, all >= 0."""

    roll_deg: float
    pitch_deg: float
    yaw_deg: float
    rot_mean_deg: float
    geodesic_deg: float
    x_cm: float
    y_cm: float
    z_cm: float
    trans_mean_cm: float
    trans_norm_cm: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


METRIC_KEYS = tuple(ExtrinsicError.__dataclass_fields__)


# Per-axis standard deviations: ONE definition, and every key names its frame.
# "cam": rotation about camera x, y, z (deg) and the components of t_cam_radar (cm), camera axes
#   (``C_report = B C B^T``, docs/conventions.md "Reported per-axis standard deviations").
# "radar": the right-tangent axes of T_cam_radar [omega, v] themselves (radar frame), deg and cm.
# "ego": the same perturbation about and along the vehicle's axes (an exported radar mount, calib.export).
STD_FRAMES = ("cam", "radar", "ego")
# a transform measured by ``extrinsic_error`` is rigid to this (R R^T = I): a float32 network output passes, a sheared
# or scaled rotation block does not
RIGID_ATOL = 1e-4


def std_keys(frame: str) -> tuple[str, ...]:
    """``(rot_x_<frame>_deg, rot_y_.., rot_z_.., t_x_<frame>_cm, t_y_.., t_z_..)`` for a frame in
    ``STD_FRAMES``."""
    if frame not in STD_FRAMES:
        raise ValueError(f"std frame {frame!r}; valid: {STD_FRAMES}")
    return tuple(f"rot_{a}_{frame}_deg" for a in "xyz") + tuple(f"t_{a}_{frame}_cm" for a in "xyz")


STD_KEYS_CAM = std_keys("cam")
STD_KEYS_RADAR = std_keys("radar")


def std_dict(std: np.ndarray, frame: str) -> dict[str, float]:
    """(6,) [deg x3, cm x3] -> {key: value} with the keys of ``std_keys(frame)``."""
    return {k: float(v) for k, v in zip(std_keys(frame), np.asarray(std, np.float64).reshape(6))}


def std_from_dict(d: dict, frame: str) -> np.ndarray:
    """Inverse of ``std_dict``: (6,) float64; ``KeyError`` names a missing key."""
    return np.array([float(d[k]) for k in std_keys(frame)])


def signed_errors(T_est: np.ndarray, T_gt: np.ndarray) -> np.ndarray:
    """Signed ``[roll, pitch, yaw]`` (rad) and ``[dx, dy, dz]`` (m) errors, (6,), of two (4, 4) ``T_cam_radar``
    (``ValueError`` naming the one that is not a finite rigid transform: a scaled rotation read as 0 error, probe
    67)."""
    T_est, T_gt = (check_transform(T, f"signed_errors {name}", atol=RIGID_ATOL)
                   for name, T in (("T_est", T_est), ("T_gt", T_gt)))
    return _signed_errors(T_est, T_gt)


def _signed_errors(T_est: np.ndarray, T_gt: np.ndarray) -> np.ndarray:
    """``signed_errors`` of checked transforms (``extrinsic_error`` checks them once)."""
    dR = T_est[:3, :3] @ T_gt[:3, :3].T
    return np.concatenate([camera_euler_from_rotation(dR), T_est[:3, 3] - T_gt[:3, 3]])


def extrinsic_error(T_est: np.ndarray, T_gt: np.ndarray) -> ExtrinsicError:
    """Error of a (4, 4) ``T_cam_radar`` estimate against the (4, 4) ground truth (``ValueError`` naming the one
    that is not a finite rigid (4, 4) transform: a NaN was numpy's "SVD did not converge", and a rotation block 5 %
    sheared measured as 0 error (probe 51); a float32 network output's rotation, orthonormal to ~1e-6 only, is
    measured as it is)."""
    T_est, T_gt = (check_transform(T, f"extrinsic_error {name}", atol=RIGID_ATOL)
                   for name, T in (("T_est", T_est), ("T_gt", T_gt)))
    s = _signed_errors(T_est, T_gt)
    rpy = np.degrees(np.abs(s[:3]))
    dt = np.abs(s[3:]) * 100.0
    geo = np.degrees(np.linalg.norm(so3_log(T_est[:3, :3] @ T_gt[:3, :3].T)))
    return ExtrinsicError(
        roll_deg=float(rpy[0]),
        pitch_deg=float(rpy[1]),
        yaw_deg=float(rpy[2]),
        rot_mean_deg=float(rpy.mean()),
        geodesic_deg=float(geo),
        x_cm=float(dt[0]),
        y_cm=float(dt[1]),
        z_cm=float(dt[2]),
        trans_mean_cm=float(dt.mean()),
        trans_norm_cm=float(np.linalg.norm(s[3:]) * 100.0),
    )


def summarize(errors: list[ExtrinsicError]) -> dict[str, float]:
    """Mean of every metric over many estimates (the paper's table rows)."""
    if not errors:
        raise ValueError("summarize() needs at least one ExtrinsicError")
    return {k: float(np.mean([getattr(e, k) for e in errors])) for k in METRIC_KEYS}


def format_table(rows: dict[str, dict[str, float]]) -> str:
    """Plain-text table in the paper's layout: one row per method."""
    head = (
        f"{'method':<22}{'R.Mean':>8}{'Roll':>8}{'Pitch':>8}{'Yaw':>8}{'Geo':>8}"
        f"{'T.Mean':>9}{'X':>8}{'Y':>8}{'Z':>8}{'Norm':>8}"
    )
    lines = [head, "-" * len(head)]
    for name, m in rows.items():
        lines.append(
            f"{name:<22}{m['rot_mean_deg']:8.3f}{m['roll_deg']:8.3f}{m['pitch_deg']:8.3f}"
            f"{m['yaw_deg']:8.3f}{m['geodesic_deg']:8.3f}{m['trans_mean_cm']:9.2f}{m['x_cm']:8.2f}"
            f"{m['y_cm']:8.2f}{m['z_cm']:8.2f}{m['trans_norm_cm']:8.2f}"
        )
    lines.append("(rotation in degrees, translation in cm)")
    return "\n".join(lines)
