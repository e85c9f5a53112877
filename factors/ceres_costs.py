"""The radar-pixel residuals as Ceres cost functions (pyceres 2.6): one Ceres solve and its covariance.

Only residuals, losses and one solve live here; the robust schedule (convex start, redescending
kernel, gated least squares) and the status of the covariance are ``hybrid_calib.calib``'s
(``schedule.run_schedule``, ``covariance.analyse_information``), shared with the GTSAM back end.

Parametrisation (Ceres has no SE(3) manifold): a rotation block ``q`` (4,) in Eigen's storage order
``[x, y, z, w]`` with ``pyceres.EigenQuaternionManifold`` and a translation block ``t`` (3,),
metres, camera frame, Euclidean; ``T_cam_radar = [R(q), t]``. One residual block (2 rows) per
correspondence, each with its own loss function, so the robust weighting is per correspondence
(plus, for the anisotropic model, one loss-free log-determinant block per correspondence).

Covariance conversion. Ceres's quaternion plus is ``q <- [cos|d|, sin|d| d/|d|] * q``: a LEFT
perturbation by the rotation vector ``2 d`` (half-angle units), ``R <- Exp(2 d) R``; the
translation plus is ``t <- t + dt``. Our right perturbation ``T Exp([omega, v])`` gives, to first
order, ``R Exp(omega) = Exp(R omega) R`` and ``t + R v``. Hence ``[d, dt] = A [omega, v]`` with
``A = blockdiag(R/2, R)`` and ``C_ours = B C_ceres B^T``, ``B = A^-1 = blockdiag(2 R^T, R^T)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyceres

from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences
from factors.projection import RowModel, row_model, whitened_rows
from factors.robust import weight
from hybrid_calib.geometry import check_transform, make_T


@dataclass
class CeresStage:
    """One Ceres solve (``solve_ceres_stage``).

    T: (4, 4) estimate of T_cam_radar. usable: Ceres's ``IsSolutionUsable``; message: Ceres's
    message when it is not. summary: Ceres's brief report. The problem and its blocks (q (4,),
    t (3,)) stay alive for ``ceres_covariance``.
    """

    T: np.ndarray
    iterations: int
    final_cost: float
    usable: bool
    message: str
    summary: str
    problem: pyceres.Problem | None  # None when there was nothing to solve
    q: np.ndarray
    t: np.ndarray
    keep: list


def quat_xyzw_from_R(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation -> (4,) Eigen-order quaternion [x, y, z, w], w >= 0."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat()
    return q if q[3] >= 0 else -q


def R_from_quat_xyzw(q: np.ndarray) -> np.ndarray:
    """(4,) [x, y, z, w] (normalised here) -> (3, 3) rotation."""
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def ambient_to_right_tangent(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """d xi / d q (6, 4) and d xi / d t (6, 3) at a unit quaternion q = [x, y, z, w].

    A change dq of q rotates by the left rotation vector ``2 (w dv - dw v + v x dv)``
    (``v = [x, y, z]``; a radial dq does nothing because R(q) normalises q); our right rotation is
    ``R^T`` of it; a change dt is the right translation ``R^T dt``.
    """
    q = np.asarray(q, np.float64) / np.linalg.norm(q)
    v, w = q[:3], q[3]
    R = R_from_quat_xyzw(q)
    S = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    dleft = np.zeros((3, 4))
    dleft[:, :3] = 2 * (w * np.eye(3) + S)
    dleft[:, 3] = -2 * v
    Jq = np.zeros((6, 4))
    Jq[:3] = R.T @ dleft
    Jt = np.zeros((6, 3))
    Jt[3:] = R.T
    return Jq, Jt


def ceres_cov_to_ours(C_ceres: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(6, 6) covariance of Ceres's tangent [d (half-angle, left), dt] -> our right tangent."""
    B = np.zeros((6, 6))
    B[:3, :3], B[3:, 3:] = 2 * R.T, R.T
    return B @ C_ceres @ B.T


class FrameEvaluator:
    """Vectorised evaluation of all rows of a frame at one parameter value, cached, so the N
    per-correspondence residual blocks of a frame cost one numpy pass per Ceres evaluation.

    ``evaluate(q, t)`` returns ``e`` (N, 2), ``Jq`` (N, 2, 4), ``Jt`` (N, 2, 3), ``ld`` (N,),
    ``Jldq`` (N, 4), ``Jldt`` (N, 3) for ``q = [x, y, z, w]`` (4,), ``t`` (3,) metres.
    """

    def __init__(self, rows: RowModel):
        self.rows = rows
        self._key: bytes | None = None
        self._val = None

    def evaluate(self, q: np.ndarray, t: np.ndarray):
        key = np.concatenate([q, t]).tobytes()
        if key != self._key:
            e, J, _, ld, Jld = whitened_rows(make_T(R_from_quat_xyzw(q), t), self.rows)
            Aq, At = ambient_to_right_tangent(q)
            self._val = (e, J @ Aq, J @ At, ld, Jld @ Aq, Jld @ At)
            self._key = key
        return self._val


