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
  read by ``covariance.analyse_drive_information`` (status naming weak/unobservable directions).
- Step change: ``drift.StepDetector`` compares the estimate of the last ``recent_frames`` frames,
  solved WITH a convex start (a redescending kernel warm-started at the old value rejects every
  post-step correspondence and locks on), against the long-run estimate. It runs every
  ``step.every`` frames and at once when a frame's inlier fraction collapses (the signature of a
  lock-on). The last ``step.long_frames`` frames (10 and 20) are tested alongside with the free
  Gauss-Newton step of their cached linearisations (small steps in weakly observed directions).
  On an alarm the history is dropped, the window shrinks to the recent frames and is re-solved
  with a convex start.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from collections import deque
from dataclasses import dataclass

import numpy as np

from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences, SeenRows, doubled_message, repeat_message, replayed_message
from factors.scene import scene_prior_std
from hybrid_calib.calib.covariance import (
    CovarianceConfig,
    analyse_drive_information,
    graph_covariance,
    information_from_graph,
    prior_pinned_std,
)
from hybrid_calib.calib.degeneracy import RowGeometry
from hybrid_calib.calib.drift import StepConfig, StepDetector, StepOutcome
from hybrid_calib.calib.result import Estimate, FrameEstimate
from hybrid_calib.calib.schedule import (
    GaussianPrior,
    ScheduleConfig,
    SolveResult,
    X,
    build_graph,
    convergence_note,
    frame_information,
    frame_scene_cross,
    inlier_mask,
    lm_params,
    robust_solve,
)
from hybrid_calib.config import merge
from hybrid_calib.geometry import check_transform, local, retract


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
    # a convex-start update whose new frame fits less than this fraction of its rows: local solves from the previous
    # estimate and the start are tried beside it, the one fitting most rows kept (probe 54; 0 = off)
    convex_check_fraction: float = 0.5

    def __post_init__(self):
        if self.window < 1:
            raise ValueError(f"WindowConfig.window must be >= 1, got {self.window}")
        from hybrid_calib.config import finite, require, require_ranges

        numbers_ok = finite(*(getattr(self, k) for k in (
            "random_walk_rot_deg_per_sqrt_s", "random_walk_trans_cm_per_sqrt_s", "default_dt_s", "relinearize_rot_deg",
            "relinearize_trans_cm", "min_inlier_fraction", "convex_check_fraction")))
        require(self, {
            "convex_frames >= 0": self.convex_frames >= 0,
            "random_walk_rot_deg_per_sqrt_s >= 0": self.random_walk_rot_deg_per_sqrt_s >= 0,
            "random_walk_trans_cm_per_sqrt_s >= 0": self.random_walk_trans_cm_per_sqrt_s >= 0,
            "default_dt_s > 0": self.default_dt_s > 0,
            "relinearize_rot_deg > 0": self.relinearize_rot_deg > 0,
            "relinearize_trans_cm > 0": self.relinearize_trans_cm > 0,
            "0 <= min_inlier_fraction <= 1": 0 <= self.min_inlier_fraction <= 1,
            "finite numbers": numbers_ok})
        require_ranges(self, {"window": "[1, 1e9]", "convex_frames": "[0, 1e9]",
                              "random_walk_rot_deg_per_sqrt_s": "[0, 90]",
                              "random_walk_trans_cm_per_sqrt_s": "[0, 10000]", "default_dt_s": "(0, 3600]",
                              "relinearize_rot_deg": "(0, 180]", "relinearize_trans_cm": "(0, 10000]",
                              "convex_check_fraction": "[0, 1]"})


@dataclass(frozen=True)
class Linearisation:
    """A frame's cached Gauss-Newton quadratic (gated least squares, incl. the frame's own prior)."""

    T_lin: np.ndarray  # (4, 4) linearisation point; frames linearised together share this object
    g: np.ndarray  # (6,) gradient at T_lin, right tangent
    H: np.ndarray  # (6, 6) information at T_lin
    inliers: float  # fraction of gated inliers at T_lin
    scene_cross: np.ndarray | None = None  # (6, K) J^T W G with the scene nuisance (factors.scene); None = off


@dataclass
class _Frame:
    corr: Correspondences
    prior: GaussianPrior | None
    lin: Linearisation | None = None  # None until the frame was solved once


REPEAT_MEMORY = 1000  # frames whose rows a new frame is compared with (a repeat of one of them is refused)
_WEAK_INFO = 1e-8  # information added to a Gaussian before inverting it (std 1e4 rad / 1e4 m)


