"""How much a drive's ego poses jitter in heading from one record to the next.

A vehicle's heading changes smoothly: between the radar channel's records (nuScenes' RADAR_FRONT: ~13 Hz, every
record with its own ego pose, listed in the tables whether or not its sweep file is there) its turn per record
changes by the yaw acceleration times the interval squared, hundredths of a degree. A localiser whose headings
carry independent noise of ``sigma`` per record makes the second difference of the heading scatter by
``sqrt(6) sigma``. So the robust spread (1.4826 MAD) of the second differences, divided by sqrt(6), estimates the
per-record heading noise; the vehicle's own yaw acceleration, the turn a real car makes in ~75 ms, enters as well,
so it is an upper bound; only evenly spaced triples under ``MAX_SPACING_S`` count (around a gap the yaw acceleration
over the longer interval enters). The camera's keyframes (0.5 s apart) are too sparse for that; their headings are
checked against the path the radar's records trace (``against_path``): the poses the motion constraint turns by.
Measured (``NuScenesRadarCamera.heading_jitter``, the larger of the two): scene-0916 0.020 deg (265 radar records,
75 ms apart); simulated drives (exact poses, 13 Hz sweeps) under 1e-4 deg; probe 98's copies with noise of 0.05 /
0.25 / 0.5 deg per pose record and axis 0.06 / 0.30-0.33 / 0.55-0.81 deg; probe 99's with 0.5 deg on the camera's
records alone 0.39-0.40 deg (by the camera keyframes) and on the radar's alone 0.10 / 0.15 deg: 0.08-0.10 / 0.11-0.15.

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
from hybrid_calib.metrics import mad_scale

# per-record heading noise (deg) beyond which the ego poses' turn between frames is not used: 5x scene-0916's
MAX_HEADING_JITTER_DEG = 0.1
# records further apart (a keyframe-only table; the radar's sweeps at 13 Hz are 75 ms apart, the simulator's 77 ms):
# the vehicle's own yaw acceleration over the interval squared enters (a sharp turn's 50 deg/s^2 over 150 ms: 1.1 deg)
MAX_SPACING_S = 0.11
MIN_RECORDS = 12  # fewer: not measured


@dataclass(frozen=True)
class HeadingJitter:
    """``sigma_deg``: the per-record heading noise estimate (module doc); ``records``: the pose records it rests on;
    ``spacing_s``: their median spacing."""

    sigma_deg: float
    records: int
    spacing_s: float
    # whose records: "radar" (their own second difference) | "camera" (the camera keyframes' headings against the
    # path the radar's records trace, ``against_path``: the poses the motion constraint turns by)
    source: str = "radar"

    @property
    def too_noisy(self) -> bool:
        return self.sigma_deg > MAX_HEADING_JITTER_DEG

    def words(self) -> str:
        where = (f"from one record to the next (robust spread over {self.records} radar records, "
                 f"{1e3 * self.spacing_s:.0f} ms apart" if self.source == "radar" else
                 f"at the camera's keyframes against the path the radar's records trace (robust spread over "
                 f"{self.records} keyframes")
        return (f"the ego poses' heading jitters by {self.sigma_deg:.2f} deg {where}; a vehicle's heading is smooth: "
                f"scene-0916's 0.02 deg; more than {MAX_HEADING_JITTER_DEG:g} deg is noise in ego_pose.json), so the "
                "motion constraint takes the camera's turn between frames from the images, not from the ego poses")

    def to_dict(self) -> dict:
        return {"measured": True, "sigma_deg": self.sigma_deg, "records": self.records, "spacing_s": self.spacing_s,
                "source": self.source, "max_deg": MAX_HEADING_JITTER_DEG, "too_noisy": self.too_noisy}


# a drive whose pose records cannot say (the result's record, so that "not measured" is not silent: probe 99)
NOT_MEASURED = {"measured": False, "too_noisy": False,
                "note": f"not measured: fewer than {MIN_RECORDS} radar pose records under {MAX_SPACING_S:g} s apart "
                        "(a keyframe-only table) and fewer camera keyframes within their span; noise in the ego "
                        "poses' heading would not be seen"}


def _clean(times_s, headings_rad) -> tuple[np.ndarray, np.ndarray]:
    """The finite records in time order, without any that share a timestamp with another (which of two poses at one
    instant is the vehicle's is not known: a duplicated stamp read as 0.23 deg of jitter, probe 99)."""
    t = np.asarray(times_s, np.float64)
    h = np.asarray(headings_rad, np.float64)
    ok = np.isfinite(t) & np.isfinite(h)
    order = np.argsort(t[ok], kind="stable")
    t, h = t[ok][order], h[ok][order]
    near = np.diff(t) <= 1e-4
    alone = ~(np.r_[False, near] | np.r_[near, False])
    return t[alone], h[alone]


def against_path(times_s, headings_rad, path_times_s, path_headings_rad) -> HeadingJitter | None:
    """The heading noise of records at ``times_s`` (N,) with ``headings_rad`` against a smooth path of other records
    (the radar channel's, ``MAX_SPACING_S`` apart at most): the robust spread of their heading minus the path's,
    interpolated at their time (records outside the path's span left out); None when fewer than ``MIN_RECORDS``
    or the path is too sparse. The path's own noise enters too (an upper bound, as ``heading_jitter``)."""
    tc, hc = _clean(times_s, headings_rad)
    tp, hp = _clean(path_times_s, path_headings_rad)
    if len(tp) < MIN_RECORDS or float(np.median(np.diff(tp))) > MAX_SPACING_S:
        return None
    inside = (tc >= tp[0]) & (tc <= tp[-1])
    if inside.sum() < MIN_RECORDS:
        return None
    r = np.angle(np.exp(1j * (hc[inside] - np.interp(tc[inside], tp, np.unwrap(hp)))))
    spacing = float(np.median(np.diff(tc[inside])))
    return HeadingJitter(float(np.degrees(mad_scale(r))), int(inside.sum()), spacing, "camera")


def heading_of(T: np.ndarray) -> float:
    """The heading (rad) of an ego -> global pose (4, 4): the angle of its forward axis in the ground plane."""
    return float(np.arctan2(T[1, 0], T[0, 0]))


def heading_jitter(times_s: np.ndarray, headings_rad: np.ndarray) -> HeadingJitter | None:
    """The per-record heading noise of pose records at ``times_s`` (N,) with headings ``headings_rad`` (N,), any
    order; None when fewer than ``MIN_RECORDS`` or their median spacing is above ``MAX_SPACING_S``. The second
    difference is taken of the turn per record, each scaled to the next record's interval (uneven spacing at a
    steady turn leaves no residue)."""
    t, h = _clean(times_s, headings_rad)
    if len(t) < MIN_RECORDS:
        return None
    dt = np.diff(t)
    spacing = float(np.median(dt))
    if spacing > MAX_SPACING_S:
        return None
    step = np.angle(np.exp(1j * np.diff(h)))  # wrapped turn per record
    d2 = step[1:] - step[:-1] * (dt[1:] / dt[:-1])
    # triples around a gap (a record missing or left out: probe 99's duplicated stamps read 0.40 deg) carry the
    # vehicle's own yaw acceleration over the gap: only evenly spaced ones, both intervals within 1.5x of each other
    # and under MAX_SPACING_S
    even = (np.maximum(dt[1:], dt[:-1]) <= 1.5 * np.minimum(dt[1:], dt[:-1])) & \
        (np.maximum(dt[1:], dt[:-1]) <= MAX_SPACING_S)
    if even.sum() < MIN_RECORDS - 2:
        return None
    return HeadingJitter(float(np.degrees(mad_scale(d2[even]) / np.sqrt(6.0))), len(t), spacing)


def _headings(tables, records) -> tuple[np.ndarray, np.ndarray]:
    """(times s, headings rad) of ``sample_data`` records whose ego pose reads (the others left out: the frame that
    needs one says why)."""
    seen, times, heads = set(), [], []
    for rec in records:
        if rec.get("token") in seen:
            continue
        seen.add(rec.get("token"))
        try:
            T = tables.T_global_ego_unchecked(rec)
            t = float(rec["timestamp"]) * 1e-6
        except (DataError, KeyError, TypeError, ValueError):
            continue
        times.append(t)
        heads.append(heading_of(T))
    return np.array(times), np.array(heads)


def drive_heading_jitter(tables, keyframes: list[dict], camera_keyframes: list[dict] | None = None
                         ) -> HeadingJitter | None:
    """The larger of: ``heading_jitter`` of one channel's pose records over a drive (each keyframe ``sample_data``
    record of ``keyframes``, time order, and the records between it and the keyframe before:
    ``data.sweeps.records_between``), and, with ``camera_keyframes``, those keyframes' headings ``against_path`` of
    the first channel's records (a camera whose keyframes alone carry the noise: probe 99, 0.5 deg on the camera's
    records, a yaw 1.70 deg off at NEES 17.9, unmeasured). None where neither is measured."""
    from hybrid_calib.data.sweeps import records_between

    t, h = _headings(tables, [rec for sd in keyframes for rec in [*records_between(tables, sd), sd]])
    found = [heading_jitter(t, h)]
    if camera_keyframes:
        found.append(against_path(*_headings(tables, camera_keyframes), t, h))
    found = [j for j in found if j is not None]
    return max(found, key=lambda j: j.sigma_deg) if found else None
