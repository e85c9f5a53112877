"""``simulate``: render a fleet of drives and write them as a nuScenes root (``v1.0-sim``).

Output layout under ``out``::

    samples/CAM_FRONT/<log>__CAM_FRONT__<ts>.jpg        RGB images
    samples/RADAR_FRONT/<log>__RADAR_FRONT__<ts>.pcd    radar sweeps, nuScenes binary PCD, z = 0
    samples/LIDAR_TOP/<log>__LIDAR_TOP__<ts>.pcd.bin    LiDAR sweeps (x, y, z, intensity, ring)
    sweeps/RADAR_FRONT/<log>__RADAR_FRONT__<ts>.pcd     earlier radar sweeps (radar_sweeps_per_frame > 0)
    sim_depth/CAM_FRONT/<jpg stem>.png                  ground-truth depth, uint16 cm, 0 = none
    sim_truth/RADAR_FRONT/<pcd stem>.npz                radar truth (see ``RADAR_TRUTH_KEYS``)
    v1.0-sim/*.json                                     the 13 nuScenes tables
    v1.0-sim/sim_vehicle.json                           per-log ground truth and effective configs
    maps/<token>.png                                    top-down road map (the map table's file)
    sim_config.json                                     the effective SimConfig

Work already on disk is kept unless ``overwrite``: frames whose files all exist are not rendered
again, so an interrupted run resumes. A frame that fails is recorded (``failed_frames`` in
sim_vehicle.json), left out of the tables, and the run goes on.
"""

from __future__ import annotations

import json
import logging
import shutil
import traceback
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from hybrid_calib.atomic import LOCK_NAME, atomic_path, exit_with_parent, out_dir_lock
from hybrid_calib.config import save_json_atomic, to_dict
from hybrid_calib.data.frame import write_depth_png
from hybrid_calib.data.image_header import write_image
from hybrid_calib.data.pcd import write_lidar_bin, write_radar_pcd
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.geometry import pose_to_nuscenes
from hybrid_calib.sim.drive import SimConfig, VehicleDrive, check_mounts
from hybrid_calib.sim.extrinsics import NOMINAL_T_EGO_CAM, NOMINAL_T_EGO_RADAR
from hybrid_calib.sim.nuscenes_writer import (
    VERSION,
    FrameRecord,
    VehicleRecord,
    build_tables,
    log_key,
    log_name,
    sample_file_name,
    token,
    write_map_png,
    write_tables,
)
from hybrid_calib.sim.trajectory import EgoStops

log = logging.getLogger(__name__)
RADAR_TRUTH_KEYS = ("true_xyz", "kind", "object_id", "elevation", "object_speed", "snr_db")
OWNED_DIRS = ("samples/CAM_FRONT", "samples/RADAR_FRONT", "samples/LIDAR_TOP", "sweeps/RADAR_FRONT", "sim_depth",
              "sim_truth", VERSION, "maps")


def depth_file(root: Path, camera_file: str) -> Path:
    """Ground-truth depth PNG of a camera sample file (relative name)."""
    return Path(root) / "sim_depth" / "CAM_FRONT" / (Path(camera_file).stem + ".png")


def radar_truth_file(root: Path, radar_file: str) -> Path:
    """Radar truth NPZ of a radar sample file (relative name)."""
    return Path(root) / "sim_truth" / "RADAR_FRONT" / (Path(radar_file).stem + ".npz")


def frame_record(drive: VehicleDrive, k: int, name: str) -> FrameRecord:
    """Timestamps, file names and poses of frame k (no rendering)."""
    tm = drive.times(k)
    t_cam, t_radar, t_lidar = tm.seconds(drive.base_us)
    return FrameRecord(
        index=k, camera_us=tm.camera_us, radar_us=tm.radar_us, lidar_us=tm.lidar_us,
        camera_file=sample_file_name(name, "CAM_FRONT", tm.camera_us),
        radar_file=sample_file_name(name, "RADAR_FRONT", tm.radar_us),
        lidar_file=sample_file_name(name, "LIDAR_TOP", tm.lidar_us),
        T_global_ego_cam=drive.ego.T_global_ego(t_cam), T_global_ego_radar=drive.ego.T_global_ego(t_radar),
        T_global_ego_lidar=drive.ego.T_global_ego(t_lidar), T_ego_radar=drive.T_ego_radar(k),
        radar_sweeps=[(us, sample_file_name(name, "RADAR_FRONT", us, key_frame=False),
                       drive.ego.T_global_ego((us - drive.base_us) * 1e-6)) for us in tm.radar_sweeps_us],
    )


