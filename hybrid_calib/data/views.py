"""Which keyframes of a drive are new views, and which repeat one already taken (the ego stood still).

A calibration treats its frames as independent measurements of one extrinsic. Keyframes taken while the ego waits at
a light (199 of the 850 nuScenes trainval scenes' descriptions name a wait or a stop) see the same scene from the
same place: the network's pass, its rows, the LiDAR's and the radar's detections repeat the first frame's, errors and
all. Fused as independent frames they shrink the covariance as 1/N while the error stays (measured on simulated
drives with one 10 s stop: docs/benchmarks.md "Drives that stop"). So a frame is a new view only when the ego has
moved at least ``min_travel_m`` or turned at least ``min_turn_deg`` since the last view taken; the others are left out
with a reason naming the view they repeat. Distances and turns are between the camera's poses at its keyframes (tables:
the ego pose times the camera's mount; not the ego origin's, which a root may put anywhere).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.config import require_ranges
from hybrid_calib.geometry import so3_log


@dataclass(frozen=True)
class ViewConfig:
    """When a keyframe is a new view (module doc); ``min_travel_m=0`` and ``min_turn_deg=0`` take every frame."""

    min_travel_m: float = 1.0  # the camera's travel since the last view taken that makes a new view, metres
    min_turn_deg: float = 3.0  # or its heading change since the last view taken, degrees

    def __post_init__(self):
        require_ranges(self, {"min_travel_m": "[0, 1000]", "min_turn_deg": "[0, 180]"})

    @property
    def enabled(self) -> bool:
        return self.min_travel_m > 0 or self.min_turn_deg > 0


@dataclass(frozen=True)
class Repeat:
    """A keyframe that repeats an earlier view: ``of`` (its position in the drive), how far the camera moved and turned
    since that view."""

    of: int
    travel_m: float
    turn_deg: float

    def reason(self, conf: ViewConfig) -> str:
        return (f"the same view as frame {self.of}: the camera moved {self.travel_m:.2f} m and turned "
                f"{self.turn_deg:.1f} deg since (a new view needs {conf.min_travel_m:g} m or {conf.min_turn_deg:g} "
                "deg, views.min_travel_m / views.min_turn_deg): its errors would repeat that frame's")

    def record(self, k: int, token: str | None, conf: ViewConfig) -> dict:
        """Frame ``k``'s (its position in the drive) ``frames_skipped`` record: every method writes this one."""
        return {"index": int(k), "token": token, "reason": self.reason(conf), "repeats": self.of}


def repeated_views(poses: list, conf: ViewConfig) -> dict[int, Repeat]:
    """Position in the drive -> ``Repeat`` for each frame of ``poses`` (time order; (4, 4) camera -> global, or None
    where a pose does not read: such a frame is taken, as before) that repeats the last view taken."""
    if not conf.enabled:
        return {}
    out: dict[int, Repeat] = {}
    last = None  # (position, pose) of the last view taken
    for k, T in enumerate(poses):
        if T is None or not np.all(np.isfinite(T)):
            continue
        T = np.asarray(T, np.float64)
        if last is not None:
            d = float(np.linalg.norm(T[:3, 3] - last[1][:3, 3]))
            turn = float(np.degrees(np.linalg.norm(so3_log(last[1][:3, :3].T @ T[:3, :3]))))
            if d < conf.min_travel_m and turn < conf.min_turn_deg:
                out[k] = Repeat(last[0], d, turn)
                continue
        last = (k, T)
    return out
