"""SE(3) / SO(3) helpers in numpy, matching GTSAM's conventions exactly.

Conventions (see docs/conventions.md):
- A transform ``T_a_b`` is a (4, 4) float64 homogeneous matrix that maps points expressed in
  frame ``b`` into frame ``a``: ``p_a = T_a_b @ [p_b, 1]``.
- Tangent vectors are ``xi = [omega, v]`` (rotation first, radians then metres), exactly as
  ``gtsam.Pose3.Expmap``.
- Perturbations are on the right: ``retract(T, xi) = T @ exp(xi)`` and
  ``local(T1, T2) = log(T1^-1 @ T2)``, as ``gtsam.Pose3.retract`` / ``localCoordinates``.
- Quaternions in files follow nuScenes: ``[w, x, y, z]``.

The helpers take checked input and do not check it again (they run in the solvers' inner loops): a value from
outside (a user's, a file's) goes through ``check_transform`` / ``check_covariance`` first, as every typed entry
point does; ``se3_log`` of a scaled matrix, say, is not a meaningful number.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

_EPS = 1e-10


def skew(w: np.ndarray) -> np.ndarray:
    """(3,) -> (3, 3) cross-product matrix, ``skew(a) @ b == cross(a, b)``."""
    w = np.asarray(w, dtype=np.float64)
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) radians -> rotation matrix (3, 3)."""
    return Rotation.from_rotvec(np.asarray(omega, dtype=np.float64)).as_matrix()


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> rotation vector (3,) radians."""
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec()


def _left_jacobian(omega: np.ndarray) -> np.ndarray:
    """SO(3) left Jacobian V(omega), (3, 3): translation part of the SE(3) exponential."""
    theta = float(np.linalg.norm(omega))
    W = skew(omega)
    if theta < 1e-6:
        return np.eye(3) + 0.5 * W + W @ W / 6.0
    return (
        np.eye(3)
        + (1.0 - np.cos(theta)) / theta**2 * W
        + (theta - np.sin(theta)) / theta**3 * (W @ W)
    )


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) and translation (3,) metres -> (4, 4) transform."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """Tangent ``[omega, v]`` (6,) -> (4, 4), identical to ``gtsam.Pose3.Expmap``."""
    xi = np.asarray(xi, dtype=np.float64).reshape(6)
    omega, v = xi[:3], xi[3:]
    return make_T(so3_exp(omega), _left_jacobian(omega) @ v)


def se3_log(T: np.ndarray) -> np.ndarray:
    """(4, 4) -> tangent ``[omega, v]`` (6,), identical to ``gtsam.Pose3.Logmap``."""
    T = np.asarray(T, dtype=np.float64)
    omega = so3_log(T[:3, :3])
    v = np.linalg.solve(_left_jacobian(omega), T[:3, 3])
    return np.concatenate([omega, v])


def is_rigid(T: np.ndarray, atol: float = 1e-6) -> bool:
    """Whether a finite (4, 4) ``T`` is a rigid transform: an orthonormal, right-handed rotation block (to ``atol``)
    and a last row [0, 0, 0, 1]."""
    R = T[:3, :3]
    return bool(np.allclose(R.T @ R, np.eye(3), atol=atol) and np.linalg.det(R) > 0
                and np.allclose(T[3], [0, 0, 0, 1], atol=atol))


def check_finite_array(x, shape: tuple, name: str, what: str) -> np.ndarray:
    """``x`` as a float64 array of ``shape``, or ``ValueError`` naming ``name`` (``what``: transform, covariance)."""
    try:
        x = np.array(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{name}: not a {shape} array of numbers ({e})") from None
    if x.shape != shape:
        raise ValueError(f"{name}: expected a finite {shape} {what}, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name}: {what} holds non-finite values (NaN/inf)")
    return x


def check_transform(T, name: str, atol: float = 1e-6) -> np.ndarray:
    """``T`` as a float64 (4, 4) array, or ``ValueError`` naming ``name`` when it is not a finite rigid transform
    (shape, NaN/inf, a rotation block that is not a proper rotation to ``atol``, a last row other than [0, 0, 0, 1]):
    the one check of a transform a caller passes in (a start, a reference, a prior's mean)."""
    T = check_finite_array(T, (4, 4), name, "transform")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=atol) or np.linalg.det(R) < 0:
        raise ValueError(f"{name}: rotation block is not a proper rotation (R R^T = I, det +1)")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise ValueError(f"{name}: last row is {T[3].tolist()}, not [0, 0, 0, 1]")
    return T


