"""``hybrid-calib inspect``: what a nuScenes-format root holds, per scene and vehicle, and what is wrong with it.

Prints one line per scene (frames, radar points per sweep after filtering, NaN points dropped,
radar-camera time offset; the camera images are decoded, and the LiDAR files read when the root
has a LiDAR channel, as the learned methods read them on real roots: ``--set load_lidar=false``
skips them) and the skipped items grouped by reason (a count, one reason in full, a
few more frames and tokens). With ``--out DIR`` also writes ``DIR/inspect_summary.json`` (schema:
``hybrid_calib.data.summary``; every skipped item), ``DIR/inspect_config.json`` (the effective data
config) and ``DIR/overlay.png`` (one frame's radar and LiDAR points projected on its image with the
ground-truth extrinsics; ``--frame N`` picks the frame, and needs ``--out``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hybrid_calib.commands import given_flags, nonnegative_int, positive_int, version_name
from hybrid_calib.config import merge, parse_overrides, save_json_atomic, to_dict
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.errors import OptionError

HELP = "summarise a nuScenes-format root (real or simulated): frames, radar points, skipped items, overlay"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, type=Path, help="nuScenes root (holds VERSION/ and samples/)")
    parser.add_argument("--version", type=version_name, default=SIM_VERSION,  # as every other command (probe 120)
                        help="version folder, e.g. v1.0-mini, v1.0-trainval (default: v1.0-sim)")
    parser.add_argument("--radar", default="RADAR_FRONT", help="radar channel (default RADAR_FRONT)")
    parser.add_argument("--camera", default="CAM_FRONT", help="camera channel (default CAM_FRONT)")
    parser.add_argument("--nsweeps", type=positive_int, default=None,
                        help="radar sweeps accumulated per frame (default: 1, or --set nsweeps=N)")
    parser.add_argument("--frame", type=nonnegative_int, default=None,
                        help="frame index for the overlay written with --out (default: first loaded)")
    parser.add_argument("--out", type=Path, default=None, help="write the JSON summary, config and overlay PNG here")
    parser.add_argument("--set", dest="overrides", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
                        help="DataConfig override, e.g. --set radar_filter.enabled=false (repeatable)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.data.nuscenes import DataConfig, NuScenesRadarCamera
    from hybrid_calib.data.summary import summarize_dataset
    from hybrid_calib.plots.projection import render_overlay

    if args.frame is not None and args.out is None:  # the overlay is the only thing --frame picks
        raise OptionError("--frame", "picks the frame of the overlay PNG, which is written only with --out; pass --out "
                                     f"DIR to draw frame {args.frame}, or drop --frame")
    overrides = parse_overrides(args.overrides)
    overrides.update(given_flags(args, {"nsweeps": "nsweeps"}, overrides))  # a flag given wins, as everywhere
    overrides.setdefault("decode_images", True)  # inspect looks for everything that is wrong, pixel data included
    overrides.setdefault("load_lidar", None)  # and the LiDAR files the learned methods read, when the root has them
    conf = merge(DataConfig, overrides)
    ds = NuScenesRadarCamera(args.data, args.version, args.radar, args.camera, conf)
    conf = ds.conf  # load_lidar resolved on the root's channels
    if args.frame is not None and args.frame >= len(ds):  # before the summary: it reads every frame
        valid = f" (0..{len(ds) - 1}); pass one of them, or drop --frame to draw the first loaded" if len(ds) else ""
        raise OptionError("--frame", f"frame {args.frame} does not exist; this root has {len(ds)} frames{valid}")
    summary = summarize_dataset(ds, progress=not args.no_progress)
    if args.out is None:
        print(summary.format(None))
        return 0 if summary.n_loaded else 1
    out = Path(args.out)
    # the files first, then the table: a reader that stops early (`| head -1`) or a full stdout lost them (probe 66)
    save_json_atomic(out / "inspect_config.json", dict(data=str(args.data), version=args.version, radar=args.radar,
                                                       camera=args.camera, conf=to_dict(conf)))
    save_json_atomic(out / "inspect_summary.json", summary.to_json())
    print(summary.format(str(out / "inspect_summary.json")))
    print(f"wrote {out / 'inspect_summary.json'}")
    index = args.frame if args.frame is not None else summary.first_loaded
    bad = next((r for r in summary.skipped if args.frame is not None and r.get("index") == args.frame), None)
    if bad is not None:  # the summary is written; the overlay of a frame that does not load cannot be
        other = (f"e.g. --frame {summary.first_loaded} (the first that loads)" if summary.first_loaded is not None
                 else "no frame of this root loads")
        raise OptionError("--frame", f"frame {args.frame} is one of the skipped frames ({bad['reason']}), so it "
                                     f"cannot be drawn; pick another, {other}")
    if index is not None:
        lidar = conf.lidar_channel in ds.tables.channels()
        frame_ds = ds if (conf.load_lidar or not lidar) else NuScenesRadarCamera(
            args.data, args.version, args.radar, args.camera, merge(DataConfig, {**overrides, "load_lidar": True}))
        png = render_overlay(frame_ds[index], out / "overlay.png")
        print(f"wrote {png}")
    return 0 if summary.n_loaded else 1
