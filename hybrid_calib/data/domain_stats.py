"""What a network sees of a frame, as statistics that can be compared between real and simulated
roots (``benchmarks/sim_vs_real.py``, docs/sim_vs_real.md).

Per frame: radar points after the filters (range, azimuth, RCS), the share of them without LiDAR
support (a clutter proxy that works on real data too), image colour / contrast / sharpness at a
common size, a depth map's density and error against held-out LiDAR points (and the simulator's
true depth), the camera intrinsics normalised to 1600 x 900, and the mounts as angles.
All functions take plain arrays or a ``RadarCameraFrame`` and return plain dicts / arrays.
"""

from __future__ import annotations

import numpy as np

from hybrid_calib.data.files import read_npz
from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import R_AXES_CAM_FROM_RADAR, se3_inverse
from hybrid_calib.sensors.ground import ground_level

IMAGE_SIZE_WH = (400, 225)  # image statistics are taken at this common size (nuScenes 1600 x 900 / 4)
SUPPORT_MIN_HEIGHT_M = 0.3  # LiDAR points lower than this above the radar's ground are ground, not support
SUPPORT_MAX_HEIGHT_M = 3.0  # and higher than this are above anything the radar sees
SUPPORT_RADIUS_M = 1.0  # a radar point is supported by a LiDAR point within this (+ 2 % of its range), BEV
SUPPORT_MAX_RANGE_M = 50.0  # the proxy is computed only for radar points this near (LiDAR gets sparse beyond)


def radar_stats(frame: RadarCameraFrame) -> dict:
    """Radar statistics of one frame (its points after the dataset's filters).

    Returns: n (points), n_raw (before filtering), range_m / azimuth_deg / rcs_dbsm: (n,) arrays;
    true_kind: (n,) int8 REAL 0 / CLUTTER 1 / GHOST 2 from the simulator's truth, or None on real data;
    unsupported: (m,) bool for the points nearer than ``SUPPORT_MAX_RANGE_M``: no LiDAR point within
    ``SUPPORT_RADIUS_M`` (+ 2 % of range) in bird's eye view between ``SUPPORT_MIN_HEIGHT_M`` and
    ``SUPPORT_MAX_HEIGHT_M`` above the ground (None without LiDAR)."""
    p = np.asarray(frame.radar_points, float)
    r = np.hypot(p[:, 0], p[:, 1])
    out = {"n": len(p), "n_raw": int(frame.extras.get("radar_points_raw", len(p))), "range_m": r,
           "azimuth_deg": np.degrees(np.arctan2(p[:, 1], p[:, 0])),
           "rcs_dbsm": np.asarray(frame.radar_fields.get("rcs", np.full(len(p), np.nan)), float),
           "true_kind": None, "unsupported": None}
    truth = frame.extras.get("radar_truth_path")
    if truth is not None and "radar_rows" in frame.extras:
        try:
            with read_npz(truth, "simulator truth file", "re-run hybrid-calib simulate") as t:
                out["true_kind"] = np.asarray(t["kind"])[frame.extras["radar_rows"]]
        except DataError:
            pass  # a damaged simulator truth file: the kinds are unknown for this frame (the statistics go on)
    if frame.lidar_points is not None and frame.T_cam_lidar is not None:
        T_radar_lidar = se3_inverse(frame.T_cam_radar) @ frame.T_cam_lidar
        q = np.asarray(frame.lidar_points[:, :3], float) @ T_radar_lidar[:3, :3].T + T_radar_lidar[:3, 3]
        h = q[:, 2]  # above the road the sweep sees around the radar (not the ego origin's, a root's choice:
        h = h - ground_level(h, np.hypot(q[:, 0], q[:, 1]))  # probe 143)
        q = q[(h > SUPPORT_MIN_HEIGHT_M) & (h < SUPPORT_MAX_HEIGHT_M), :2]
        near = r < SUPPORT_MAX_RANGE_M
        out["unsupported"] = _unsupported(p[near, :2], r[near], q)
    return out


def _unsupported(xy: np.ndarray, r: np.ndarray, lidar_xy: np.ndarray) -> np.ndarray:
    if len(xy) == 0:
        return np.zeros(0, bool)
    if len(lidar_xy) == 0:
        return np.ones(len(xy), bool)
    from scipy.spatial import cKDTree

    d, _ = cKDTree(lidar_xy).query(xy, k=1)
    return d > SUPPORT_RADIUS_M + 0.02 * r


