"""Solving radar-pixel graphs with GTSAM: LM with an explicit status, the two-stage robust schedule,
marginal covariance that never raises, and the names of poorly observed directions.

Why two stages: a convex kernel (Huber) has one basin, so it converges from far starts (R2), but
with 20 % gross outliers its estimate stays biased (every outlier still pulls with force ``c``); a
redescending kernel (Cauchy, Tukey, Geman-McClure) ignores gross outliers but has local minima
away from the truth. ``solve_gnc`` runs the convex kernel first, then the configured kernel from
its result.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import gtsam
import numpy as np

from factors.config import RadarPixelFactorConfig, SolverConfig
from factors.correspondences import Correspondences
from factors.gtsam_factors import extrinsic_prior_factor, radar_pixel_factor

# Names of the six directions of the report frame (camera axes, docs/conventions.md).
DEFAULT_SOLVER = SolverConfig()
AXIS_NAMES = ("pitch(rot x_cam)", "yaw(rot y_cam)", "roll(rot z_cam)", "x_cam", "y_cam", "z_cam")


@dataclass
class SolveResult:
    """Outcome of a solve.

    T: (4, 4) estimate of T_cam_radar. cov: (6, 6) marginal covariance in the right radar-frame
    tangent [rot rad, trans m] (docs/conventions.md), or None when the information is singular.
    status: "ok", "poorly_observed" (cov given but some directions are weak, see
    ``poorly_observed``), "indeterminant" (cov None) or "failed: <reason>".
    poorly_observed: names of weak directions in camera axes, e.g. ("pitch(rot x_cam)+z_cam",).
    """

    T: np.ndarray
    cov: np.ndarray | None
    status: str
    poorly_observed: tuple[str, ...]
    iterations: int
    final_error: float
    values: gtsam.Values | None = None


def lm_params(solver: SolverConfig) -> gtsam.LevenbergMarquardtParams:
    p = gtsam.LevenbergMarquardtParams()
    p.setMaxIterations(solver.max_iterations)
    p.setRelativeErrorTol(solver.relative_error_tol)
    p.setAbsoluteErrorTol(solver.absolute_error_tol)
    p.setlambdaUpperBound(1e12)
    return p


def optimize(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
             solver: SolverConfig = DEFAULT_SOLVER) -> tuple[gtsam.Values, str, int, float]:
    """Levenberg-Marquardt; returns (values, status "ok" | "failed: ...", iterations, final error).

    Never raises for a singular system: GTSAM's IndeterminantLinearSystemException (and any
    RuntimeError from the solver) becomes status "failed: indeterminant ..." with the input values.
    """
    try:
        opt = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params(solver))
        out = opt.optimize()
        return out, "ok", int(opt.iterations()), float(graph.error(out))
    except RuntimeError as exc:  # gtsam raises IndeterminantLinearSystemException as RuntimeError
        kind = "indeterminant" if "ndeterminant" in str(exc) else "error"
        return values, f"failed: {kind}: {str(exc).splitlines()[0][:200]}", 0, float("nan")


def solve_gnc(build_graph: Callable[[str, float], gtsam.NonlinearFactorGraph], values: gtsam.Values,
              kernel: str, kernel_scale: float, solver: SolverConfig = DEFAULT_SOLVER
              ) -> tuple[gtsam.Values, str, int, float]:
    """Two-stage robust schedule: ``solver.convex_kernel`` from ``values``, then ``kernel``.

    build_graph(kernel, scale) must return the graph with that kernel on every radar-pixel factor.
    Returns like ``optimize`` (iterations summed over both stages).
    """
    stage1, status, it1, _ = optimize(build_graph(solver.convex_kernel, solver.convex_scale), values, solver)
    if status != "ok":
        return stage1, status, it1, float("nan")
    if kernel == solver.convex_kernel and kernel_scale == solver.convex_scale:
        graph = build_graph(kernel, kernel_scale)
        return stage1, status, it1, float(graph.error(stage1))
    out, status, it2, err = optimize(build_graph(kernel, kernel_scale), stage1, solver)
    return out, status, it1 + it2, err


def _dense_information(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, key: int) -> np.ndarray:
    """Information of ``key`` (6, 6) after marginalising every other key (Schur complement, dense)."""
    keys = [k for k in values.keys() if k != key] + [key]
    H, _ = graph.linearize(values).hessian(gtsam.Ordering(keys))
    H = 0.5 * (H + H.T)
    if H.shape[0] == 6:
        return H
    A, B, C = H[:-6, :-6], H[:-6, -6:], H[-6:, -6:]
    return C - B.T @ np.linalg.pinv(A) @ B


def weak_directions(info: np.ndarray, T_cam_radar: np.ndarray, solver: SolverConfig = DEFAULT_SOLVER
                    ) -> tuple[str, ...]:
    """Names of poorly observed directions of a (6, 6) information in our right radar tangent.

    The information is rotated into camera axes (``B = blockdiag(R, R)``, docs/conventions.md). A
    direction is weak when its eigenvalue is below ``min_eigen_ratio`` times the largest, or when
    its standard deviation exceeds ``max_std_deg`` / ``max_std_m``. Translations are scaled by 1 m
    per radian for the eigen-analysis. Names list the components with |coefficient| > 0.3.
    """
    R = np.asarray(T_cam_radar)[:3, :3]
    B = np.zeros((6, 6))
    B[:3, :3], B[3:, 3:] = R, R
    Hc = B @ info @ B.T
    lam, V = np.linalg.eigh(0.5 * (Hc + Hc.T))
    names = []
    lam_max = max(lam.max(), 1e-300)
    for i in range(6):
        v = V[:, i]
        rot = np.linalg.norm(v[:3]) >= np.linalg.norm(v[3:])
        limit = np.deg2rad(solver.max_std_deg) if rot else solver.max_std_m
        std = 1.0 / np.sqrt(lam[i]) if lam[i] > 0 else np.inf
        if lam[i] < solver.min_eigen_ratio * lam_max or std > limit:
            parts = [f"{'+' if v[j] > 0 else '-'}{AXIS_NAMES[j]}" for j in np.argsort(-np.abs(v)) if abs(v[j]) > 0.3]
            names.append("".join(parts).lstrip("+"))
    return tuple(names)


def marginal_covariance(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, key: int,
                        solver: SolverConfig = DEFAULT_SOLVER) -> tuple[np.ndarray | None, str, tuple[str, ...]]:
    """(cov (6, 6) or None, status, weak direction names) of ``key``; never raises.

    status: "ok", "poorly_observed" (covariance returned, honest but large in the named
    directions) or "indeterminant" (singular information: no covariance, directions named).
    """
    T = values.atPose3(key).matrix()
    try:
        info = _dense_information(graph, values, key)
    except RuntimeError as exc:
        return None, f"failed: {str(exc).splitlines()[0][:200]}", ()
    weak = weak_directions(info, T, solver)
    lam = np.linalg.eigvalsh(info)
    if lam.min() <= solver.min_eigen_ratio * max(lam.max(), 1e-300):
        return None, "indeterminant", weak
    try:
        cov = np.asarray(gtsam.Marginals(graph, values).marginalCovariance(key))
    except RuntimeError:
        cov = np.linalg.inv(info)
    cov = 0.5 * (cov + cov.T)
    return cov, ("poorly_observed" if weak else "ok"), weak


def frames_graph(key: int, frames: list[Correspondences], conf: RadarPixelFactorConfig,
                 prior: tuple[np.ndarray, np.ndarray] | None = None) -> gtsam.NonlinearFactorGraph:
    """One radar-pixel factor per frame on ``key`` (a static extrinsic), plus an optional prior
    ``(T_prior (4, 4), cov (6, 6))``."""
    graph = gtsam.NonlinearFactorGraph()
    for corr in frames:
        if len(corr):
            graph.add(radar_pixel_factor(key, corr, conf))
    if prior is not None:
        graph.add(extrinsic_prior_factor(key, prior[0], prior[1]))
    return graph


def solve_frames(frames: list[Correspondences], T_init: np.ndarray, conf: RadarPixelFactorConfig = None,
                 prior: tuple[np.ndarray, np.ndarray] | None = None, solver: SolverConfig = DEFAULT_SOLVER,
                 two_stage: bool = True, key: int = 0) -> SolveResult:
    """Batch estimate of a static ``T_cam_radar`` from several frames (GTSAM back end).

    T_init: (4, 4) start. With ``two_stage`` the convex kernel runs first (see module doc).
    The covariance is the marginal of the final graph at the optimum (status as in
    ``marginal_covariance``).
    """
    conf = conf or RadarPixelFactorConfig()
    if not frames or sum(len(f) for f in frames) == 0:
        return SolveResult(np.asarray(T_init, np.float64), None, "failed: no correspondences", (), 0, float("nan"))
    values = gtsam.Values()
    values.insert(key, gtsam.Pose3(np.asarray(T_init, np.float64)))

    def build(kernel, scale):
        return frames_graph(key, frames, dataclasses.replace(conf, kernel=kernel, kernel_scale=scale), prior)

    if two_stage:
        out, status, iters, err = solve_gnc(build, values, conf.kernel, conf.kernel_scale, solver)
    else:
        out, status, iters, err = optimize(build(conf.kernel, conf.kernel_scale), values, solver)
    T = out.atPose3(key).matrix()
    if status != "ok":
        return SolveResult(T, None, status, (), iters, err, out)
    cov, cstatus, weak = marginal_covariance(build(conf.kernel, conf.kernel_scale), out, key, solver)
    return SolveResult(T, cov, cstatus, weak, iters, err, out)