def is_symmetric(cov: np.ndarray) -> bool:
    """Whether ``cov`` ((..., n, n)) is symmetric to the tolerance every covariance check uses (rtol 1e-9, atol
    1e-15 of its largest entry, at least 1)."""
    cov = np.asarray(cov, np.float64)
    return bool(np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=1e-9, atol=1e-15 * max(1.0, float(np.abs(cov).max()))))


def check_covariance(cov, name: str, semidefinite: bool = False) -> np.ndarray:
    """``cov`` as a float64 (6, 6) array, or ``ValueError`` naming ``name`` when it is not a finite symmetric
    positive definite matrix (``semidefinite``: a zero eigenvalue allowed, not an all-zero matrix): the one check of a
    covariance a caller passes in (a prior, an estimate's to test or average)."""
    cov = check_finite_array(cov, (6, 6), name, "covariance")
    scale = max(1.0, float(np.abs(cov).max()))
    if not is_symmetric(cov):
        raise ValueError(f"{name}: covariance is not symmetric")
    low = float(np.linalg.eigvalsh(cov).min())
    if (low < -1e-12 * scale or not np.any(cov)) if semidefinite else low <= 0:
        raise ValueError(f"{name}: covariance is not positive {'semi' if semidefinite else ''}definite (smallest "
                         f"eigenvalue {low:.3g}; use a large variance for a free axis)")
    return cov


def nearest_rigid(T: np.ndarray) -> np.ndarray:
    """(4, 4) ``T`` with its rotation block replaced by the nearest rotation (SVD, Frobenius norm) and the last row
    [0, 0, 0, 1]: e.g. a float32 network output, orthonormal only to ~1e-7, made exact in float64."""
    T = np.array(T, dtype=np.float64)
    U, _, Vt = np.linalg.svd(T[:3, :3])
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    T[:3, :3] = U @ D @ Vt
    T[3] = [0.0, 0.0, 0.0, 1.0]
    return T


def se3_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a (4, 4) rigid transform."""
    R, t = T[:3, :3], T[:3, 3]
    return make_T(R.T, -R.T @ t)


def retract(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Right perturbation ``T @ exp(xi)`` (GTSAM ``Pose3.retract`` with the full Expmap)."""
    return np.asarray(T, dtype=np.float64) @ se3_exp(xi)


def local(T1: np.ndarray, T2: np.ndarray) -> np.ndarray:
    """``log(T1^-1 @ T2)`` (6,): the right-tangent from T1 to T2."""
    return se3_log(se3_inverse(T1) @ T2)


