"""Radar point filters on the ARS 408 state fields, with the nuScenes devkit's defaults.

The devkit (``RadarPointCloud``) keeps points whose ``invalid_state`` is 0 (valid), whose
``dyn_prop`` is 0..6 (all dynamic properties except 7 = "stopped/unknown"), and whose
``ambig_state`` is 3 (velocity unambiguous). ``RadarFilterConfig`` reproduces that and lets each
test be widened or switched off (``None`` = do not filter on that field, ``enabled=False`` = keep
every finite point).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

XYZ = ("x", "y", "z")


@dataclass(frozen=True)
class RadarFilterConfig:
    enabled: bool = True  # False keeps every point with finite x, y, z (no state filtering)
    invalid_states: tuple[int, ...] | None = (0,)  # kept invalid_state values; None = any
    dynprop_states: tuple[int, ...] | None = (0, 1, 2, 3, 4, 5, 6)  # kept dyn_prop values; None = any
    ambig_states: tuple[int, ...] | None = (3,)  # kept ambig_state values; None = any

    def __post_init__(self):  # a code the ARS 408 never writes kept nothing, said only as "0 points" (probe 79)
        from hybrid_calib.config import require

        require(self, {f"{name} within {lo}..{hi} (the ARS 408's codes), or null": all(
            isinstance(v, int) and lo <= v <= hi for v in (getattr(self, name) or ()))
            for name, (lo, hi) in STATE_CODES.items()})


# the ARS 408's state codes (nuScenes devkit, RadarPointCloud): invalid_state 0..17, dyn_prop 0..7, ambig_state 0..4
STATE_CODES = {"invalid_states": (0, 17), "dynprop_states": (0, 7), "ambig_states": (0, 4)}


# beyond any automotive radar's reach (the ARS 408's: 250 m; long-range radars' ~300 m): a corrupt coordinate. 1 km
# until session 39 (probe 80: a sweep of points all at 900 m was read as a frame)
MAX_RANGE_M = 400.0


def finite_mask(points: np.ndarray) -> np.ndarray:
    """(N,) structured radar array -> (N,) bool: x, y and z all finite and within ``MAX_RANGE_M`` of the sensor
    (a point at 3e38 m is a corrupt file, not a reflector)."""
    keep = np.ones(len(points), dtype=bool)
    for name in XYZ:
        v = np.asarray(points[name], np.float64)
        with np.errstate(invalid="ignore"):
            keep &= np.isfinite(v) & (np.abs(v) <= MAX_RANGE_M)
    return keep


def state_mask(points: np.ndarray, conf: RadarFilterConfig) -> np.ndarray:
    """(N,) structured radar array -> (N,) bool: passes the state filters of ``conf``.

    Fields the filters need but the PCD lacks raise ``KeyError`` naming every one of them (its args; callers turn
    it into a ``DataError`` naming the file: one field per try made a user rerun three times, probe 52).
    """
    keep = np.ones(len(points), dtype=bool)
    if not conf.enabled:
        return keep
    used = [(field, allowed) for field, allowed in (("invalid_state", conf.invalid_states),
                                                    ("dyn_prop", conf.dynprop_states),
                                                    ("ambig_state", conf.ambig_states)) if allowed is not None]
    if missing := [field for field, _ in used if field not in (points.dtype.names or ())]:
        raise KeyError(*missing)
    for field, allowed in used:
        keep &= np.isin(points[field], np.asarray(allowed))
    return keep


def filter_radar(points: np.ndarray, conf: RadarFilterConfig) -> tuple[np.ndarray, int]:
    """Rows of a structured radar array to keep.

    Returns ``(rows, n_nonfinite)``: ``rows`` (K,) int64 indices into ``points`` of finite points
    that pass ``conf``; ``n_nonfinite`` how many rows had NaN/inf coordinates (always dropped).
    """
    fin = finite_mask(points)
    keep = fin & state_mask(points, conf)
    return np.flatnonzero(keep).astype(np.int64), int((~fin).sum())