def frame_files(root: Path, rec: FrameRecord) -> list[Path]:
    return [root / rec.camera_file, root / rec.radar_file, root / rec.lidar_file,
            depth_file(root, rec.camera_file), radar_truth_file(root, rec.radar_file)] + [
        p for _, name, _ in rec.radar_sweeps for p in (root / name, radar_truth_file(root, name))]


def write_frame(root: Path, drive: VehicleDrive, rec: FrameRecord) -> None:
    """Simulate frame ``rec.index`` and write its five files atomically."""
    import cv2

    f = drive.simulate_frame(rec.index)
    write_depth_png(depth_file(root, rec.camera_file), f.depth)
    for (_, name, _), (_, sweep, _) in zip(rec.radar_sweeps, f.radar_sweeps):
        write_radar(root, name, sweep)
    write_radar(root, rec.radar_file, f.radar)
    write_lidar_bin(root / rec.lidar_file, f.lidar)
    write_image(root / rec.camera_file, f.image[:, :, ::-1],
                (cv2.IMWRITE_JPEG_QUALITY, drive.jpeg_quality(rec.index)))


def write_radar(root: Path, radar_file: str, sweep) -> None:
    """A radar sweep's PCD and its truth NPZ (truth first: the PCD's presence marks the pair done)."""
    truth = radar_truth_file(root, radar_file)
    with atomic_path(truth) as tmp:
        np.savez(tmp, true_xyz=sweep.true_xyz.astype(np.float64), kind=sweep.kind.astype(np.int8),
                 object_id=sweep.object_id.astype(np.int32), elevation=sweep.elevation.astype(np.float64),
                 object_speed=sweep.object_speed.astype(np.float64), snr_db=sweep.snr_db.astype(np.float64))
    write_radar_pcd(root / radar_file, sweep.points)


_WORKER_DRIVES: dict[tuple, VehicleDrive] = {}


def _work(args) -> tuple[int, int, str | None]:
    conf, v, root, rec = args
    try:
        key = (repr(conf), v)
        if key not in _WORKER_DRIVES:
            _WORKER_DRIVES.clear()
            _WORKER_DRIVES[key] = VehicleDrive(conf, v)
        write_frame(root, _WORKER_DRIVES[key], rec)
        return v, rec.index, None
    except Exception as e:  # recorded and reported; the run goes on
        return v, rec.index, f"{type(e).__name__}: {e}\n{traceback.format_exc(limit=3)}"


# options added after roots were simulated and documented: at these values they leave the tokens as they were, so a
# documented `simulate --seed N` still writes the same root
SALT_NEUTRAL = {"radar_lag": "either"}


def _salted(conf_dict: dict) -> dict:
    """``conf_dict`` without the options at their ``SALT_NEUTRAL`` values."""
    return {k: v for k, v in conf_dict.items() if k not in SALT_NEUTRAL or SALT_NEUTRAL[k] != v}


