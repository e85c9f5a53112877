"""Has the radar moved on the vehicle? A step test on the radar's heading against the vehicle's own motion.

Per pair of sweeps (``calib.ego_doppler``: each sweep and the latest one ``pair_dt_s`` or more before it;
on a root with the radar's non-keyframe sweeps 6-7 pairs per keyframe interval, on a keyframe-only root the
pair of consecutive keyframes) the radar's Doppler gives the direction of its own travel in its
own frame (``sensors.radar_velocity``, the chord of its velocities at the two sweeps), and the ego
poses at the two radar timestamps give the same travel in the vehicle's frame (odometry: the
vehicle's displacement ``D`` and rotation ``R_A`` between the sweeps, in ego frame a). Each keyframe's
reading is the median of the pairs ending in its interval. With the radar's mount ``T_ego_radar`` the
residual is the factor of ``factors.motion`` with the ego in the camera's place::

    d = R^T (D + (R_A - I) t),    y = wrap(atan2(d_y, d_x) - psi)        (T_ego_radar = (R, t))

``y`` is the radar's yaw on the vehicle minus the mount's (plus the Doppler's own bias): constant
while the radar stays where it is, and it moves by the yaw of a knock at once. It needs no camera
and no network, and it does not depend on the reference mount's rotation (only on its lever arm
``t``, to centimetres): the test looks for a change of ``y``, not at its level. Its noise is the
Doppler's, ~0.15-0.3 deg per pair in the simulator (a 1 deg knock is 3-6 sigma in one pair; the median of a
keyframe interval's 6 pairs 0.07-0.105 deg), against
~1.1 deg for the camera's two-view odometry (``hybrid.motion``), whose errors also drift with the
scene by about as much as a knock (measured, docs/benchmarks.md "The mount monitor").

The test (``MountMonitor``). The level is the median of the last ``level_pairs`` values of ``y``
since the last change (at least ``min_frames``) before a CUSUM's current excursion, so a step does
not pull it along while the slow wander of the Doppler's bias (a few tenths of a degree over tens of
frames, with the scene) is followed. Only an excursion of ``freeze_at`` noise sigmas or more holds the
level: one that has barely left zero did so by chance, and holding the level there made the wander that
followed an alarm (probe 26: on the real scene-0916 a 0.005 deg change of one reading decided between "no
step" and "turned 0.58 deg"; replayed, 25 of 37 real series flipped under a 0.01 deg change, 0 with
``freeze_at`` 1, while the alarms of 101 simulated series, 10 of them with steps or drifts, were unchanged).
The noise scale is the larger of those values' median absolute deviation and their successive differences'
(over sqrt 2), at least ``floor_deg / sqrt(n)`` for readings of ``n`` pairs (the level's median; ``floor_deg``
is one pair's floor), at least ``wander_deg`` (the Doppler's slow wander with the scene, which more pairs do not
average down), and at least the readings' own noise: the median over the level's readings of the scatter of each
reading's pairs about their median, as the std of that median (``reading_std``; readings of 3 or more pairs). A few
readings that agree by chance do not make a noisy radar's level look steady (probe 39: a randomised radar, 0.24 m/s
velocity noise, pairs scattered by ~0.5 deg; its first 5 readings agreed within 0.05 deg, the 18 after wandered by
+-0.5 deg with no change, and the test alarmed "turned 0.43 +- 0.11 deg"). The standardised
deviations ``z``, clipped to ``+-clip`` (one failed Doppler fit adds at most ``clip - drift``), feed
a two-sided CUSUM with allowance ``drift``; above ``threshold`` it alarms. The change point is the
split of the level's pairs with the largest two-sample mean difference (``change_point``), the step
is the median after it minus the median before it, and the test restarts from the change point
(hysteresis: one step, one alarm; the new level needs ``min_frames`` pairs before the next alarm).

Skipped pairs (and why): slower than ``min_speed_mps`` (the Doppler heading is noise), turning
faster than ``max_turn_dps`` (the chord model and the sweep's timing error grow with the turn
rate: on the real nuScenes scene-0916 ``y`` moves by 1.5 deg in 20-30 deg/s turns, and by
less than its noise up to 15 deg/s), further apart
than ``max_gap_s``, no ego pose, an unreadable frame, no Doppler velocity.

What it does not see: a radar tilt (roll, pitch: a 2D radar's Doppler lies in its own plane), a
translation of the radar, and a camera that moves (the camera's heading is VO's, ``hybrid.motion``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from factors.motion import heading_residual
from hybrid_calib.calib.ego_doppler import EgoSweep, ego_measurement, frame_sweeps, pair_skip, partner
from hybrid_calib.config import require, require_ranges
from hybrid_calib.data.mounts import same_calibration
from hybrid_calib.data.reference import reference_nouns
from hybrid_calib.errors import DataError
from hybrid_calib.metrics import mad_scale

MOUNT_KEY = "monitor_T_ego_radar"  # a sweep's extras: the reference radar mount of its frame (MountMonitor.mount_at)

MEDIAN_VAR = np.pi / 2  # variance of a Gaussian sample's median, in units of sigma^2 / n
# the drive's last reading this far from the level, in its noise, of this many sweep pairs: said (``end_reading``)
END_Z, END_PAIRS = 6.0, 3
# on a drive too short for the step test, the readings either side of its longest untested stretch (at least this many
# frames) this far apart in their noise: the radar may have turned there (``short_split``)
SPLIT_GAP, SPLIT_Z = 3, 4.0


@dataclass(frozen=True)
class MountMonitorConfig:
    enabled: bool = True  # run the monitor (hybrid: a step alarm restarts the window from the change)
    min_speed_mps: float = 2.0  # slower: the Doppler heading is too noisy, the pair is skipped
    max_gap_s: float = 1.5  # radar sweeps further apart are not a pair
    max_turn_dps: float = 15.0  # faster turns are skipped (module doc), deg/s
    floor_deg: float = 0.25  # the smallest noise std the test assumes for one pair, deg (benchmarks/mount_steps.py)
    # the smallest for any reading, however many pairs: the Doppler's slow wander with the scene, which the median
    # of an interval's pairs does not average down (a 0.12 deg drift alarmed on a test highway drive without it; a
    # fresh seed confirms it: docs/benchmarks.md "The radar mount monitor"), deg
    wander_deg: float = 0.15
    drift: float = 1.0  # CUSUM allowance per pair, in noise sigmas (half the smallest step sought: 2 sigma)
    threshold: float = 8.0  # CUSUM alarm level, in noise sigmas
    clip: float = 3.0  # standardised deviations are clipped to +-this (heavy tails)
    freeze_at: float = 1.0  # a CUSUM excursion holds the level only from this size on, in noise sigmas (module doc)
    level_pairs: int = 20  # the level: the median of at most this many readings (it follows the Doppler's slow wander)
    min_frames: int = 8  # readings of a level before the test runs (after the start and after each change)
    sweeps: bool = True  # pair the non-keyframe sweeps too, where the root has them (calib.ego_doppler)
    pair_dt_s: float = 0.4  # a sweep's partner is the latest sweep at least this much earlier (calib.ego_doppler), s
    # a level farther than this from the tables' mount (deg, beyond 3 of its stds) is no mount a radar holds: the
    # ego poses' headings or the radar's velocity fields are wrong (mirrored poses read -110 deg, doubled +55)
    max_level_deg: float = 10.0

    def blind_end(self) -> int:
        """The readings at a drive's end in which a step cannot alarm (the fewest that can is one more): each adds at
        most ``clip - drift`` to the CUSUM, which must exceed ``threshold`` (4 by default: a radar turned 180 deg with
        4 readings left read "too near the end for a step alarm (an alarm needs 4 frames)": probe 39)."""
        return int(np.floor(self.threshold / (self.clip - self.drift)))

    def finds_deg(self, scatter_deg: float, frames: int, within: int = 20) -> float:
        """The smallest yaw step, deg, the test finds within ``within`` readings of it in about 9 drives of 10, for
        readings that scatter by ``scatter_deg`` about a level of ``frames`` readings. After a step of d the CUSUM
        rises by d / (s a) - ``drift`` a reading (s the scatter, a^2 = 1 + pi/2 / n for the level's median of n
        readings); over ``within`` readings its noise has the variance (within + within^2 pi/2 / n) / a^2 (each
        reading's own, and the level's error, common to all of them); the rise must pass ``threshold`` by 1.96 of
        that std. The margin absorbs what the model leaves out (the scatter's own estimation error, where the CUSUM
        stood at the step): simulated Gaussian readings (0.2, 0.3, 0.6 deg; levels of 12 and 40) stepped by 2.2 of
        their measured scatter, about this size, were found within 20 readings in 91-95 % of 150 drives each. On the
        simulated drives: a drive whose readings scatter by 0.63 deg (1.4 deg here) missed a 0.5 deg knock, every
        drive that found one scattered by 0.31 deg or less (docs/benchmarks.md "The radar mount monitor")."""
        n = max(min(frames, self.level_pairs), 1)
        a = np.sqrt(1.0 + MEDIAN_VAR / n)
        noise = np.sqrt(within + within ** 2 * MEDIAN_VAR / n) / a
        return float(scatter_deg * a * (self.drift + (self.threshold + 1.96 * noise) / within))

    def __post_init__(self):
        require(self, {
            "min_frames >= 3": self.min_frames >= 3, "floor_deg > 0": self.floor_deg > 0,
            "wander_deg >= 0": self.wander_deg >= 0, "threshold > 0": self.threshold > 0,
            "clip > drift": self.clip > self.drift, "level_pairs >= min_frames": self.level_pairs >= self.min_frames,
            "max_turn_dps > 0": self.max_turn_dps > 0, "min_speed_mps >= 0": self.min_speed_mps >= 0,
            "max_gap_s > 0": self.max_gap_s > 0, "0 < pair_dt_s < max_gap_s": 0 < self.pair_dt_s < self.max_gap_s,
            "max_level_deg > 0": self.max_level_deg > 0})
        require_ranges(self, {"min_speed_mps": "[0, 100]", "max_gap_s": "(0, 3600]", "max_turn_dps": "(0, 360]",
                              "floor_deg": "(0, 90]", "wander_deg": "[0, 90]", "drift": "[0, 100]",
                              "threshold": "(0, 1e6]", "clip": "(0, 1000]", "level_pairs": "[3, 1e9]",
                              "freeze_at": "[0, 1e6]",
                              "min_frames": "[3, 1e9]", "max_level_deg": "(0, 180]"})


@dataclass(frozen=True)
class MountStep:
    """An alarm: at drive position ``at`` the radar's yaw on the vehicle was found to have moved by
    ``step_deg`` (+- ``std_deg``) from about position ``change`` (the first frame after the change)."""

    at: int
    change: int
    step_deg: float
    std_deg: float
    statistic: float

    def describe(self, threshold: float) -> str:
        return (f"radar mount step: the radar's heading against the vehicle's own motion (Doppler vs ego poses) "
                f"moved by {turn_words(self.step_deg, self.std_deg)} from frame {self.change} "
                f"(CUSUM {self.statistic:.1f} > {threshold:g})")


@dataclass(frozen=True)
class MountReading:
    """One frame's reading: ``residual_deg`` (None when the pair was skipped, with ``skipped`` saying
    why), its standardised deviation ``z`` from the level and the CUSUM ``statistic`` (None while the
    level is still being learned), and the ``step`` when this frame raised an alarm."""

    position: int
    residual_deg: float | None = None
    z: float | None = None
    statistic: float | None = None
    skipped: str = ""
    step: MountStep | None = None
    pairs: int = 0  # sweep pairs whose median ``residual_deg`` is

    def record(self) -> dict:
        """The reading as a frame row's ``mount`` entry (plain JSON)."""
        if self.residual_deg is None:
            return {"skipped": self.skipped}
        return {"residual_deg": self.residual_deg, "z": self.z, "statistic": self.statistic, "pairs": self.pairs}


