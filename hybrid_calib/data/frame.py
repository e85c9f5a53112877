"""The synchronised radar-camera frame that the data layer yields and every consumer reads."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.errors import DataError
from hybrid_calib.sensors.camera import PinholeCamera


@dataclass(frozen=True)
class RadarCameraFrame:
    """One camera keyframe with the radar sweep(s) nearest to it.

    Frames / units (docs/conventions.md):
      radar_points: (N, 3) float64, metres, radar frame (x forward, y left, z up; z = 0 for a 2D
        radar). Multi-sweep accumulation moves older sweeps into the current radar frame.
      radar_fields: name -> (N,) array for every PCD field (rcs, vx_comp, dyn_prop, ...).
      T_cam_radar: (4, 4) float64, ground truth from the tables, radar(t_radar) -> camera(t_cam),
        ego-motion compensated through ego -> global -> ego.
      lidar_points: (M, 4) float32 [x, y, z, intensity] in the LiDAR frame, or None.
      T_cam_lidar: (4, 4) LiDAR(t_lidar) -> camera(t_cam), or None.
      camera: intrinsics and the image size of the file on disk.
    """

    index: int
    sample_token: str
    scene_name: str
    vehicle: str  # the log's vehicle name (one log per vehicle in the simulator)
    log_token: str
    camera_channel: str
    radar_channel: str
    camera_token: str  # sample_data token of the image
    radar_token: str  # sample_data token of the (newest) radar sweep
    timestamp_camera_us: int
    timestamp_radar_us: int
    image_path: Path
    camera: PinholeCamera
    radar_points: np.ndarray
    radar_fields: dict[str, np.ndarray]
    T_cam_radar: np.ndarray
    lidar_points: np.ndarray | None = None
    T_cam_lidar: np.ndarray | None = None
    depth_path: Path | None = None  # simulator ground-truth depth (uint16 PNG, cm, 0 = no hit)
    extras: dict = field(default_factory=dict)

    @property
    def K(self) -> np.ndarray:
        return self.camera.K

    @property
    def radar_motion(self) -> np.ndarray:
        """(4, 4) ``N``: the radar's motion between its timestamp and the camera's, in the radar frame, with
        ``T_cam_radar = T_cam_radar_static N`` (docs/conventions.md "Transforms"); the identity for a frame without
        ``extras["T_cam_radar_static"]``."""
        from hybrid_calib.geometry import se3_inverse

        static = self.extras.get("T_cam_radar_static")
        if static is None:
            return np.eye(4)
        return se3_inverse(np.asarray(static, np.float64)) @ np.asarray(self.T_cam_radar, np.float64)

    def load_image(self) -> np.ndarray:
        """The camera image as (H, W, 3) uint8 RGB. ``DataError`` if it is missing, undecodable or
        decodes with corrupt pixel data (``image_header.decode_image``)."""
        from hybrid_calib.data.image_header import decode_image

        return decode_image(self.image_path, self.camera_token)[:, :, ::-1].copy()

    def load_depth(self) -> np.ndarray | None:
        """Ground-truth depth (H, W) float32 metres (0 = no return), or None when the dataset has none."""
        if self.depth_path is None:
            return None
        return read_depth_png(self.depth_path)


DEPTH_UNIT_M = 0.01  # ground-truth depth PNGs store centimetres in uint16


def read_depth_png(path: str | Path) -> np.ndarray:
    """uint16 PNG (centimetres, 0 = no return) -> (H, W) float32 metres."""
    import cv2

    from hybrid_calib.data.image_header import read_image

    try:
        d = read_image(path, cv2.IMREAD_UNCHANGED)
    except OSError:
        d = None
    if d is None or d.dtype != np.uint16 or d.ndim != 2:
        raise DataError("depth file missing, corrupt or not a uint16 single-channel PNG", path=str(path))
    return d.astype(np.float32) * DEPTH_UNIT_M


def write_depth_png(path: str | Path, depth_m: np.ndarray) -> Path:
    """(H, W) metres (0 or inf/NaN = no return) -> uint16 PNG in centimetres, atomically."""
    from hybrid_calib.data.image_header import write_image

    d = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=0.0, posinf=0.0)
    return write_image(path, np.clip(np.round(d / DEPTH_UNIT_M), 0, 65535).astype(np.uint16))