def local_many(T1: np.ndarray, Ts: np.ndarray) -> np.ndarray:
    """``local(T1, T)`` for each of ``Ts`` (F, 4, 4) at once -> (F, 6) (the per-transform call was the whole cost of
    averaging a long drive's estimates; probe 57)."""
    D = np.einsum("ij,fjk->fik", se3_inverse(np.asarray(T1, np.float64)), np.asarray(Ts, np.float64))
    omega = Rotation.from_matrix(D[:, :3, :3]).as_rotvec().reshape(-1, 3)
    theta = np.linalg.norm(omega, axis=1)
    W = np.zeros((len(D), 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -omega[:, 2], omega[:, 1], -omega[:, 0]
    W -= W.transpose(0, 2, 1)
    small = theta < 1e-6
    th = np.where(small, 1.0, theta)
    # V^-1 = I - W / 2 + (1 / theta^2 - (1 + cos theta) / (2 theta sin theta)) W^2 (1/12 as theta -> 0)
    c = np.where(small, 1.0 / 12.0, 1.0 / th**2 - (1.0 + np.cos(th)) / (2.0 * th * np.sin(th)))
    Vinv = np.eye(3) - 0.5 * W + c[:, None, None] * (W @ W)
    return np.concatenate([omega, np.einsum("fij,fj->fi", Vinv, D[:, :3, 3])], axis=1)


def adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) adjoint for ``[omega, v]`` ordering: ``T exp(xi) = exp(Ad_T xi) T``.

    Maps a right (body-frame) perturbation of ``T_a_b`` into the equivalent left perturbation,
    expressed in frame ``a``. Covariances transform as ``Ad @ C @ Ad.T``.
    """
    R, t = T[:3, :3], T[:3, 3]
    Ad = np.zeros((6, 6))
    Ad[:3, :3] = R
    Ad[3:, 3:] = R
    Ad[3:, :3] = skew(t) @ R
    return Ad


def without_motion(T: np.ndarray, N: np.ndarray, cov: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray | None]:
    """(``T N^-1``, ``Ad_N cov Ad_N^T``): an estimate ``T`` ((4, 4), or a stack (K, 4, 4)) of a frame's transform
    ``X N`` read as one of ``X``, with its right-perturbation covariance (6, 6) (None: none), since
    ``T Exp(xi) N^-1 = T N^-1 Exp(Ad_N xi)``; ``N`` (4, 4) the radar's motion between its and the camera's timestamps
    (docs/conventions.md "Transforms")."""
    N = np.asarray(N, np.float64)
    A = adjoint(N)
    return np.asarray(T) @ se3_inverse(N), None if cov is None else A @ np.asarray(cov) @ A.T


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply (4, 4) ``T_a_b`` to points (N, 3) in frame b -> (N, 3) in frame a."""
    points = np.asarray(points, dtype=np.float64)
    return points @ T[:3, :3].T + T[:3, 3]


def project_points(K: np.ndarray, T: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection (no distortion) of points (N, 3) in frame b through ``T_cam_b`` (4, 4) and
    ``K`` (3, 3) -> pixels (N, 2) and camera depth z (N,). Points behind the camera are projected
    as the formula gives them (mirrored); callers mask with ``z``."""
    q = transform_points(T, points)
    z = q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (q[:, :2] / z[:, None]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    return uv, z


def quat_wxyz_to_matrix(q: np.ndarray) -> np.ndarray:
    """nuScenes quaternion ``[w, x, y, z]`` -> rotation matrix (3, 3). Normalises the input."""
    q = np.asarray(q, dtype=np.float64).reshape(4)
    n = np.linalg.norm(q)
    if not np.isfinite(n) or n < _EPS:
        raise ValueError(f"invalid quaternion {q.tolist()}: norm {n}")
    w, x, y, z = q / n
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def matrix_to_quat_wxyz(R: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) -> quaternion ``[w, x, y, z]`` with w >= 0."""
    x, y, z, w = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def pose_from_nuscenes(rotation_wxyz, translation) -> np.ndarray:
    """A nuScenes record's ``rotation`` and ``translation`` -> (4, 4) (child -> parent)."""
    return make_T(quat_wxyz_to_matrix(rotation_wxyz), np.asarray(translation, dtype=np.float64))


def pose_to_nuscenes(T: np.ndarray) -> tuple[list[float], list[float]]:
    """(4, 4) -> (``rotation`` [w, x, y, z], ``translation`` [x, y, z]) lists for a JSON record."""
    return matrix_to_quat_wxyz(T[:3, :3]).tolist(), T[:3, 3].astype(float).tolist()


def to_gtsam(T: np.ndarray):
    """(4, 4) -> ``gtsam.Pose3``."""
    import gtsam

    return gtsam.Pose3(np.asarray(T, dtype=np.float64))


def from_gtsam(pose) -> np.ndarray:
    """``gtsam.Pose3`` -> (4, 4)."""
    return np.asarray(pose.matrix(), dtype=np.float64)


# Nominal axis permutation from a radar frame (x forward, y left, z up) into a camera frame
# (x right, y down, z forward). ``R_cam_radar = R_delta @ R_AXES`` defines the reported angles.
R_AXES_CAM_FROM_RADAR = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def camera_euler_from_rotation(R_delta: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) expressed in camera axes -> ``[roll, pitch, yaw]`` radians.

    ``R_delta = Ry(yaw) @ Rx(pitch) @ Rz(roll)`` (intrinsic Y-X-Z): roll turns about the optical
    axis (camera z), pitch about camera x (right), yaw about camera y (down). At a pitch of +-90 deg only
    yaw -+ roll is defined: roll reads 0 there (docs/conventions.md; scipy's "Gimbal lock" warning, which leaked
    onto the terminal with its source line, probe 118, is not passed on).
    """
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        yaw, pitch, roll = Rotation.from_matrix(np.asarray(R_delta, dtype=np.float64)).as_euler("YXZ")
    return np.array([roll, pitch, yaw])


def rotation_from_camera_euler(rpy: np.ndarray) -> np.ndarray:
    """``[roll, pitch, yaw]`` radians -> ``Ry(yaw) @ Rx(pitch) @ Rz(roll)`` (3, 3)."""
    roll, pitch, yaw = np.asarray(rpy, dtype=np.float64).reshape(3)
    return Rotation.from_euler("YXZ", [yaw, pitch, roll]).as_matrix()


def perturb_camera_frame(T_cam_radar: np.ndarray, rpy: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Mis-calibrate an extrinsic: rotate by ``[roll, pitch, yaw]`` (rad, camera axes) on the left
    and add ``dt`` (3,) metres to the translation. Used to sample R1/R2 starts."""
    T = np.array(T_cam_radar, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = rotation_from_camera_euler(rpy) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + np.asarray(dt, dtype=np.float64)
    return out
