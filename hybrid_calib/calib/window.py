"""Sliding-window calibrator of ``T_cam_radar``: one estimate with a trustworthy covariance per frame.

Design (one extrinsic state; a fixed-lag window with lazy relinearisation):
- A radar-camera mount is rigid, so the state is ONE ``Pose3``. The window holds the last
  ``window`` frames as nonlinear radar-pixel factors (``factors.radar_pixel_factor``) together
  with each frame's Gauss-Newton linearisation (gradient, information) at its linearisation point;
  a Gaussian prior (``factors.extrinsic_prior_factor``) summarises every frame that has left the
  window (marginalisation of a single state: ``H <- H_prior + J^T W J``, mean moved by the
  Gauss-Newton step). With ``random_walk_*`` > 0 that prior's covariance grows by ``Q dt`` per
  frame, the marginalised form of per-frame states tied by ``factors.random_walk_factor``.
- Update: the GTSAM graph is the new frame's nonlinear factor plus ONE prior holding the
  marginalised history and the linearised window frames; LM on it costs a few factor
  evaluations (the cost of a per-frame vectorised factor, not of the window). Like ISAM2's
  ``relinearizeThreshold``, the window frames are relinearised (a full nonlinear solve of the
  window, inlier gates re-decided) only when the estimate has moved more than
  ``relinearize_rot_deg`` / ``relinearize_trans_cm`` from their linearisation point, or in the
  first ``convex_frames`` updates after a (re)start, which run the convex-start schedule.
- Why not ``gtsam.IncrementalFixedLagSmoother`` with per-frame states: the robust schedule must
  re-solve the window with a *different kernel* (convex start after a (re)start or a step) and the
  step test must *discard* the marginalised history; both are explicit here and awkward through a
  smoother's frozen marginal factors. With Q = 0 (default) the estimate after the last frame
  matches the batch solution (tested).
- Covariance: ``gtsam.Marginals`` of the update graph (IndeterminantLinearSystemException caught),
  read by ``covariance.analyse_information`` (status naming weak/unobservable directions).
- Step change: ``drift.StepDetector`` compares the estimate of the last ``recent_frames`` frames,
  solved WITH a convex start (a redescending kernel warm-started at the old value rejects every
  post-step correspondence and locks on), against the long-run estimate. It runs every
  ``step.every`` frames and at once when a frame's inlier fraction collapses (the signature of a
  lock-on). On an alarm the history is dropped, the window shrinks to the recent frames and is
  re-solved with a convex start.
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
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
from hybrid_calib.calib.drift import StepConfig, StepDetector
from hybrid_calib.calib.result import Estimate, FrameEstimate
from hybrid_calib.calib.schedule import (
    GaussianPrior,
    ScheduleConfig,
    X,
    build_graph,
    frame_information,
    inlier_mask,
    lm_params,
    robust_solve,
)
from hybrid_calib.config import merge
from hybrid_calib.geometry import local, retract


@dataclass(frozen=True)
class WindowConfig:
    window: int = 20  # frames kept as factors; older ones are marginalised into a Gaussian prior
    factor: RadarPixelFactorConfig = RadarPixelFactorConfig()  # redescending kernel and elevation model
    schedule: ScheduleConfig = ScheduleConfig()  # convex stage, LM settings, final inlier gate
    covariance: CovarianceConfig = CovarianceConfig()  # degeneracy analysis and regularisation
    step: StepConfig = StepConfig()  # windowed chi-square step detector
    detect_steps: bool = True  # run the step detector (costs one small convex solve per frame)
    convex_frames: int = 3  # after a (re)start, this many updates use the convex start
    random_walk_rot_deg_per_sqrt_s: float = 0.0  # mount drift (random walk) std per sqrt(second), rotation
    random_walk_trans_cm_per_sqrt_s: float = 0.0  # mount drift (random walk) std per sqrt(second), translation
    default_dt_s: float = 0.5  # time step used when frames carry no timestamps (nuScenes keyframes: 2 Hz)
    relinearize_rot_deg: float = 0.1  # relinearise the window when the estimate moved more than this (deg) ...
    relinearize_trans_cm: float = 2.0  # ... or this (cm) from a frame's linearisation point
    min_inlier_fraction: float = 0.25  # below this the solve has not converged: re-solve from T_init (convex)


@dataclass
class _Frame:
    corr: Correspondences
    prior: GaussianPrior | None
    T_lin: np.ndarray | None = None  # linearisation point (4, 4)
    g: np.ndarray | None = None  # gradient (6,) at T_lin (gated least squares, incl. the frame's prior)
    H: np.ndarray | None = None  # information (6, 6) at T_lin
    inliers: float = 0.0  # fraction of gated inliers at T_lin


_WEAK_INFO = 1e-8  # information added to a Gaussian before inverting it (std 1e4 rad / 1e4 m)


def _transported(T: np.ndarray, frames) -> tuple[np.ndarray, np.ndarray]:
    """Sum over linearised frames of (gradient at T, information), first-order transport of each
    quadratic ``g.xi + xi.H.xi/2`` stored at its T_lin. Frames linearised together share one T_lin
    object, so ``local`` runs once per linearisation point."""
    G, H = np.zeros(6), np.zeros((6, 6))
    offsets: dict[int, np.ndarray] = {}
    for fr in frames:
        d = offsets.get(id(fr.T_lin))
        if d is None:
            d = offsets[id(fr.T_lin)] = local(fr.T_lin, T)
        G += fr.g + fr.H @ d
        H += fr.H
    return G, H


class SlidingWindowCalibrator:
    """Call ``update`` once per frame; it returns a ``FrameEstimate``.

    T_init: (4, 4) initial T_cam_radar (tables, network, or a perturbed start).
    """

    def __init__(self, T_init: np.ndarray, conf: WindowConfig | dict | None = None):
        self.conf = merge(WindowConfig, conf)
        if self.conf.window < 1:
            raise ValueError(f"WindowConfig.window must be >= 1, got {self.conf.window}")
        T_init = np.asarray(T_init, np.float64)
        if T_init.shape != (4, 4) or not np.all(np.isfinite(T_init)):
            raise ValueError(f"T_init must be a finite (4, 4) transform, got shape {T_init.shape}")
        self.T = T_init.copy()
        self.T_init = T_init.copy()
        self.frames: deque[_Frame] = deque()
        self.marg: tuple[np.ndarray, np.ndarray] | None = None  # (T_m (4, 4), information (6, 6))
        self.n_marg = 0
        self.n_updates = 0
        self.since_reset = 0
        self.last_ts: int | None = None
        self.detector = StepDetector(self.conf.step)
        self.info = np.zeros((6, 6))
        self._inlier_mean: float | None = None
        # information of external priors (e.g. the network's SE(3)) folded into the marginal prior;
        # kept apart so the prior-pinned nuisance is removed from the data part only
        self._marg_external_info = np.zeros((6, 6))

    # ------------------------------------------------------------------ linearisation
    def _gate(self) -> float:
        return self.conf.schedule.final_gate

    def _linearise(self, fr: _Frame, T: np.ndarray) -> None:
        """T: (4, 4), stored by reference (frames linearised together share it)."""
        """Cache the frame's gradient and information at T (gated least squares, or IRLS weights of the
        final kernel when the gate is off), including its own prior."""
        g, H, inl = frame_information(T, fr.corr, self.conf.factor, self._gate())
        if fr.prior is not None:
            Lp = np.linalg.inv(fr.prior.cov)
            H = H + Lp
            g = g + Lp @ local(fr.prior.T, T)
        fr.T_lin, fr.g, fr.H, fr.inliers = T, g, H, inl

    def _history_gaussian(self, frames) -> tuple[np.ndarray, np.ndarray] | None:
        """(gradient, information) at self.T of the marginal prior plus the given linearised frames."""
        G, H = _transported(self.T, frames)
        if self.marg is not None:
            Tm, Lm = self.marg
            G += Lm @ local(Tm, self.T)
            H += Lm
        if not np.any(H):
            return None
        return G, 0.5 * (H + H.T)

    def _history_gaussian_frames(self, frames) -> tuple[np.ndarray, np.ndarray]:
        """(gradient, information) at self.T of the given linearised frames only."""
        G, H = _transported(self.T, frames)
        return G, 0.5 * (H + H.T)

    def _as_prior(self, gh) -> GaussianPrior | None:
        if gh is None:
            return None
        G, H = gh
        Hr = H + _WEAK_INFO * np.eye(6)
        cov = np.linalg.inv(Hr)
        return GaussianPrior(retract(self.T, -np.linalg.solve(Hr, G)), 0.5 * (cov + cov.T))

    def _marginalise(self, fr: _Frame) -> None:
        """Fold a leaving frame into the marginal prior at the current estimate."""
        gh = self._history_gaussian([fr])
        if gh is None:
            return
        G, H = gh
        self.marg = (retract(self.T, -np.linalg.pinv(H, hermitian=True) @ G), H)
        self.n_marg += 1
        if fr.prior is not None:
            self._marg_external_info = self._marg_external_info + np.linalg.inv(fr.prior.cov)

    def _q(self, dt_s: float) -> np.ndarray:
        c = self.conf
        return np.diag([np.radians(c.random_walk_rot_deg_per_sqrt_s) ** 2] * 3
                       + [(c.random_walk_trans_cm_per_sqrt_s / 100) ** 2] * 3) * dt_s

    def reset(self, keep_last: int = 0) -> None:
        """Drop the marginalised history and all but the last ``keep_last`` frames (the next
        ``convex_frames`` updates use the convex start)."""
        self.marg = None
        self.n_marg = 0
        self._marg_external_info = np.zeros((6, 6))
        while len(self.frames) > keep_last:
            self.frames.popleft()
        self.since_reset = 0
        self.detector.reset()
        self._inlier_mean = None

    # ------------------------------------------------------------------ solves
    def _needs_relinearisation(self) -> bool:
        c = self.conf
        seen: set[int] = set()
        for fr in self.frames:
            if fr.T_lin is None:
                return True
            if id(fr.T_lin) in seen:
                continue
            seen.add(id(fr.T_lin))
            d = local(fr.T_lin, self.T)
            if np.degrees(np.linalg.norm(d[:3])) > c.relinearize_rot_deg or \
                    np.linalg.norm(d[3:]) * 100 > c.relinearize_trans_cm:
                return True
        return False

    def _solve_window(self, convex: bool):
        """Full nonlinear solve of the window (+ marginal prior + frame priors); relinearises every frame."""
        c = self.conf
        priors = [fr.prior for fr in self.frames if fr.prior is not None]
        marg = self._as_prior(self._history_gaussian([]))
        res = robust_solve([f.corr for f in self.frames], self.T, c.factor, priors + ([marg] if marg else []),
                           c.schedule, convex)
        self.T = res.T
        T_lin = self.T.copy()
        for fr in self.frames:
            self._linearise(fr, T_lin)
        return res

    def _solve_incremental(self, fr: _Frame):
        """New frame nonlinear (gated at the warm start) + one prior holding history and window."""
        import gtsam

        c = self.conf
        hist = self._as_prior(self._history_gaussian([f for f in self.frames if f is not fr]))
        gate = self._gate()
        if gate > 0:
            conf = dataclasses.replace(c.factor, kernel="none")
            corr = fr.corr.subset(inlier_mask(self.T, fr.corr, c.factor, gate))
        else:
            conf, corr = c.factor, fr.corr
        priors = ([hist] if hist else []) + ([fr.prior] if fr.prior is not None else [])
        graph = build_graph([corr] if len(corr) else [], conf, priors)
        values = gtsam.Values()
        values.insert(X, gtsam.Pose3(self.T))
        if graph.size() == 0:
            return None
        values = gtsam.LevenbergMarquardtOptimizer(graph, values, lm_params(c.schedule)).optimize()
        self.T = values.atPose3(X).matrix()
        self._linearise(fr, self.T.copy())
        return _Solved(graph, values)

    def _estimate(self, solved, note: str = "") -> tuple[Estimate, float]:
        t0 = time.perf_counter()
        if solved is None:
            info, cov, why = np.zeros((6, 6)), None, "no correspondences yet"
        else:
            info = information_from_graph(solved.graph, solved.values, X)
            cov, why = marginal_covariance(solved.graph, solved.values, X)
        ext = self._marg_external_info + sum(
            (np.linalg.inv(fr.prior.cov) for fr in self.frames if fr.prior is not None), np.zeros((6, 6)))
        rep = analyse_information(self.T, info, self.conf.covariance, cov_hint=cov,
                                  pinned_std=prior_pinned_std(self.conf.factor), external_info=ext)
        self.info = info
        notes = [n for n in (why, note) if n]
        return Estimate.from_report(self.T, rep, info, "; ".join(notes)), (time.perf_counter() - t0) * 1e3

    # ------------------------------------------------------------------ public
    def update(self, corr: Correspondences, prior: GaussianPrior | None = None,
               timestamp_us: int | None = None) -> FrameEstimate:
        """Add one frame (its correspondences and optional prior on T_cam_radar) and re-estimate."""
        if not isinstance(corr, Correspondences):
            raise TypeError(f"update() needs a Correspondences, got {type(corr)}")
        c = self.conf
        t0 = time.perf_counter()
        ts = int(corr.timestamp_us if timestamp_us is None else timestamp_us)
        dt = (ts - self.last_ts) * 1e-6 if (self.last_ts is not None and ts > self.last_ts) else c.default_dt_s
        self.last_ts = ts
        if self.marg is not None and (c.random_walk_rot_deg_per_sqrt_s > 0 or c.random_walk_trans_cm_per_sqrt_s > 0):
            Tm, Lm = self.marg
            L = np.linalg.inv(np.linalg.inv(Lm + _WEAK_INFO * np.eye(6)) + self._q(dt))
            self.marg = (Tm, 0.5 * (L + L.T))
        fr = _Frame(corr, prior)
        self.frames.append(fr)
        while len(self.frames) > c.window:
            self._marginalise(self.frames.popleft())
        events: list[str] = []
        if self.since_reset < c.convex_frames or self._needs_relinearisation_except(fr):
            res = self._solve_window(convex=self.since_reset < c.convex_frames)
            solved = _Solved(res.graph, res.values)
        else:
            solved = self._solve_incremental(fr)
            if self._needs_relinearisation():
                res = self._solve_window(convex=False)
                solved = _Solved(res.graph, res.values)
        if fr.inliers < c.min_inlier_fraction and len(fr.corr):
            # diverged (e.g. a far start solved from too few frames): retry the window from the initial
            # extrinsic with the convex start and keep whichever explains more correspondences
            T_prev, inl_prev, lin_prev = self.T, fr.inliers, [(f.T_lin, f.g, f.H, f.inliers) for f in self.frames]
            self.T = self.T_init.copy()
            res = self._solve_window(convex=True)
            if fr.inliers > inl_prev:
                solved = _Solved(res.graph, res.values)
                events.append(f"not converged (inlier fraction {inl_prev:.2f}): re-solved the window from the "
                              f"initial extrinsic with a convex start (inlier fraction {fr.inliers:.2f})")
            else:
                self.T = T_prev
                for f, (a, b, h, i) in zip(self.frames, lin_prev):
                    f.T_lin, f.g, f.H, f.inliers = a, b, h, i
        est, cov_ms = self._estimate(solved, note="" if fr.inliers >= c.min_inlier_fraction else
                                     f"NOT CONVERGED: only {100 * fr.inliers:.0f} % of the frame's "
                                     "correspondences fit the estimate")
        stat = thr = None
        alarm = False
        n_total = len(self.frames) + self.n_marg
        m = c.step.recent_frames
        inl = fr.inliers
        collapse = self._inlier_mean is not None and inl < c.step.inlier_drop * self._inlier_mean
        if c.detect_steps and n_total >= max(c.step.min_history, 2 * m) and len(self.frames) >= m:
            recent = list(self.frames)[-m:]
            gh = self._history_gaussian_frames(recent)
            stat = self.detector.statistic(self.T, self.info, retract(self.T, -np.linalg.pinv(gh[1]) @ gh[0]), gh[1])
            rr = None
            if collapse or self.n_updates % max(1, c.step.every) == 0:
                rr = robust_solve([f.corr for f in recent], self.T, c.factor, None, c.schedule, convex_start=True)
                info_r = information_from_graph(rr.graph, rr.values, X)
                stat = max(stat, self.detector.statistic(self.T, self.info, rr.T, info_r))
            test = self.detector.observe(stat)
            thr, alarm = test.threshold, test.alarm
            if alarm:
                events.append(f"step change detected (chi2 {test.statistic:.1f} > {test.threshold:.1f}, dof 6): "
                              f"history dropped, window reset to the recent frames that fit the new estimate, "
                              f"convex restart")
                if rr is None:
                    rr = robust_solve([f.corr for f in recent], self.T, c.factor, None, c.schedule, convex_start=True)
                self.reset(keep_last=m)
                self.T = rr.T
                # keep only the recent frames that agree with the post-step estimate (drop pre-step ones)
                inl = np.array([frame_information(rr.T, f.corr, c.factor, self._gate())[2] for f in self.frames])
                keep = inl >= 0.5 * inl.max() if inl.max() > 0 else np.ones(len(inl), bool)
                self.frames = deque(f for f, k in zip(self.frames, keep) if k)
                res = self._solve_window(convex=True)
                est, cov_ms = self._estimate(_Solved(res.graph, res.values), note="recovering after a step change")
                n_total = len(self.frames)
                inl = fr.inliers
        if not alarm:
            k = min(self.since_reset, 50)
            self._inlier_mean = inl if self._inlier_mean is None else (self._inlier_mean * k + inl) / (k + 1)
        self.since_reset += 1
        self.n_updates += 1
        total_ms = (time.perf_counter() - t0) * 1e3
        return FrameEstimate(self.n_updates - 1, corr.frame_id, ts, est, len(self.frames), n_total, inl, stat, thr,
                             alarm, total_ms - cov_ms, cov_ms, tuple(events))

    def _needs_relinearisation_except(self, new: _Frame) -> bool:
        """Relinearisation test over the frames already linearised (the new one is not yet)."""
        saved = new.T_lin
        new.T_lin = self.T
        try:
            return self._needs_relinearisation()
        finally:
            new.T_lin = saved


@dataclass
class _Solved:
    graph: object
    values: object