def simulate(conf: SimConfig, out: str | Path, overwrite: bool = False, workers: int = 1,
             progress: bool = True) -> Path:
    """Simulate ``conf.vehicles`` drives and write ``out`` as a nuScenes root; returns ``out``.

    overwrite: re-render everything (and remove the simulator's previous outputs) instead of
    resuming. workers: processes rendering frames in parallel.
    """
    if not isinstance(conf, SimConfig):
        raise TypeError(f"conf must be a SimConfig (build one with hybrid_calib.config.merge), got {type(conf)}")
    check_mounts(conf)  # before anything is written
    root = Path(out)
    conf_path = root / "sim_config.json"
    conf_dict = to_dict(conf)
    for key, default in (("stops", EgoStops()), ("world", {})):  # not set: the root, its tokens and a resume as
        if getattr(conf, key) == default:  # before the option existed
            conf_dict.pop(key)
    if root.is_dir() and any(p.name != LOCK_NAME for p in root.iterdir()) and not conf_path.exists():
        raise HybridCalibError(
            f"{root} is not empty and holds no hybrid-calib simulation (no sim_config.json); refusing to write "
            "or delete anything there: choose an empty or new --out")
    with out_dir_lock(root, "simulate", reentrant=True):  # probe 140: a library run and a command in one root
        return _simulate_into(conf, root, conf_dict, overwrite, workers, progress)


def _simulate_into(conf: SimConfig, root: Path, conf_dict: dict, overwrite: bool, workers: int, progress: bool
                   ) -> Path:
    """``simulate`` once its root is checked and locked."""
    from tqdm import tqdm

    conf_path = root / "sim_config.json"
    if conf_path.exists() and not overwrite:
        try:
            old = json.loads(conf_path.read_text())
        except (OSError, ValueError, RecursionError):
            old = None
        if old != json.loads(json.dumps(conf_dict)):
            raise HybridCalibError(
                f"{root} already holds a simulation with a different configuration ({conf_path}); "
                "pass --overwrite to replace it or choose another --out")
    if overwrite and root.is_dir():  # the sample folders are shared by every version of a root: never another's
        others = sorted(d.name for d in root.iterdir() if d.is_dir() and d.name != VERSION
                        and any((d / f"{t}.json").exists() for t in ("sample_data", "sample", "scene", "log")))
        if others:
            raise HybridCalibError(
                f"{root} also holds {', '.join(others)} (another version's tables, whose files share samples/ with "
                f"the simulation's): --overwrite would delete them with the simulation's sample folders; refusing. "
                "Choose another --out")
        for d in OWNED_DIRS:
            shutil.rmtree(root / d, ignore_errors=True)
    root.mkdir(parents=True, exist_ok=True)
    save_json_atomic(conf_path, conf_dict)

    drives = [VehicleDrive(conf, v) for v in range(conf.vehicles)]
    records = {v: [frame_record(d, k, log_name(_vehicle_record(d))) for k in range(conf.frames)]
               for v, d in enumerate(drives)}
    jobs = [(conf, v, root, rec) for v in range(conf.vehicles) for rec in records[v]
            if overwrite or not all(p.exists() for p in frame_files(root, rec))]
    failed: dict[int, list[dict]] = {v: [] for v in range(conf.vehicles)}
    bar = tqdm(total=len(jobs), desc=f"simulate {conf.scenario}", unit="frame", disable=not progress)
    if workers > 1 and len(jobs) > 1:
        # no idle process forked; a worker exits when this process is killed (probe 111: they slept for ever)
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), initializer=exit_with_parent) as pool:
            results = pool.map(_work, jobs, chunksize=4)
            for v, k, err in results:
                _record(failed, v, k, err)
                bar.update()
    else:
        for job in jobs:
            _WORKER_DRIVES[(repr(conf), job[1])] = drives[job[1]]
            v, k, err = _work(job)
            _record(failed, v, k, err)
            bar.update()
        _WORKER_DRIVES.clear()
    bar.close()

    vehicles = []
    for v, d in enumerate(drives):
        bad = {f["frame"] for f in failed[v]}
        vr = _vehicle_record(d)
        vr.frames = [r for r in records[v] if r.index not in bad]
        vr.salt = token("sim_config", json.dumps(_salted(conf_dict), sort_keys=True))[:12]  # another config, other
        # tokens
        vehicles.append(vr)
    tables = build_tables(vehicles)
    write_tables(root, tables)
    write_map_png(root, tables["map"][0]["token"], [d.world.path.xy for d in drives])
    save_json_atomic(root / VERSION / "sim_vehicle.json",
                     [_vehicle_truth(d, vr, failed[v]) for v, (d, vr) in enumerate(zip(drives, vehicles))])
    n_bad = sum(len(f) for f in failed.values())
    if n_bad == conf.vehicles * conf.frames:  # a config every frame fails on (a value the checks let through)
        v0 = next(v for v in failed if failed[v])
        first = failed[v0][0]
        last = (first["error"].strip().splitlines() or ["unknown error"])[-1]
        # an error writing a file is the disk's, not a config's (probe 66: a file-size limit read "check --set"); by
        # the exception's class, every OSError (probe 70: NotADirectoryError, IsADirectoryError were "check --set")
        import builtins

        kind = getattr(builtins, last.split(":")[0].strip(), None)
        what = ("check that the --out folder can be written (free space, file size limits, permissions)"
                if isinstance(kind, type) and issubclass(kind, OSError) or "cannot be written" in last
                else "check the --set values")
        raise HybridCalibError(f"no frame could be simulated (all {n_bad} failed; first, vehicle {v0} frame "
                               f"{first['frame']}: {last}); {what} "
                               f"(failed_frames in {root / VERSION / 'sim_vehicle.json'})")
    if n_bad:
        log.warning("%d frame(s) failed and were left out; see failed_frames in %s", n_bad,
                    root / VERSION / "sim_vehicle.json")
    return root