@dataclass
class MountMonitor:
    """The test of the module doc over one drive, fed frame by frame (``update``).

    frames: indexable by dataset index -> frame (``RadarCameraFrame``: radar points and fields,
    ``extras["T_global_ego_radar"]``), with ``radar_sweeps_between`` where the non-keyframe sweeps are to be
    paired too (``calib.ego_doppler``). T_ego_radar: (4, 4) the radar's reference mount (its lever arm
    matters, its rotation does not). velocity: dataset index -> (``RadarVelocity`` | None, why); the
    hybrid passes its motion source's (one cached Doppler fit per frame for both uses); default:
    ``estimate_velocity`` of the frame with the default ``RadarVelocityConfig``."""

    frames: object
    T_ego_radar: np.ndarray
    conf: MountMonitorConfig = MountMonitorConfig()
    velocity: Callable[[int], tuple] | None = None
    sweep_cache: dict | None = None  # ``calib.ego_doppler.frame_sweeps``' cache (the hybrid's motion source's)
    # dataset index -> the reference radar mount (4, 4) at that frame, or None for ``T_ego_radar``: a vehicle whose
    # tables re-define its frame between logs (camera-radar unchanged) is measured against each log's mount (probe
    # 137: against the first frame's, a 3 deg re-definition read "the radar turned by 3.07 deg")
    mount_at: Callable[[int], np.ndarray | None] | None = None
    series: list[tuple[int, float]] = field(default_factory=list)  # (position, reading deg) of the tested frames
    pairs: list[int] = field(default_factory=list)  # sweep pairs behind each reading of ``series``
    own: list[float] = field(default_factory=list)  # each reading's own noise std (``reading_std``; nan: < 3 pairs)
    # each reading's sensitivity to the radar's forward lever arm (deg of reading per metre the tables' radar sits
    # forward of the truth; ``lever_sensitivity``; nan: not known): a wrong lever arm reads as a turn-dependent level
    lever: list[float] = field(default_factory=list)
    steps: list[MountStep] = field(default_factory=list)
    skipped: int = 0  # frames after the first with no reading
    skip_example: str = ""  # the first one's reason
    _history: list[EgoSweep] = field(default_factory=list)  # the sweeps a partner can still be (calib.ego_doppler)
    _start: int = 0  # first element of ``series`` in the current level
    _pos: float = 0.0
    _neg: float = 0.0
    _pos_from: int | None = None  # where each CUSUM last left zero (None: at the level's first tested pair)
    _neg_from: int | None = None
    # the last tested reading: (position, its offset from the level (deg), z, pairs), or None (``end_reading``)
    _last: tuple[int, float, float, int] | None = None

    def residual(self, a: EgoSweep, b: EgoSweep) -> tuple[float | None, float, str]:
        """(y deg, its ``lever_sensitivity`` deg/m, "") of the pair a -> b, or (None, nan, why it was skipped)."""
        c = self.conf
        why = pair_skip(a, b)
        if why:
            return None, float("nan"), why
        T, Ta = b.extras.get(MOUNT_KEY, self.T_ego_radar), a.extras.get(MOUNT_KEY, self.T_ego_radar)
        if T is not Ta and not same_calibration(T, Ta):  # ego poses of two frames of reference (float noise of
            # tables written by other tools is one mount: probe 138 lost every pair to 1e-7)
            return None, float("nan"), ("the tables' radar mount changes between the two sweeps (their records "
                                        "differ: a vehicle frame the tables re-define)")
        m, why = ego_measurement(a, a.velocity, b, b.velocity, T, c.min_speed_mps, c.max_gap_s, c.max_turn_dps)
        if m is None:
            return None, float("nan"), why
        y = float(np.degrees(heading_residual(T, m)[0]))
        if not np.isfinite(y):
            return None, float("nan"), "the residual is not finite (a Doppler fit without a direction)"
        return y, lever_sensitivity(T, m, y), ""

    def update(self, position: int, index: int) -> MountReading:
        """Feed the frame at drive ``position`` (dataset ``index``): the pairs ending at the sweeps of its keyframe
        interval (``calib.ego_doppler``: each sweep and its partner ``pair_dt_s`` or more before it), their
        median as the reading. Skipped, with the keyframe pair's reason, when none of them gives a residual."""
        sweeps, _ = frame_sweeps(self.frames, index, position, self.velocity, self.conf.sweeps, self.sweep_cache)
        if self.mount_at is not None and (T := self.mount_at(index)) is not None:
            for b in sweeps:  # the frame's own mount (the sweeps of a frame share its tables' record)
                b.extras[MOUNT_KEY] = np.asarray(T, np.float64)
        ys, gs, why = [], [], ""
        for b in sweeps:
            a = partner(self._history, b, self.conf.pair_dt_s)
            self._history.append(b)
            y, g, why = (None, float("nan"), "first frame of a pair") if a is None else self.residual(a, b)
            if y is not None:
                ys.append(y)
                gs.append(g)
        known = [s for s in self._history if s.timestamp_radar_us is not None]
        if known:  # keep what a partner can still be: max_gap_s back from the newest sweep (and one barrier)
            t_last = known[-1].timestamp_radar_us
            keep = next((k for k, s in enumerate(self._history) if s.timestamp_radar_us is not None
                         and (t_last - s.timestamp_radar_us) * 1e-6 <= self.conf.max_gap_s), 0)
            self._history = self._history[max(keep - 1, 0):]
        if not ys:
            if why != "first frame of a pair":
                self.skipped += 1
                self.skip_example = self.skip_example or why
            return MountReading(position, skipped=why)
        return self.add_residual(position, float(np.median(ys)), len(ys), reading_std(ys),
                                 float(np.median(gs)) if np.all(np.isfinite(gs)) else float("nan"))

    def scale(self, level: np.ndarray, pairs: float = 1.0, own: float = 0.0) -> float:
        """The level's noise std, deg (module doc): the larger of its spread and its successive
        differences' (over sqrt 2), robustly (MAD), and at least ``floor_deg / sqrt(pairs)`` (``pairs``: the
        median number of pairs in a reading of the level; the median of n pairs is ~sqrt(n) times steadier),
        ``wander_deg`` and ``own`` (the readings' own noise std, ``level_scale``)."""
        floor = max(self.conf.floor_deg / np.sqrt(max(pairs, 1.0)), self.conf.wander_deg, own)
        return max(floor, mad_scale(level), mad_scale(np.diff(level)) / np.sqrt(2.0))

    def level_scale(self, a: int, b: int) -> float:
        """``scale`` of the readings ``series[a:b]`` (at least 1), with their median number of pairs and the median of
        their own noise stds (those of 3 or more pairs)."""
        v = np.array([y for _, y in self.series[a:b]])
        own = [x for x in self.own[a:b] if np.isfinite(x)]
        return self.scale(v, float(np.median(self.pairs[a:b])), float(np.median(own)) if own else 0.0)

    def add_residual(self, position: int, y: float, pairs: int = 1, own: float = float("nan"),
                     lever: float = float("nan")) -> MountReading:
        """Test one reading ``y`` (deg; the median of ``pairs`` pairs' residuals, whose own noise std is ``own``,
        ``reading_std``, and whose sensitivity to the forward lever arm is ``lever`` deg/m) at drive ``position``
        (``update`` computes it from the frames)."""
        c = self.conf
        self.lever.append(lever)
        if len(self.series) - self._start < c.min_frames:
            self.series.append((position, y))
            self.pairs.append(pairs)
            self.own.append(own)
            return MountReading(position, y, pairs=pairs)
        # the level rests on the pairs before a CUSUM's current excursion (a step must not pull it along)
        ends = [f for f, v in ((self._pos_from, self._pos), (self._neg_from, self._neg))
                if v >= c.freeze_at and f is not None]
        end = max(min(ends, default=len(self.series)), self._start + c.min_frames)
        lo = max(self._start, end - c.level_pairs)
        level = np.array([v for _, v in self.series[lo:end]])
        base, s = float(np.median(level)), self.level_scale(lo, end)
        z = (y - base) / (s * np.sqrt(1.0 + MEDIAN_VAR / len(level)))
        self._last = (position, y - base, float(z), pairs)
        self.series.append((position, y))
        self.pairs.append(pairs)
        self.own.append(own)
        n = len(self.series) - 1
        self._pos_from = n if self._pos_from is None else self._pos_from
        self._neg_from = n if self._neg_from is None else self._neg_from
        zc = float(np.clip(z, -c.clip, c.clip))
        self._pos = max(0.0, self._pos + zc - c.drift)
        self._neg = max(0.0, self._neg - zc - c.drift)
        if self._pos == 0.0:
            self._pos_from = n + 1
        if self._neg == 0.0:
            self._neg_from = n + 1
        stat = max(self._pos, self._neg)
        if stat <= c.threshold:
            return MountReading(position, y, float(z), stat, pairs=pairs)
        cp = self.change_point(base, s)
        before = np.array([v for _, v in self.series[self._start:cp]])
        after = np.array([v for _, v in self.series[cp:]])
        step = MountStep(position, self.series[cp][0], float(np.median(after) - np.median(before)),
                         float(s * np.sqrt(MEDIAN_VAR / max(len(before), 1) + MEDIAN_VAR / len(after))), stat)
        self.steps.append(step)
        self._start, self._pos, self._neg = cp, 0.0, 0.0
        self._pos_from = self._neg_from = None
        return MountReading(position, y, float(z), stat, step=step, pairs=pairs)

    def end_reading(self) -> dict | None:
        """The drive's last reading when it lies ``END_Z`` or more of its noise from the level, of ``END_PAIRS`` or more
        sweep pairs, and raised no alarm, or None: a turn in the last frames, too near the end for the step test (a
        turn under ``max_level_deg``: ``tail_turn`` takes larger ones). Words only: one reading can be a bad Doppler
        fit (on 300-frame drives of one mount the largest of 283 readings lay 6.4-7.1 of its noise off). Probe 123: a
        radar turned 3 deg at the last frame of 30, its reading 1.46 deg (9.7) off, read "no step" and the level as
        the radar's yaw. {"frame" (position), "offset_deg", "z"}."""
        if self._last is None or not self.series or self._last[0] != self.series[-1][0]:
            return None
        position, offset, z, pairs = self._last
        if abs(z) < END_Z or pairs < END_PAIRS or (self.steps and self.steps[-1].at == position):
            return None
        return {"frame": position, "offset_deg": offset, "z": z}

    def change_point(self, base: float, s: float) -> int:
        """Index into ``series`` of the first pair after the change: the split of the current level's
        pairs (clipped to ``base +- clip s``) that maximises the two-sample mean difference in units
        of its std (the CUSUM's own start is late or early by a few pairs when the noise wanders)."""
        v = np.clip([y for _, y in self.series[self._start:]], base - self.conf.clip * s, base + self.conf.clip * s)
        n = len(v)
        c = np.arange(1, n)
        head = np.cumsum(v)[:-1]
        t = np.abs(head / c - (v.sum() - head) / (n - c)) * np.sqrt(c * (n - c) / n)
        return self._start + int(c[np.argmax(t)])

    def headings_implausible(self) -> bool:
        """Whether the current level (the pairs since the last step) already lies more than ``max_level_deg``
        beyond 3 stds from the tables' mount (``summary``'s "implausible", on the pairs seen so far): the ego
        poses' headings are then not to be trusted by anyone (the hybrid's motion
        constraint takes its rotation from the images instead). Three readings suffice: the margin is 10 deg."""
        v = np.array([y for _, y in self.series[self._start:]])
        if len(v) < 3:
            return False
        s = float(self.level_scale(self._start, len(self.series)) * np.sqrt(MEDIAN_VAR / len(v)))
        return abs(float(np.median(v))) - 3 * s > self.conf.max_level_deg

    def tail_turn(self) -> dict | None:
        """The drive's last readings when they turned away from the rest of the current level by more than
        ``max_level_deg`` (each of them, wrapped at 180 deg) before the step test could alarm, or None.

        Probe 36: a radar knocked 90 or 180 deg at frame 12 or 14 of 16 read "no step" (a step in the last
        ``blind_end`` readings cannot alarm; a level's median and robust spread pass over its last few), and the
        hybrid's estimate stayed `weak` far off. Two readings at least, or the last one alone when the median of 3 or
        more sweep pairs (a reading of one pair may be a failed Doppler fit, which the CUSUM clips); three before them
        (a level to turn from). The turn is measured from the readings after the run's first (the first one's sweep
        pairs may straddle the knock: a 90 deg knock read 45 there, probe 39), or from the last alone, then a lower
        bound ("at_least"). A turn under ``max_level_deg`` in the blind end stays unseen (said by ``blind_words``).
        Returns {"from", "to", "frames", "offset_deg" (deg), "at_least", "level_from", "level_to"} (positions)."""
        part = self.series[self._start:]
        y = np.array([v for _, v in part])
        for r in range(len(y) - 3, 0, -1):  # the longest trailing run that turned
            if r == 1 and self.pairs[-1] < 3:
                break
            d = (y[-r:] - np.median(y[:-r]) + 180.0) % 360.0 - 180.0
            d = d[0] + (d - d[0] + 180.0) % 360.0 - 180.0  # unwrapped about the first (180 deg reads +-180)
            if np.all(np.abs(d) > self.conf.max_level_deg):
                return {"from": part[-r][0], "to": part[-1][0], "frames": r,
                        "offset_deg": float(np.median(d[1:] if r > 1 else d)), "at_least": r == 1,
                        "level_from": part[0][0], "level_to": part[-r - 1][0]}
        return None

    def short_split(self) -> dict | None:
        """On a drive too short for the step test (fewer readings than a level and an alarm need, no step), the
        readings after its longest untested stretch (``SPLIT_GAP`` frames or more: a stop, a slow stretch) when they
        lie ``SPLIT_Z`` or more of their noise from those before it (two readings a side at least), else None. Probe
        145: a radar turned 2 deg during a stop at a light, on a 20-frame drive of 8 tested frames, read one level of
        0.35 deg over frames 1-19 (the yaw of no frame), and the yaw check took it. {"before_to", "after_from"
        (positions), "offset_deg", "std_deg" (deg)}."""
        n = len(self.series)
        if self.steps or n < 4 or n >= self.conf.min_frames + self.conf.blind_end():
            return None
        pos = [p for p, _ in self.series]
        k = int(np.argmax(np.diff(pos)))
        a = k + 1  # readings [0, a) before the stretch, [a, n) after it
        if pos[a] - pos[k] < SPLIT_GAP or a < 2 or n - a < 2:
            return None
        before = np.array([y for _, y in self.series[:a]])
        after = np.array([y for _, y in self.series[a:]])
        s = max(self.level_scale(0, a), self.level_scale(a, n))
        std = float(s * np.sqrt(MEDIAN_VAR / a + MEDIAN_VAR / (n - a)))
        d = float(np.median(after) - np.median(before))
        if abs(d) < SPLIT_Z * std:
            return None
        return {"before_to": int(pos[k]), "after_from": int(pos[a]), "offset_deg": d, "std_deg": std}

    def _cuts(self) -> list[int]:
        """The indices into ``series`` where its pieces start (0, each step's change), and its length last."""
        return [0] + [next(k for k, (p, _) in enumerate(self.series) if p >= s.change) for s in self.steps] + [
            len(self.series)]

    def levels(self) -> list[dict]:
        """The drive cut at its alarms: per piece the positions it spans, its level of ``y`` (deg:
        the radar's yaw on the vehicle minus the reference mount's, plus the Doppler's bias), the
        level's std, and the frames and sweep pairs behind it."""
        cuts = self._cuts()
        out = []
        for a, b in zip(cuts, cuts[1:]):
            v = np.array([y for _, y in self.series[a:b]])
            if not len(v):
                continue
            s = (self.level_scale(a, b) if len(v) > 2
                 else self.conf.floor_deg / np.sqrt(float(np.median(self.pairs[a:b]))))
            out.append({"from": self.series[a][0], "to": self.series[b - 1][0], "level_deg": float(np.median(v)),
                        "std_deg": float(s * np.sqrt(MEDIAN_VAR / len(v))), "frames": int(len(v)),
                        "pairs": int(sum(self.pairs[a:b])), "scatter_deg": float(s)})
        return out

    def summary(self) -> dict:
        """The result's ``mount`` block: steps, levels and the test's threshold. Each step's
        ``step_deg`` / ``std_deg`` are re-measured from the whole levels on either side of it (the
        figures at the alarm, from the few pairs after the change, are kept as ``*_at_alarm``)."""
        levels, steps, cuts = self.levels(), [], self._cuts()
        for j, st in enumerate(self.steps):
            d = {**vars(st), "step_deg_at_alarm": st.step_deg, "std_deg_at_alarm": st.std_deg}
            if j + 1 < len(levels):
                a, b = levels[j], levels[j + 1]
                d.update(step_deg=b["level_deg"] - a["level_deg"], std_deg=float(np.hypot(a["std_deg"], b["std_deg"])))
            lo, cut, hi = cuts[j], cuts[j + 1], cuts[j + 2]
            if cut > 0 and self.series[cut][0] - self.series[cut - 1][0] > 1:  # untested frames before its change
                d["tested_before"] = int(self.series[cut - 1][0])
            lever = lever_reading(np.array([v for _, v in self.series[lo:hi]]), np.array(self.lever[lo:hi]), cut - lo)
            if lever is not None:
                d["lever_m"] = lever
            steps.append(d)
        far = [lv for lv in levels if abs(lv["level_deg"]) - 3 * lv["std_deg"] > self.conf.max_level_deg]
        # a step measured into a far level is told (probe 36: a radar knocked 180 deg read "... so its steps are not
        # told"); one from a level already far at the drive's start is not: the tables, poses or velocities are wrong
        # from the start, and no change can be read against them (probe 95: tables with x and y swapped read
        # "recalibrate: the radar turned 4.39 deg" where the vehicle stopped turning, status inconclusive)
        untold = bool(far) and far[0] is levels[0]
        implausible = {"far": {k: far[-1][k] for k in ("level_deg", "std_deg", "from", "to")}, "implausible": (
            f"the radar's Doppler heading and the ego poses' disagree by {far[0]['level_deg']:+.1f} +- "
            f"{far[0]['std_deg']:.1f} deg (frames {far[0]['from']}-{far[0]['to']}; a radar's mount is within "
            f"{self.conf.max_level_deg:g} deg of its tables): the ego poses' headings (ego_pose.json), the radar's "
            "velocity fields or its mount in the tables are wrong"
            + ("" if steps and not untold else ", so its steps are not told")),
            **({"steps_told": False} if steps and untold else {})} if far else {}
        # readings of one level that scatter beyond any mount (probe 34: a radar turned 180 deg mid-drive read 0.08 +-
        # 89.7 deg, "no step", and the result stayed "weak" 180 deg off): no one heading to tell steps from
        scattered = [lv for lv in levels if lv["frames"] >= 3 and lv["scatter_deg"] > self.conf.max_level_deg]
        if scattered and not far:
            lv = scattered[0]
            implausible = {"scattered": {k: lv[k] for k in ("scatter_deg", "from", "to")}, "implausible": (
                f"the radar's Doppler heading on the vehicle scatters by {_spread(lv['scatter_deg'])} from frame to "
                f"frame (frames {lv['from']}-{lv['to']}; a radar's mount stays within {self.conf.max_level_deg:g} deg "
                "of its tables): the radar turned during the drive by more than its step test could place, or its "
                "velocity fields or the ego poses are wrong, so its steps are not told")}
        if (tail := self.tail_turn()) and not far and not scattered:
            implausible = {"tail": tail, "implausible": (
                f"the radar's Doppler heading on the vehicle in the {_last(tail)} lies {turn_size(tail)} from the "
                f"rest of the drive's (frames {tail['level_from']}-{tail['level_to']}; a radar's mount stays within "
                f"{self.conf.max_level_deg:g} deg of its tables): the radar turned too near the drive's end for its "
                f"step test (an alarm needs {self.conf.blind_end() + 1} frames), or those frames' velocity fields or "
                "ego poses are wrong")}
        if not implausible and (split := self.short_split()):
            implausible = {"split": split, "implausible": (
                f"on a drive too short for its step test, the radar's Doppler heading on the vehicle from frame "
                f"{split['after_from']} on lies {split['offset_deg']:+.2f} +- {split['std_deg']:.2f} deg from its "
                f"heading up to frame {split['before_to']} (the frames between untested: the vehicle stood still or "
                "moved too slowly): the radar may have turned there, so no one level is its yaw; check its mount on "
                "a longer drive")}
        end = self.end_reading() if not implausible else None
        last = levels[-1] if levels and levels[-1]["frames"] >= 3 and not implausible else None
        finds = {"finds_deg": self.conf.finds_deg(last["scatter_deg"], last["frames"]), "finds_within": 20,
                 "scatter_deg": last["scatter_deg"]} if last else {}
        return {"steps": steps, "levels": levels, "frames_tested": len(self.series), **finds,
                "pairs_tested": int(sum(self.pairs)), "threshold": self.conf.threshold, **implausible,
                **({"end_reading": end} if end else {}),
                "blind_frames": [self.conf.min_frames, self.conf.blind_end()],
                **({"frames_skipped": self.skipped, "skip_example": self.skip_example} if self.skipped else {})}


