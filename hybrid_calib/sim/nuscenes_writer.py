"""Write a simulated fleet as a nuScenes root: the 13 standard tables of ``v1.0-sim`` and file names.

Schema follows the nuScenes devkit (v1.0): every table is a JSON list of records with a 32-hex-digit
``token``. Tokens here are deterministic (an MD5 of the record's identity), so re-running a
simulation reproduces the same tables. One log and one scene per vehicle; every frame is a keyframe
sample with CAM_FRONT, RADAR_FRONT and LIDAR_TOP sample_data; each sample_data has its own ego_pose
(same token, as in nuScenes). ``calibrated_sensor`` holds the TRUE mounts; a new RADAR_FRONT record
starts whenever the radar mount changes.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hybrid_calib.config import save_json_atomic
from hybrid_calib.data.image_header import write_image
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.geometry import pose_to_nuscenes

VERSION = SIM_VERSION
CHANNELS = {"CAM_FRONT": "camera", "RADAR_FRONT": "radar", "LIDAR_TOP": "lidar"}
TABLES = ("attribute", "calibrated_sensor", "category", "ego_pose", "instance", "log", "map", "sample",
          "sample_annotation", "sample_data", "scene", "sensor", "visibility")

# The standard nuScenes definitions (names and descriptions as in v1.0).
VISIBILITY = [
    {"description": "visibility of whole object is between 0 and 40%", "token": "1", "level": "v0-40"},
    {"description": "visibility of whole object is between 40 and 60%", "token": "2", "level": "v40-60"},
    {"description": "visibility of whole object is between 60 and 80%", "token": "3", "level": "v60-80"},
    {"description": "visibility of whole object is between 80 and 100%", "token": "4", "level": "v80-100"},
]
ATTRIBUTES = [
    ("vehicle.moving", "Vehicle is moving."),
    ("vehicle.stopped", "Vehicle, with a driver/rider in/on it, is currently stationary but has an intent to move."),
    ("vehicle.parked", "Vehicle is stationary (usually for longer duration) with no immediate intent to move."),
    ("pedestrian.moving", "The human is moving."),
    ("pedestrian.standing", "The human is standing."),
    ("pedestrian.sitting_lying_down", "The human is sitting or lying down."),
    ("cycle.with_rider", "There is a rider on the bicycle or motorcycle."),
    ("cycle.without_rider", "There is NO rider on the bicycle or motorcycle."),
]
CATEGORIES = [
    ("human.pedestrian.adult", "Adult subcategory."),
    ("vehicle.car", "Vehicle designed primarily for personal use, e.g. sedans, hatch-backs, wagons, vans, mini-vans, "
                    "SUVs and jeeps."),
    ("vehicle.truck", "Vehicles primarily designed to haul cargo including pick-ups, lorrys, trucks and "
                      "semi-tractors."),
    ("vehicle.bus.rigid", "Rigid bus."),
    ("movable_object.barrier", "Temporary road barrier placed in the scene in order to redirect traffic."),
    ("static_object.bicycle_rack", "Area or device intended to park or secure the bicycles in a row."),
]


def token(*parts) -> str:
    """Deterministic 32-hex-digit token from the parts' string forms."""
    return hashlib.md5("/".join(str(p) for p in parts).encode()).hexdigest()


@dataclass
class FrameRecord:
    """What the tables need about one simulated keyframe (files relative to the root)."""

    index: int
    camera_us: int
    radar_us: int
    lidar_us: int
    camera_file: str
    radar_file: str
    lidar_file: str
    T_global_ego_cam: np.ndarray
    T_global_ego_radar: np.ndarray
    T_global_ego_lidar: np.ndarray
    T_ego_radar: np.ndarray
    radar_sweeps: list[tuple[int, str, np.ndarray]] = field(default_factory=list)
    # earlier non-keyframe radar sweeps: (timestamp us, file, T_global_ego), oldest first


