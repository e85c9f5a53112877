"""How much a drive's ego poses jitter in heading from one record to the next.

A vehicle's heading changes smoothly: between the radar channel's records (nuScenes' RADAR_FRONT: ~13 Hz, every
record with its own ego pose, listed in the tables whether or not its sweep file is there) its turn per record
changes by the yaw acceleration times the interval squared, hundredths of a degree. A localiser whose headings
carry independent noise of ``sigma`` per record makes the second difference of the heading scatter by
``sqrt(6) sigma``. So the robust spread (1.4826 MAD) of the second differences, divided by sqrt(6), estimates the
per-record heading noise; the vehicle's own yaw acceleration, the turn a real car makes in ~75 ms, enters as well,
so it is an upper bound. Measured (``NuScenesRadarCamera.heading_jitter``): scene-0916's radar records (265, 75 ms
apart) 0.020 deg; simulated drives (exact poses, 13 Hz sweeps) under 1e-4 deg; the same drives with noise of 0.05 /
0.25 / 0.5 deg per pose record and axis (probe 98's roots) 0.06 / 0.23-0.24 / 0.49-0.58 deg.

Why it matters: the hybrid's motion constraint takes the camera's turn between two frames from the ego poses (the
visual odometry then finds only the direction of travel, ``hybrid.motion``). Poses with 0.5 deg of heading noise per
record moved its yaw 1.3-2.7 deg at 3-7 sigma and read "recalibrate" on radars that had not moved (probe 98); with
the turn taken from the images (the five-point essential matrix) the same drives ended 0.2-0.6 deg off, NEES 4.3-9.2.
A drive whose jitter is above ``MAX_HEADING_JITTER_DEG`` therefore takes the motion's rotation from the images, and
says so. Smooth pose errors (a localiser's slow drift) do not show here: their second differences are small.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.errors import DataError

# per-record heading noise (deg) beyond which the ego poses' turn between frames is not used: 5x scene-0916's
MAX_HEADING_JITTER_DEG = 0.1
MAX_SPACING_S = 0.2  # records further apart (a keyframe-only table): the vehicle's own yaw acceleration dominates
MIN_RECORDS = 12  # fewer: not measured


@dataclass(frozen=True)
class HeadingJitter:
    """``sigma_deg``: the per-record heading noise estimate (module doc); ``records``: the pose records it rests on;
    ``spacing_s``: their median spacing."""

    sigma_deg: float
    records: int
    spacing_s: float

    @property
    def too_noisy(self) -> bool:
        return self.sigma_deg > MAX_HEADING_JITTER_DEG

    def words(self) -> str:
        return (f"the ego poses' heading jitters by {self.sigma_deg:.2f} deg from one record to the next (robust "
                f"spread over {self.records} radar records, {1e3 * self.spacing_s:.0f} ms apart; a vehicle's heading "
                f"is smooth: scene-0916's 0.02 deg; more than {MAX_HEADING_JITTER_DEG:g} deg is noise in "
                "ego_pose.json), so the motion constraint takes the camera's turn between frames from the images, "
                "not from the ego poses")

    def to_dict(self) -> dict:
        return {"sigma_deg": self.sigma_deg, "records": self.records, "spacing_s": self.spacing_s,
                "max_deg": MAX_HEADING_JITTER_DEG, "too_noisy": self.too_noisy}


def heading_of(T: np.ndarray) -> float:
    """The heading (rad) of an ego -> global pose (4, 4): the angle of its forward axis in the ground plane."""
    return float(np.arctan2(T[1, 0], T[0, 0]))


def heading_jitter(times_s: np.ndarray, headings_rad: np.ndarray) -> HeadingJitter | None:
    """The per-record heading noise of pose records at ``times_s`` (N,) with headings ``headings_rad`` (N,), any
    order; None when fewer than ``MIN_RECORDS`` or their median spacing is above ``MAX_SPACING_S``. The second
    difference is taken of the turn per record, each scaled to the next record's interval (uneven spacing at a
    steady turn leaves no residue)."""
    t = np.asarray(times_s, np.float64)
    h = np.asarray(headings_rad, np.float64)
    ok = np.isfinite(t) & np.isfinite(h)
    order = np.argsort(t[ok], kind="stable")
    t, h = t[ok][order], h[ok][order]
    keep = np.r_[True, np.diff(t) > 1e-4]  # a record repeated at one instant
    t, h = t[keep], h[keep]
    if len(t) < MIN_RECORDS:
        return None
    dt = np.diff(t)
    spacing = float(np.median(dt))
    if spacing > MAX_SPACING_S:
        return None
    step = np.angle(np.exp(1j * np.diff(h)))  # wrapped turn per record
    d2 = step[1:] - step[:-1] * (dt[1:] / dt[:-1])
    mad = 1.4826 * float(np.median(np.abs(d2 - np.median(d2))))
    return HeadingJitter(float(np.degrees(mad / np.sqrt(6.0))), len(t), spacing)


def drive_heading_jitter(tables, keyframes: list[dict]) -> HeadingJitter | None:
    """``heading_jitter`` of the pose records of one channel over a drive: each keyframe ``sample_data`` record of
    ``keyframes`` (time order) and the records between it and the keyframe before (``data.sweeps.records_between``);
    a record whose ego pose does not read is left out (the frame that needs it says why)."""
    from hybrid_calib.data.sweeps import records_between

    seen, times, heads = set(), [], []
    for sd in keyframes:
        for rec in [*records_between(tables, sd), sd]:
            if rec.get("token") in seen:
                continue
            seen.add(rec.get("token"))
            try:
                T = tables.T_global_ego_unchecked(rec)
                times.append(float(rec["timestamp"]) * 1e-6)
            except (DataError, KeyError, TypeError, ValueError):
                continue
            heads.append(heading_of(T))
    return heading_jitter(np.array(times), np.array(heads))