LEVER_MAX_M = 5.0  # a lever arm wrong by more than this in the tables is not offered as a step's other reading, m


def lever_sensitivity(T_ego_radar: np.ndarray, m, y_deg: float, h: float = 0.1) -> float:
    """How a pair's reading (``y_deg``, of measurement ``m`` at the mount ``T_ego_radar`` (4, 4)) moves per metre the
    mount's radar is moved forward along the vehicle's x axis, deg/m (a forward difference of ``h`` m): the radar's
    velocity in a turn is the vehicle's plus the turn rate times the lever arm, so a lever arm wrong in the tables
    reads as a level that follows the turn per metre (probe 95: tables 3 m forward, 1.9 deg while the vehicle turned,
    0.1 deg after it)."""
    T = np.array(T_ego_radar, np.float64)
    T[0, 3] += h
    return float((np.degrees(heading_residual(T, m)[0]) - y_deg) / h)


LEVER_LEVEL_DEG = 0.5  # a lever arm alone leaves the level where the vehicle drives straight within this of 0, deg


def lever_reading(y: np.ndarray, g: np.ndarray, cut: int, ratio: float = 1.5, floor_deg: float = 0.05
                  ) -> float | None:
    """The forward lever-arm error (m: how far forward of the radar its tables put it) that explains the
    readings ``y`` (deg) of two levels, split at ``cut``, as well as their step does, or None: ``y = k + L g`` (``g``
    each reading's ``lever_sensitivity``, deg/m) fitted by least squares, its residual sum of squares within
    ``ratio`` of the two levels' (each about its median) plus ``floor_deg`` squared a reading, ``|L|`` at most
    ``LEVER_MAX_M``, and ``|k|`` (the level where the vehicle drives straight) at most ``LEVER_LEVEL_DEG``: a lever arm
    alone leaves the straight-driving level at the tables' yaw, so a fit that needs a yaw far from it as well is two
    table errors, not the one a step is (probe 96: a knock where a turn ended read "2.0 m forward" with k 1.44 deg).
    A step where the vehicle's turn per metre changes is then told with that other reading: one turn of the radar, or
    its lever arm wrong in the tables, read the same there."""
    y, g = np.asarray(y, np.float64), np.asarray(g, np.float64)
    if min(cut, len(y) - cut) < 3 or not np.all(np.isfinite(g)) or np.ptp(g) <= 0:
        return None
    rss_step = float(np.sum((y[:cut] - np.median(y[:cut])) ** 2) + np.sum((y[cut:] - np.median(y[cut:])) ** 2))
    A = np.c_[np.ones(len(y)), g]
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    rss_lever = float(np.sum((y - A @ coef) ** 2))
    if abs(coef[1]) > LEVER_MAX_M or abs(coef[0]) > LEVER_LEVEL_DEG or \
            rss_lever > ratio * rss_step + len(y) * floor_deg ** 2:
        return None
    return float(coef[1])


