"""Ego motion along the road: T_global_ego(t) with a slowly varying speed, a little body pitch/roll, and
stops (waiting at a light: ``EgoStops``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.config import require_ranges
from hybrid_calib.geometry import make_T
from hybrid_calib.sim.world import RoadPath

EGO_START_S = 150.0  # metres along the road where every drive starts (room behind for traffic)
SPEED_PERIOD_S = 40.0  # the ego's speed oscillation period P, seconds (``EgoMotion.period``)
EGO_FRONT_M = 3.7  # the ego's front bumper ahead of its origin (the rear axle; nuScenes' front radar: 3.4 m)


def ego_catch_up_m(speed: float, variation: float, other_speed: float, period: float = SPEED_PERIOD_S) -> float:
    """How far, at most, the ego (``EgoMotion`` of mean ``speed`` m/s and relative ``variation``) gains on a vehicle
    driving ``other_speed`` m/s ahead of it in its lane from the same start, metres (>= 0): max over t of
    ``s(t) - s0 - other_speed t``. Its speed oscillation outran a lead vehicle 2 % faster on average by up to
    2 a v / w - 0.02 v t: at 25 m/s about 22 m, and highway drives ran the camera into the lead truck (probe 35)."""
    t = np.linspace(0.0, 3.0 * period, 4001)
    w = 2 * np.pi / period
    gain = speed * t + variation * speed / w * (1 - np.cos(w * t)) - other_speed * t
    return float(max(gain.max(), 0.0))


@dataclass(frozen=True)
class EgoStops:
    """Where the ego stops during each drive, as at a red light: ``count`` stops spread evenly over the drive (stop k
    of n centred at ``(k + 1/2) / n`` of its duration), each ``ramp_s`` of braking (a cosine speed ramp), ``hold_s`` at
    standstill and ``ramp_s`` pulling away. nuScenes: 199 of the 850 trainval scenes' descriptions name a wait or a
    stop ("wait at intersection", "waiting for traffic light", ...): in those the keyframes repeat one view."""

    count: int = 0  # stops per drive (0 = none)
    hold_s: float = 8.0  # time at standstill per stop, seconds
    ramp_s: float = 3.0  # braking time before it and pulling-away time after it, seconds each

    def __post_init__(self):
        require_ranges(self, {"count": "[0, 1000]", "hold_s": "(0, 1e4]", "ramp_s": "(0, 1e3]"})

    def windows(self, duration_s: float) -> tuple[tuple[float, float, float], ...]:
        """((start, hold, ramp), ...) seconds since the drive's start, for a drive of ``duration_s`` seconds;
        ``ValueError`` when the stops do not fit in it."""
        if not self.count:
            return ()
        span = self.hold_s + 2 * self.ramp_s
        if self.count * span > duration_s:
            raise ValueError(f"stops.count={self.count} stops of stops.hold_s={self.hold_s:g} s + 2 x stops.ramp_s="
                             f"{self.ramp_s:g} s do not fit in the {duration_s:g} s drive (frames x frame_interval_s): "
                             "use fewer or shorter stops, or more frames")
        return tuple(((k + 0.5) * duration_s / self.count - span / 2, self.hold_s, self.ramp_s)
                     for k in range(self.count))


def _lost_time(t: float, start: float, hold: float, ramp: float) -> float:
    """Seconds of driving one stop (``EgoStops.windows``) has taken out of the time up to ``t``: the integral of
    ``1 - r`` with r the speed factor (1 while driving, a cosine ramp to 0, 0 while held, a ramp back to 1)."""
    u = t - start
    if u <= 0:
        return 0.0
    if u < ramp:  # braking: 1 - r = (1 - cos(pi u / R)) / 2
        return u / 2 - ramp / (2 * np.pi) * np.sin(np.pi * u / ramp)
    if u < ramp + hold:
        return ramp / 2 + (u - ramp)
    v = u - ramp - hold
    if v < ramp:  # pulling away: 1 - r = (1 + cos(pi v / R)) / 2
        return ramp / 2 + hold + v / 2 + ramp / (2 * np.pi) * np.sin(np.pi * v / ramp)
    return ramp + hold


@dataclass(frozen=True)
class EgoMotion:
    """The ego drives lane ``lateral`` of ``path`` from s = EGO_START_S.

    s(t) = s0 + v t + a v P / (2 pi) (1 - cos(2 pi t / P)): speed v (1 + a sin(2 pi t / P)).
    Body pitch / roll oscillate by ``body_sway`` radians (suspension), ego z stays 0. ``stops``
    (``EgoStops.windows``) slow the drive's own clock: position, speed oscillation and sway follow the driven time
    ``tau(t) = t - lost time``, so at a stop the ego stands still, pose and all.
    """

    path: RoadPath
    lateral: float  # metres, lane centre (negative: right of the centre line)
    speed: float  # mean speed, m/s
    speed_variation: float = 0.1  # relative amplitude a
    period: float = SPEED_PERIOD_S  # speed oscillation period P, seconds
    body_sway: float = 0.004  # pitch / roll amplitude, radians
    s0: float = EGO_START_S
    stops: tuple = ()  # ((start, hold, ramp), ...) seconds: EgoStops.windows

    def tau(self, t: float) -> float:
        """The driven time at time ``t`` (seconds): ``t`` less what the stops before it took."""
        return t - sum(_lost_time(t, *w) for w in self.stops)

    def s(self, t: float) -> float:
        w = 2 * np.pi / self.period
        t = self.tau(t)
        return self.s0 + self.speed * t + self.speed_variation * self.speed / w * (1 - np.cos(w * t))

    def T_global_ego(self, t: float) -> np.ndarray:
        """(4, 4) ego -> global at time t (seconds since the start of the drive)."""
        xy, h = self.path.to_global(self.s(t), self.lateral)
        t = self.tau(t)
        pitch = self.body_sway * np.sin(2 * np.pi * t / 3.1)
        roll = 0.5 * self.body_sway * np.sin(2 * np.pi * t / 2.3 + 1.0)
        cy, sy = np.cos(float(h)), np.sin(float(h))
        cp, sp = np.cos(pitch), np.sin(pitch)
        cr, sr = np.cos(roll), np.sin(roll)
        Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
        Ry = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
        Rx = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
        return make_T(Rz @ Ry @ Rx, np.array([xy[0], xy[1], 0.0]))

    def point_velocity(self, t: float, p_ego: np.ndarray, dt: float = 0.005) -> np.ndarray:
        """Global velocity (3,) m/s at time t of a point fixed in the ego frame at ``p_ego`` (3,)."""
        a = self.T_global_ego(t - dt)
        b = self.T_global_ego(t + dt)
        p = np.append(np.asarray(p_ego, float), 1.0)
        return ((b @ p) - (a @ p))[:3] / (2 * dt)
