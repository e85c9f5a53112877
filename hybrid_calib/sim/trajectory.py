"""Ego motion along the road: T_global_ego(t) with a slowly varying speed and a little body pitch/roll."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
class EgoMotion:
    """The ego drives lane ``lateral`` of ``path`` from s = EGO_START_S.

    s(t) = s0 + v t + a v P / (2 pi) (1 - cos(2 pi t / P)): speed v (1 + a sin(2 pi t / P)).
    Body pitch / roll oscillate by ``body_sway`` radians (suspension), ego z stays 0.
    """

    path: RoadPath
    lateral: float  # metres, lane centre (negative: right of the centre line)
    speed: float  # mean speed, m/s
    speed_variation: float = 0.1  # relative amplitude a
    period: float = SPEED_PERIOD_S  # speed oscillation period P, seconds
    body_sway: float = 0.004  # pitch / roll amplitude, radians
    s0: float = EGO_START_S

    def s(self, t: float) -> float:
        w = 2 * np.pi / self.period
        return self.s0 + self.speed * t + self.speed_variation * self.speed / w * (1 - np.cos(w * t))

    def T_global_ego(self, t: float) -> np.ndarray:
        """(4, 4) ego -> global at time t (seconds since the start of the drive)."""
        xy, h = self.path.to_global(self.s(t), self.lateral)
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