@dataclass
class VehicleRecord:
    """One vehicle (log + scene) and its frames."""

    name: str  # e.g. sim-veh-000
    scenario: str
    seed: int
    description: str
    T_ego_cam: np.ndarray
    T_ego_lidar: np.ndarray
    K: np.ndarray  # (3, 3) camera intrinsic of the written images
    width: int
    height: int
    frames: list[FrameRecord] = field(default_factory=list)
    # part of every token of this vehicle's records: a digest of the simulation's config, so two roots simulated
    # with the same seed and scenario but other options (other data) never share a token
    salt: str = ""


def sample_file_name(log_name: str, channel: str, timestamp_us: int, key_frame: bool = True) -> str:
    """nuScenes-style relative file name, e.g. samples/CAM_FRONT/<log>__CAM_FRONT__<ts>.jpg
    (``sweeps/...`` for non-keyframes)."""
    ext = {"CAM_FRONT": "jpg", "RADAR_FRONT": "pcd", "LIDAR_TOP": "pcd.bin"}[channel]
    return f"{'samples' if key_frame else 'sweeps'}/{channel}/{log_name}__{channel}__{timestamp_us}.{ext}"


def log_name(vehicle: VehicleRecord) -> str:
    return f"{vehicle.name}-{vehicle.scenario}-seed{vehicle.seed}"


def log_key(v: VehicleRecord) -> str:
    """The part of every token of ``v``'s records that names its log (its name, salted: ``VehicleRecord.salt``)."""
    return f"{log_name(v)}/{v.salt}" if v.salt else log_name(v)


def build_tables(vehicles: list[VehicleRecord]) -> dict[str, list[dict]]:
    """All 13 tables for the given vehicles."""
    t: dict[str, list[dict]] = {name: [] for name in TABLES}
    t["visibility"] = [dict(v) for v in VISIBILITY]
    t["attribute"] = [{"token": token("attribute", n), "name": n, "description": d} for n, d in ATTRIBUTES]
    t["category"] = [{"token": token("category", n), "name": n, "description": d, "index": i}
                     for i, (n, d) in enumerate(CATEGORIES)]
    sensor_tok = {ch: token("sensor", ch) for ch in CHANNELS}
    t["sensor"] = [{"token": sensor_tok[ch], "channel": ch, "modality": m} for ch, m in CHANNELS.items()]
    map_token = token("map", *(log_key(v) for v in vehicles))
    for v in vehicles:
        _vehicle_tables(t, v, sensor_tok)
    t["map"] = [{"category": "semantic_prior", "token": map_token, "filename": f"maps/{map_token}.png",
                 "log_tokens": [token("log", log_key(v)) for v in vehicles]}]
    return t


def _cs_record(tok: str, sensor_token: str, T: np.ndarray, K: np.ndarray | None = None) -> dict:
    rot, trans = pose_to_nuscenes(T)
    return {"token": tok, "sensor_token": sensor_token, "translation": trans, "rotation": rot,
            "camera_intrinsic": K.tolist() if K is not None else []}


