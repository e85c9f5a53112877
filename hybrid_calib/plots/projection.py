"""Pictures people would rather see than read: points projected over a camera image.

``draw_projection`` (any points over any image), ``draw_radar_on_frame`` (a frame's radar points,
optionally against a second extrinsic), ``draw_radar_truth`` (recorded radar points and the true
reflectors they came from; the demo's ``projection.png``) and ``render_overlay`` (LiDAR and radar
with the ground-truth extrinsics; ``hybrid-calib inspect``'s ``overlay.png``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.geometry import transform_points
from hybrid_calib.plots.figure import pyplot, save_figure


def draw_projection(image_rgb: np.ndarray, uv: np.ndarray, depth: np.ndarray, out_path: str | Path,
                    title: str | None = None, extra: dict | None = None) -> Path:
    """Save a PNG of points coloured by depth over an image.

    image_rgb: (H, W, 3) uint8. uv: (N, 2) pixels (column, row). depth: (N,) metres (colour scale).
    extra: optional second point set drawn as hollow markers, e.g. truth vs. estimate:
      ``{"uv": (M, 2), "label": str, "color": str, "lines_to_first": bool}``; with
      ``lines_to_first`` (and M == N) a segment joins each pair of points.
    Points outside the image or with non-finite coordinates are left out. Returns the PNG path.
    """
    plt = pyplot()
    image_rgb = np.asarray(image_rgb)
    if image_rgb.ndim != 3 or image_rgb.shape[2] != 3:
        raise ValueError(f"image_rgb must be (H, W, 3), got {image_rgb.shape}")
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    depth = np.asarray(depth, dtype=np.float64).reshape(-1)
    if len(uv) != len(depth):
        raise ValueError(f"uv has {len(uv)} points but depth has {len(depth)}")
    H, W = image_rgb.shape[:2]
    inside = np.isfinite(uv).all(1) & np.isfinite(depth) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (
        uv[:, 1] < H)
    dpi = 100
    fig = plt.figure(figsize=(W / dpi, H / dpi + (0.35 if title else 0)), dpi=dpi)
    ax = fig.add_axes((0, 0, 1, H / (H + (35 if title else 0))))
    ax.imshow(image_rgb)
    ax.set_xlim(-0.5, W - 0.5)
    ax.set_ylim(H - 0.5, -0.5)
    ax.axis("off")
    if inside.any():
        sc = ax.scatter(uv[inside, 0], uv[inside, 1], c=depth[inside], cmap="turbo", s=14, vmin=0,
                        vmax=max(float(np.percentile(depth[inside], 95)), 1.0), edgecolors="k", linewidths=0.3)
        cax = fig.add_axes((0.88, 0.05, 0.015, 0.3 * H / (H + (35 if title else 0))))
        cb = fig.colorbar(sc, cax=cax)
        cb.set_label("depth (m)", color="w", fontsize=7)
        cb.ax.tick_params(colors="w", labelsize=6)
    if extra is not None:
        euv = np.asarray(extra["uv"], dtype=np.float64).reshape(-1, 2)
        ok = np.isfinite(euv).all(1)
        color = extra.get("color", "w")
        ax.scatter(euv[ok, 0], euv[ok, 1], s=30, facecolors="none", edgecolors=color, linewidths=0.9,
                   label=extra.get("label"))
        if extra.get("lines_to_first") and len(euv) == len(uv):
            both = ok & np.isfinite(uv).all(1)
            for a, b in zip(uv[both], euv[both]):
                ax.plot([a[0], b[0]], [a[1], b[1]], color=color, linewidth=0.6)
        if extra.get("label"):
            ax.legend(loc="upper left", fontsize=7)
    if title:
        fig.text(0.01, 1 - 0.3 / (H / dpi + 0.35), title, fontsize=9, va="center")
    return save_figure(fig, out_path, dpi=dpi)


def draw_radar_on_frame(frame: RadarCameraFrame, out_path: str | Path, T_cam_radar: np.ndarray | None = None,
                        title: str | None = None, compare_T_cam_radar: np.ndarray | None = None) -> Path:
    """Radar points of a ``RadarCameraFrame`` projected on its image, coloured by camera depth.

    T_cam_radar: (4, 4) extrinsic to project with (default: the frame's ground truth).
    compare_T_cam_radar: optional second extrinsic (e.g. an estimate); its projections are drawn as
    hollow markers joined to the first ones. Returns the PNG path.
    """
    T = frame.T_cam_radar if T_cam_radar is None else np.asarray(T_cam_radar, dtype=np.float64)
    uv, z = frame.camera.project(transform_points(T, frame.radar_points))
    extra = None
    if compare_T_cam_radar is not None:
        uv2, _ = frame.camera.project(transform_points(compare_T_cam_radar, frame.radar_points))
        extra = {"uv": uv2, "label": "compared extrinsic", "color": "w", "lines_to_first": True}
    if title is None:
        title = (f"{frame.vehicle} {frame.scene_name} frame {frame.index}: {len(frame.radar_points)} "
                 f"{frame.radar_channel} points on {frame.camera_channel}")
    return draw_projection(frame.load_image(), uv, z, out_path, title=title, extra=extra)


def draw_radar_truth(frame: RadarCameraFrame, true_xyz: np.ndarray, out_path: str | Path) -> Path:
    """The frame's radar points (z = 0 as recorded, coloured by depth) projected with its
    ground-truth extrinsic, and the true reflectors they came from (``true_xyz``: (N, 3) metres,
    radar frame, row-aligned with ``frame.radar_points``; None to leave them out) as cyan rings
    joined to them. Returns the PNG path."""
    uv, z = frame.camera.project(transform_points(frame.T_cam_radar, frame.radar_points))
    extra = None
    if true_xyz is not None:
        uv_true, _ = frame.camera.project(transform_points(frame.T_cam_radar, true_xyz))
        extra = {"uv": uv_true, "label": "true reflector", "color": "cyan", "lines_to_first": True}
    return draw_projection(
        frame.load_image(), uv, z, out_path, extra=extra,
        title=f"{frame.vehicle} frame {frame.index}: radar points (z=0, coloured by depth) with the ground-truth "
              "extrinsic; cyan: true reflectors",
    )


def render_overlay(frame: RadarCameraFrame, path: str | Path, max_lidar: int = 20000) -> Path:
    """Save a PNG of the frame's image with its LiDAR points (small, coloured by depth) and radar
    points (large, coloured by depth) projected with the ground-truth extrinsics. Atomic write."""
    plt = pyplot()
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
    return save_figure(fig, path)
