"""``hybrid-calib demo``: the main job on the embedded default: calibrate a drive, then check a small fleet.

``run_demo`` chains idempotent stages, each writing one output under ``out``:

1. ``sim/``: a small synthetic drive written as a nuScenes root (``hybrid-calib simulate``).
2. ``projection.png``: one frame's radar points projected with the ground-truth extrinsic over the
   camera image: the recorded points (z = 0, elevation unknown) and the true reflectors they came from.
3. ``calibration/``: the hybrid (``hybrid_calib.hybrid``): the shipped small network runs frame by
   frame from the sliding window's fused estimate, its rows and SE(3) prior enter the window, from an
   R1 mis-calibrated start: ``result.json`` (extrinsic, covariance, per-axis std, status, drift
   decision) and plots. ``method=oracle`` uses the simulator's true reflectors instead.
4. ``fleet-sim/`` + ``fleet/``: a small fleet, one simulated root per vehicle (``urban``: a normal
   drive; ``knocked``: urban, its radar knocked by ``knock_deg`` in yaw at the middle of the drive
   (``ExtrinsicChange(kind="step")``); ``straight``: a straight road), calibrated as fleet jobs
   (``fleet.driver.run_fleet``, engine ``process``) with ``fleet_method`` (default: the hybrid and
   the shipped checkpoint; its radar mount monitor, ``calib.mount_monitor``, raises the knocked
   vehicle's step alarm), then ``fleet/fleet.html`` and a ``report.html`` per vehicle.

It chains the simulator, the calibrator and the plots, so it lives with the commands (the top layer).
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hybrid_calib.calib.covariance import status_kind
from hybrid_calib.calib.mount_monitor import turn_words
from hybrid_calib.config import merge, parse_overrides, require_ranges, save_json_atomic, to_dict
from hybrid_calib.data.tables import SIM_VERSION

HELP = ("simulate a small drive, draw radar points on the image, calibrate radar->camera; then calibrate a 3-vehicle "
        "simulated fleet (one radar knocked) and print one verdict per vehicle")


@dataclass(frozen=True)
class DemoConfig:
    scenario: str = "urban"  # simulator preset
    frames: int = 40  # keyframes of the drive (2 Hz: 20 s)
    seed: int = 0  # simulator and oracle seed
    image_scale: float = 0.5  # camera = nuScenes CAM_FRONT scaled by this (800x450)
    start: str = "R1"  # calibration start: R1 (+-10 deg, +-0.25 m) | R2 | reference
    window: int = 20  # sliding-window length, frames
    method: str = "hybrid"  # hybrid (shipped network + window) | pure | pure-avg | oracle (true reflectors)
    threads: int = 1  # torch CPU threads (1: on a busy 2-core machine 2 threads were 40x slower, measured)
    fleet_frames: int = 40  # keyframes per fleet vehicle
    fleet_method: str = "hybrid"  # method of the fleet step (hybrid | pure | pure-avg | oracle)
    knock_deg: float = 1.0  # the knocked vehicle's radar turns by this about its z axis (yaw) mid-drive
    engine: str = "process"  # fleet engine: local | process
    workers: int = 2  # fleet jobs in parallel

    def __post_init__(self):
        if self.engine not in ("local", "process"):
            raise ValueError(f"DemoConfig.engine={self.engine!r}; valid: local, process")
        if self.fleet_frames < 2 or self.workers < 1:
            raise ValueError(f"DemoConfig.fleet_frames={self.fleet_frames} (>= 2) / workers={self.workers} (>= 1)")
        require_ranges(self, {"frames": "[2, 1e5]", "image_scale": "[0.01, 2]", "window": "[1, 1e9]",
                              "threads": "[1, 256]", "fleet_frames": "[2, 1e5]", "knock_deg": "[-90, 90]",
                              "workers": "[1, 256]"})


FLEET = {  # demo fleet vehicle -> SimConfig overrides (the knock is added by fleet_sim_configs)
    "urban": {"scenario": "urban"},
    "knocked": {"scenario": "urban"},
    "straight": {"scenario": "straight"},
}


def fleet_sim_configs(conf: DemoConfig) -> dict:
    """The demo fleet's ``SimConfig`` per vehicle (one root each; seeds ``seed + 1 ...``)."""
    from hybrid_calib.sim.drive import SimConfig

    knock = {"kind": "step", "rotation_deg": (0.0, 0.0, conf.knock_deg), "translation_m": (0.0, 0.0, 0.0)}
    return {name: merge(SimConfig, {**o, "vehicles": 1, "frames": conf.fleet_frames, "seed": conf.seed + 1 + i,
                                    "image_scale": conf.image_scale,
                                    **({"extrinsic_change": knock} if name == "knocked" else {})})
            for i, (name, o) in enumerate(FLEET.items())}