def _vehicle_tables(t: dict[str, list[dict]], v: VehicleRecord, sensor_tok: dict[str, str]) -> None:
    ln = log_name(v)
    lk = log_key(v)
    log_tok = token("log", lk)
    scene_tok = token("scene", lk)
    t["log"].append({"token": log_tok, "logfile": ln, "vehicle": v.name, "date_captured": "2026-01-01",
                     "location": f"sim-{v.scenario}"})
    cam_cs = token("cs", lk, "CAM_FRONT")
    lidar_cs = token("cs", lk, "LIDAR_TOP")
    t["calibrated_sensor"].append(_cs_record(cam_cs, sensor_tok["CAM_FRONT"], v.T_ego_cam, v.K))
    t["calibrated_sensor"].append(_cs_record(lidar_cs, sensor_tok["LIDAR_TOP"], v.T_ego_lidar))
    radar_cs: list[str] = []  # per frame: the radar record in force (a new one whenever the mount moves)
    last_T, current = None, ""
    for f in v.frames:
        if last_T is None or not np.array_equal(last_T, f.T_ego_radar):
            current = token("cs", lk, "RADAR_FRONT", f.index)
            t["calibrated_sensor"].append(_cs_record(current, sensor_tok["RADAR_FRONT"], f.T_ego_radar))
            last_T = f.T_ego_radar
        radar_cs.append(current)
    samples = [token("sample", lk, f.index) for f in v.frames]
    for i, f in enumerate(v.frames):
        t["sample"].append({"token": samples[i], "timestamp": f.lidar_us,
                            "prev": samples[i - 1] if i > 0 else "",
                            "next": samples[i + 1] if i + 1 < len(samples) else "",
                            "scene_token": scene_tok})
    for ch in CHANNELS:
        # (sample index, timestamp, file, ego pose, calibrated_sensor, key frame) in time order
        rows = []
        for i, f in enumerate(v.frames):
            if ch == "CAM_FRONT":
                rows.append((i, f.camera_us, f.camera_file, f.T_global_ego_cam, cam_cs, True))
            elif ch == "LIDAR_TOP":
                rows.append((i, f.lidar_us, f.lidar_file, f.T_global_ego_lidar, lidar_cs, True))
            else:
                rows += [(i, us, name, T, radar_cs[i], False) for us, name, T in f.radar_sweeps]
                rows.append((i, f.radar_us, f.radar_file, f.T_global_ego_radar, radar_cs[i], True))
        toks = [token("sample_data", lk, ch, ts) for _, ts, *_ in rows]
        is_cam = ch == "CAM_FRONT"
        for n, (i, ts, name, T, cs_tok, key) in enumerate(rows):
            rot, trans = pose_to_nuscenes(T)
            t["ego_pose"].append({"token": toks[n], "timestamp": ts, "rotation": rot, "translation": trans})
            t["sample_data"].append({
                "token": toks[n], "sample_token": samples[i], "ego_pose_token": toks[n],
                "calibrated_sensor_token": cs_tok, "timestamp": ts,
                "fileformat": "jpg" if is_cam else "pcd", "is_key_frame": key,
                "height": v.height if is_cam else 0, "width": v.width if is_cam else 0,
                "filename": name, "prev": toks[n - 1] if n > 0 else "",
                "next": toks[n + 1] if n + 1 < len(toks) else "",
            })
    t["scene"].append({"token": scene_tok, "log_token": log_tok, "nbr_samples": len(samples),
                       "first_sample_token": samples[0] if samples else "",
                       "last_sample_token": samples[-1] if samples else "",
                       "name": f"scene-{v.name}", "description": v.description})


def write_tables(root: Path, tables: dict[str, list[dict]]) -> Path:
    """Write every table to ``root/v1.0-sim/<name>.json`` atomically; returns the version folder."""
    out = Path(root) / VERSION
    for name in TABLES:
        save_json_atomic(out / f"{name}.json", tables[name])
    return out


def write_map_png(root: Path, map_token: str, paths_xy: list[np.ndarray], resolution: float = 0.5,
                  max_pixels: int = 8000) -> Path:
    """A top-down semantic prior: the vehicles' roads rasterised at ``resolution`` m/pixel (coarser when
    the roads span more than ``max_pixels`` pixels), uint8 PNG, north up."""
    import cv2

    pts = np.concatenate(paths_xy) if paths_xy else np.zeros((1, 2))
    lo = pts.min(0) - 20
    extent = pts.max(0) + 20 - lo
    resolution = max(resolution, float(extent.max()) / max_pixels)
    size = np.ceil(extent / resolution).astype(int) + 1
    img = np.zeros((size[1], size[0]), np.uint8)
    for p in paths_xy:
        px = ((p - lo) / resolution).astype(np.int32)
        px[:, 1] = img.shape[0] - 1 - px[:, 1]
        cv2.polylines(img, [px.reshape(-1, 1, 2)], False, 255, thickness=max(int(14 / resolution), 1))
    return write_image(Path(root) / "maps" / f"{map_token}.png", img)