def image_stats(image_rgb: np.ndarray) -> dict:
    """(H, W, 3) uint8 RGB -> statistics at ``IMAGE_SIZE_WH``: mean R / G / B and luminance (0..1),
    contrast (luminance std), saturation (mean HSV S, 0..1), sharpness (std of the Laplacian of the
    luminance, 0..1 per pixel) and dark / bright clipping (fraction of luminance < 0.02 / > 0.98)."""
    import cv2

    img = cv2.resize(np.asarray(image_rgb), IMAGE_SIZE_WH, interpolation=cv2.INTER_AREA).astype(np.float32) / 255
    lum = img @ np.asarray([0.299, 0.587, 0.114], np.float32)
    hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV)
    lap = cv2.Laplacian(lum, cv2.CV_32F)
    m = img.reshape(-1, 3).mean(0)
    return {"mean_r": float(m[0]), "mean_g": float(m[1]), "mean_b": float(m[2]), "luminance": float(lum.mean()),
            "contrast": float(lum.std()), "saturation": float(hsv[..., 1].mean()), "sharpness": float(lap.std()),
            "dark": float((lum < 0.02).mean()), "bright": float((lum > 0.98).mean())}


def split_points(n: int, holdout: float, seed: int) -> np.ndarray:
    """(n,) bool: True for the held-out share ``holdout`` of n points, fixed by ``seed``."""
    return np.random.default_rng(seed).random(n) < holdout


def depth_stats(depth: np.ndarray, K: np.ndarray, heldout_cam: np.ndarray | None = None,
                truth: np.ndarray | None = None) -> dict:
    """A depth map's density and errors.

    depth: (H, W) metres, 0 = unknown. K: (3, 3) at that size. heldout_cam: (M, 3) camera-frame points
    (metres) that did not go into ``depth``; truth: (H, W) metres true depth (0 = none), simulator only.
    Returns density (share of pixels with depth), and for each reference (``lidar``: held-out points,
    ``truth``): abs_rel (mean |d - ref| / ref), rmse_m, delta1 (share with max(d/ref, ref/d) < 1.25)
    and coverage (share of reference pixels with a depth); NaN where there is no reference."""
    depth = np.asarray(depth, np.float32)
    H, W = depth.shape
    out = {"density": float((depth > 0).mean())}
    refs: dict[str, tuple[np.ndarray, np.ndarray] | None] = {"lidar": None, "truth": None}
    if heldout_cam is not None and len(heldout_cam):
        p = np.asarray(heldout_cam, float)
        p = p[p[:, 2] > 1.0]
        u = np.floor(K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2] + 0.5).astype(int)
        v = np.floor(K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2] + 0.5).astype(int)
        ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        refs["lidar"] = (depth[v[ok], u[ok]], p[ok, 2])
    if truth is not None:
        t = np.asarray(truth, np.float32)
        if t.shape != depth.shape:
            import cv2

            t = cv2.resize(t, (W, H), interpolation=cv2.INTER_NEAREST)
        m = t > 0
        refs["truth"] = (depth[m], t[m])
    for name, ref in refs.items():
        stats = dict(abs_rel=np.nan, rmse_m=np.nan, delta1=np.nan, coverage=np.nan)
        if ref is not None and len(ref[1]):
            d, g = ref
            have = d > 0
            stats["coverage"] = float(have.mean())
            if have.any():
                d, g = d[have].astype(float), g[have].astype(float)
                stats.update(abs_rel=float(np.mean(np.abs(d - g) / g)), rmse_m=float(np.sqrt(np.mean((d - g) ** 2))),
                             delta1=float((np.maximum(d / g, g / d) < 1.25).mean()))
        out.update({f"{name}_{k}": v for k, v in stats.items()})
    return out


def intrinsics_full_res(K: np.ndarray, width: int, height: int) -> dict:
    """fx, fy, cx, cy of a camera of ``width`` x ``height`` expressed at 1600 x 900 pixels."""
    sx, sy = 1600.0 / width, 900.0 / height
    return {"fx": float(K[0, 0] * sx), "fy": float(K[1, 1] * sy), "cx": float((K[0, 2] + 0.5) * sx - 0.5),
            "cy": float((K[1, 2] + 0.5) * sy - 0.5)}


def mount_angles(T_ego_cam: np.ndarray, T_ego_radar: np.ndarray) -> dict:
    """Mounts as numbers: camera yaw / pitch / roll (degrees, ego-frame Euler ZYX of the camera's
    rotation away from the ideal camera axes), camera x / y / z (metres), radar yaw / pitch / roll
    (degrees, ego-frame ZYX) and radar x / y / z (metres)."""
    from scipy.spatial.transform import Rotation

    R_ideal = R_AXES_CAM_FROM_RADAR.T  # ideal camera axes in the ego (= radar axes) frame
    cam = Rotation.from_matrix(T_ego_cam[:3, :3] @ R_ideal.T).as_euler("ZYX", degrees=True)
    rad = Rotation.from_matrix(T_ego_radar[:3, :3]).as_euler("ZYX", degrees=True)
    out = {f"cam_{k}_deg": float(v) for k, v in zip(("yaw", "pitch", "roll"), cam)}
    out.update({f"cam_{k}_m": float(v) for k, v in zip("xyz", T_ego_cam[:3, 3])})
    out.update({f"radar_{k}_deg": float(v) for k, v in zip(("yaw", "pitch", "roll"), rad)})
    out.update({f"radar_{k}_m": float(v) for k, v in zip("xyz", T_ego_radar[:3, 3])})
    return out