def vehicle_verdict(row: dict) -> str:
    """One line for a fleet summary row (``fleet.summary``): flagged or not, and why."""
    if row["state"] != "done":
        return f"FAILED: {row.get('reason')}"
    why = []
    if "drifted_in_drive" in row["flags"]:  # fleet.summary: not a window alarm on an untrusted estimate
        turned = "".join(f"; its radar turned by {turn_words(s['step_deg'], s['std_deg'])} from frame "
                         f"{s['change']}" for s in row.get("mount_steps", [])[:1])
        why.append(f"its mount stepped inside the drive (step alarm at frame {row['step_alarms'][0]}{turned})")
    if "out_of_tolerance" in row["flags"]:
        why.append(f"vs its tables: {row['verdict'].split(':')[0]}")
    if "fleet_outlier" in row["flags"]:
        why.append("an outlier of the fleet")
    if "degenerate" in row["flags"]:
        why.append("degenerate drive")
    if "inconclusive" in row["flags"]:
        why.append(f"not trusted: {row.get('status', 'inconclusive')}")
    if why:
        return "FLAGGED: " + "; ".join(why)
    test = row.get("fleet_test") or {}
    fleet = ("not a fleet outlier" if "p_value" in test else test.get("left_out")
             or "no fleet test (fewer than 3 trusted vehicles done)")
    verdict = row["verdict"].split(":")[0]
    # "ok" only when the tables test says so; "cannot tell" (a short drive, a prior-pinned axis) is no alarm, not ok
    return f"{'ok' if verdict == 'within tolerance' else 'no alarm'}: no step alarm, {fleet}; vs its tables: {verdict}"


