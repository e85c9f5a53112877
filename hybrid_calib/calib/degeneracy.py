"""Why a drive does not constrain the extrinsic: the words after "weak:" / "degenerate:".

Two readings, both documented with their thresholds in docs/conventions.md ("Degeneracy words"):

1. Which directions TRADE OFF: the correlation of two camera axes (pitch, yaw, roll about camera
   x, y, z; lateral, vertical, longitudinal offset along camera x, y, z) in the reported covariance
   (camera axes, ``covariance.report_cov``), conditioned on the prior-pinned directions and between
   the axes they do not pin (the prior's 1 deg / 30 cm leak into every axis through the mount
   rotation and would otherwise read as trade-offs). Above ``trade_off_correlation`` (or
   ``cause_correlation`` when a geometric cause is present) the data move one only together with
   the other ("yaw and lateral offset trade off (correlation -0.97)").
2. What in the GEOMETRY of the rows causes it (``RowGeometry``: the radar-frame range and azimuth of
   every correspondence of the drive, and the number of frames):
   - a single frame: one scene, its reflector heights and outliers are not averaged over a drive;
   - few correspondences (< ``min_rows``);
   - all points at one range (p90 / p10 of the range < ``min_range_ratio``): a rotation shifts the
     pixels of every point alike and so does a translation (its shift is translation / range), so
     yaw and lateral offset, pitch and vertical offset cannot be told apart;
   - all reflectors in one direction (p90 - p10 of the azimuth < ``min_azimuth_spread_deg``): depth
     (longitudinal offset) and roll are barely seen;
   - all reflectors along the road (``along_road_fraction`` of the rows within
     ``along_road_lateral_m`` of ONE lateral offset on each side, i.e. two lines parallel to the
     travel direction: a straight road's kerbs, poles and parked cars): their azimuth changes with
     range in lockstep, so yaw and lateral offset trade off.

Each geometric cause is a reason the status is at least "weak"; correlated pairs are named as the
consequence when the status is not "ok".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

AXIS_WORDS = ("pitch", "yaw", "roll", "lateral offset", "vertical offset", "longitudinal offset")

_AZ_EDGES = np.linspace(-90.0, 90.0, 181)  # 1 deg bins, radar azimuth (x forward, y left)
_RANGE_EDGES = np.linspace(0.0, 300.0, 601)  # 0.5 m bins, radar range in the x-y plane
_LAT_EDGES = np.linspace(-30.0, 30.0, 241)  # 0.25 m bins, lateral offset y of the reflector (radar frame)


@dataclass(frozen=True)
class DegeneracyConfig:
    trade_off_correlation: float = 0.9  # |correlation| of two observed camera axes above this: "X and Y trade off"
    cause_correlation: float = 0.6  # ... above this when a geometric cause below is present (named with it)
    min_rows: int = 50  # fewer correspondences than this: "only N correspondences"
    min_frames: int = 2  # fewer frames than this: "a single frame"
    min_range_ratio: float = 1.5  # range p90 / p10 below this: "all points at one range"
    min_azimuth_spread_deg: float = 10.0  # azimuth p90 - p10 below this (deg): "all reflectors in one direction"
    along_road_lateral_m: float = 1.0  # half-width of a "line along the road" (m, radar lateral offset)
    along_road_fraction: float = 0.8  # this fraction of the rows on two such lines: "all reflectors along the road"

    def __post_init__(self):
        from hybrid_calib.config import require_ranges

        require_ranges(self, {"trade_off_correlation": "(0, 1]", "cause_correlation": "(0, 1]",
                              "min_rows": "[0, 1e9]", "min_frames": "[0, 1e9]", "min_range_ratio": "[1, 1000]",
                              "min_azimuth_spread_deg": "[0, 180]", "along_road_lateral_m": "(0, 100]",
                              "along_road_fraction": "(0, 1]"})


@dataclass
class RowGeometry:
    """Running histogram of where the correspondences lie in the radar frame (cheap to update per
    frame; ``percentile`` reads it back to bin resolution: 1 deg, 0.5 m, 0.25 m).

    azimuth: counts per 1 deg bin over [-90, 90] deg; range: per 0.5 m over [0, 300] m; lateral:
    per 0.25 m over [-30, 30] m (values outside are clipped into the end bins).
    """

    n_rows: int = 0
    n_frames: int = 0
    azimuth: np.ndarray = field(default_factory=lambda: np.zeros(len(_AZ_EDGES) - 1))
    range: np.ndarray = field(default_factory=lambda: np.zeros(len(_RANGE_EDGES) - 1))
    lateral: np.ndarray = field(default_factory=lambda: np.zeros(len(_LAT_EDGES) - 1))

    def add(self, points_radar: np.ndarray) -> None:
        """One frame's radar points (N, 3), metres, radar frame (z ignored)."""
        P = np.asarray(points_radar, np.float64).reshape(-1, 3)
        P = P[np.all(np.isfinite(P), axis=1)]
        self.n_frames += 1
        if not len(P):
            return
        self.n_rows += len(P)
        for hist, edges, vals in ((self.azimuth, _AZ_EDGES, np.degrees(np.arctan2(P[:, 1], P[:, 0]))),
                                  (self.range, _RANGE_EDGES, np.hypot(P[:, 0], P[:, 1])),
                                  (self.lateral, _LAT_EDGES, P[:, 1])):
            hist += np.histogram(np.clip(vals, edges[0], edges[-1] - 1e-9), edges)[0]

    @classmethod
    def from_frames(cls, frames) -> RowGeometry:
        """From ``Correspondences`` frames (their ``points_radar``)."""
        g = cls()
        for f in frames:
            g.add(f.points_radar)
        return g

    @staticmethod
    def _quantile(hist: np.ndarray, edges: np.ndarray, q: float) -> float:
        c = np.cumsum(hist)
        if c[-1] <= 0:
            return float("nan")
        i = int(np.searchsorted(c, q * c[-1]))
        return float(0.5 * (edges[i] + edges[i + 1]))

    def percentile(self, which: str, q: float) -> float:
        """Quantile ``q`` (0..1) of "azimuth" (deg), "range" (m) or "lateral" (m); NaN without rows."""
        edges = {"azimuth": _AZ_EDGES, "range": _RANGE_EDGES, "lateral": _LAT_EDGES}[which]
        return self._quantile(getattr(self, which), edges, q)

    def along_road_fraction(self, half_width_m: float) -> float:
        """Largest fraction of the rows on two lines parallel to the radar x axis, one left and one right of the
        radar (each ``half_width_m`` wide, sharing no row): a straight road's kerbs, poles, parked cars. The best
        left and right bands used to overlap at the axis, so a lead vehicle dead ahead counted twice ("105 %",
        "200 % on two lines"; probe 29)."""
        if self.n_rows == 0:
            return 0.0
        centres = 0.5 * (_LAT_EDGES[:-1] + _LAT_EDGES[1:])
        k = max(1, int(round(half_width_m / (_LAT_EDGES[1] - _LAT_EDGES[0]))))
        band = np.convolve(self.lateral, np.ones(2 * k + 1), mode="same")  # rows within +-half_width of each centre
        gap = 2 * k + 1  # band centres this many bins apart share no bin
        right = np.maximum.accumulate(np.where(centres < 0, band, 0.0))  # the best right band at or below each bin
        left = np.flatnonzero(centres > 0)
        below = left - gap
        pairs = band[left] + np.where(below >= 0, right[np.maximum(below, 0)], 0.0)
        return float(pairs.max() / self.n_rows)