def _transported(T: np.ndarray, lins: list[Linearisation]) -> tuple[np.ndarray, np.ndarray]:
    """Sum over linearisations of (gradient at T, information), first-order transport of each
    quadratic ``g.xi + xi.H.xi/2`` stored at its T_lin. Frames linearised together share one T_lin
    object, so ``local`` runs once per linearisation point."""
    G, H = np.zeros(6), np.zeros((6, 6))
    offsets: dict[int, np.ndarray] = {}
    for lin in lins:
        d = offsets.get(id(lin.T_lin))
        if d is None:
            d = offsets[id(lin.T_lin)] = local(lin.T_lin, T)
        G += lin.g + lin.H @ d
        H += lin.H
    return G, H


def needs_relinearisation(points: list[np.ndarray | None], T: np.ndarray, rot_deg: float, trans_cm: float) -> bool:
    """True when a linearisation point (4, 4) is missing (None) or lies more than ``rot_deg`` /
    ``trans_cm`` from the estimate ``T`` (4, 4) (ISAM2's ``relinearizeThreshold``)."""
    seen: set[int] = set()
    for T_lin in points:
        if T_lin is None:
            return True
        if id(T_lin) in seen:
            continue
        seen.add(id(T_lin))
        d = local(T_lin, T)
        if np.degrees(np.linalg.norm(d[:3])) > rot_deg or np.linalg.norm(d[3:]) * 100 > trans_cm:
            return True
    return False


