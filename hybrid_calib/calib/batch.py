"""Batch calibration: every frame of a drive in one solve (the reference for the sliding window).

Same schedule as the window (``schedule.robust_solve``: convex start, redescending kernel, gated
least squares), same covariance reading (``covariance.analyse_drive_information``). Two back ends:
``gtsam`` (one vectorised CustomFactor per frame) and ``ceres`` (``factors.ceres_costs.solve_ceres_stage``
per stage of the same ``ScheduleConfig``: per-row cost blocks with a quaternion manifold; its covariance
converted to our convention by ``ceres_covariance``).

A batch solve from a far start can settle in a wrong basin (measured: two of 60 R2 starts on
simulated straight roads ended 21-23 deg away, with 10 % of the rows fitting; the sliding window
from the same starts did not, since it adds the frames one at a time). When fewer than
``min_inlier_fraction`` of the rows fit the estimate, the batch re-solves progressively as the window
does (the first frame, then 4, 16, 64, ... frames, each from the previous optimum, then all) and,
when that is still short of the fraction (the first frames alone settle wrong too: a 5-frame urban
drive ended 66 deg off), once more from the sliding window's own estimate over the frames, and then from the
start without the schedule's convex stage (the Huber cost of rows with gross outliers can be lowest at a collapsed
pose that puts every reflector far ahead, and the convex stage walked there even from the truth: probe 118); it
keeps whichever estimate more rows fit; the status says so, and says ``NOT CONVERGED`` when none reaches the
fraction.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from factors.config import RadarPixelFactorConfig
from factors.correspondences import (
    Correspondences,
    doubled_message,
    fresh_rows,
    repeat_message,
    repeated_rows,
    replayed_message,
)
from factors.scene import scene_prior_std
from hybrid_calib.calib.covariance import (
    CovarianceConfig,
    analyse_drive_information,
    graph_covariance,
)
from hybrid_calib.calib.degeneracy import RowGeometry
from hybrid_calib.calib.result import Estimate
from hybrid_calib.calib.schedule import (
    GaussianPrior,
    ScheduleConfig,
    Stage,
    X,
    convergence_note,
    frame_information,
    frame_scene_cross,
    robust_solve,
    run_schedule,
)
from hybrid_calib.config import merge
from hybrid_calib.geometry import check_transform

BACKENDS = ("gtsam", "ceres")


@dataclass(frozen=True)
class BatchConfig:
    backend: str = "gtsam"  # gtsam | ceres
    factor: RadarPixelFactorConfig = RadarPixelFactorConfig()  # redescending kernel and elevation model
    schedule: ScheduleConfig = ScheduleConfig()  # convex stage, LM settings, final inlier gate
    covariance: CovarianceConfig = CovarianceConfig()  # degeneracy analysis and regularisation
    min_inlier_fraction: float = 0.25  # fewer rows fit: re-solve progressively (module doc), else NOT CONVERGED
    # the fit-change test (``fit_change``): the fractions of rows that fit the estimate before and after a frame
    # differ by at least ``fit_change_drop`` and by ``fit_change_z`` of their frame-to-frame spread (0: no test).
    # Measured (oracle rows, 30-frame urban drives, R1): 69-81 % of each frame's rows fit on drives of one mount; a
    # radar turned 0.5-3 deg in yaw at frame 15: 33-76 % before and 0-53 % after (probe 123)
    fit_change_drop: float = 0.2
    fit_change_z: float = 6.0
    fit_change_frames: int = 3  # frames on each side at least

    def __post_init__(self):
        from hybrid_calib.config import require, require_ranges

        require(self, {"backend in ('gtsam', 'ceres')": self.backend in ("gtsam", "ceres")})
        require_ranges(self, {"min_inlier_fraction": "[0, 1)", "fit_change_drop": "(0, 1]", "fit_change_z": "[0, 1e3]",
                              "fit_change_frames": "[1, 1e6]"})


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


def _check_frames(frames: list[Correspondences]) -> tuple[list[Correspondences], str]:
    """``frames`` checked, each kept once and without the rows that repeat an earlier frame's (``fresh_rows``), and
    the words for what was left out ("" when nothing)."""
    if not frames:
        raise ValueError("batch calibration needs at least one frame")
    for i, f in enumerate(frames):
        if not isinstance(f, Correspondences):
            raise TypeError(f"frame {i}: expected Correspondences, got {type(f)}")
    # the same rows N times shrank the covariance as N frames' (probe 31: NEES 62 for 20 copies of one frame)
    rows = repeated_rows(frames)  # rows of an earlier frame again (a replay, whole or in part) are one measurement
    if rep := {i: j for i, (m, j) in rows.items() if m.all()}:
        i, j = next(iter(rep.items()))
        raise ValueError(f"{len(rep)} of the {len(frames)} frames repeat an earlier frame's rows; first: frame {i}: "
                         f"{repeat_message(frames[i].frame_id, frames[j].frame_id)}: pass each frame once")
    notes = []
    if part := {i: (m, j) for i, (m, j) in rows.items() if m.any()}:  # said, as the window's event says it
        i, (m, j) = next(iter(part.items()))
        notes.append(f"{sum(int(m.sum()) for m, _ in part.values())} row(s) of {len(part)} frame(s) repeat an earlier "
                     f"frame's rows; first: frame {frames[i].frame_id or i}: "
                     + replayed_message(frames[i].once(), m, frames[j].frame_id))  # m: rows of the frame kept once
    if doubled := [(i, msg) for i, f in enumerate(frames) if (msg := doubled_message(f))]:
        i, msg = doubled[0]
        notes.append(f"{len(doubled)} frame(s) hold a row twice; first: frame {frames[i].frame_id or i}: {msg}")
    return fresh_rows(frames, rows), "; ".join(notes)


def solve_batch(frames: list[Correspondences], T_init: np.ndarray, conf: BatchConfig | dict | None = None,
                priors: list[GaussianPrior] | None = None) -> BatchResult:
    """Calibrate ``T_cam_radar`` (4, 4) from all ``frames`` at once, starting at ``T_init`` (4, 4).

    Never raises on degenerate geometry: the estimate's status names the poorly observed directions
    and the covariance is regularised (and says so) where information is missing.
    """
    conf = merge(BatchConfig, conf)
    if conf.backend not in BACKENDS:
        raise ValueError(f"BatchConfig.backend={conf.backend!r}; valid: {BACKENDS}")
    frames, left_out = _check_frames(frames)  # a row twice, in a frame or across frames, is one measurement
    T_init = check_transform(T_init, "solve_batch T_init")  # both backends (Ceres took a scaled rotation)
    n_rows = sum(len(f) for f in frames)
    T, info, cov, why, iters, secs, t0 = _solve(frames, T_init, conf, priors)
    inl, rescue = _inlier_fraction(T, frames, conf), ""
    rowed = [f for f in frames if len(f)]
    inl0 = inl
    # the first frames alone from the start, then the window's way in, then the start without the convex stage
    # (module doc); each only while too few fit
    for how, start_from, convex in (("re-solved progressively (frames 1, 4, 16, ... then all, each from the "
                                     "previous optimum)", _progressive_start, True),
                                    ("re-solved from the sliding window's estimate (frames added one at a time)",
                                     _window_start, True),
                                    ("re-solved from the start without the convex (Huber) stage, which had left "
                                     "the start's basin", _given_start, False)):
        if inl >= conf.min_inlier_fraction or len(rowed) < 2:
            break
        T_s, it_s, secs_s = start_from(rowed, T_init, conf, priors)
        again = _solve(frames, T_s, conf, priors, convex_start=convex)
        inl_s = _inlier_fraction(again[0], frames, conf)
        if inl_s > inl:
            rescue = f"from the start only {100 * inl0:.0f} % of the rows fit: {how}: {100 * inl_s:.0f} % fit"
            T, info, cov, why, it, sec, t0 = again
            iters, secs, inl = iters + it_s + it, secs + secs_s + sec, inl_s
    notes = [why, rescue, convergence_note(inl, conf.min_inlier_fraction, "the drive's"), left_out]
    cross = sum((frame_scene_cross(T, f, conf.factor, conf.schedule.final_gate) for f in frames),
                np.zeros((6, len(scene_prior_std(conf.factor)))))
    rep = analyse_drive_information(T, info, conf.covariance, conf.factor, cov_hint=cov,
                                    external_info=_prior_info(priors), scene_cross=cross,
                                    geometry=RowGeometry.from_frames(frames))
    cov_s = time.perf_counter() - t0
    return BatchResult(Estimate.from_report(T, rep, info, "; ".join(n for n in notes if n)), conf.backend, iters,
                       secs, cov_s, len(frames), n_rows, inl)


def _solve(frames, T0, conf: BatchConfig, priors, covariance: bool = True, convex_start: bool = True):
    """The schedule on ``conf.backend`` from T0 (``convex_start``: with its convex first stage): (T, information,
    covariance or None, why it is None, iterations, solve seconds, perf_counter at the start of the covariance)."""
    if conf.backend == "ceres":
        return _solve_ceres(frames, T0, conf, priors, convex_start)
    res = robust_solve(frames, T0, conf.factor, priors, conf.schedule, convex_start=convex_start)
    t0 = time.perf_counter()
    info, cov, why = graph_covariance(res.graph, res.values, X) if covariance else (None, None, "")
    return res.T, info, cov, why, res.iterations, res.seconds, t0


def fit_change(T: np.ndarray, frames: list[Correspondences], positions: list[int], conf: BatchConfig
               ) -> dict | None:
    """Where the fraction of each frame's rows that fit the batch's estimate ``T`` (4, 4) changes along the drive, or
    None. A batch solve pools every frame under one mount: a radar that moved inside the drive leaves the rows of one
    side of the move unfit (probe 123: a 0.5 deg turn in yaw at frame 15 of 30, batch mode read "weak", 4.2 deg off
    in roll at a 0.14 deg std, NEES 9300; 3 deg kept the mount before the turn at a yaw std of 0.03 deg). The split
    (at least ``fit_change_frames`` frames with rows on each side) whose two pooled fractions differ most in stds of
    their frame-to-frame spread (frames are clusters: their rows share a scene) is reported when they differ by
    ``fit_change_drop`` and ``fit_change_z`` stds: {"frame" (its position, ``positions``), "before", "after"
    (fractions), "z"}. ``frames``: those with rows, in drive order."""
    m = conf.fit_change_frames
    if conf.fit_change_z <= 0 or len(frames) < 2 * m:
        return None
    n = np.array([len(f) for f in frames], np.float64)
    fit = np.array([frame_information(T, f, conf.factor, conf.schedule.final_gate)[2] for f in frames])

    def pooled(sl: slice) -> tuple[float, float]:
        w, q = n[sl], fit[sl]
        p = float(w @ q / w.sum())
        k = len(w)
        return p, float(np.sum(w ** 2 * (q - p) ** 2) / w.sum() ** 2 * k / max(k - 1, 1))

    best = None
    for k in range(m, len(frames) - m + 1):
        (pa, va), (pb, vb) = pooled(slice(0, k)), pooled(slice(k, None))
        z = abs(pa - pb) / np.sqrt(va + vb + 0.01 ** 2)  # a floor: a side whose frames all fit alike
        if abs(pa - pb) >= conf.fit_change_drop and z >= conf.fit_change_z and (best is None or z > best["z"]):
            best = {"frame": int(positions[k]), "before": pa, "after": pb, "z": float(z)}
    return best or split_fit(T, frames, positions, conf)


def split_fit(T: np.ndarray, frames: list[Correspondences], positions: list[int], conf: BatchConfig) -> dict | None:
    """The second half of ``fit_change``: a drive cut at a third, half and two thirds, each side solved alone from
    the batch's estimate ``T``; the cut where a side's own estimate fits ``fit_change_drop`` or more of its rows beyond
    what ``T`` fits, or None. A compromise between two mounts fits about half the rows on both sides alike, which the
    fraction's change along the drive does not show (probe 134: 4 of 12 fresh urban drives turned 0.5 deg in yaw read
    "weak", 2.4-6.2 deg off in roll at a 0.14 deg std, NEES 5700-7900; each side's own estimate fit 28-31 % more of its
    rows, drives of one mount 0-1 %). {"frame", "before", "after" (fractions at ``T``), "own_before", "own_after"
    (at each side's own estimate), "z": None}."""
    n, m = len(frames), conf.fit_change_frames
    rows = np.array([len(f) for f in frames], np.float64)
    # rows fitting ``T`` per frame, once for every cut (as ``_inlier_fraction`` counts them)
    fits = rows * np.array([frame_information(T, f, conf.factor, conf.schedule.final_gate)[2] if len(f) else 0.0
                            for f in frames])
    best = None
    for k in sorted({n // 3, n // 2, 2 * n // 3}):
        if k < m or n - k < m:
            continue
        at_T = [float(fits[sl].sum() / rows[sl].sum()) if rows[sl].sum() else 0.0
                for sl in (slice(0, k), slice(k, None))]
        own = [_inlier_fraction(_solve(part, T, conf, None, covariance=False, convex_start=False)[0], part, conf)
               for part in (frames[:k], frames[k:])]
        gains = sorted(o - t for o, t in zip(own, at_T))
        # found where a side gains; the cut named is the one where both gain most (each side nearest one mount)
        if gains[1] >= conf.fit_change_drop and (best is None or gains > best["gains"]):
            best = {"frame": int(positions[k]), "before": at_T[0], "after": at_T[1], "own_before": own[0],
                    "own_after": own[1], "z": None, "gains": gains}
    if best is not None:
        best["gain"] = float(best.pop("gains")[1])
    return best


def fit_change_words(change: dict) -> str:
    """``fit_change``'s finding in words: why the batch's estimate is not trusted."""
    if change.get("z") is None:  # split_fit: each side's own estimate fits its rows far better
        return (f"{change['before']:.0%} of the rows of the frames before frame {change['frame']} and "
                f"{change['after']:.0%} of those from it on fit the estimate, while each side solved alone fits "
                f"{change['own_before']:.0%} and {change['own_after']:.0%} of its own: the estimate is a compromise "
                "of two mounts (the mount likely moved inside the drive, or what the rows see changed), which a batch "
                "solve pools; calibrate with --mode window, whose step test restarts from a step")
    return (f"{change['before']:.0%} of the rows of the frames before frame {change['frame']} fit the estimate and "
            f"{change['after']:.0%} of those from it on ({change['z']:.0f} stds of their frame-to-frame spread): the "
            "mount likely moved inside the drive at about that frame (or what the rows see changed there), and a batch "
            "solve pools both sides; calibrate with --mode window, whose step test restarts from a step (--max-frames "
            f"{change['frame']} calibrates the frames before it alone)")


def _inlier_fraction(T: np.ndarray, frames: list[Correspondences], conf: BatchConfig) -> float:
    """The fraction of the drive's rows inside the final gate at ``T``: rows counted, not frames averaged (one
    frame of 300 rows that fit and three of 5 that do not is 90 %, not 24 %: probe 28)."""
    rowed = [f for f in frames if len(f)]
    fitting = sum(frame_information(T, f, conf.factor, conf.schedule.final_gate)[2] * len(f) for f in rowed)
    return float(fitting / sum(len(f) for f in rowed)) if rowed else 0.0


def _progressive_start(frames: list[Correspondences], T0: np.ndarray, conf: BatchConfig, priors
                       ) -> tuple[np.ndarray, int, float]:
    """(the batch's estimate after solving the first 1, 4, 16, ... of ``frames``, each from the previous optimum,
    starting at ``T0``; iterations; seconds)."""
    T, iters, secs = T0, 0, 0.0
    for k in _prefixes(len(frames)):
        T, _, _, _, it, sec, _ = _solve(frames[:k], T, conf, priors, covariance=False)
        iters, secs = iters + it, secs + sec
    return T, iters, secs


def _window_start(frames: list[Correspondences], T0: np.ndarray, conf: BatchConfig, priors
                  ) -> tuple[np.ndarray, int, float]:
    """(the sliding window's estimate after ``frames``, from ``T0``, with the batch's factor and schedule;
    iterations (not counted: 0); seconds). Measured (5-frame urban drive, R1 start 10.5 deg off, real reflector
    heights): the batch and its progressive re-solve settled 66 deg away with 15 % of the rows fitting, the window
    2.8 deg away with 80 %."""
    from hybrid_calib.calib.window import SlidingWindowCalibrator

    t0 = time.perf_counter()
    cal = SlidingWindowCalibrator(T0, {"factor": conf.factor, "schedule": conf.schedule})
    for k, f in enumerate(frames):
        out = cal.update(f, priors[0] if priors and k == 0 and len(priors) == 1 else None)
    return out.T, 0, time.perf_counter() - t0


def _given_start(frames: list[Correspondences], T0: np.ndarray, conf: BatchConfig, priors
                 ) -> tuple[np.ndarray, int, float]:
    """(``T0`` itself, 0, 0.0): the start, solved again without the schedule's convex stage. Probe 118: on the
    simulator's oracle rows (20 % gross outliers) the Huber stage's lowest cost is a collapsed pose that puts every
    reflector 35-80 m ahead, 50-72 deg from the truth, and it walked there even from the truth; the default Cauchy
    stage came back, Tukey and Geman-McClure did not (2-5 of 8 R1 solves NOT CONVERGED)."""
    return np.asarray(T0, np.float64), 0, 0.0


def _prefixes(n: int) -> list[int]:
    """Frame counts of the progressive re-solve: 1, 4, 16, ... below ``n``."""
    out, k = [], 1
    while k < n:
        out.append(k)
        k *= 4
    return out


def _prior_info(priors: list[GaussianPrior] | None) -> np.ndarray:
    """Summed information (6, 6) of the external priors on T_cam_radar."""
    return sum((np.linalg.inv(p.cov) for p in priors or []), np.zeros((6, 6)))


def _solve_ceres(frames, T_init, conf: BatchConfig, priors, convex_start: bool = True):
    """The schedule (``run_schedule``, the same ``ScheduleConfig`` as GTSAM) with Ceres solving each
    stage; the covariance from Ceres at the last stage, the information for the status from the
    same residuals (``frame_information``, gated least squares). Returns (T, info, cov or None, why
    cov is None, iterations, solve seconds, perf_counter at the start of the covariance)."""
    from factors.ceres_costs import ceres_covariance, solve_ceres_stage

    if priors and len(priors) > 1:
        raise ValueError("the ceres back end takes at most one prior")
    prior = (priors[0].T, priors[0].cov) if priors else None
    sched = conf.schedule
    t0 = time.perf_counter()

    def solve_stage(stage_frames, stage_conf, T0):
        r = solve_ceres_stage(stage_frames, T0, stage_conf, prior, max_iterations=sched.max_iterations)
        failure = "" if r.usable else f"ceres failed: {r.message}"
        return Stage(r.T, r.iterations, r.final_cost, r, failure)

    last, iters = run_schedule(frames, T_init, conf.factor, sched, solve_stage, convex_start=convex_start)
    secs = time.perf_counter() - t0
    t1 = time.perf_counter()
    cov = None if last.failure else ceres_covariance(last.state)
    T = last.T
    info = sum((frame_information(T, f, conf.factor, sched.final_gate)[1] for f in frames if len(f)), np.zeros((6, 6)))
    info = info + _prior_info(priors)
    why = "" if cov is not None else \
        f"ceres covariance unavailable ({last.failure or 'rank-deficient'}); using the regularised pseudo-inverse"
    return T, np.asarray(info), cov, why, iters, secs, t1