def along_road(geom: RowGeometry | None, conf: DegeneracyConfig) -> float | None:
    """The fraction of the rows on two lines along the road when it reaches
    ``conf.along_road_fraction`` over at least ``conf.min_frames`` frames (a straight road), else None."""
    if geom is None or geom.n_rows == 0 or geom.n_frames < conf.min_frames:
        return None
    frac = geom.along_road_fraction(conf.along_road_lateral_m)
    return frac if frac >= conf.along_road_fraction else None


def geometry_causes(geom: RowGeometry | None, conf: DegeneracyConfig) -> list[str]:
    """The geometric reasons (module docstring) this drive's rows constrain the extrinsic poorly."""
    if geom is None:
        return []
    causes = []
    if geom.n_frames < conf.min_frames:
        causes.append("a single frame (one scene: its reflector heights and outliers are not averaged over a drive)")
    if geom.n_rows < conf.min_rows:
        causes.append(f"only {geom.n_rows} correspondences (fewer than {conf.min_rows})")
    if geom.n_rows == 0:
        return causes
    r10, r90 = geom.percentile("range", 0.1), geom.percentile("range", 0.9)
    if r90 < conf.min_range_ratio * max(r10, 1e-9):
        causes.append(f"all points at one range ({r10:.0f}-{r90:.0f} m): a rotation and a translation shift "
                      "every pixel alike")
    a10, a90 = geom.percentile("azimuth", 0.1), geom.percentile("azimuth", 0.9)
    if a90 - a10 < conf.min_azimuth_spread_deg:
        causes.append(f"all reflectors in one direction (azimuth {a10:.0f} to {a90:.0f} deg)")
    frac = along_road(geom, conf)
    if frac is not None:
        causes.append(f"all reflectors lie along the road ({100 * frac:.0f} % on two lines parallel to the "
                      "travel direction: every frame sees the same geometry, so a bias from the reflector heights "
                      "does not average out)")
    return causes


def trade_offs(cov_report: np.ndarray, threshold: float, axes: np.ndarray | None = None) -> list[str]:
    """Pairs of camera axes whose reported errors are correlated beyond ``threshold``, strongest
    first: "yaw and lateral offset trade off (correlation -0.97)". cov_report: (6, 6) camera-axes
    covariance (``covariance.report_cov``); axes: optional (6,) bool, the axes to pair (default all)."""
    C = np.asarray(cov_report, np.float64)
    use = np.ones(6, bool) if axes is None else np.asarray(axes, bool)
    d = np.sqrt(np.clip(np.diag(C), 1e-300, None))
    rho = C / np.outer(d, d)
    pairs = sorted(((abs(rho[i, j]), i, j) for i in range(6) for j in range(i + 1, 6)
                    if use[i] and use[j] and abs(rho[i, j]) > threshold), reverse=True)
    return [f"{AXIS_WORDS[i]} and {AXIS_WORDS[j]} trade off (correlation {rho[i, j]:+.2f})" for _, i, j in pairs]


def explain(cov_report: np.ndarray, geom: RowGeometry | None, conf: DegeneracyConfig,
            already_weak: bool, axes: np.ndarray | None = None) -> tuple[list[str], bool]:
    """(phrases, weak): the trade-offs (between ``axes``, see ``trade_offs``) and their geometric
    causes, and whether the geometry alone makes the status "weak". Trade-offs are named only when
    something is weak."""
    causes = geometry_causes(geom, conf)
    weak = already_weak or bool(causes)
    if not weak:
        return [], False
    pairs = trade_offs(cov_report, conf.cause_correlation if causes else conf.trade_off_correlation, axes)
    if pairs and causes:
        return ["; ".join(pairs) + ": " + "; ".join(causes)], True
    return pairs + causes, True
