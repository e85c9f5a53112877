"""A tiny nuScenes-format root written by the tests themselves (hand-written tables, real file formats).

One scene, one log (vehicle ``tiny``), ``n_samples`` samples. The ego drives along global +x at
``speed`` m/s. Each sample has a CAM_FRONT keyframe at t, a RADAR_FRONT keyframe at t + 45 ms and a
LIDAR_TOP keyframe at t + 5 ms; with ``sweeps`` > 0, that many non-keyframe radar sweeps (files in
``sweeps/RADAR_FRONT``) sit between consecutive radar keyframes, 50 ms apart, linked by prev/next.
Radar returns are static world landmarks (``LANDMARKS_GLOBAL``) seen from the radar pose at each
sweep's timestamp, so ground truth is exact.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from hybrid_calib.data.pcd import empty_radar_points, write_lidar_bin, write_radar_pcd
from hybrid_calib.geometry import make_T, pose_to_nuscenes, se3_inverse, so3_exp, transform_points

VERSION = "v1.0-mini"
W, H = 160, 90
K = np.array([[100.0, 0.0, 80.0], [0.0, 100.0, 45.0], [0.0, 0.0, 1.0]])
# sensor -> ego mountings (ego: x forward, y left, z up; camera: x right, y down, z forward)
T_EGO_CAM = make_T(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), [1.7, 0.0, 1.5])
T_EGO_RADAR = make_T(so3_exp([0.0, 0.0, 0.02]), [3.4, 0.0, 0.5])  # yawed 1.15 deg left
T_EGO_LIDAR = make_T(np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [0.9, 0.0, 1.8])
# static reflectors in the global frame (x forward of the start, y left, z up), metres
LANDMARKS_GLOBAL = np.array([[30.0, -2.0, 0.5], [35.0, 3.0, 0.5], [40.0, 0.0, 0.5], [45.0, -4.0, 0.5],
                             [50.0, 5.0, 0.5], [38.0, 1.0, 0.5]])


@dataclass
class TinyRoot:
    root: Path
    version: str
    tables: dict[str, list[dict]]
    cam_sd: list[dict] = field(default_factory=list)  # keyframe camera sample_data, per sample
    radar_sd: list[dict] = field(default_factory=list)  # keyframe radar sample_data, per sample
    lidar_sd: list[dict] = field(default_factory=list)

    @property
    def vdir(self) -> Path:
        return self.root / self.version

    def path(self, sd: dict) -> Path:
        return self.root / sd["filename"]

    def rewrite_table(self, name: str) -> None:
        (self.vdir / f"{name}.json").write_text(json.dumps(self.tables[name]))


def T_global_ego_at(t_us: int, t0_us: int, speed: float) -> np.ndarray:
    return make_T(np.eye(3), [speed * (t_us - t0_us) * 1e-6, 0.0, 0.0])


def radar_points_at(T_global_ego: np.ndarray) -> np.ndarray:
    """Structured radar points of the landmarks seen from the radar at an ego pose."""
    p = transform_points(se3_inverse(T_global_ego @ T_EGO_RADAR), LANDMARKS_GLOBAL)
    pts = empty_radar_points(len(p))
    pts["x"], pts["y"], pts["z"] = p[:, 0], p[:, 1], p[:, 2]
    pts["rcs"] = 10.0
    pts["dyn_prop"] = 1
    pts["ambig_state"] = 3
    pts["invalid_state"] = 0
    pts["id"] = np.arange(len(p))
    return pts


def make_tiny_root(root: Path, n_samples: int = 4, sweeps: int = 0, speed: float = 10.0) -> TinyRoot:
    root = Path(root)
    t0 = 1_600_000_000_000_000
    tables: dict[str, list[dict]] = {k: [] for k in ("scene", "sample", "sample_data", "calibrated_sensor", "sensor",
                                                     "ego_pose", "log")}
    tables["log"].append(dict(token="log0", vehicle="tiny", logfile="tiny-log", date_captured="2026-01-01",
                              location="nowhere"))
    sensors = (("CAM_FRONT", "camera", T_EGO_CAM, K.tolist()), ("RADAR_FRONT", "radar", T_EGO_RADAR, []),
               ("LIDAR_TOP", "lidar", T_EGO_LIDAR, []))
    for ch, modality, T, intr in sensors:
        tables["sensor"].append(dict(token=f"sensor_{ch}", channel=ch, modality=modality))
        rot, trans = pose_to_nuscenes(T)
        tables["calibrated_sensor"].append(dict(token=f"cs_{ch}", sensor_token=f"sensor_{ch}", rotation=rot,
                                                translation=trans, camera_intrinsic=intr))
    tiny = TinyRoot(root, VERSION, tables)
    last: dict[str, dict | None] = {"CAM_FRONT": None, "RADAR_FRONT": None, "LIDAR_TOP": None}

    def add_sd(channel: str, sample_token: str, t_us: int, key: bool, filename: str) -> dict:
        token = f"sd_{channel}_{t_us}"
        rot, trans = pose_to_nuscenes(T_global_ego_at(t_us, t0, speed))
        tables["ego_pose"].append(dict(token=token, timestamp=t_us, rotation=rot, translation=trans))
        rec = dict(token=token, sample_token=sample_token, ego_pose_token=token,
                   calibrated_sensor_token=f"cs_{channel}", timestamp=t_us,
                   fileformat=filename.rsplit(".", 1)[-1], is_key_frame=key,
                   height=H if channel == "CAM_FRONT" else 0, width=W if channel == "CAM_FRONT" else 0,
                   filename=filename, prev="", next="")
        prev = last[channel]
        if prev is not None:
            rec["prev"], prev["next"] = prev["token"], token
        last[channel] = rec
        tables["sample_data"].append(rec)
        return rec

    g = np.random.default_rng(0)
    for i in range(n_samples):
        t = t0 + i * 500_000
        sample_token = f"sample{i}"
        tables["sample"].append(dict(token=sample_token, timestamp=t, scene_token="scene0",
                                     prev=f"sample{i - 1}" if i else "",
                                     next=f"sample{i + 1}" if i < n_samples - 1 else ""))
        if i > 0:
            for k in range(sweeps, 0, -1):  # non-keyframe sweeps before this keyframe
                ts = t + 45_000 - k * 50_000
                rec = add_sd("RADAR_FRONT", sample_token, ts, False, f"sweeps/RADAR_FRONT/tiny__RADAR_FRONT__{ts}.pcd")
                write_radar_pcd(tiny.path(rec), radar_points_at(T_global_ego_at(ts, t0, speed)))
        cam = add_sd("CAM_FRONT", sample_token, t, True, f"samples/CAM_FRONT/tiny__CAM_FRONT__{t}.jpg")
        img = (g.integers(0, 255, (H, W, 3))).astype(np.uint8)
        tiny.path(cam).parent.mkdir(parents=True, exist_ok=True)
        assert cv2.imwrite(str(tiny.path(cam)), img)
        tr = t + 45_000
        rad = add_sd("RADAR_FRONT", sample_token, tr, True, f"samples/RADAR_FRONT/tiny__RADAR_FRONT__{tr}.pcd")
        write_radar_pcd(tiny.path(rad), radar_points_at(T_global_ego_at(tr, t0, speed)))
        tl = t + 5_000
        lid = add_sd("LIDAR_TOP", sample_token, tl, True, f"samples/LIDAR_TOP/tiny__LIDAR_TOP__{tl}.pcd.bin")
        pl = transform_points(se3_inverse(T_global_ego_at(tl, t0, speed) @ T_EGO_LIDAR), LANDMARKS_GLOBAL)
        write_lidar_bin(tiny.path(lid), np.column_stack([pl, np.full(len(pl), 7.0), np.zeros(len(pl))]))
        tiny.cam_sd.append(cam)
        tiny.radar_sd.append(rad)
        tiny.lidar_sd.append(lid)
    tables["scene"].append(dict(token="scene0", log_token="log0", nbr_samples=n_samples,
                                first_sample_token="sample0", last_sample_token=f"sample{n_samples - 1}",
                                name="tiny-scene", description="written by tests"))
    tiny.vdir.mkdir(parents=True, exist_ok=True)
    for name in tables:
        tiny.rewrite_table(name)
    return tiny


def corrupt_jpeg_scan(jpeg: bytes) -> bytes:
    """The same JPEG with its entropy-coded scan data overwritten (header and end marker intact): the
    cheap header check passes, and the decoder complains (``image_header.decode_image``)."""
    b = bytearray(jpeg)
    for i in range(b.find(b"\xff\xda") + 20, len(b) - 2, 3):
        b[i] = 0xFF if i % 2 else 0xD0
    return bytes(b)