def told_steps(summary: dict | None) -> list[dict]:
    """The steps of a ``mount`` block (``MountMonitor.summary``) that are told: none where the monitor's first level
    was already beyond any mount (``steps_told`` false: the tables, poses or velocities are wrong from the start)."""
    s = summary or {}
    return list(s.get("steps") or []) if s.get("steps_told", True) else []


def reading_std(ys) -> float:
    """A reading's own noise std, deg: the robust scatter (MAD, corrected for a small sample: x n / (n - 0.8)) of its
    ``ys`` (n pairs' residuals, deg) about their median, as the std of that median (x sqrt(pi / 2 / n)); nan for fewer
    than 3 pairs (their scatter says little)."""
    n = len(ys)
    if n < 3:
        return float("nan")
    return mad_scale(np.asarray(ys, np.float64)) * n / (n - 0.8) * float(np.sqrt(MEDIAN_VAR / n))


def reference_mounts(frames) -> Callable[[int], np.ndarray | None] | None:
    """``MountMonitor.mount_at`` of a drive of a dataset (``data.nuscenes.NuScenesRadarCamera``): the reference radar
    mount of the drive's first frame moved as the tables' own radar mount moves from it, ``T_tab(i) T_tab(0)^-1
    T_ref(0)``. One calibration's frames hold one camera-radar extrinsic, so a tables' radar mount that moves moves
    the camera with it: a vehicle frame the tables re-define between logs, measured against each log's own (probe
    137), also against an export's mount (probe 138). None (one mount for the drive) for frames without tables and
    for a simulated root, whose tables hold the true mount: it moves where the radar was knocked (probe 138: measured
    against it, a 1.5 deg knock read "no step")."""
    if not hasattr(frames, "reference_T_ego_radar") or not hasattr(frames, "frames") or getattr(frames, "simulated",
                                                                                                 False):
        return None
    anchor: list = []  # T_tab(0)^-1 T_ref(0) of the drive's first frame that reads

    def mount_at(index: int) -> np.ndarray | None:
        try:
            ref = frames.frames[index]
            T_tab = np.asarray(frames.tables.T_ego_sensor(ref.radar_sd), np.float64)
            if not anchor:
                anchor.append(np.linalg.inv(T_tab) @ np.asarray(frames.reference_T_ego_radar(ref), np.float64))
        except (DataError, KeyError, TypeError, ValueError, IndexError, AttributeError):
            return None  # the frame's reading says what is wrong with its records
        return T_tab @ anchor[0]

    return mount_at


