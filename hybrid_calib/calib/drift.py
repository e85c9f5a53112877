"""Drift detection: has the extrinsic moved away from a reference, or stepped inside a drive?

Two tests, both chi-square tests on a 6-DoF difference in the right tangent of ``T_cam_radar``
(docs/conventions.md):

1. Against a reference (the vehicle's calibration tables, i.e. its factory calibration):
   ``d = local(T_ref, T_est)`` (6,), ``s = d^T (C_est + C_ref)^-1 d`` ~ chi2(6) under "no change"
   (statistic and p-value reported), and a VERDICT in words from a per-axis tolerance test in
   camera axes (pitch, yaw, roll about camera x, y, z; lateral, vertical, longitudinal offset along
   camera x, y, z): an axis whose ``|delta| - z_out sigma`` exceeds the tolerance
   (``tolerance_rot_deg``, ``tolerance_trans_cm``) DIFFERS ("differs by 0.9 deg in yaw:
   recalibrate"; ``z_out = Phi^-1(1 - alpha / 6)``, one-sided, Bonferroni over the 6 axes: a
   false "recalibrate" has probability <= alpha); an axis with ``|delta| + z_in sigma`` inside it
   is within tolerance (``z_in = Phi^-1(1 - alpha)``: "all axes within" is an intersection-union
   test, level alpha without a correction); anything else cannot be told apart ("cannot tell:
   ..."), naming why: the axis is prior-pinned (a 2D radar does not observe pitch and height:
   ``pinned_std``, ``covariance.pinned_camera_axes``) or its std is too large.
   Prior-pinned axes whose difference is not itself beyond the tolerance are listed as "not
   checked" and do not block "within tolerance" of the observed axes. A significant but
   sub-tolerance change is not a reason to recalibrate: with hundreds of frames a sub-millimetre
   change is significant but irrelevant.
2. Step change inside a drive (``StepDetector``): a windowed chi-square of the estimate from the
   last ``m`` frames alone against the long-run estimate. Every frame the recent estimate is the
   Gauss-Newton step of the recent frames' cached linearisations (free); every ``every`` frames and
   whenever a frame's inlier fraction collapses it is re-solved from scratch with a convex start,
   so that a step large enough to push every new correspondence outside the inlier gate (which a
   warm-started redescending kernel would ignore: lock-on) is followed instead of rejected.
   With the long-run information ``I_all`` and the recent
   frames' information ``I_m`` (a subset of it), the difference of the two efficient estimates has
   covariance ``I_m^-1 - I_all^-1`` (Hausman), so ``s = d^T (I_m^-1 - I_all^-1)^-1 d`` ~ chi2(6).
   On realistic scenes the windowed statistic is over-dispersed (the reflector heights of a few
   frames bias their estimate by more than the pixel noise says: median 8-9 instead of chi2(6)'s
   5.35 on the straight preset), so the statistic is divided by a running scale, the median of the
   last ``scale_window`` statistics over chi2(6)'s median (at least 1; from ``scale_min_tests`` on;
   kept across restarts: it is a property of the scenes and the model, not of the extrinsic).
   An alarm needs the scaled ``s`` above the chi2(6) quantile at ``p_alarm`` on ``consecutive``
   tests. Hysteresis: after an alarm the detector is disarmed until the scaled statistic has been
   below the re-arm level (the chi2(6) quantile at ``rearm_p``) on ``rearm_tests`` tests in a row,
   so one step raises one alarm. False-alarm rate and detection delay: benchmarks/bench_steps.py,
   docs/benchmarks.md.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from hybrid_calib.geometry import local, retract


@dataclass(frozen=True)
class DriftConfig:
    alpha: float = 0.01  # significance level of the reference test (p-value below -> significant)
    tolerance_rot_deg: float = 0.5  # per camera axis: a rotation difference inside this needs no recalibration (deg)
    tolerance_trans_cm: float = 2.0  # per camera axis: a translation difference inside this needs none (cm)
    ref_rot_std_deg: float = 0.0  # uncertainty of the reference itself, per axis (deg), added to C_est
    ref_trans_std_cm: float = 0.0  # uncertainty of the reference itself, per axis (cm), added to C_est


@dataclass(frozen=True)
class StepConfig:
    recent_frames: int = 5  # m: frames in the recent estimate that is tested against the long-run one
    min_history: int = 15  # the long-run estimate must hold at least this many frames before testing
    p_alarm: float = 1e-4  # per-frame false-alarm probability of the windowed chi-square test
    consecutive: int = 2  # tests in a row above the threshold before an alarm (the tails are heavier than chi2)
    every: int = 10  # the convex-start test (one small solve) runs every this many frames ...
    inlier_drop: float = 0.6  # ... and at once when a frame's inlier fraction falls below this x the running mean
    scale_window: int = 100  # tests in the running median that scales the statistic (over-dispersion)
    scale_min_tests: int = 10  # the statistic is scaled from this many tests on
    rearm_p: float = 0.1  # hysteresis: after an alarm, re-arm once the scaled statistic < chi2.isf(rearm_p, 6) ...
    rearm_tests: int = 3  # ... on this many tests in a row


# report axes in camera coordinates (docs/conventions.md): rotation about / translation along camera x, y, z
AXIS_WORDS = ("pitch", "yaw", "roll", "lateral offset", "vertical offset", "longitudinal offset")
AXIS_KEYS = ("rot_x_deg", "rot_y_deg", "rot_z_deg", "t_x_cm", "t_y_cm", "t_z_cm")
VERDICT_KINDS = ("within tolerance", "recalibrate", "cannot tell")


@dataclass(frozen=True)
class AxisCheck:
    """One camera axis of the reference test: difference and std in deg (rotation) or cm."""

    name: str
    delta: float
    std: float
    tolerance: float
    decision: str  # "within" | "differs" | "undecided"
    prior_pinned: bool  # most of the axis' variance is the elevation prior's (the data do not see it)

    @property
    def unit(self) -> str:
        return "deg" if self.name in AXIS_WORDS[:3] else "cm"

    def to_dict(self) -> dict:
        return {"delta": float(self.delta), "std": float(self.std), "tolerance": float(self.tolerance),
                "unit": self.unit, "decision": self.decision, "prior_pinned": bool(self.prior_pinned)}


@dataclass(frozen=True)
class DriftDecision:
    """Result of the reference test. ``delta_report``: [rot x, y, z deg, t x, y, z cm] camera axes.

    verdict_kind: one of ``VERDICT_KINDS``; verdict: the sentence a fleet engineer reads
    ("within tolerance", "differs by 0.9 deg in yaw: recalibrate", "cannot tell: pitch is
    prior-pinned ..."); axes: the per-axis checks behind it. ``drifted`` = "recalibrate".
    """

    statistic: float
    dof: int
    p_value: float
    threshold: float
    significant: bool
    exceeds_margin: bool
    drifted: bool
    delta_report: np.ndarray
    rot_change_deg: float
    trans_change_cm: float
    verdict_kind: str = "cannot tell"
    verdict: str = ""
    axes: tuple[AxisCheck, ...] = ()
    z: float = float("nan")

    def to_dict(self) -> dict:
        return {
            "test": "chi-square on d = local(T_ref, T_est), s = d^T (C_est + C_ref)^-1 d, dof 6",
            "statistic": float(self.statistic), "dof": self.dof, "p_value": float(self.p_value),
            "threshold": float(self.threshold), "significant": bool(self.significant),
            "exceeds_margin": bool(self.exceeds_margin), "drifted": bool(self.drifted),
            "delta_camera": {k: float(v) for k, v in zip(AXIS_KEYS, self.delta_report)},
            "rot_change_deg": float(self.rot_change_deg), "trans_change_cm": float(self.trans_change_cm),
            "verdict_kind": self.verdict_kind, "verdict": self.verdict,
            "verdict_test": f"per camera axis: differs if |delta| - {self.z:.2f} sigma > tolerance, within if "
                            "|delta| + z_in sigma <= tolerance (z_in = Phi^-1(1 - alpha))",
            "axes": {a.name: a.to_dict() for a in self.axes},
        }


def drift_verdict(drift: dict | None) -> str:
    """The verdict sentence of a stored ``VehicleResult.drift`` dict ("" when there is none). Files
    written before verdicts existed only hold ``drifted``: they read "drifted (no verdict stored)"."""
    if not drift:
        return ""
    if drift.get("verdict"):
        return str(drift["verdict"])
    return "drifted (no verdict stored)" if drift.get("drifted") else "no drift (no verdict stored)"


def chi2_quadratic(d: np.ndarray, cov: np.ndarray) -> float:
    """``d^T cov^-1 d`` with a symmetric pseudo-inverse (never raises on a singular cov)."""
    d = np.asarray(d, dtype=np.float64)
    cov = 0.5 * (np.asarray(cov, dtype=np.float64) + np.asarray(cov, dtype=np.float64).T)
    return float(d @ np.linalg.pinv(cov, hermitian=True) @ d)


def _fmt(x: float, unit: str) -> str:
    return f"{x:.2g} {unit}" if abs(x) < 0.1 else f"{x:.2f} {unit}" if abs(x) < 10 else f"{x:.0f} {unit}"


def _and(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def _check_axes(delta: np.ndarray, std: np.ndarray, pinned: np.ndarray, conf: DriftConfig, z_out: float,
                z_in: float) -> list[AxisCheck]:
    out = []
    for i, name in enumerate(AXIS_WORDS):
        tol = conf.tolerance_rot_deg if i < 3 else conf.tolerance_trans_cm
        lo, hi = abs(delta[i]) - z_out * std[i], abs(delta[i]) + z_in * std[i]
        decision = "differs" if lo > tol else "within" if hi <= tol else "undecided"
        out.append(AxisCheck(name, float(delta[i]), float(std[i]), tol, decision, bool(pinned[i])))
    return out


def _verdict(axes: list[AxisCheck]) -> tuple[str, str]:
    """(kind, sentence) from the per-axis checks (module docstring)."""
    differs = [a for a in axes if a.decision == "differs"]
    if differs:
        parts = [f"{_fmt(abs(a.delta), a.unit)} in {a.name} (+- {_fmt(a.std, a.unit)}, tolerance "
                 f"{_fmt(a.tolerance, a.unit)})" for a in differs]
        return "recalibrate", "differs by " + "; ".join(parts) + ": recalibrate"
    # a prior-pinned axis only blocks the verdict when its difference itself is beyond the tolerance
    blocking = [a for a in axes if a.decision == "undecided" and (not a.prior_pinned or abs(a.delta) > a.tolerance)]
    unchecked = [a for a in axes if a.decision == "undecided" and a not in blocking]
    note = ""
    if unchecked:
        note = (f"; {_and([a.name for a in unchecked])} not checked: prior-pinned "
                f"(std {', '.join(_fmt(a.std, a.unit) for a in unchecked)}; a 2D radar does not observe "
                f"{'it' if len(unchecked) == 1 else 'them'})")
    if not blocking:
        return "within tolerance", "within tolerance" + note
    why = []
    for a in blocking:
        if a.prior_pinned:
            why.append(f"{a.name} is prior-pinned (differs by {_fmt(abs(a.delta), a.unit)} +- {_fmt(a.std, a.unit)}, "
                       f"tolerance {_fmt(a.tolerance, a.unit)}; the data do not observe it)")
        else:
            why.append(f"{a.name} differs by {_fmt(abs(a.delta), a.unit)} +- {_fmt(a.std, a.unit)}, not precise "
                       f"enough to decide against the {_fmt(a.tolerance, a.unit)} tolerance (more frames narrow it)")
    return "cannot tell", "cannot tell: " + "; ".join(why) + note


def reference_test(
    T_est: np.ndarray, cov_est: np.ndarray, T_ref: np.ndarray, conf: DriftConfig | None = None,
    pinned_std: np.ndarray | None = None,
) -> DriftDecision:
    """Chi-square test and tolerance verdict of the estimate (4, 4) with covariance (6, 6, right
    tangent, radar frame) against a reference (4, 4).

    pinned_std: optional (6,) right-tangent std (rad, m) of the directions only the elevation
    prior pins (``covariance.prior_pinned_std``), already contained in ``cov_est``; the camera axes
    they map to (``covariance.pinned_camera_axes``: pitch, vertical offset) are named
    "prior-pinned" in the verdict.
    """
    from scipy.stats import norm

    from hybrid_calib.calib.covariance import pinned_camera_axes, report_basis
    from hybrid_calib.config import merge

    conf = merge(DriftConfig, conf)
    T_est, T_ref = np.asarray(T_est, float), np.asarray(T_ref, float)
    d = local(T_ref, T_est)
    C_ref = np.diag([np.radians(conf.ref_rot_std_deg) ** 2] * 3 + [(conf.ref_trans_std_cm / 100) ** 2] * 3)
    # the reference's std is given in camera axes: rotate into the radar-frame tangent of T_est
    B = report_basis(T_est)
    C = np.asarray(cov_est, float) + B.T @ C_ref @ B
    s = chi2_quadratic(d, C)
    p = float(chi2.sf(s, 6))
    thr = float(chi2.isf(conf.alpha, 6))
    R = T_est[:3, :3]
    delta_report = np.concatenate([np.degrees(R @ d[:3]), (T_est[:3, 3] - T_ref[:3, 3]) * 100])
    units = np.array([np.degrees(1.0)] * 3 + [100.0] * 3)
    var_rep = np.clip(np.diag(B @ C @ B.T), 0.0, None)
    std_report = np.sqrt(var_rep) * units
    pinned = pinned_camera_axes(B, pinned_std)
    z = float(norm.isf(conf.alpha / 6))
    axes = _check_axes(delta_report, std_report, pinned, conf, z, float(norm.isf(conf.alpha)))
    kind, sentence = _verdict(axes)
    rot = float(np.degrees(np.linalg.norm(d[:3])))
    trans = float(np.linalg.norm(delta_report[3:]))
    exceeds = any(abs(a.delta) > a.tolerance for a in axes)
    return DriftDecision(s, 6, p, thr, p < conf.alpha, exceeds, kind == "recalibrate", delta_report, rot, trans,
                         kind, sentence, tuple(axes), z)


@dataclass
class StepTest:
    """One evaluation of the windowed step test. statistic: scaled (``raw / scale``); armed: the
    detector could raise an alarm at this test (hysteresis)."""

    statistic: float
    threshold: float
    above: bool
    alarm: bool
    raw: float = float("nan")
    scale: float = 1.0
    armed: bool = True


@dataclass(frozen=True)
class StepOutcome:
    """One windowed step test of the sliding window (``StepDetector.check``).

    test: the statistic, threshold and alarm. T_recent: (4, 4) the convex-start estimate of the
    recent frames when it was solved (always after an alarm: the window restarts from it), else None.
    """

    test: StepTest
    T_recent: np.ndarray | None


# () -> ((4, 4) estimate, (6, 6) information) of the recent frames alone, solved with a convex start
RecentSolver = Callable[[], tuple[np.ndarray, np.ndarray]]


class StepDetector:
    """Windowed chi-square of the recent-frames estimate against the long-run estimate.

    The caller passes both estimates with their information matrices (``test``), or the recent
    frames' linearisation and a solver for them (``check``); the detector keeps the count of
    consecutive exceedances and the running inlier fraction whose collapse triggers a re-solve.
    """

    def __init__(self, conf: StepConfig | None = None):
        from hybrid_calib.config import merge

        self.conf = merge(StepConfig, conf)
        self.threshold = float(chi2.isf(self.conf.p_alarm, 6))
        self.rearm_level = float(chi2.isf(self.conf.rearm_p, 6))
        self._run = 0
        self._below = 0
        self.armed = True
        self.inlier_mean: float | None = None  # running mean of the frames' inlier fractions
        self._history: deque[float] = deque(maxlen=max(1, self.conf.scale_window))

    def reset(self) -> None:
        """After a restart of the window: forget the run of exceedances and the inlier mean; keep
        the statistic's scale and the hysteresis state (one step, one alarm)."""
        self._run = 0
        self.inlier_mean = None

    @property
    def scale(self) -> float:
        """Over-dispersion of the statistic: median of the recent statistics / chi2(6) median, >= 1."""
        if len(self._history) < max(1, self.conf.scale_min_tests):
            return 1.0
        return max(1.0, float(np.median(self._history)) / float(chi2.median(6)))

    def ready(self, n_total: int, n_window: int) -> bool:
        """Enough history to test: ``n_total`` frames in the long-run estimate, ``n_window`` in the window."""
        m = self.conf.recent_frames
        return n_total >= max(self.conf.min_history, 2 * m) and n_window >= m

    def collapsed(self, inlier_fraction: float) -> bool:
        """The frame's inlier fraction fell below ``inlier_drop`` x the running mean (a lock-on)."""
        return self.inlier_mean is not None and inlier_fraction < self.conf.inlier_drop * self.inlier_mean

    def resolve_due(self, index: int, collapsed: bool) -> bool:
        """Re-solve the recent frames with a convex start at update ``index``: every ``every`` updates
        and whenever the inlier fraction collapsed."""
        return collapsed or index % max(1, self.conf.every) == 0

    def track_inliers(self, inlier_fraction: float, n_seen: int) -> None:
        """Fold a frame's inlier fraction into the running mean (``n_seen``: frames since the last
        reset; the weight of the past is capped at 50 frames so the mean follows slow changes)."""
        k = min(n_seen, 50)
        m = self.inlier_mean
        self.inlier_mean = inlier_fraction if m is None else (m * k + inlier_fraction) / (k + 1)

    def check(self, T_long: np.ndarray, info_long: np.ndarray, recent: tuple[np.ndarray, np.ndarray],
              solve_recent: RecentSolver, resolve: bool) -> StepOutcome:
        """One test of the sliding window.

        T_long (4, 4), info_long (6, 6): the long-run estimate and its information. recent:
        (gradient (6,), information (6, 6)) at T_long of the recent frames' cached linearisations;
        their Gauss-Newton step is the free recent estimate. With ``resolve`` the recent frames are
        also solved from scratch (``solve_recent``, convex start) and the larger statistic counts.
        """
        G, H = recent
        stat = self.statistic(T_long, info_long, retract(T_long, -np.linalg.pinv(H) @ G), H)
        T_recent = None
        if resolve:
            T_recent, info_recent = solve_recent()
            stat = max(stat, self.statistic(T_long, info_long, T_recent, info_recent))
        test = self.observe(stat)
        if test.alarm and T_recent is None:
            T_recent, _ = solve_recent()
        return StepOutcome(test, T_recent)

    def statistic(self, T_long: np.ndarray, info_long: np.ndarray, T_recent: np.ndarray,
                  info_recent: np.ndarray) -> float:
        """Windowed chi-square (dof 6). T_*: (4, 4); info_*: (6, 6) right-tangent information. The
        recent frames are a subset of the long-run estimate's frames."""
        d = local(np.asarray(T_long, float), np.asarray(T_recent, float))
        cov_recent = np.linalg.pinv(0.5 * (info_recent + info_recent.T), hermitian=True)
        cov_long = np.linalg.pinv(0.5 * (info_long + info_long.T), hermitian=True)
        cov_d = cov_recent - cov_long
        # Hausman's difference is PSD only for efficient, same-weight estimates; fall back to the
        # (conservative) recent covariance when it is not.
        if np.min(np.linalg.eigvalsh(0.5 * (cov_d + cov_d.T))) <= 0:
            cov_d = cov_recent
        return chi2_quadratic(d, cov_d)

    def observe(self, s: float) -> StepTest:
        """Record one raw statistic; scaled by the running scale (before it joins the history), an
        alarm after ``consecutive`` exceedances in a row while armed; disarmed after an alarm until
        ``rearm_tests`` scaled statistics in a row are below ``rearm_level``."""
        scale = self.scale
        z = float(s) / scale
        self._history.append(float(s))
        above = z > self.threshold
        armed = self.armed
        if not armed:
            self._below = self._below + 1 if z < self.rearm_level else 0
            if self._below >= self.conf.rearm_tests:
                self.armed, self._below = True, 0
            self._run = 0
            return StepTest(z, self.threshold, bool(above), False, float(s), scale, False)
        self._run = self._run + 1 if above else 0
        alarm = self._run >= self.conf.consecutive
        if alarm:
            self.armed, self._run, self._below = False, 0, 0
        return StepTest(z, self.threshold, bool(above), bool(alarm), float(s), scale, True)

    def test(self, T_long: np.ndarray, info_long: np.ndarray, T_recent: np.ndarray,
             info_recent: np.ndarray) -> StepTest:
        """``statistic`` then ``observe``."""
        return self.observe(self.statistic(T_long, info_long, T_recent, info_recent))