def _record(failed: dict, v: int, k: int, err: str | None) -> None:
    if err is not None:
        log.warning("vehicle %d frame %d failed: %s", v, k, err.splitlines()[0])
        failed[v].append({"frame": k, "error": err})


def _vehicle_record(d: VehicleDrive) -> VehicleRecord:
    c = d.conf
    cam = d.camera
    ch = c.extrinsic_change
    desc = (f"simulated {c.scenario} drive, vehicle {d.vehicle}, seed {c.seed}, radar mount change: {ch.kind}"
            + (f" at frame {ch.step_frame(c.frames)}" if ch.kind == "step" else ""))
    return VehicleRecord(name=d.name, scenario=c.scenario, seed=c.seed, description=desc,
                         T_ego_cam=d.mounts.T_ego_cam, T_ego_lidar=d.mounts.T_ego_lidar, K=cam.K,
                         width=cam.width, height=cam.height)


def _pose(T: np.ndarray) -> dict:
    rot, trans = pose_to_nuscenes(T)
    return {"rotation": rot, "translation": trans}


def _vehicle_truth(d: VehicleDrive, vr: VehicleRecord, failed: list[dict]) -> dict:
    c = d.conf
    ch = c.extrinsic_change
    base = d.base_mounts
    return {
        "log_token": token("log", log_key(vr)),
        "vehicle": d.name,
        "scenario": c.scenario,
        "seed": c.seed,
        # the design mounts: the fleet's nominal ones, or with randomised real mounts the drawn nuScenes mount
        "nominal_T_ego_radar": _pose(NOMINAL_T_EGO_RADAR if base is None else base[1]),
        "nominal_T_ego_cam": _pose(NOMINAL_T_EGO_CAM if base is None else base[0]),
        "true_T_ego_radar_start": _pose(d.mounts.T_ego_radar),
        "true_T_ego_cam": _pose(d.mounts.T_ego_cam),
        # the vehicle's calibration tables: what a real vehicle's calibrated_sensor would hold (the
        # truth + the factory calibration error, MountPerturbation.factory_*); the reference of the
        # drift test. The nominal_* above are the fleet design values.
        "factory_T_ego_radar": _pose(d.mounts.factory_T_ego_radar),
        "factory_T_ego_cam": _pose(d.mounts.factory_T_ego_cam),
        "extrinsic_change": {"kind": ch.kind, "frame": ch.step_frame(c.frames) if ch.kind == "step" else None,
                             "rotation_deg": list(ch.rotation_deg), "translation_m": list(ch.translation_m),
                             "xi_radar": ch.xi.tolist()},
        "radar_config": to_dict(d.radar_config),
        # domain randomisation draws of this vehicle (SimConfig.randomise), null when off
        "randomisation": d.draw.to_json() if d.draw is not None else None,
        "sim_config": to_dict(c),
        "failed_frames": failed,
    }