def monitor_drive(frames, indices: list[int], T_ego_radar: np.ndarray, conf: MountMonitorConfig = MountMonitorConfig()
                  ) -> tuple[MountMonitor, list[MountReading]]:
    """The monitor over a whole drive (dataset ``indices`` in time order) against the one mount ``T_ego_radar``:
    (monitor, readings)."""
    mon = MountMonitor(frames, np.asarray(T_ego_radar, np.float64), conf)
    return mon, [mon.update(k, i) for k, i in enumerate(indices)]


def turn_words(step_deg: float, std_deg: float, n_sigma: int = 1) -> str:
    """A yaw step of the radar on the vehicle in words: "1.43 +- 0.09 deg (1 sigma) to the left in yaw" (``n_sigma``
    3: "+- x deg (3 sigma)"). The monitor measures about the vehicle's up axis (left positive); the reference test's
    yaw turns about camera y (down), so one turn of the radar reads with opposite signs there: said as a direction,
    never as a sign (probe 24: "turned by +1.43 deg in yaw" beside "yaw -1.40" for the same turn)."""
    side = _side(step_deg)
    return (f"{abs(step_deg):.2f} +- {n_sigma * std_deg:.2f} deg ({n_sigma} sigma)" + (f" {side}" if side else "")
            + " in yaw")  # the sigma always said: one step read "+- 0.34 deg (3 sigma)" and "+- 0.11 deg" (probe 30)


