"""The real nuScenes fleet's sensor mounts: which (CAM_FRONT, RADAR_FRONT, LIDAR_TOP) mount
combinations occur and in how many scenes, read from a ``calibrated_sensor.json`` of v1.0-trainval.

The trainval tables hold no sample / sample_data links (``../shared/data/nuscenes-trainval-tables``
is metadata only), but ``calibrated_sensor.json`` comes in one block per scene of one record per
sensor in a fixed channel order; ``fleet_mounts`` checks that every block holds each channel once
and joins the channels of a block into one vehicle mount. The simulator's randomisation draws
from a copy of the result (``hybrid_calib.sim.real_mounts``; a test keeps the copy equal to the
tables when they are present).
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybrid_calib.data.tables import load_table
from hybrid_calib.errors import DataError

FLEET_CHANNELS = ("CAM_FRONT", "RADAR_FRONT", "LIDAR_TOP")


@dataclass(frozen=True)
class FleetMount:
    """One mount combination of the real fleet.

    scenes: how many scenes use it. Poses are nuScenes ``calibrated_sensor`` records (sensor -> ego):
    rotation quaternion (w, x, y, z), translation metres. camera_K: CAM_FRONT intrinsics at
    1600 x 900 pixels, row-major 3 x 3.
    """

    scenes: int
    cam_translation: tuple[float, float, float]
    cam_rotation: tuple[float, float, float, float]
    camera_K: tuple[tuple[float, float, float], ...]
    radar_translation: tuple[float, float, float]
    radar_rotation: tuple[float, float, float, float]
    lidar_translation: tuple[float, float, float]
    lidar_rotation: tuple[float, float, float, float]


def _key(rec: dict, decimals: int) -> tuple:
    return (tuple(round(float(x), decimals) for x in rec["translation"]),
            tuple(round(float(x), decimals) for x in rec["rotation"]))


def fleet_mounts(version_dir: str | Path, decimals: int = 4) -> list[FleetMount]:
    """Distinct fleet mounts in ``version_dir/calibrated_sensor.json`` (+ ``sensor.json``), most
    scenes first; records are compared after rounding to ``decimals`` places.

    ``DataError`` naming the file if a block of records does not hold each channel exactly once."""
    vdir = Path(version_dir)
    sensors = {s["token"]: s["channel"] for s in load_table(vdir, "sensor", ("token", "channel"))}
    cs = load_table(vdir, "calibrated_sensor", ("token", "sensor_token", "translation", "rotation", "camera_intrinsic"))
    per_block = len(sensors)
    if per_block == 0 or len(cs) % per_block:
        raise DataError(f"calibrated_sensor holds {len(cs)} records, not a whole number of blocks of one record per "
                        f"sensor ({per_block} sensors); this is not a v1.0-trainval table in scene order",
                        path=str(vdir / "calibrated_sensor.json"))
    counts: Counter = Counter()
    for b in range(0, len(cs), per_block):
        block: dict[str, dict] = {}
        for rec in cs[b:b + per_block]:
            ch = sensors.get(rec["sensor_token"])
            if ch in block:
                raise DataError(f"calibrated_sensor block {b // per_block} holds {ch} twice; the table is not in "
                                "scene blocks, so its mounts cannot be joined per vehicle",
                                path=str(vdir / "calibrated_sensor.json"), token=rec["token"])
            block[ch] = rec
        missing = [ch for ch in FLEET_CHANNELS if ch not in block]
        if missing:
            raise DataError(f"calibrated_sensor block {b // per_block} lacks {missing}",
                            path=str(vdir / "calibrated_sensor.json"))
        K = np.asarray(block["CAM_FRONT"]["camera_intrinsic"], float)
        if K.shape != (3, 3):
            raise DataError(f"CAM_FRONT camera_intrinsic of block {b // per_block} is not 3 x 3",
                            path=str(vdir / "calibrated_sensor.json"), token=block["CAM_FRONT"]["token"])
        key = (_key(block["CAM_FRONT"], decimals), tuple(tuple(round(float(x), 3) for x in row) for row in K),
               _key(block["RADAR_FRONT"], decimals), _key(block["LIDAR_TOP"], decimals))
        counts[key] += 1
    return [FleetMount(scenes=n, cam_translation=cam[0], cam_rotation=cam[1], camera_K=K, radar_translation=rad[0],
                       radar_rotation=rad[1], lidar_translation=lid[0], lidar_rotation=lid[1])
            for (cam, K, rad, lid), n in counts.most_common()]
