"""Batch calibration: every frame of a drive in one solve (the reference for the sliding window).

Same schedule as the window (``schedule.robust_solve``: convex start, redescending kernel, gated
least squares), same covariance reading (``covariance.analyse_information``). Two back ends:
``gtsam`` (one vectorised CustomFactor per frame) and ``ceres`` (``factors.ceres_costs.solve_ceres``,
per-row cost blocks with a quaternion manifold; its covariance converted to our convention by C).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences
from hybrid_calib.calib.covariance import (
    CovarianceConfig,
    analyse_information,
    information_from_graph,
    marginal_covariance,
    prior_pinned_std,
)
from hybrid_calib.calib.result import Estimate
from hybrid_calib.calib.schedule import GaussianPrior, ScheduleConfig, X, frame_information, gate_frames, robust_solve
from hybrid_calib.config import merge

BACKENDS = ("gtsam", "ceres")


@dataclass(frozen=True)
class BatchConfig:
    backend: str = "gtsam"  # gtsam | ceres
    factor: RadarPixelFactorConfig = RadarPixelFactorConfig()  # redescending kernel and elevation model
    schedule: ScheduleConfig = ScheduleConfig()  # convex stage, LM settings, final inlier gate
    covariance: CovarianceConfig = CovarianceConfig()  # degeneracy analysis and regularisation


@dataclass(frozen=True)
class BatchResult:
    estimate: Estimate
    backend: str
    iterations: int
    seconds: float  # wall time of the solve (all stages), without the covariance
    cov_seconds: float
    n_frames: int
    n_rows: int
    inlier_fraction: float


def _check_frames(frames: list[Correspondences]) -> None:
    if not frames:
        raise ValueError("batch calibration needs at least one frame")
    for i, f in enumerate(frames):
        if not isinstance(f, Correspondences):
            raise TypeError(f"frame {i}: expected Correspondences, got {type(f)}")


def solve_batch(frames: list[Correspondences], T_init: np.ndarray, conf: BatchConfig | dict | None = None,
                priors: list[GaussianPrior] | None = None) -> BatchResult:
    """Calibrate ``T_cam_radar`` (4, 4) from all ``frames`` at once, starting at ``T_init`` (4, 4).

    Never raises on degenerate geometry: the estimate's status names the poorly observed directions
    and the covariance is regularised (and says so) where information is missing.
    """
    conf = merge(BatchConfig, conf)
    if conf.backend not in BACKENDS:
        raise ValueError(f"BatchConfig.backend={conf.backend!r}; valid: {BACKENDS}")
    _check_frames(frames)
    T_init = np.asarray(T_init, np.float64)
    n_rows = sum(len(f) for f in frames)
    if conf.backend == "gtsam":
        res = robust_solve(frames, T_init, conf.factor, priors, conf.schedule, convex_start=True)
        t0 = time.perf_counter()
        info = information_from_graph(res.graph, res.values, X)
        cov, why = marginal_covariance(res.graph, res.values, X)
        rep = analyse_information(res.T, info, conf.covariance, cov_hint=cov,
                                  pinned_std=prior_pinned_std(conf.factor), external_info=_prior_info(priors))
        T, iters, secs = res.T, res.iterations, res.seconds
        cov_s = time.perf_counter() - t0
    else:
        T, info, cov, why, iters, secs, cov_s = _solve_ceres(frames, T_init, conf, priors)
        rep = analyse_information(T, info, conf.covariance, cov_hint=cov,
                                  pinned_std=prior_pinned_std(conf.factor), external_info=_prior_info(priors))
    inl = float(np.mean([frame_information(T, f, conf.factor, conf.schedule.final_gate)[2] for f in frames if len(f)]))
    return BatchResult(Estimate.from_report(T, rep, info, why), conf.backend, iters, secs, cov_s, len(frames),
                       n_rows, inl)


def _prior_info(priors: list[GaussianPrior] | None) -> np.ndarray:
    """Summed information (6, 6) of the external priors on T_cam_radar."""
    return sum((np.linalg.inv(p.cov) for p in priors or []), np.zeros((6, 6)))


def _solve_ceres(frames, T_init, conf: BatchConfig, priors):
    from factors.ceres_costs import solve_ceres

    if priors and len(priors) > 1:
        raise ValueError("the ceres back end takes at most one prior")
    prior = (priors[0].T, priors[0].cov) if priors else None
    t0 = time.perf_counter()
    r = solve_ceres(frames, T_init, conf.factor, prior, max_iterations=conf.schedule.max_iterations, two_stage=True)
    iters = r.iterations
    T, cov, status = r.T, r.cov, r.status
    fconf = conf.factor
    if conf.schedule.final_gate > 0 and conf.factor.kernel != "none" and not status.startswith("failed"):
        gated = [c for c in gate_frames(T, frames, conf.factor, conf.schedule.final_gate) if len(c)]
        fconf = dataclasses.replace(conf.factor, kernel="none")
        r = solve_ceres(gated, T, fconf, prior, max_iterations=conf.schedule.max_iterations, two_stage=False)
        iters += r.iterations
        T, cov, status = r.T, r.cov, r.status
    secs = time.perf_counter() - t0
    # information for the degeneracy analysis, from the same residuals (gated least squares)
    t1 = time.perf_counter()
    info = sum(frame_information(T, f, conf.factor, conf.schedule.final_gate)[1] for f in frames if len(f))
    if prior is not None:
        info = info + np.linalg.inv(prior[1])
    why = "" if cov is not None else f"ceres covariance unavailable ({status}); using the regularised pseudo-inverse"
    return T, np.asarray(info), cov, why, iters, secs, time.perf_counter() - t1