def _side(yaw_deg: float) -> str:
    """A yaw about the vehicle's up axis as a direction: "to the left" (positive), "to the right", or ""."""
    return "to the left" if yaw_deg > 0 else "to the right" if yaw_deg < 0 else ""


def level_words(level_deg: float, std_deg: float) -> str:
    """The radar's yaw on the vehicle against its tables' in words, a direction as ``turn_words``: "0.36 +- 0.12 deg
    (1 sigma) to the right of" (the level turns about the vehicle's up axis, left positive; a signed "-0.36" beside the
    reference test's camera yaw "+1.63" read as two different turns: probe 30)."""
    return f"{abs(level_deg):.2f} +- {std_deg:.2f} deg (1 sigma) {_side(level_deg) + ' of' if level_deg else 'at'}"


def change_words(step: dict, about: bool = True) -> str:
    """Where a ``summary()`` step changed, in words: "from about frame N" ("from frame N" without ``about``), or, where
    no reading was tested between it and the reading before (``tested_before``: a stop, sweeps without a usable Doppler
    velocity), the interval (probe 123: a radar knocked at frame 20 of a 10 s stop read "from about frame 33", the
    first tested after it)."""
    before = step.get("tested_before")
    if isinstance(before, int) and step["change"] - before > 1:
        return (f"between frames {before} and {step['change']} (frames {before + 1}-{step['change'] - 1} were not "
                "tested: no usable sweep pair there, as at a stop)")
    return f"from {'about ' if about else ''}frame {step['change']}"


def doppler_std(std_deg: float, bias_deg: float | None = None) -> float:
    """A level's 1-sigma with the Doppler's own bias (``LEVEL_BIAS_DEG`` unless given), deg: as every comparison with
    the level takes it."""
    return float(np.hypot(std_deg, LEVEL_BIAS_DEG if bias_deg is None else bias_deg))