def _write(residuals, jacobians, r, Jq, Jt) -> bool:
    residuals[:] = r
    if jacobians is not None:
        if jacobians[0] is not None:
            jacobians[0][:] = Jq.reshape(-1)
        if jacobians[1] is not None:
            jacobians[1][:] = Jt.reshape(-1)
    return True


class _RowCost(pyceres.CostFunction):
    """A cost of ONE correspondence on blocks [q (4,), t (3,)]: ``Cost(rows)`` for a single-row
    ``RowModel``, or ``Cost(evaluator, i)`` for row i of a shared ``FrameEvaluator``."""

    n_residuals = 0

    def __init__(self, rows: RowModel | FrameEvaluator, index: int = 0):
        super().__init__()
        if isinstance(rows, RowModel):
            if len(rows) != 1:
                raise ValueError(f"{type(self).__name__}(RowModel) takes exactly one correspondence row")
            rows = FrameEvaluator(rows)
        self.ev, self.i = rows, int(index)
        self.set_num_residuals(self.n_residuals)
        self.set_parameter_block_sizes([4, 3])


class RadarPixelCost(_RowCost):
    """Whitened residual (2,) of ONE correspondence (before the loss) on blocks [q (4,), t (3,)]."""

    n_residuals = 2

    def Evaluate(self, parameters, residuals, jacobians):  # noqa: N802 (Ceres API name)
        e, Jq, Jt, _, _, _ = self.ev.evaluate(parameters[0], parameters[1])
        return _write(residuals, jacobians, e[self.i], Jq[self.i], Jt[self.i])


class LogDetCost(_RowCost):
    """The anisotropic model's log-determinant row ``sqrt(log(1 + |q|^2))`` (1,) of ONE
    correspondence on blocks [q, t]; added without a loss (it is not a residual to robustify)."""

    n_residuals = 1

    def Evaluate(self, parameters, residuals, jacobians):  # noqa: N802 (Ceres API name)
        _, _, _, ld, Jq, Jt = self.ev.evaluate(parameters[0], parameters[1])
        return _write(residuals, jacobians, ld[self.i : self.i + 1], Jq[self.i], Jt[self.i])


class _PythonLoss(pyceres.LossFunction):
    """Ceres loss for kernels pyceres does not expose. Ceres's convention: ``rho(s2)`` of the
    squared norm with cost ``rho/2``; so ``rho = 2 rho_ours(sqrt(s2))``, ``rho' = w``, ``rho'' = dw/ds2``."""

    def __init__(self, kernel: str, scale: float):
        super().__init__()
        self.kernel, self.c = kernel, float(scale)

    def Evaluate(self, s2, rho):  # noqa: N802 (Ceres API name)
        from factors.robust import rho as rho_fn

        s = np.sqrt(max(s2, 0.0))
        c2 = self.c * self.c
        rho[0] = 2.0 * float(rho_fn(self.kernel, np.array(s), self.c))
        rho[1] = float(weight(self.kernel, np.array(s), self.c))
        if self.kernel == "tukey":
            rho[2] = -2.0 * (1.0 - s2 / c2) / c2 if s2 <= c2 else 0.0
        else:  # geman_mcclure
            rho[2] = -2.0 * c2 * c2 / (c2 + s2) ** 3


def ceres_loss(kernel: str, scale: float):
    """The Ceres loss matching ``factors.robust`` (same cost ``rho``), or None for ``none``."""
    if kernel == "none":
        return None
    if kernel == "huber":
        return pyceres.HuberLoss(scale)
    if kernel == "cauchy":
        return pyceres.CauchyLoss(scale)
    if kernel in ("tukey", "geman_mcclure"):
        return _PythonLoss(kernel, scale)
    raise ValueError(f"unknown kernel {kernel!r}")


class _PriorCost(pyceres.CostFunction):
    """Prior ``L^T Log(T_prior^-1 T)`` (6,), L L^T = cov^-1; Jacobian via the right Jacobian inverse."""

    def __init__(self, T_prior: np.ndarray, cov: np.ndarray):
        super().__init__()
        self.T_prior = np.asarray(T_prior, np.float64)
        self.sqrt_info = np.linalg.cholesky(np.linalg.inv(cov)).T
        self.set_num_residuals(6)
        self.set_parameter_block_sizes([4, 3])

    def evaluate_numpy(self, q, t):
        import gtsam

        T = make_T(R_from_quat_xyzw(q), t)
        err = gtsam.Pose3(self.T_prior).localCoordinates(gtsam.Pose3(T))
        # d Log(T0^-1 T) / d xi  (xi: right tangent of T) = Jr^-1(err)
        Jr_inv = np.linalg.inv(gtsam.Pose3.ExpmapDerivative(err)) if np.linalg.norm(err) > 0 else np.eye(6)
        Jq, Jt = ambient_to_right_tangent(q)
        r = self.sqrt_info @ err
        return r, self.sqrt_info @ Jr_inv @ Jq, self.sqrt_info @ Jr_inv @ Jt

    def Evaluate(self, parameters, residuals, jacobians):  # noqa: N802
        return _write(residuals, jacobians, *self.evaluate_numpy(parameters[0], parameters[1]))