def random_walk_information(info: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """Information (6, 6) of a Gaussian with information ``info`` after a random walk of covariance
    ``Q`` (6, 6): ``inv(inv(info) + Q)``, symmetrised (``info`` regularised by ``_WEAK_INFO``)."""
    L = np.linalg.inv(np.linalg.inv(info + _WEAK_INFO * np.eye(6)) + Q)
    return 0.5 * (L + L.T)


@dataclass
class _Solved:
    graph: object
    values: object


class SlidingWindowCalibrator:
    """Call ``update`` once per frame; it returns a ``FrameEstimate``.

    T_init: (4, 4) initial T_cam_radar (tables, network, or a perturbed start).
    """

    def __init__(self, T_init: np.ndarray, conf: WindowConfig | dict | None = None):
        self.conf = merge(WindowConfig, conf)
        T_init = check_transform(T_init, "SlidingWindowCalibrator T_init")
        self.T = T_init.copy()
        self.T_init = T_init.copy()
        self.frames: deque[_Frame] = deque()
        self.marg: tuple[np.ndarray, np.ndarray] | None = None  # (T_m (4, 4), information (6, 6))
        self.n_marg = 0
        self.n_updates = 0
        self.since_reset = 0
        self.last_ts: int | None = None
        self.detector = StepDetector(self.conf.step, prior_pinned_std(self.conf.factor))
        self.info = np.zeros((6, 6))
        self.geometry = RowGeometry()  # where the rows since the last reset lie (status words)
        # information of external priors (e.g. the network's SE(3)) folded into the marginal prior;
        # kept apart so the prior-pinned nuisance is removed from the data part only
        self._marg_external_info = np.zeros((6, 6))
        # per-drive scene nuisance (factors.scene): its cross information with the marginalised frames
        self._scene = len(scene_prior_std(self.conf.factor)) > 0
        self._marg_scene_cross = np.zeros((6, len(scene_prior_std(self.conf.factor))))
        # the rows of the last REPEAT_MEMORY frames with rows; added to only as a frame's update ends (a failed update
        # leaves it as it was, so the snapshot shares it)
        self._seen = SeenRows(REPEAT_MEMORY)

    # ------------------------------------------------------------------ linearisation
    def _gate(self) -> float:
        return self.conf.schedule.final_gate

    def _linearisation(self, fr: _Frame, T: np.ndarray) -> Linearisation:
        """The frame's gradient and information at T (4, 4, stored by reference: frames linearised
        together share it): gated least squares, or IRLS weights of the final kernel when the gate
        is off, including the frame's own prior."""
        g, H, inl = frame_information(T, fr.corr, self.conf.factor, self._gate())
        if fr.prior is not None:
            Lp = np.linalg.inv(fr.prior.cov)
            H = H + Lp
            g = g + Lp @ local(fr.prior.T, T)
        cross = frame_scene_cross(T, fr.corr, self.conf.factor, self._gate()) if self._scene else None
        return Linearisation(T, g, H, inl, cross)

    def _history_gaussian(self, frames, T: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(gradient, information) at T of the marginal prior plus the given linearised frames."""
        G, H = _transported(T, [fr.lin for fr in frames])
        if self.marg is not None:
            Tm, Lm = self.marg
            G += Lm @ local(Tm, T)
            H += Lm
        if not np.any(H):
            return None
        return G, 0.5 * (H + H.T)

    def _history_gaussian_frames(self, frames) -> tuple[np.ndarray, np.ndarray]:
        """(gradient, information) at self.T of the given linearised frames only."""
        G, H = _transported(self.T, [fr.lin for fr in frames])
        return G, 0.5 * (H + H.T)

    @staticmethod
    def _as_prior(gh, T: np.ndarray) -> GaussianPrior | None:
        """The Gaussian (gradient, information) at T as a prior: mean at its Gauss-Newton step."""
        if gh is None:
            return None
        G, H = gh
        # inverted in its eigenbasis: an ill-conditioned history (probe 95: tables 180 deg off, a highway's rows; an
        # information spanning 1e13) made np.linalg.inv's covariance indefinite, and the run ended on "covariance is
        # not positive definite"; a rounding-level eigenvalue left at or below 0 is lifted to 1e-14 of the largest
        w, V = np.linalg.eigh(0.5 * (H + H.T))
        w = np.maximum(w, 0.0) + _WEAK_INFO
        cov = (V / w) @ V.T
        cov = 0.5 * (cov + cov.T)
        if (low := float(np.linalg.eigvalsh(cov).min())) <= 0:
            cov = cov + (1e-14 * float(np.abs(cov).max()) - low) * np.eye(6)
        return GaussianPrior(retract(T, -((V / w) @ (V.T @ G))), cov)

    def _marginalise(self, fr: _Frame) -> None:
        """Fold a leaving frame into the marginal prior at the current estimate."""
        gh = self._history_gaussian([fr], self.T)
        if gh is None:
            return
        G, H = gh
        self.marg = (retract(self.T, -np.linalg.pinv(H, hermitian=True) @ G), H)
        self.n_marg += 1
        if fr.prior is not None:
            self._marg_external_info = self._marg_external_info + np.linalg.inv(fr.prior.cov)
        if fr.lin is not None and fr.lin.scene_cross is not None:
            self._marg_scene_cross = self._marg_scene_cross + fr.lin.scene_cross

    def _q(self, dt_s: float) -> np.ndarray:
        c = self.conf
        return np.diag([np.radians(c.random_walk_rot_deg_per_sqrt_s) ** 2] * 3
                       + [(c.random_walk_trans_cm_per_sqrt_s / 100) ** 2] * 3) * dt_s

    def reset(self, keep_last: int = 0, T: np.ndarray | None = None) -> None:
        """Drop the marginalised history and all but the last ``keep_last`` frames (the next
        ``convex_frames`` updates use the convex start); ``T`` (4, 4): the estimate to go on from."""
        if T is not None:
            self.T = np.asarray(T, np.float64).copy()
        self.marg = None
        self.n_marg = 0
        self._marg_external_info = np.zeros((6, 6))
        self._marg_scene_cross = np.zeros_like(self._marg_scene_cross)
        while len(self.frames) > keep_last:
            self.frames.popleft()
        self.geometry = RowGeometry.from_frames([f.corr for f in self.frames])
        self.since_reset = 0
        self.detector.reset()

    # ------------------------------------------------------------------ solves
    def _relinearisation_due(self, frames) -> bool:
        c = self.conf
        return needs_relinearisation([None if fr.lin is None else fr.lin.T_lin for fr in frames], self.T,
                                     c.relinearize_rot_deg, c.relinearize_trans_cm)

    def _solve_window(self, T_start: np.ndarray, convex: bool) -> tuple[SolveResult, list[Linearisation]]:
        """Full nonlinear solve of the window (+ marginal prior + frame priors) from T_start (4, 4):
        the result and every frame's linearisation at its optimum; nothing is changed (``_adopt``)."""
        c = self.conf
        priors = [fr.prior for fr in self.frames if fr.prior is not None]
        marg = self._as_prior(self._history_gaussian([], T_start), T_start)
        res = robust_solve([f.corr for f in self.frames], T_start, c.factor, priors + ([marg] if marg else []),
                           c.schedule, convex)
        T_lin = res.T.copy()
        return res, [self._linearisation(fr, T_lin) for fr in self.frames]

    def _adopt(self, res: SolveResult, lins: list[Linearisation]) -> _Solved:
        """Make a window solve (``_solve_window``) the current estimate."""
        self.T = res.T
        for fr, lin in zip(self.frames, lins, strict=True):
            fr.lin = lin
        return _Solved(res.graph, res.values)

    def _solve_incremental(self, fr: _Frame):
        """New frame nonlinear (gated at the warm start) + one prior holding history and window."""
        import gtsam

        c = self.conf
        hist = self._as_prior(self._history_gaussian([f for f in self.frames if f is not fr], self.T), self.T)
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
        fr.lin = self._linearisation(fr, self.T.copy())
        return _Solved(graph, values)

    def _solve_new_frame(self, fr: _Frame) -> _Solved | None:
        """A full window solve in the first ``convex_frames`` updates after a (re)start (convex start)
        or when the estimate has left the other frames' linearisation points; otherwise the new frame
        alone against the window's Gaussian (then a full solve if that moved the estimate too far)."""
        convex = self.since_reset < self.conf.convex_frames
        if convex or self._relinearisation_due([f for f in self.frames if f is not fr]):
            return self._adopt(*self._solve_window(self.T, convex=convex))
        solved = self._solve_incremental(fr)
        if self._relinearisation_due(self.frames):
            solved = self._adopt(*self._solve_window(self.T, convex=False))
        return solved

    def _window_inliers(self, T: np.ndarray) -> int:
        """Rows of every frame in the window that fit ``T`` (whitened residual below the final gate)."""
        gate = self._gate()
        return int(sum(inlier_mask(T, fr.corr, self.conf.factor, gate).sum() for fr in self.frames if len(fr.corr)))

    def _rescue_if_diverged(self, fr: _Frame, solved: _Solved | None, events: list[str],
                            T_prev: np.ndarray) -> _Solved | None:
        """When too few of the new frame's rows fit, re-solve the window locally from the previous estimate
        ``T_prev`` (a convex start that left the basin the earlier frames agree on: measured, 83 deg away with 7 %
        of the frame fitting) and, with the convex start, from the initial extrinsic (a far start solved from too
        few frames), and keep whichever fits most rows of the whole window: a new frame that fits no candidate
        (the sensor moved; the step detector's case) does not pull the estimate into a basin only it supports."""
        before = fr.lin.inliers
        if not len(fr.corr):
            return solved
        candidates = ((T_prev, False, "locally from the previous estimate"),
                      (self.T_init, True, "from the initial extrinsic with a convex start"))
        if self.since_reset < self.conf.convex_frames and before < self.conf.convex_check_fraction:
            # a convex start from few frames that fits less than half the rows may have left the start's basin
            # (probe 54: frame 0 of an oracle drive, R1 start, solved 74 deg away with 29 % of the rows fitting):
            # a local solve from the start and from the previous estimate, kept when it fits more rows
            why = f"inlier fraction {before:.2f} after a convex start from {len(self.frames)} frame(s)"
            local = ((T_prev, False, "locally from the previous estimate"),
                     (self.T_init, False, "locally from the initial extrinsic"))
            # not converged by the 25 % rule too: its convex re-solve from the start is tried as well
            candidates = local + (candidates[1:] if before < self.conf.min_inlier_fraction else ())
        elif before >= self.conf.min_inlier_fraction:
            return solved
        else:
            why = f"inlier fraction {before:.2f}"
        best, score, how = None, self._window_inliers(self.T), ""
        for T0, convex, words in candidates:
            res, lins = self._solve_window(np.array(T0, copy=True), convex=convex)
            if (n := self._window_inliers(res.T)) > score:
                best, score, how = (res, lins), n, words
        if best is None:
            return solved
        events.append(f"not converged ({why}): re-solved the window {how} (inlier fraction "
                      f"{best[1][-1].inliers:.2f}; {score} of the window's rows fit)")
        return self._adopt(*best)

    def _estimate(self, solved, note: str = "") -> tuple[Estimate, float]:
        t0 = time.perf_counter()
        if solved is None:
            info, cov, why = np.zeros((6, 6)), None, "no correspondences yet"
        else:
            info, cov, why = graph_covariance(solved.graph, solved.values, X)
        ext = self._marg_external_info + sum(
            (np.linalg.inv(fr.prior.cov) for fr in self.frames if fr.prior is not None), np.zeros((6, 6)))
        cross = None
        if self._scene:
            cross = self._marg_scene_cross + sum(
                (fr.lin.scene_cross for fr in self.frames if fr.lin is not None and fr.lin.scene_cross is not None),
                np.zeros_like(self._marg_scene_cross))
        rep = analyse_drive_information(self.T, info, self.conf.covariance, self.conf.factor, cov_hint=cov,
                                        external_info=ext, scene_cross=cross, geometry=self.geometry)
        self.info = info
        notes = [n for n in (why, note) if n]
        return Estimate.from_report(self.T, rep, info, "; ".join(notes)), (time.perf_counter() - t0) * 1e3

    # ------------------------------------------------------------------ step change
    def _test_step(self, inlier_fraction: float) -> StepOutcome | None:
        """The windowed step test after this update (None while there is too little history)."""
        det = self.detector
        lengths = det.ready_lengths(len(self.frames) + self.n_marg, len(self.frames))
        if not lengths:
            return None
        c = self.conf
        frames = list(self.frames)
        recent = frames[-lengths[0]:]

        def solve_recent():
            rr = robust_solve([f.corr for f in recent], self.T, c.factor, None, c.schedule, convex_start=True)
            return rr.T, information_from_graph(rr.graph, rr.values, X)

        resolve = det.resolve_due(self.n_updates, det.collapsed(inlier_fraction))
        recents = {m: self._history_gaussian_frames(frames[-m:]) for m in lengths}
        return det.check(self.T, self.info, recents, solve_recent, resolve)

    def _restart_after_step(self, step: StepOutcome, new: _Frame) -> tuple[Estimate, float, float]:
        """Drop the history, keep the recent frames that agree with the post-step estimate and
        re-solve them with a convex start from it; returns the estimate, its covariance time and the fraction of the
        ``new`` frame's rows that fit it (below ``min_inlier_fraction``: NOT CONVERGED, probe 58: the alarm frame
        56-68 deg off with 0-5 % fitting read "recovering after a step change" alone)."""
        c = self.conf
        self.reset(keep_last=self.detector.conf.recent_frames)
        self.T = step.T_recent
        inl = np.array([frame_information(self.T, f.corr, c.factor, self._gate())[2] for f in self.frames])
        keep = inl >= 0.5 * inl.max() if inl.max() > 0 else np.ones(len(inl), bool)
        self.frames = deque(f for f, k in zip(self.frames, keep) if k)
        solved = self._adopt(*self._solve_window(self.T, convex=True))
        fits = (float(frame_information(self.T, new.corr, c.factor, self._gate())[2]) if len(new.corr)
                else new.lin.inliers)
        note = "; ".join(n for n in ("recovering after a step change",
                                     convergence_note(fits, c.min_inlier_fraction) if len(new.corr) else "") if n)
        return (*self._estimate(solved, note=note), fits)

    # ------------------------------------------------------------------ public
    def _advance_clock(self, ts: int) -> None:
        """Time since the previous frame (``default_dt_s`` without timestamps) widens the marginal
        prior by the random walk."""
        c = self.conf
        walk = c.random_walk_rot_deg_per_sqrt_s > 0 or c.random_walk_trans_cm_per_sqrt_s > 0
        if walk and self.last_ts is not None and 0 < ts < self.last_ts:  # read as one default step (probe 31)
            raise ValueError(f"timestamp {ts} us is {(self.last_ts - ts) * 1e-6:.3f} s before the previous frame's "
                             f"({self.last_ts} us): with a random walk the frames must come in time order (the drift "
                             "allowed between them is per second); sort them, or pass timestamp_us")
        dt = (ts - self.last_ts) * 1e-6 if (self.last_ts is not None and ts > self.last_ts) else c.default_dt_s
        self.last_ts = ts
        if self.marg is not None and walk:
            Tm, Lm = self.marg
            self.marg = (Tm, random_walk_information(Lm, self._q(dt)))

    def _push(self, corr: Correspondences, prior: GaussianPrior | None) -> _Frame:
        """Append the frame; frames beyond ``window`` leave into the marginal prior."""
        fr = _Frame(corr, prior)
        self.frames.append(fr)
        self.geometry.add(corr.points_radar)
        while len(self.frames) > self.conf.window:
            self._marginalise(self.frames.popleft())
        return fr

    def _snapshot(self) -> dict:
        """The calibrator's state, to restore when an update fails (the frames' rows and priors are shared, not
        copied: nothing changes them)."""
        memo = {id(self.conf): self.conf, id(self._seen): self._seen}
        for fr in self.frames:
            memo[id(fr.corr)] = fr.corr
            if fr.prior is not None:
                memo[id(fr.prior)] = fr.prior
        return copy.deepcopy(self.__dict__, memo)

    def update(self, corr: Correspondences, prior: GaussianPrior | None = None,
               timestamp_us: int | None = None) -> FrameEstimate:
        """Add one frame (its correspondences and optional prior on T_cam_radar) and re-estimate. A frame whose
        update raises leaves the calibrator as it was before it (a stream that logs the error and goes on loses
        that frame only: the frame stayed in the window and failed the next 20 good ones, probe 31)."""
        if not isinstance(corr, Correspondences):
            raise TypeError(f"update() needs a Correspondences, got {type(corr)}")
        if timestamp_us is not None and (isinstance(timestamp_us, bool)
                                         or not isinstance(timestamp_us, (int, np.integer))):
            # as Correspondences.timestamp_us (probe 67: 1.5 was truncated, NaN an error from int())
            raise ValueError(f"update({corr.frame_id}): timestamp_us must be an integer number of microseconds, got "
                             f"{type(timestamp_us).__name__} {timestamp_us!r}")
        before = self._snapshot()
        try:
            return self._update(corr, prior, timestamp_us)
        except BaseException:
            self.__dict__.update(before)
            raise

    def _update(self, corr: Correspondences, prior: GaussianPrior | None, timestamp_us: int | None
                ) -> FrameEstimate:
        events: list[str] = []
        if len(corr):  # the same rows again: one measurement, which counted twice shrinks the covariance (probe 31)
            if pairs := corr.doubled_rows():  # found once, said and kept once
                events.append(doubled_message(corr, pairs))
                corr = corr.once(pairs)
            seen = self._seen.match(corr)  # rows of earlier frames again (a replay, whole or in part: probe 59)
            if (seen >= 0).all():
                raise ValueError(repeat_message(corr.frame_id, self._seen.frame_id(int(seen[0]))))
            if (seen >= 0).any():
                events.append(replayed_message(corr, seen >= 0, self._seen.frame_id(int(seen[seen >= 0][0]))))
                corr = corr.subset(seen < 0)
        t0 = time.perf_counter()
        ts = int(corr.timestamp_us if timestamp_us is None else timestamp_us)
        self._advance_clock(ts)
        fr = self._push(corr, prior)
        T_prev = self.T.copy()
        starting = self.since_reset < self.conf.convex_frames  # a convex start from these few frames
        solved = self._rescue_if_diverged(fr, self._solve_new_frame(fr), events, T_prev)
        # a frame without rows (e.g. only a network prior) says nothing about convergence; from a convex start on the
        # rows alone (no prior in the window), a frame that fits fewer than convex_check_fraction of its rows after
        # the check's re-solves has not converged either (probe 58: R2 starts, frame 0 38-54 deg off with 30-32 %
        # fitting, a plain "weak" and a degree-level std)
        alone = starting and not any(f.prior is not None for f in self.frames) and self.marg is None
        need = max(self.conf.min_inlier_fraction, self.conf.convex_check_fraction if alone else 0.0)
        note = convergence_note(fr.lin.inliers, need) if len(corr) else ""
        est, cov_ms = self._estimate(solved, note=note)
        n_total = len(self.frames) + self.n_marg
        inl = fr.lin.inliers
        step = self._test_step(inl) if self.conf.detect_steps else None
        alarm = step is not None and step.test.alarm
        if alarm:
            events.append(f"step change detected (chi2 {step.test.statistic:.1f} > {step.test.threshold:.1f}, dof "
                          f"{self.detector.dof}): history dropped, window reset to the recent frames that fit the new "
                          "estimate, convex restart")
            est, cov_ms, inl = self._restart_after_step(step, fr)
            n_total = len(self.frames)
        else:
            self.detector.track_inliers(inl, self.since_reset)
        self.since_reset += 1
        self.n_updates += 1
        total_ms = (time.perf_counter() - t0) * 1e3
        if len(corr):
            self._seen.add(corr)
        return FrameEstimate(
            index=self.n_updates - 1, frame_id=corr.frame_id, timestamp_us=ts, estimate=est,
            n_window=len(self.frames), n_total=n_total, inlier_fraction=inl,
            step_statistic=None if step is None else step.test.statistic,
            step_threshold=None if step is None else step.test.threshold,
            step_alarm=alarm, solve_ms=total_ms - cov_ms, cov_ms=cov_ms, events=tuple(events))
