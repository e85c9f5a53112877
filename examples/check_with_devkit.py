"""Open a nuScenes-format root with the official nuscenes-devkit and walk its tables.

Acceptance check, not a CI test (the devkit pins its own numpy, matplotlib and OpenCV versions, which need not
match hybrid-calib's): run it in a throwaway environment::

    python3 -m venv /tmp/devkit-venv && /tmp/devkit-venv/bin/pip install nuscenes-devkit
    /tmp/devkit-venv/bin/python examples/check_with_devkit.py DIR VERSION
    # and hybrid-calib's reader against the devkit's, frame by frame (T_cam_radar, radar points):
    PYTHONPATH=. /tmp/devkit-venv/bin/python examples/check_with_devkit.py DIR VERSION --compare

It prints table sizes, walks every scene -> sample -> sample_data (following the devkit's
``sample['data']`` reverse index and the ``next`` pointers), counts the sample_data files that
exist on disk per channel, and resolves each keyframe's calibrated_sensor and ego_pose through
the devkit's ``get``. Exit status 0 when everything resolves, 1 otherwise.

The devkit asserts that every ``map.json`` record's mask PNG exists, but partial releases (like
the shared one-scene copy) ship without ``maps/``. When masks are missing and ``--no-map-stub`` is
not given, the script builds a throwaway overlay root (symlinks to the real folders plus a 1x1
placeholder PNG per missing mask) and says so; nothing in DIR is modified.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from collections import Counter

_PNG_1X1 = bytes.fromhex(
    "89504e470d0a1a0a0000000d49484452000000010000000108000000003a7e9b55"
    "0000000a49444154789c63600000000200015e2b2a5a0000000049454e44ae426082")


def overlay_with_map_stubs(dataroot: str, version: str) -> str:
    """``dataroot`` itself if every map mask exists, else a temp overlay root with placeholder masks."""
    with open(os.path.join(dataroot, version, "map.json")) as f:
        maps = json.load(f)
    missing = [m["filename"] for m in maps if not os.path.isfile(os.path.join(dataroot, m["filename"]))]
    if not missing:
        return dataroot
    overlay = tempfile.mkdtemp(prefix="devkit-overlay-")
    for name in os.listdir(dataroot):
        if name != "maps":
            os.symlink(os.path.join(os.path.abspath(dataroot), name), os.path.join(overlay, name))
    for rel in missing:
        os.makedirs(os.path.dirname(os.path.join(overlay, rel)), exist_ok=True)
        with open(os.path.join(overlay, rel), "wb") as f:
            f.write(_PNG_1X1)
    print(f"note: {len(missing)} map mask(s) missing under {dataroot} (e.g. {missing[0]}); the devkit asserts they "
          f"exist, so using overlay root {overlay} with 1x1 placeholder masks")
    return overlay


def compare_with_hybrid_calib(nusc, dataroot: str, version: str, radar: str = "RADAR_FRONT",
                              camera: str = "CAM_FRONT") -> int:
    """Per keyframe: devkit-filtered radar point count and the devkit-chained radar -> camera transform
    (pyquaternion, as the devkit's tutorials do) against ``hybrid_calib.data.nuscenes``. Returns #mismatches."""
    import numpy as np
    from nuscenes.utils.data_classes import RadarPointCloud
    from pyquaternion import Quaternion

    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    def T(rec):
        M = np.eye(4)
        M[:3, :3] = Quaternion(rec["rotation"]).rotation_matrix
        M[:3, 3] = rec["translation"]
        return M

    ours = {f.sample_token: f for f in NuScenesRadarCamera(dataroot, version, radar, camera)}
    bad = n = 0
    worst = 0.0
    for sample in nusc.sample:
        if radar not in sample["data"] or camera not in sample["data"]:
            continue
        rsd = nusc.get("sample_data", sample["data"][radar])
        csd = nusc.get("sample_data", sample["data"][camera])
        n += 1
        try:
            pc = RadarPointCloud.from_file(os.path.join(nusc.dataroot, rsd["filename"]))
        except Exception as e:  # already reported above
            print(f"  compare: devkit cannot read {rsd['filename']} ({type(e).__name__}); skipped")
            bad += 1
            continue
        chain = (np.linalg.inv(T(nusc.get("calibrated_sensor", csd["calibrated_sensor_token"])))
                 @ np.linalg.inv(T(nusc.get("ego_pose", csd["ego_pose_token"])))
                 @ T(nusc.get("ego_pose", rsd["ego_pose_token"]))
                 @ T(nusc.get("calibrated_sensor", rsd["calibrated_sensor_token"])))
        f = ours.get(sample["token"])
        if f is None:
            print(f"  compare: sample {sample['token']} missing from hybrid-calib's frames")
            bad += 1
            continue
        diff = float(np.abs(chain - f.T_cam_radar).max())
        worst = max(worst, diff)
        xyz_ok = np.allclose(np.sort(pc.points[0]), np.sort(f.radar_points[:, 0]), atol=1e-5)
        if pc.nbr_points() != len(f.radar_points) or diff > 1e-9 or not xyz_ok:
            print(f"  compare: sample {sample['token']}: devkit {pc.nbr_points()} points vs ours "
                  f"{len(f.radar_points)}, max |T diff| {diff:.2e}")
            bad += 1
    print(f"compare with hybrid-calib: {n} keyframes compared, {bad} mismatch(es) or unreadable; "
          f"max |T_cam_radar(devkit) - T_cam_radar(ours)| = {worst:.2e}")
    return bad


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataroot", help="nuScenes root (holds VERSION/ and samples/)")
    parser.add_argument("version", help="version folder, e.g. v1.0-mini or v1.0-sim")
    parser.add_argument("--no-map-stub", action="store_true", help="do not stub missing map masks")
    parser.add_argument("--compare", action="store_true",
                        help="also compare hybrid-calib's reader with the devkit (needs the repo on PYTHONPATH)")
    args = parser.parse_args(argv)

    try:
        from nuscenes.nuscenes import NuScenes
    except ImportError:  # probe 117: a ModuleNotFoundError traceback in the project's own environment
        print("check_with_devkit.py needs the nuscenes-devkit, which hybrid-calib does not install (it pins its own "
              "numpy and OpenCV): run it in a throwaway environment, as this file's docstring says: python3 -m venv "
              "/tmp/devkit-venv && /tmp/devkit-venv/bin/pip install nuscenes-devkit", file=sys.stderr)
        return 2

    dataroot = args.dataroot if args.no_map_stub else overlay_with_map_stubs(args.dataroot, args.version)
    nusc = NuScenes(version=args.version, dataroot=dataroot, verbose=True)
    print(f"tables: scene={len(nusc.scene)} sample={len(nusc.sample)} sample_data={len(nusc.sample_data)} "
          f"ego_pose={len(nusc.ego_pose)} calibrated_sensor={len(nusc.calibrated_sensor)} sensor={len(nusc.sensor)} "
          f"log={len(nusc.log)}")
    problems = 0
    keyframes: Counter[str] = Counter()
    on_disk: Counter[str] = Counter()
    for scene in nusc.scene:
        log = nusc.get("log", scene["log_token"])
        n = 0
        token = scene["first_sample_token"]
        while token:
            sample = nusc.get("sample", token)
            n += 1
            for channel, sd_token in sample["data"].items():
                sd = nusc.get("sample_data", sd_token)
                nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
                nusc.get("ego_pose", sd["ego_pose_token"])
                keyframes[channel] += 1
                if os.path.isfile(os.path.join(nusc.dataroot, sd["filename"])):
                    on_disk[channel] += 1
            token = sample["next"]
        if n != scene["nbr_samples"]:
            print(f"  scene {scene['name']}: walked {n} samples but nbr_samples={scene['nbr_samples']}")
            problems += 1
        print(f"scene {scene['name']} vehicle={log['vehicle']} samples={n}")
    for channel in sorted(keyframes):
        print(f"  {channel:20s} keyframe sample_data={keyframes[channel]:5d} files on disk={on_disk[channel]:5d}")
    # the devkit's own point-cloud / image path helpers on the first sample
    first = nusc.sample[0]
    for channel in ("RADAR_FRONT", "CAM_FRONT", "LIDAR_TOP"):
        if channel in first["data"]:
            path, boxes, K = nusc.get_sample_data(first["data"][channel])
            print(f"  get_sample_data({channel}): {os.path.relpath(path, nusc.dataroot)} boxes={len(boxes)} "
                  f"intrinsic={'yes' if K is not None else 'no'}")
    if "RADAR_FRONT" in first["data"]:
        from nuscenes.utils.data_classes import RadarPointCloud

        n_ok, failures = 0, []
        for sd in nusc.sample_data:
            if sd["is_key_frame"] and sd["channel"] == "RADAR_FRONT":
                path = os.path.join(nusc.dataroot, sd["filename"])
                if not os.path.isfile(path):
                    continue
                try:
                    RadarPointCloud.from_file(path)
                    n_ok += 1
                except Exception as e:  # report every file the devkit cannot parse
                    failures.append((path, f"{type(e).__name__}: {e}"))
        print(f"  RadarPointCloud.from_file (devkit default filters): {n_ok} RADAR_FRONT keyframe files read, "
              f"{len(failures)} failed")
        for path, err in failures[:5]:
            print(f"    devkit cannot read {path}: {err or 'assertion failed'}")
        if failures:
            print("    (the devkit asserts `end_p < len(data_binary)`: it needs at least one byte after the last "
                  "point; real nuScenes PCDs carry trailing bytes. It also asserts WIDTH > 0.)")
            problems += 1
    if args.compare:
        problems += compare_with_hybrid_calib(nusc, dataroot, args.version)
    print("OK" if problems == 0 else f"{problems} problem(s)")
    return 0 if problems == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
