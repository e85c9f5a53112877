"""``hybrid-calib calibrate``: sliding-window (or batch) calibration of every vehicle of a dataset."""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

from hybrid_calib.commands import (
    add_split_arguments,
    given_flags,
    nonnegative_int,
    positive_int,
    reject_learned_keys,
    reject_set_keys,
    reject_unused_batch,
    reject_unused_blocks,
    reject_unused_oracle,
    reject_unused_window,
    seed_int,
    split_overrides,
    version_name,
)
from hybrid_calib.config import parse_overrides
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.errors import OptionError
from hybrid_calib.perturbation import RANGES

HELP = "calibrate T_cam_radar per vehicle: hybrid (network + factor graph), pure, pure-avg or oracle"

METHODS = ("oracle", "hybrid", "pure", "pure-avg")
# config key -> flag (default None: not passed)
FLAGS = {"start": "start", "seed": "seed", "max_frames": "max_frames", "reference": "reference"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, required=True, help="nuScenes root (e.g. written by hybrid-calib simulate)")
    p.add_argument("--version", type=version_name,
                   default=SIM_VERSION, help=f"version folder under --data (default: {SIM_VERSION})")
    p.add_argument("--method", default="oracle", choices=METHODS,
                   help="oracle (default: the simulator's true reflectors, or --correspondences DIR), hybrid (the "
                        "network in a closed loop with the sliding window), pure (the network alone, last frame), "
                        "pure-avg (the network alone, robust SE(3) average over the drive)")
    p.add_argument("--checkpoint", default="",
                   help="learned methods: network checkpoint (default: the shipped small one of the start range)")
    p.add_argument("--refine", default="",
                   help="learned methods: a refining network run after --checkpoint on every pass (a cascade): "
                        "'shipped' (the shipped near-truth R0 checkpoint) or a checkpoint path (default: none)")
    p.add_argument("--depth", default="",
                   help="learned methods: depth estimator (default: the checkpoint's; a real root with LiDAR: "
                        "lidar-densified)")
    p.add_argument("--correspondences", default=None,
                   help="'oracle' (the default; simulated roots: from the ground truth) or a directory of measurement "
                        "files "
                        "(factors.io *.npz: the --out of hybrid-calib evaluate, flat, or one sub-directory per "
                        "vehicle)")
    p.add_argument("--mode", default=None, choices=("window", "batch"), help="default: window (or --set mode=...)")
    p.add_argument("--window", type=positive_int, default=None,
                   help="sliding-window length in frames (default: 20, or --set window.window=N)")
    p.add_argument("--backend", default=None, choices=("gtsam", "ceres"),
                   help="batch back end (default: gtsam, or --set batch.backend=...)")
    p.add_argument("--start", default=None, choices=("reference", *RANGES),
                   help="initial extrinsic: the vehicle's tables, or a perturbation of the truth (of the tables on a "
                        "real root) drawn in R0 / R1 / R2 with --seed (default: reference)")
    p.add_argument("--reference", default=None, metavar="EXPORT",
                   help="check each vehicle against the mount an earlier hybrid-calib export wrote for it (its --out "
                        "folder, or its export.json), not its tables: a later drive after a recalibration (default: "
                        "the tables; a vehicle the export did not replace keeps them)")
    p.add_argument("--max-frames", type=nonnegative_int, default=None, help="frames per vehicle, 0 = all (default: 0)")
    p.add_argument("--seed", type=seed_int, default=None, help="oracle noise and start seed (default: 0)")
    add_split_arguments(p, "all", "learned methods: all, or the train / val / test part of the split flags below "
                                  "(e.g. --split test --split-by time: the held-out end of each scene)")
    p.add_argument("--out", type=Path, default=Path("outputs/calibrate"),
                   help="run directory (default: outputs/calibrate)")
    p.add_argument("--overwrite", action="store_true",
                   help="recompute even if RUN/result.json exists (its network and depth caches too)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    p.add_argument("--no-progress", action="store_true",
                   help="hide the progress bars (any method; the learned ones: as --set progress=false)")
    p.add_argument("--set", action="extend", nargs="+", metavar="KEY=VALUE", default=[],
                   help="CalibrateConfig overrides (oracle), e.g. window.factor.kernel=tukey oracle.outlier_frac=0.3; "
                        "HybridConfig overrides (learned methods), e.g. threads=1 window.window=30; some of a "
                        "root: 'vehicles=[\"n015\"]', and for the learned methods 'data.scenes=[\"scene-0916\"]'")