def blind_words(summary: dict) -> str:
    """Where the monitor could not have seen a step, in words ("" for a result without ``blind_frames``): before
    its first ``min_frames`` readings (the level is being learnt) and in the last frames a step needs to push the
    CUSUM over its threshold (``MountMonitorConfig.blind_end``). A 1.5 deg knock at frame 6 of a 12-frame
    drive read "no step" as on a clean drive (probe 7)."""
    first, last = (summary.get("blind_frames") or [None, None])[:2]
    if first is None:
        return ""
    n = int(summary.get("frames_tested", 0))
    if n < first + last:
        return (f"it could not see a step on a drive this short: {n} frames tested, a level needs {first} and an alarm "
                f"{last} more")
    end = summary.get("end_reading")
    return f"blind to a step in the first {first} or the last {last} frames tested" + (
        f"; but its last reading (frame {end['frame']}) lies {end['offset_deg']:+.2f} deg ({abs(end['z']):.1f} times "
        "its noise) from the level: the radar may have turned there, too near the drive's end to confirm (check it on "
        "a later drive)" if isinstance(end, dict) else "")


def finds_words(summary: dict) -> str:
    """The smallest turn the step test would have found on this drive, in words ("" for a result without it): "a turn
    of 0.32 deg or more in yaw is found within 20 frames (9 drives in 10; its readings scatter by 0.15 deg)". "no step"
    on a radar whose Doppler scatters by 0.6 deg a reading is no statement on a 0.5 deg knock (a simulated one went
    unseen there)."""
    if not isinstance(summary.get("finds_deg"), (int, float)):
        return ""
    within, scatter = summary.get("finds_within", 20), summary.get("scatter_deg", float("nan"))
    return (f"a turn of {summary['finds_deg']:.2f} deg or more in yaw is found within {within} frames (9 drives in 10; "
            f"its readings scatter by {scatter:.2f} deg)")


def tested_words(summary: dict, reference: dict | None = None) -> str:
    """How much a ``summary()`` block tested, in words: frames and the sweep pairs behind them (a result written
    before the sweeps were paired holds ``pairs_tested`` alone, one pair per frame), and, when the hybrid recorded
    ``sweeps_absent``, that the root's sweeps between keyframes were listed but not on disk. ``reference``: the
    result's ``drift["reference"]``: against an earlier export the level is the exported mount's, and named so
    (``data.reference.reference_nouns``; probe 106: "1.83 deg ... of its tables'" where the tables put the radar
    3.85 deg off)."""
    return reference_nouns(_tested_words(summary), reference)


def _tested_words(summary: dict) -> str:
    pairs = int(summary.get("pairs_tested", 0))
    frames = int(summary.get("frames_tested", pairs))
    if not pairs:
        why = (f"{summary['frames_skipped']} frames skipped, the first because {summary['skip_example']}"
               if summary.get("skip_example") else "no pair had a usable Doppler velocity of the radar and ego poses")
        words = f"no frame pair tested ({why}: a step of the radar's yaw alone would go unseen by it)"
    elif pairs != frames:
        words = f"{frames} frames tested ({pairs} sweep pairs)"
    else:
        words = f"{frames} frame pairs tested"
    levels = summary.get("levels") or []
    if summary.get("implausible"):
        words += f"; {summary['implausible']}"
    elif len(levels) == 1 and pairs and not summary.get("steps"):  # the radar's yaw on the vehicle, as it reads
        # the level's std, and with the Doppler's own bias as every comparison takes it (probe 129: "1.43 +- 0.04 deg
        # (1 sigma)" here beside "1.43 +- 0.11 deg (1 sigma)" in the verdict, one quantity)
        sd = levels[0]["std_deg"]
        words += (f"; the radar's yaw on the vehicle {level_words(levels[0]['level_deg'], sd)} its tables' (its "
                  f"Doppler against the ego poses; +- {doppler_std(sd):.2f} deg with the "
                  "Doppler's own bias, as the checks against it take it)")
    if summary.get("sweeps_absent"):  # the hybrid's record: the tables list sweeps between keyframes, no files
        words += "; keyframes only: the root's radar sweeps between keyframes have no files (add sweeps/)"
    elif isinstance(gone := summary.get("sweeps_missing"), dict):
        words += (f"; {gone.get('n')} of the {gone.get('of')} radar sweep files between keyframes are missing "
                  f"(first: {gone.get('first')}): their pairs are skipped")
    if isinstance(bad := summary.get("sweeps_unreadable"), dict):
        words += (f"; {bad.get('n')} of the {bad.get('of')} radar sweep files between keyframes do not read (first: "
                  f"{bad.get('first')}): their pairs are skipped; replace the files")
    return words


def sole_level(summary: dict | None, plausible: bool = True) -> dict | None:
    """The monitor's one level (``summary``'s only entry of "levels": the radar's yaw on the vehicle against its
    tables, as one number over the drive) when it measured no step, and with ``plausible`` no implausible reading
    either; None otherwise. What the yaw check, the camera-side note and the Doppler note read."""
    s = summary or {}
    levels = s.get("levels") or []
    if len(levels) != 1 or s.get("steps") or (plausible and s.get("implausible")):
        return None
    return levels[0]


def current_level(summary: dict | None) -> dict | None:
    """The monitor's level of the radar's mount as it is at the drive's end: its one level, or after a step the last
    one when read over at least 3 frames; None with an implausible reading or none. What the yaw check reads: after
    a knock the window restarts, and the restarted estimate is what the radar's own heading must agree with (probe 46:
    the check skipped every knocked drive, and a restarted window 6-9 deg off in yaw kept its 0.7 deg 1-sigma)."""
    s = summary or {}
    levels = s.get("levels") or []
    if not levels or s.get("implausible"):
        return None
    if len(levels) == 1 and not s.get("steps"):
        return levels[0]
    return levels[-1] if int(levels[-1].get("frames", 0)) >= 3 else None


def turn_size(tail: dict) -> str:
    """The turn of ``summary()``'s "tail" in words: "89.9 deg", or "45.0 deg or more" (one reading, whose sweep
    pairs may straddle the knock)."""
    return f"{abs(float(tail['offset_deg'])):.1f} deg" + (" or more" if tail.get("at_least") else "")


def _last(tail: dict) -> str:
    """"last 3 frames tested (frames 13-15)" / "last frame tested (frame 15)"."""
    n = int(tail["frames"])
    return (f"last {n} frames tested (frames {tail['from']}-{tail['to']})" if n > 1 else
            f"last frame tested (frame {tail['to']})")


def _spread(deg: float) -> str:
    """A heading's frame-to-frame spread in words: "+-14 deg", or "more than 90 deg" (a robust std of headings that
    wrap at 180 deg read "+-189 deg": probe 36)."""
    return f"+-{deg:.0f} deg" if deg <= 90 else "more than 90 deg"


