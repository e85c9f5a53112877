"""How far apart two sensor mounts are, and when a vehicle's tables hold two of them as one calibration.

Mounts are (4, 4) rigid transforms (a sensor -> ego mount, or a camera-radar extrinsic ``T_cam_radar``); offsets are
the rotation angle between them (degrees) and the distance between their translations (centimetres), as
docs/conventions.md's error metrics. The one home of the rule both the dataset (``data.nuscenes``: a vehicle's
calibrations, NAME-calN) and an earlier export (``data.reference``) apply.
"""

from __future__ import annotations

import numpy as np

from hybrid_calib.geometry import so3_log

# two camera-radar extrinsics of a vehicle's tables closer than this (deg, cm) are one calibration: nuScenes' own
# differ by 0.46 deg and more (radar yaws -0.85, -0.26, 0.00, +0.20 deg) or by centimetres (camera mounts)
SAME_CALIBRATION = (0.01, 0.1)


def mount_offset(T: np.ndarray, T0: np.ndarray) -> tuple[float, float]:
    """How far apart two mounts ``T``, ``T0`` (4, 4) are: (rotation angle, deg; translation distance, cm)."""
    angle = float(np.degrees(np.linalg.norm(so3_log(T0[:3, :3].T @ T[:3, :3]))))
    return angle, float(100 * np.linalg.norm(T[:3, 3] - T0[:3, 3]))


def same_calibration(T: np.ndarray, T0: np.ndarray) -> bool:
    """Whether two mounts ``T``, ``T0`` (4, 4) are one calibration of the tables: within ``SAME_CALIBRATION``
    (0.01 deg and 0.1 cm) of each other."""
    return all(d <= tol for d, tol in zip(mount_offset(T, T0), SAME_CALIBRATION, strict=True))