def _overlay(root: Path, out_png: Path) -> Path:
    """Draw the frame with the most radar returns inside the image (of 8 spread over the drive)
    with its true reflectors."""
    from hybrid_calib.data.files import read_npz
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.geometry import transform_points
    from hybrid_calib.plots.projection import draw_radar_truth

    ds = NuScenesRadarCamera(root, SIM_VERSION)
    best, best_n = None, -1
    for i in range(0, len(ds), max(1, len(ds) // 8)):
        f = ds[i]
        uv, z = f.camera.project(transform_points(f.T_cam_radar, f.radar_points))
        n = int(((z > 0) & f.camera.in_image(uv)).sum())
        if n > best_n:
            best, best_n = f, n
    true_xyz = None
    truth_path = best.extras.get("radar_truth_path")
    if truth_path is not None:
        rows = best.extras.get("radar_rows", np.arange(len(best.radar_points)))
        with read_npz(truth_path, "simulator truth file", "re-run make demo") as truth:
            true_xyz = truth["true_xyz"][rows]
    return draw_radar_truth(best, true_xyz, out_png)


RUN_ONLY = ("threads", "engine", "workers")  # DemoConfig fields that change how the stages run, not what they give


def check_same_demo(path: Path, conf: DemoConfig) -> None:
    """``HybridCalibError`` when ``path`` (an earlier run's ``demo_config.json``) records another configuration:
    the stages already done there (the calibration, the fleet) would be reported as this run's."""
    from hybrid_calib.config import read_out_record
    from hybrid_calib.errors import HybridCalibError

    old = read_out_record(path, "demo config", "what its stages were computed with: pass --overwrite to recompute "
                          "every stage, or another --out")
    if old is None:
        return
    new = to_dict(conf)
    changed = [f"{k}: {old.get(k)!r} -> {v!r}" for k, v in new.items() if k not in RUN_ONLY and old.get(k) != v]
    if changed:
        raise HybridCalibError(f"{path.parent} holds a demo of another configuration ({'; '.join(changed)}; "
                               f"{path}), whose finished stages this run would report as its own; pass --overwrite "
                               "to recompute every stage, or another --out")


@dataclass(frozen=True)
class DemoResult:
    """What ``run_demo`` made; ``to_dict`` is ``out/summary.json``. Paths are strings as written."""

    sim_root: str  # the simulated drive (a nuScenes root)
    projection_png: str  # radar points and true reflectors over a camera image
    calibration_result: str  # the calibration's result.json
    calibration_plots: str
    vehicles: dict[str, dict]  # the calibration's vehicles (``VehicleResult.to_dict`` each)
    fleet_method: str
    fleet_dir: str
    fleet_page: str | None
    fleet: dict[str, dict]  # fleet job id -> {"root", "verdict", "flags", "report" (the page, or None)}

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def run_demo(out: str | Path, conf: DemoConfig | dict | None = None, overwrite: bool = False) -> DemoResult:
    """Run the demo into ``out``; returns what it made (also written to ``out/summary.json``)."""
    import shutil
    from functools import partial

    from hybrid_calib.fleet.driver import FleetOptions, run_fleet
    from hybrid_calib.hybrid import HybridConfig, run_calibration
    from hybrid_calib.plots.calibration import plot_vehicle
    from hybrid_calib.report import write_fleet_pages
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    conf = merge(DemoConfig, conf)
    out = Path(out)
    # both stage configs are built (and checked) before anything is written or simulated
    sim_conf = merge(SimConfig, {"scenario": conf.scenario, "vehicles": 1, "frames": conf.frames,
                                 "seed": conf.seed, "image_scale": conf.image_scale})
    cal_conf = merge(HybridConfig, {"method": conf.method, "start": conf.start, "seed": conf.seed,
                                    "threads": conf.threads, "window": {"window": conf.window}})
    fleet_confs = fleet_sim_configs(conf)
    merge(HybridConfig, {"method": conf.fleet_method})
    if not overwrite:
        check_same_demo(out / "demo_config.json", conf)
    out.mkdir(parents=True, exist_ok=True)
    save_json_atomic(out / "demo_config.json", to_dict(conf))

    root = simulate(sim_conf, out / "sim", overwrite=overwrite)
    png = _overlay(root, out / "projection.png")

    run = run_calibration(root, SIM_VERSION, out / "calibration", cal_conf, overwrite=overwrite,
                          on_vehicle=partial(plot_vehicle, out_dir=out / "calibration" / "plots"))
    roots = [str(simulate(c, out / "fleet-sim" / name, overwrite=overwrite)) for name, c in fleet_confs.items()]
    if overwrite and (out / "fleet").exists():
        shutil.rmtree(out / "fleet")
    fleet = run_fleet(roots, None, SIM_VERSION, conf.fleet_method, out / "fleet", conf.seed,
                      options=FleetOptions(conf.engine, conf.workers, threads=conf.threads))
    page = write_fleet_pages(fleet, out / "fleet")
    summary = DemoResult(
        str(root), str(png), str(out / "calibration" / "result.json"), str(out / "calibration" / "plots"),
        run.to_dict()["vehicles"], conf.fleet_method, str(out / "fleet"), None if page is None else str(page),
        {jid: {"root": r["data"], "verdict": vehicle_verdict(r), "flags": r["flags"],
               "report": str(out / "fleet" / Path(r["result"]).parent / "report.html") if r.get("result") else None}
         for jid, r in fleet["vehicles"].items()})
    save_json_atomic(out / "summary.json", summary.to_dict())
    return summary


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("outputs/demo"), help="output directory (default: outputs/demo)")
    p.add_argument("--overwrite", action="store_true", help="recompute every stage")
    p.add_argument("--set", action="extend", nargs="+", metavar="KEY=VALUE", default=[],
                   help="DemoConfig overrides, e.g. frames=60 scenario=highway start=R2")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.calib.drift import drift_verdict
    from hybrid_calib.calib.lever_arm import describe as describe_doppler
    from hybrid_calib.calib.lidar_alignment import describe as describe_lidar

    s = run_demo(args.out, parse_overrides(args.set), overwrite=args.overwrite)
    print(f"simulated drive:      {s.sim_root}")
    print(f"radar on camera:      {s.projection_png}")
    for name, v in s.vehicles.items():
        f = v["final"]
        std = f["std_cam"]
        print(f"calibration [{name}]: method {v['method']}"
              + (f" (checkpoint {v['checkpoint']})" if v.get("checkpoint") else "") + f"; status {f['status']}")
        if v.get("error"):
            e = v["error"]
            print(f"  error vs truth:     rotation {e['rot_mean_deg']:.3f} deg (mean |roll,pitch,yaw|), "
                  f"translation {e['trans_norm_cm']:.2f} cm (norm)")
        print(f"  1-sigma (camera):   rot x/y/z (pitch/yaw/roll) {std['rot_x_cam_deg']:.3f}/{std['rot_y_cam_deg']:.3f}/"
              f"{std['rot_z_cam_deg']:.3f} deg, t x/y/z {std['t_x_cam_cm']:.2f}/{std['t_y_cam_cm']:.2f}/"
              f"{std['t_z_cam_cm']:.2f} cm")
        if v.get("lidar"):
            print(f"  LiDAR alignment:    {describe_lidar(v['lidar'])}")
        if v.get("doppler"):
            print(f"  Doppler lever arm:  {describe_doppler(v['doppler'])}")
        if status_kind(f["status"]) == "weak" and v["method"] == "oracle":
            print("  note: a 2D radar records no elevation, so its height and pitch against the camera are pinned\n"
                  "        only by the reflector-height prior; the 1-sigma above says so (docs/conventions.md)")
        elif status_kind(f["status"]) == "weak":
            print("  note: a 2D radar records no elevation: its roll and pitch here are the network's learned prior\n"
                  "        of the radar's mount and its height is the start's, not measured (the status names them)")
        if v.get("drift"):
            print(f"  vs reference:       {drift_verdict(v['drift'])} (chi2 p {v['drift']['p_value']:.2g}; the "
                  "reference is the vehicle's calibration tables)")
    print(f"calibration result:   {s.calibration_result}")
    print(f"calibration plots:    {s.calibration_plots}")
    print(f"fleet of {len(s.fleet)} simulated vehicles (urban; urban with its radar knocked mid-drive; straight "
          f"road), method {s.fleet_method}" + (" (the simulator's true reflectors)" if s.fleet_method == "oracle"
                                               else "") + ":")
    for jid, v in s.fleet.items():
        print(f"  {jid}: {v['verdict']}")
        if v["report"]:
            print(f"    report: {v['report']}")
    print(f"fleet page:           {s.fleet_page}")
    return 0
