"""Per-scene / per-vehicle summary of a nuScenes-format root, and a radar + LiDAR overlay picture.

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
from pathlib import Path
from typing import Any

import numpy as np

from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.data.nuscenes import NuScenesRadarCamera
from hybrid_calib.geometry import transform_points


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


def render_overlay(frame: RadarCameraFrame, path: str | Path, max_lidar: int = 20000) -> Path:
    """Save a PNG of the frame's image with its LiDAR points (small, coloured by depth) and radar
    points (large, coloured by depth) projected with the ground-truth extrinsics. Atomic write."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    img = frame.load_image()
    cam = frame.camera
    fig, ax = plt.subplots(figsize=(12, 12 * cam.height / cam.width), dpi=100)
    ax.imshow(img)
    if frame.lidar_points is not None and frame.T_cam_lidar is not None:
        pts = frame.lidar_points[:, :3]
        if len(pts) > max_lidar:
            pts = pts[np.linspace(0, len(pts) - 1, max_lidar).astype(int)]
        uv, z = cam.project(transform_points(frame.T_cam_lidar, pts))
        ok = (z > 0.5) & cam.in_image(uv)
        ax.scatter(uv[ok, 0], uv[ok, 1], c=np.log(z[ok]), s=1.5, cmap="viridis", alpha=0.8, label="LiDAR")
    uv, z = cam.project(transform_points(frame.T_cam_radar, frame.radar_points))
    ok = (z > 0) & cam.in_image(uv)
    ax.scatter(uv[ok, 0], uv[ok, 1], c=z[ok], s=40, cmap="autumn", edgecolors="k", linewidths=0.8,
               label=f"radar ({ok.sum()}/{len(z)} in image)")
    ax.set_xlim(-0.5, cam.width - 0.5)
    ax.set_ylim(cam.height - 0.5, -0.5)
    ax.set_axis_off()
    ax.legend(loc="lower right", fontsize=9)
    ax.set_title(f"{frame.scene_name} / {frame.vehicle} / frame {frame.index}: ground-truth projection "
                 f"(dt radar-camera {(frame.timestamp_radar_us - frame.timestamp_camera_us) / 1000:.0f} ms)",
                 fontsize=10)
    fig.tight_layout()
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp)
    plt.close(fig)
    tmp.replace(path)
    return path
