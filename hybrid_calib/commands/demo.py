"""``hybrid-calib demo``: the main job on the embedded default data (see ``hybrid_calib.demo``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hybrid_calib.config import parse_overrides

HELP = "simulate a small drive, draw radar points on the image, calibrate radar->camera, report"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, default=Path("outputs/demo"), help="output directory (default: outputs/demo)")
    p.add_argument("--overwrite", action="store_true", help="recompute every stage")
    p.add_argument("--set", action="extend", nargs="+", metavar="KEY=VALUE", default=[],
                   help="DemoConfig overrides, e.g. frames=60 scenario=highway start=R2")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.demo import run_demo

    s = run_demo(args.out, parse_overrides(args.set), overwrite=args.overwrite)
    print(f"simulated drive:      {s['sim_root']}")
    print(f"radar on camera:      {s['projection_png']}")
    for name, v in s["vehicles"].items():
        f = v["final"]
        std = f["std_cam"]
        print(f"calibration [{name}]: status {f['status']}")
        if v.get("error"):
            e = v["error"]
            print(f"  error vs truth:     rotation {e['rot_mean_deg']:.3f} deg (mean |roll,pitch,yaw|), "
                  f"translation {e['trans_norm_cm']:.2f} cm (norm)")
        print(f"  1-sigma (camera):   rot {std['rot_x_cam_deg']:.3f}/{std['rot_y_cam_deg']:.3f}/"
              f"{std['rot_z_cam_deg']:.3f} deg, t {std['t_x_cam_cm']:.2f}/{std['t_y_cam_cm']:.2f}/"
              f"{std['t_z_cam_cm']:.2f} cm")
        if f["status"].startswith("weak"):
            print("  note: a 2D radar records no elevation, so its height and pitch against the camera are pinned\n"
                  "        only by the reflector-height prior; the 1-sigma above says so (docs/conventions.md)")
    print(f"calibration result:   {s['calibration_result']}")
    print(f"calibration plots:    {s['calibration_plots']}")
    return 0
