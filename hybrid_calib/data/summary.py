"""Per-scene / per-vehicle summary of a nuScenes-format root.

``summarize_dataset`` walks every frame once (tqdm progress) and returns a ``DatasetSummary``;
``DatasetSummary.to_json()`` is the schema written by ``hybrid-calib inspect``::

    {"root": str, "version": str, "radar_channel": str, "camera_channel": str,
     "n_frames": int, "n_loaded": int, "n_skipped": int,
     "groups": [{"scene": str, "vehicle": str, "log_token": str, "frames": int, "loaded": int,
                 "radar_points_per_sweep": {"mean": float, "min": int, "max": int},
                 "radar_points_raw_mean": float, "radar_nonfinite_dropped": int, "lidar_nonfinite_dropped": int,
                 "dt_radar_minus_camera_ms": {"mean": float, "min": float, "max": float}}],
     "skipped": [{"index": int | null, "token": str, "path": str | null, "reason": str}]}
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hybrid_calib.data.nuscenes import NuScenesRadarCamera


@dataclass
class GroupSummary:
    scene: str
    vehicle: str
    log_token: str
    frames: int = 0  # frames in the index
    loaded: int = 0  # frames that loaded
    radar_points: list[int] = field(default_factory=list)  # per loaded frame, after filtering
    radar_raw: list[int] = field(default_factory=list)  # per loaded frame, before filtering
    nonfinite: int = 0  # NaN/inf radar points dropped
    lidar_nonfinite: int = 0  # NaN/inf LiDAR points dropped (when LiDAR is loaded)
    dt_ms: list[float] = field(default_factory=list)  # radar minus camera timestamp, milliseconds

    def to_json(self) -> dict[str, Any]:
        pts = np.asarray(self.radar_points or [0])
        dt = np.asarray(self.dt_ms or [np.nan])
        return dict(scene=self.scene, vehicle=self.vehicle, log_token=self.log_token, frames=self.frames,
                    loaded=self.loaded,
                    radar_points_per_sweep=dict(mean=float(pts.mean()), min=int(pts.min()), max=int(pts.max())),
                    radar_points_raw_mean=float(np.mean(self.radar_raw)) if self.radar_raw else 0.0,
                    radar_nonfinite_dropped=self.nonfinite, lidar_nonfinite_dropped=self.lidar_nonfinite,
                    dt_radar_minus_camera_ms=dict(mean=float(np.mean(dt)), min=float(np.min(dt)),
                                                  max=float(np.max(dt))))


@dataclass
class DatasetSummary:
    root: str
    version: str
    radar_channel: str
    camera_channel: str
    groups: list[GroupSummary]
    skipped: list[dict[str, Any]]
    first_loaded: int | None  # index of the first frame that loaded (used for the overlay)

    @property
    def n_frames(self) -> int:
        return sum(g.frames for g in self.groups)

    @property
    def n_loaded(self) -> int:
        return sum(g.loaded for g in self.groups)

    def to_json(self) -> dict[str, Any]:
        return dict(root=self.root, version=self.version, radar_channel=self.radar_channel,
                    camera_channel=self.camera_channel, n_frames=self.n_frames, n_loaded=self.n_loaded,
                    n_skipped=len(self.skipped), groups=[g.to_json() for g in self.groups], skipped=self.skipped)

    def format(self) -> str:
        """A human-readable table: one line per scene/vehicle, then the skipped items."""
        lines = [f"{self.root} [{self.version}] {self.radar_channel} -> {self.camera_channel}: "
                 f"{self.n_loaded}/{self.n_frames} frames loaded, {len(self.skipped)} skipped",
                 f"{'scene':24s} {'vehicle':12s} {'frames':>6s} {'loaded':>6s} {'radar pts/sweep':>18s} "
                 f"{'raw':>6s} {'NaN':>5s} {'dt ms':>7s}"]
        for g in self.groups:
            j = g.to_json()
            p = j["radar_points_per_sweep"]
            lines.append(f"{g.scene[:24]:24s} {g.vehicle[:12]:12s} {g.frames:6d} {g.loaded:6d} "
                         f"{p['mean']:7.1f} [{p['min']:3d},{p['max']:4d}] {j['radar_points_raw_mean']:6.1f} "
                         f"{g.nonfinite:5d} {j['dt_radar_minus_camera_ms']['mean']:7.1f}")
        if not self.n_frames:
            lines.append(f"no frames: no sample has both a {self.radar_channel} and a {self.camera_channel} keyframe "
                         "(the skipped items below say why); check --radar/--camera and the tables")
        for s in self.skipped:
            lines.append(f"skipped frame {s['index'] if s['index'] is not None else '-'}: {s['reason']}")
        return "\n".join(lines)


def summarize_dataset(ds: NuScenesRadarCamera, progress: bool = True) -> DatasetSummary:
    """Load every frame of ``ds`` once and summarise it per scene and vehicle."""
    from tqdm import tqdm

    groups: dict[str, GroupSummary] = {}
    for ref in ds.frames:
        g = groups.setdefault(ref.scene_token, GroupSummary(ref.scene_name, ref.vehicle, ref.log_token))
        g.frames += 1
    first = None
    for f in tqdm(ds, total=len(ds), desc="inspect", unit="frame", disable=not progress):
        g = groups[f.extras["scene_token"]]
        g.loaded += 1
        g.radar_points.append(len(f.radar_points))
        g.radar_raw.append(int(f.extras["radar_points_raw"]))
        g.nonfinite += int(f.extras["radar_nonfinite_dropped"])
        g.lidar_nonfinite += int(f.extras.get("lidar_nonfinite_dropped", 0))
        g.dt_ms.append((f.timestamp_radar_us - f.timestamp_camera_us) / 1000.0)
        first = f.index if first is None else first
    return DatasetSummary(str(ds.root), ds.version, ds.radar_channel, ds.camera_channel, list(groups.values()),
                          [dataclasses.asdict(s) for s in ds.skipped], first)