def build_problem(frames: list[Correspondences], q: np.ndarray, t: np.ndarray, conf: RadarPixelFactorConfig,
                  prior: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[pyceres.Problem, list]:
    """A Ceres problem over the blocks q, t (modified in place by a solve). Returns (problem, keep-alive)."""
    problem = pyceres.Problem()
    keep = []
    for corr in frames:
        rows = row_model(corr, conf)
        ev = FrameEvaluator(rows)
        keep.append(ev)
        for i in range(len(rows)):
            cost = RadarPixelCost(ev, i)
            loss = ceres_loss(conf.kernel, conf.kernel_scale)
            keep += [cost, loss]
            problem.add_residual_block(cost, loss, [q, t])
            if rows.kappa[i] > 0:
                ld = LogDetCost(ev, i)
                keep.append(ld)
                problem.add_residual_block(ld, None, [q, t])
    if prior is not None:
        cost = _PriorCost(prior[0], prior[1])
        keep.append(cost)
        problem.add_residual_block(cost, None, [q, t])
    problem.set_manifold(q, pyceres.EigenQuaternionManifold())
    return problem, keep


def solve_ceres_stage(frames: list[Correspondences], T_init: np.ndarray, conf: RadarPixelFactorConfig,
                      prior: tuple[np.ndarray, np.ndarray] | None = None, max_iterations: int = 50) -> CeresStage:
    """One Ceres solve of ``frames`` with ``conf``'s kernel on every row, from ``T_init`` (4, 4).

    prior: optional ``(T_prior (4, 4), cov (6, 6))`` in our right tangent. Dense QR, Ceres's
    function / gradient / parameter tolerances 1e-12 (it stops on ``max_iterations`` or there).
    Never raises for a singular problem: ``usable`` is False and ``message`` says why.
    """
    T_init = check_transform(T_init, "solve_ceres_stage T_init")  # NaN ended in numpy's "SVD did not converge"
    q = quat_xyzw_from_R(T_init[:3, :3]).copy()
    t = T_init[:3, 3].copy()
    if prior is None and sum(len(f) for f in frames) == 0:
        return CeresStage(T_init, 0, float("nan"), False, "no correspondences", "", None, q, t, [])
    problem, keep = build_problem(frames, q, t, conf, prior)
    options = pyceres.SolverOptions()
    options.max_num_iterations = int(max_iterations)
    options.function_tolerance = 1e-12
    options.gradient_tolerance = 1e-12
    options.parameter_tolerance = 1e-12
    options.linear_solver_type = pyceres.LinearSolverType.DENSE_QR
    summary = pyceres.SolverSummary()
    pyceres.solve(options, problem, summary)
    usable = bool(summary.IsSolutionUsable())
    return CeresStage(make_T(R_from_quat_xyzw(q), t), summary.num_successful_steps + summary.num_unsuccessful_steps,
                      float(summary.final_cost), usable, "" if usable else str(summary.message),
                      summary.BriefReport(), problem, q, t, keep)


def ceres_covariance(stage: CeresStage) -> np.ndarray | None:
    """(6, 6) covariance of a solved stage in OUR convention (right tangent [rot rad, trans m]), from
    ``pyceres.Covariance`` (sparse QR: no pseudo-inverse), or None when Ceres cannot give a
    positive definite one (rank-deficient problem); what that means is read from the information
    (``hybrid_calib.calib.covariance``)."""
    q, t, problem = stage.q, stage.t, stage.problem
    copts = pyceres.CovarianceOptions()
    copts.algorithm_type = pyceres.CovarianceAlgorithmType.SPARSE_QR  # fails on rank deficiency
    engine = pyceres.Covariance(copts)
    if not engine.compute([(q, q), (q, t), (t, t)], problem):
        return None
    Cqq = np.asarray(engine.get_covariance_block_tangent_space(q, q, problem))
    Cqt = np.asarray(engine.get_covariance_block_tangent_space(q, t, problem))
    Ctt = np.asarray(engine.get_covariance_block_tangent_space(t, t, problem))
    cov = ceres_cov_to_ours(np.block([[Cqq, Cqt], [Cqt.T, Ctt]]), stage.T[:3, :3])
    if np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() <= 0:
        return None
    return cov
