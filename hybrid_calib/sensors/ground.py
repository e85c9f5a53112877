"""The road's height under a vehicle, from one LiDAR sweep.

A root's ego origin is its own choice (nuScenes: the rear axle's centre on the road; docs/conventions.md: nothing
depends on it), so a height "above the road" is measured from the road the frame's LiDAR sees around it, not from the
ego frame's z = 0: the calibrator's LiDAR band (``calib.lidar_alignment``) and the radar's LiDAR support
(``data.domain_stats``) keep their surfaces above it (probe 143: with the origin 0.5 m under the road, the band held no
surface). Heights in metres, in the frame the caller gives them in (z up).
"""

from __future__ import annotations

import numpy as np

GROUND_RING_M = (2.0, 15.0)  # the LiDAR returns whose height tells the road's: this far around the sensor, m
GROUND_BIN_M = 0.05  # their heights' histogram bin, m
MIN_GROUND_POINTS = 50  # fewer returns there: the ego frame's z = 0 is taken as the road
# a road read this close to the frame's z = 0 is z = 0 (nuScenes: the ego origin is on the road; its sweeps read their
# road -0.03 to +0.08 m there, the simulator's -0.01 m): the band is then the one every validated figure was measured
# with, and a root whose origin sits elsewhere (a rear axle 0.4 m up, probe 143) gets the road its sweep sees
EGO_GROUND_TOL_M = 0.15


def ground_level(height: np.ndarray, ring: np.ndarray) -> float:
    """The road's height (m) in the frame of ``height`` (N,) (a LiDAR sweep's points' heights, z up: the ego frame's
    or a level sensor's), from the points 2-15 m around the sensor (``ring`` (N,): their horizontal distance from it,
    m): the densest 5 cm band of the lower half of their heights (the road returns a LiDAR's low beams put all around
    it), refined by the median within 10 cm of it; 0 (the frame's own ground: nuScenes' ego origin is on the road)
    for fewer than ``MIN_GROUND_POINTS`` there, or when that road lies within ``EGO_GROUND_TOL_M`` of it."""
    h = height[(ring > GROUND_RING_M[0]) & (ring < GROUND_RING_M[1]) & np.isfinite(height)]
    if len(h) < MIN_GROUND_POINTS:
        return 0.0
    low = h[h <= np.median(h)]
    bins = np.floor(low / GROUND_BIN_M)
    values, counts = np.unique(bins, return_counts=True)
    peak = (values[np.argmax(counts)] + 0.5) * GROUND_BIN_M
    road = float(np.median(low[np.abs(low - peak) <= 2 * GROUND_BIN_M]))
    return road if abs(road) > EGO_GROUND_TOL_M else 0.0