def _learned(args: argparse.Namespace, on_vehicle):
    from hybrid_calib.config import merge
    from hybrid_calib.errors import HybridCalibError
    from hybrid_calib.hybrid import HybridConfig, run_calibration

    if args.correspondences is not None:  # 'oracle' too: it was accepted and had no effect
        raise HybridCalibError(f"--correspondences is for --method oracle (the true reflectors or measurement "
                               f"files); --method {args.method} runs the network itself: drop --correspondences")
    if args.window is not None and args.method in ("pure", "pure-avg"):  # no window: it was ignored
        raise HybridCalibError(f"--window sets the sliding window of --method hybrid and oracle; --method "
                               f"{args.method} runs the network alone on each frame: drop --window")
    if args.mode == "batch" or args.backend is not None:  # HybridConfig has no batch solve: they were ignored
        flag = "--mode batch" if args.mode == "batch" else "--backend"
        raise OptionError(flag, f"--method {args.method} runs the sliding window (or the network alone), not a batch "
                                f"solve; drop {flag}, or use --method oracle")
    overrides = parse_overrides(args.set)
    reject_set_keys(overrides, {"method": "--method", "split": "--split"})
    # accepted and without effect (--method oracle refuses the hybrid's keys the same way)
    reject_unused_blocks(args.method, overrides)
    # a flag that was passed wins over --set; an absent one leaves --set (or the default) in charge
    overrides.update(method=args.method, split=args.split, **given_flags(args, FLAGS, overrides))
    for key in ("checkpoint", "depth", "refine"):
        if getattr(args, key):
            overrides[key] = getattr(args, key)
    if flags := split_overrides(args):
        overrides["split_options"] = {**overrides.get("split_options", {}), **flags}
    if args.window is not None:  # an absent flag leaves --set (or the default) in charge
        overrides.setdefault("window", {})["window"] = args.window
    if args.no_progress:
        overrides["progress"] = False
    conf = merge(HybridConfig, overrides)
    return run_calibration(args.data, args.version, args.out, conf, overwrite=args.overwrite, on_vehicle=on_vehicle)


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.calib.pipeline import CalibrateConfig, calibrate
    from hybrid_calib.config import merge
    from hybrid_calib.plots.calibration import plot_vehicle

    on_vehicle = None if args.no_plots else partial(plot_vehicle, out_dir=args.out / "plots")
    reused = (args.out / "result.json").is_file() and not args.overwrite  # calibrate returns it, if of this run
    if args.method != "oracle":
        return _report(_plotted(_learned(args, on_vehicle), args), args.out, reused)
    if args.split != "all" or split_overrides(args):
        from hybrid_calib.errors import HybridCalibError

        raise HybridCalibError("--split and the split flags select frames for the learned methods (hybrid, pure, "
                               "pure-avg); --method oracle uses every frame (limit it with --max-frames)")
    network = [flag for flag in ("--checkpoint", "--refine", "--depth") if getattr(args, flag[2:])]
    if network:  # the oracle pipeline runs no network: they were ignored
        raise OptionError(network[0], f"is for the learned methods (--method hybrid, pure or pure-avg); --method "
                                      f"oracle runs no network: drop {' and '.join(network)}, or pass a learned "
                                      "--method")
    overrides = parse_overrides(args.set)
    reject_learned_keys(overrides)
    reject_unused_batch(overrides, args.mode, args.backend)
    reject_unused_window(overrides, args.mode, args.window)
    reject_unused_oracle(overrides)
    # an explicit flag wins over --set; an absent one leaves --set (or the default) in charge
    overrides.update(given_flags(args, {**FLAGS, "mode": "mode"}, overrides))
    if args.window is not None:
        overrides.setdefault("window", {})["window"] = args.window
    if args.backend is not None:
        overrides.setdefault("batch", {})["backend"] = args.backend
    conf = merge(CalibrateConfig, overrides)  # ConfigError (unknown key, wrong type, bad value) names the option
    result = calibrate(args.data, args.version, args.correspondences or "oracle", args.out, conf,
                       overwrite=args.overwrite, on_vehicle=on_vehicle, progress=not args.no_progress)
    return _report(_plotted(result, args), args.out, reused)