def monitor_trust_reason(summary: dict | None,
                         max_level_deg: float = MountMonitorConfig.max_level_deg) -> str:
    """Why an estimate is not trusted for what the radar mount monitor saw, or "": its readings scatter beyond any
    mount (``summary``'s "scattered": a radar that turned during the drive has no one extrinsic), the readings
    either side of an untested stretch of a drive too short for the step test disagree (``summary``'s "split"), its
    level lies beyond ``max_level_deg`` from the tables (``summary``'s "far"), or it measured a step beyond
    ``max_level_deg`` at 3 sigma (probe 34: a radar turned 180 deg at frame 8 of 16; the verdict said
    "recalibrate", the estimate after the turn stayed `weak` with a yaw 1-sigma of 0.35 deg, 180 deg off: the
    network knows radars within a few degrees of their mount)."""
    sp = (summary or {}).get("split")
    if isinstance(sp, dict):  # probe 145: a radar turned during a stop, on a drive too short for the step test
        return (f"the radar's own heading on the vehicle (its Doppler against the ego poses) from frame "
                f"{sp['after_from']} on lies {sp['offset_deg']:+.2f} +- {sp['std_deg']:.2f} deg from the one up to "
                f"frame {sp['before_to']}, on a drive too short for its step test: the radar may have turned between "
                "them, and the estimate is of frames on both sides; calibrate a longer drive")
    sc = (summary or {}).get("scattered")
    if isinstance(sc, dict):
        return (f"the radar's own heading on the vehicle (its Doppler against the ego poses) scatters by "
                f"{_spread(sc['scatter_deg'])} from frame to frame (frames {sc['from']}-{sc['to']}), far more than "
                "a mount allows: the radar turned during the drive (no one extrinsic holds for it), or its velocities "
                "or the ego poses are wrong; check the radar's mount, and calibrate the frames after any change")
    big = [st for st in told_steps(summary)
           if abs(float(st.get("step_deg", 0.0))) - 3 * float(st.get("std_deg", 0.0)) > max_level_deg]
    tail = (summary or {}).get("tail")
    if not big and isinstance(tail, dict):
        return (f"the radar's own heading on the vehicle (its Doppler against the ego poses) turned by "
                f"{turn_size(tail)} in the drive's {_last(tail)}, beyond any mount ({max_level_deg:g} deg) and too "
                "near the end for a step alarm: the radar was knocked at the drive's end, or those frames' velocities "
                "or ego poses are wrong; the estimate at the end is not trusted: check the radar's mount, and "
                "calibrate a drive after it")
    far = (summary or {}).get("far")
    # probe 36: a radar turned 180 deg at frame 2 of 16 read one level, -179.8 deg, and the result was "weak"
    if not big and isinstance(far, dict):
        return (f"the radar's own heading on the vehicle (its Doppler against the ego poses) lies "
                f"{level_words(far['level_deg'], far['std_deg'])} its tables' (frames {far['from']}-{far['to']}), "
                f"beyond any mount ({max_level_deg:g} deg): the radar is not mounted as its tables say (a knock, or a "
                "rotation wrong in calibrated_sensor.json), or the ego poses or its velocities are wrong; the network "
                "knows radars within a few degrees of a fleet's mounts, so the estimate is not trusted")
    if not big:
        return ""
    st = big[-1]
    return (f"the radar mount monitor measured the radar turn by {turn_words(st['step_deg'], st['std_deg'])} from "
            f"about frame {st['change']}, beyond any mount ({max_level_deg:g} deg): the network knows radars within a "
            "few degrees of their mount, so the estimate after the turn is not trusted")


# The Doppler level's own bias against the truth, deg: on simulated drives whose tables hold the truth the level
# lay within 0.11 deg of it (16 drives of 60 keyframes, urban / highway / rain / straight, seed 4242; its std 0.024:
# the level's std alone understates how far it can be from the truth). Added to the level's std when it is read
# as the radar's absolute yaw on the vehicle (``yaw_agreement``).
LEVEL_BIAS_DEG = 0.1


def yaw_agreement(T_cam_radar: np.ndarray, cov: np.ndarray, T_ego_cam: np.ndarray, T_ego_radar_ref: np.ndarray,
                  summary: dict | None, bias_deg: float = LEVEL_BIAS_DEG) -> dict | None:
    """Does a calibration's yaw agree with the radar's own yaw on the vehicle? Two measurements of one angle: the
    estimate ``T_cam_radar`` (4, 4) with ``cov`` (6, 6, right tangent, radar frame [rad, m]) put on the vehicle by
    the tables' camera mount ``T_ego_cam`` (4, 4), and the monitor's level (``summary``: ``MountMonitor.summary``;
    the radar's Doppler against the ego poses, relative to the mount ``T_ego_radar_ref`` (4, 4) it was run with).
    Both as rotations about the ego z axis relative to ``T_ego_radar_ref`` [deg].

    None when the monitor gives no level of the mount at the drive's end (``current_level``: no reading, a last step
    read over fewer than 3 frames, an implausible level). Otherwise {"estimate_deg",
    "estimate_std_deg", "doppler_deg", "doppler_std_deg" (the level's std with ``bias_deg`` added), "difference_deg",
    "sigmas" (the difference over its std), "disagree", "direction" ((6,) unit right tangent of the yaw about ego
    z)}. ``disagree``: beyond 3 sigma while the level itself lies off the tables (beyond 3 of its std): both say the
    radar sits off its tables, by different amounts, so one of them (or the camera's mount in the tables) is wrong.
    A level at the tables' yaw is ``calib.drift.camera_side_note``'s case (the camera side moved), not this one."""
    from scipy.spatial.transform import Rotation

    lv = current_level(summary)
    if lv is None:
        return None
    level, std_lvl = float(lv.get("level_deg", np.nan)), float(lv.get("std_deg", np.nan))
    if not (np.isfinite(level) and np.isfinite(std_lvl)):
        return None
    R_est = (np.asarray(T_ego_cam, np.float64) @ np.asarray(T_cam_radar, np.float64))[:3, :3]
    R_ref = np.asarray(T_ego_radar_ref, np.float64)[:3, :3]
    yaw = float(np.degrees(Rotation.from_matrix(R_est @ R_ref.T).as_rotvec()[2]))  # about ego z, ego frame
    u = np.zeros(6)
    u[:3] = R_est.T @ np.array([0.0, 0.0, 1.0])  # a right rotation w of the radar turns the ego frame by R_est w
    std_est = float(np.degrees(np.sqrt(max(u @ np.asarray(cov, np.float64) @ u, 0.0))))
    std_dop = doppler_std(std_lvl, bias_deg)
    d = yaw - level
    sig = abs(d) / max(np.hypot(std_est, std_dop), 1e-12)
    return {"estimate_deg": yaw, "estimate_std_deg": std_est, "doppler_deg": level, "doppler_std_deg": std_dop,
            "difference_deg": d, "sigmas": float(sig),
            "disagree": bool(sig > 3.0 and abs(level) > 3.0 * std_dop), "direction": u.tolist(),
            "pairs": int(lv.get("pairs", 0))}