def _pass_words(v, dropped: int) -> str:
    """Which pass ``dropped`` counts, where it is not the pass whose in-domain count the status gives (probe 92: "only
    21 of 41 frames are inside" beside "21 frame(s) dropped": the estimate's last pass started elsewhere)."""
    o = v.ood or {}
    first = o.get("in_domain")
    if first is None or first + dropped == int(o.get("frames") or 0):  # the scored frames of the first pass
        return ""
    return " by the pass the estimate used (its starts differ from the first pass's; result.json's ood.note)"


def _plotted(result, args: argparse.Namespace):
    """``result`` after drawing the plots of its vehicles that have none: a vehicle an interrupted run kept, whose
    plots were not written (probe 66: a full disk stopped the run at its first plot; the rerun kept the vehicle and
    drew none), or a reused result whose plots were removed."""
    from hybrid_calib.plots.calibration import draw_missing

    if not args.no_plots:
        drawn = draw_missing(result, args.out / "plots")
        if drawn:  # said: a reused result's line says nothing was written (probe 69)
            print(f"drew the missing plots of {len(drawn)} vehicle(s) ({', '.join(drawn[:4])}"
                  f"{', ...' if len(drawn) > 4 else ''}) into {args.out / 'plots'}")
    return result


def _report(result, out: Path, reused: bool = False) -> int:
    """Print one line per vehicle and where the result is; ``reused``: it is an earlier run's ``result.json`` (same
    data and options), read back, not computed (nor written) now."""
    from hybrid_calib.calib.covariance import untrusted_status
    from hybrid_calib.calib.drift import drift_verdict
    from hybrid_calib.calib.lever_arm import describe as describe_doppler
    from hybrid_calib.calib.lidar_alignment import describe as describe_lidar
    from hybrid_calib.calib.mount_monitor import (
        blind_words,
        change_words,
        finds_words,
        tested_words,
        told_steps,
        turn_words,
    )
    from hybrid_calib.calib.result import STD_FRAME
    from hybrid_calib.data.reference import reference_words
    from hybrid_calib.metrics import std_dict
    from hybrid_calib.report.verdict import alarm_words

    for name, v in result.vehicles.items():
        s = std_dict(v.final.std, STD_FRAME)
        label = "std (camera axes; untrusted, as the status says)" if untrusted_status(v.final.status) else \
            "std (camera axes)"
        line = (f"{name}: {v.final.status}; {label} rot x/y/z (pitch/yaw/roll) {s['rot_x_cam_deg']:.3f}/"
                f"{s['rot_y_cam_deg']:.3f}/{s['rot_z_cam_deg']:.3f} deg, t x/y/z {s['t_x_cam_cm']:.2f}/"
                f"{s['t_y_cam_cm']:.2f}/{s['t_z_cam_cm']:.2f} cm")
        if v.error:
            line += (f"; error{' vs the tables' if v.errors_against == 'tables' else ''} "
                     f"{v.error['rot_mean_deg']:.3f} deg (mean of the three angles), {v.error['trans_norm_cm']:.2f} cm "
                     "(norm)")
        if v.drift:
            line += (f"; vs reference ({reference_words(v.drift.get('reference'))}): {drift_verdict(v.drift)} (chi2 p "
                     f"{v.drift['p_value']:.2g})")
        if v.skipped:
            ood = sum("ood_score" in r for r in v.skipped)
            seen = sum("repeats" in r for r in v.skipped)  # the ego stood still: not bad (probe 49)
            frozen = sum("frozen" in r for r in v.skipped)
            # the index's: a sample without one of the keyframes, another's copy, a scene recorded during another
            # (probe 96: they read "skipped (bad files or no rows)")
            unindexed = sum(isinstance(r, dict) and r.get("index") is None for r in v.skipped)
            bad = len(v.skipped) - ood - seen - frozen - unindexed
            said = (f"{bad} frame(s) skipped (bad files or no rows)" if bad else "",
                    f"{unindexed} sample(s) of the tables hold no frame the run reads (a keyframe missing, another "
                    "sample's copy, or a scene recorded during another of the vehicle)" if unindexed else "",
                    f"{seen} frame(s) left out as repeats of a view (the camera moved under views.min_travel_m and "
                    "turned under views.min_turn_deg since the view before: it stood still or crept)" if seen else "",
                    f"{frozen} frame(s) left out whose camera image is an earlier frame's, byte for byte (a frozen "
                    "camera?)" if frozen else "",
                    f"{ood} frame(s) dropped as out of the network's domain{_pass_words(v, ood)}" if ood else "")
            line += "; " + " and ".join(w for w in said if w) + " (listed in result.json)"
        print(line)
        if alarms := alarm_words(v):  # each named with the test that raised it, as the report says it
            print(f"  step alarm{'s' if len(alarms) > 1 else ''} at " + "; ".join(alarms))
        for key in ("depth_note", "range_note"):
            if v.config and v.config.get(key):
                print(f"  note: {v.config[key]}")
        if v.frame_rows and "deflation" in v.frame_rows[0]:
            used = sum(r["used"] for r in v.frame_rows)
            rej = sum(r["rejected"] for r in v.frame_rows)
            ms = sum(r["network_ms"] for r in v.frame_rows) / len(v.frame_rows)
            meas = (v.config or {}).get("measurement_effective") or {}
            what = ("the network's SE(3) prior only (measurement.rows=none: the checkpoint's fitted model; its "
                    "correspondence rows are not used)" if meas.get("rows") == "none" and not used else
                    f"rows used {used}, rejected {rej}")
            print(f"  {v.method}: {len(v.frame_rows)} frames, {what}; network {ms:.0f} ms/frame; checkpoint "
                  f"{v.checkpoint}")
        if v.mount is not None:
            steps = "; ".join(f"the radar turned by {turn_words(st['step_deg'], st['std_deg'])} "
                              f"{change_words(st, about=False)} (alarm at frame "
                              f"{st['at']})" for st in told_steps(v.mount))
            found = steps or ("not told" if v.mount.get("implausible") else
                              "no step" if v.mount.get("pairs_tested") else "not tested")
            if found == "no step" and (why := "; ".join(w for w in (blind_words(v.mount), finds_words(v.mount)) if w)):
                found += f" ({why})"
            print(f"  radar mount monitor ({tested_words(v.mount, (v.drift or {}).get('reference'))}): {found}")
        if v.lidar is not None:
            print(f"  LiDAR alignment: {describe_lidar(v.lidar)}")
        if v.doppler is not None:
            print(f"  Doppler lever arm: {describe_doppler(v.doppler)}")
    for name, reason in result.vehicles_failed.items():
        print(f"{name}: FAILED: {reason}", file=sys.stderr)
    failed = (f" ({len(result.vehicles_failed)} vehicle(s) failed: listed there under vehicles_failed)"
              if result.vehicles_failed else "")
    if reused:
        print(f"reused the earlier result {out / 'result.json'}{failed}: it was computed with the same options, "
              "checkpoint and data (the same tables, and sensor folders unchanged since; a file rewritten in place "
              "is not checked), so nothing was recomputed or written; pass --overwrite to recompute")
    else:
        print(f"wrote {out / 'result.json'}{failed}")
    return 1 if result.vehicles_failed else 0
