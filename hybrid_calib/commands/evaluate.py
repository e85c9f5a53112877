"""``hybrid-calib evaluate``: the paper's error table for a checkpoint on a held-out split.

Export-then-evaluate (``learned.evaluate``): per-frame predictions go to ``OUT/frames/*.npz`` (rerun
skips frames already there; measurement files, ``factors.io``, so ``hybrid-calib calibrate
--correspondences OUT`` reads them), then the table (rotation Mean/Roll/Pitch/Yaw in degrees, translation
Mean/X/Y/Z in cm, geodesic angle and translation norm; the initial error, every iteration and the
final estimate) is printed and written to ``OUT/results.json`` (schema in
``learned.evaluate.write_report``), ``OUT/results.md`` and ``OUT/errors_cdf.png``. With the checkpoint's
out-of-domain model (``export.ood``) each frame is scored as calibrate's learned methods score it: the count in
domain is said and a row "<method> (in domain)" keeps to those frames. The split and the
depth estimator default to the checkpoint's training config, so ``--split test`` holds out the same
scenes training did.

``--refine CKPT`` runs a coarse-to-fine cascade (``learned.cascade``): e.g. the R2 checkpoint from
the start, then the R1 checkpoint from its estimate; the table then lists every stage's iterations.

The exported per-frame covariance of the network's SE(3) is multiplied by the checkpoint's fitted
``export.cov_scale`` when it has one. ``--fit-uncertainty`` fits it: it exports the raw covariance,
computes per-axis factors that make each axis's normalised squared error average 1 on these frames
(``learned.export.calibrate_cov_scale``) and writes them into the checkpoint's JSON. Fit on the
validation split (or a separate root), then check on the test split: the report's NEES should be ~6.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from hybrid_calib.commands import (
    SPLIT_FLAGS,
    add_split_arguments,
    given_flags,
    nonnegative_int,
    positive_int,
    reject_set_keys,
    split_overrides,
    version_name,
)
from hybrid_calib.config import parse_overrides
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.errors import OptionError
from hybrid_calib.perturbation import RANGES

HELP = "evaluate a trained network on held-out frames (paper table: rotation deg, translation cm)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data", required=True, type=Path, nargs="+",
                        help="nuScenes root(s) (each holds VERSION/ and samples/); several are read as one")
    parser.add_argument("--version", type=version_name,
                        default=SIM_VERSION, help=f"version folder (default {SIM_VERSION})")
    parser.add_argument("--range", dest="perturbation", default="R1", choices=tuple(RANGES),
                        help="perturbation range of the starts (fixed per frame; default R1)")
    parser.add_argument("--method", default="pure", help="pure = the network alone")
    parser.add_argument("--checkpoint", required=True, type=Path,
                        help="ckpt-NNNN.json / .safetensors, or a run folder (its last checkpoint)")
    parser.add_argument("--refine", type=Path, action="append", default=[], metavar="CKPT",
                        help="then refine with this checkpoint (a cascade, e.g. --checkpoint R2 --refine R1; "
                             "repeatable); the export and covariance come from the last stage")
    parser.add_argument("--out", required=True, type=Path, help="output folder (predictions, results.json/.md)")
    add_split_arguments(parser, "test", "test (scenes, or by time the end of each scene, held out in training; the "
                                        "checkpoint's split unless the flags below change it), val, train, or all "
                                        "(a separate root)")
    parser.add_argument("--max-frames", type=nonnegative_int, default=0,
                        help="evaluate at most this many frames (0 = all)")
    parser.add_argument("--depth", default=None,
                        help="depth estimator (default: the checkpoint's; real data: depth-anything:/local/model/dir "
                             "or lidar-densified)")
    parser.add_argument("--nsweeps", type=positive_int, default=None,
                        help="radar sweeps accumulated per frame (default: what the checkpoint's training run read, "
                             "else 1)")
    parser.add_argument("--set", dest="overrides", action="extend", nargs="+", default=[], metavar="KEY=VALUE",
                        help="EvalConfig override, e.g. --set batch_size=8 threads=2 (device=cuda with a CUDA build of "
                             "torch; repeatable)")
    parser.add_argument("--fit-uncertainty", action="store_true",
                        help="fit per-axis factors for the exported covariance on these frames and store them in "
                             "the checkpoint (use --split val or a separate root; never the test split)")
    parser.add_argument("--overwrite", action="store_true", help="recompute predictions already in --out")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.config import merge
    from hybrid_calib.data.files import data_stamp
    from hybrid_calib.data.nuscenes import simulated_root
    from hybrid_calib.plots.evaluation import plot_error_cdf
    from learned.checkpoint import checkpoint_digest
    from learned.dataset import open_roots
    from learned.eval_setup import setup_evaluation
    from learned.evaluate import EvalConfig, annotate, evaluate
    from learned.uncertainty_fit import fit_uncertainty, overlap_words, trained_on, training_overlap

    user = parse_overrides(args.overrides)
    merge(EvalConfig, user)  # a bad --set fails here, before the checkpoint and the data are read
    # a flag with a default always has a value: --set must not overrule it silently (the rule of every command)
    reject_set_keys(user, {"method": "--method", "perturbation": "--range", "split": "--split",
                           "max_frames": "--max-frames"})
    given = given_flags(args, {"depth": "depth"}, user)
    flags = split_overrides(args)  # the split flags change the checkpoint's split (or the default)
    given_flags(args, {f"split_options.{k}": a for k, a in SPLIT_FLAGS.items()},  # says a --set value it overrules
                {f"split_options.{k}": v for k, v in (user.get("split_options") or {}).items()})
    from hybrid_calib.data.files import absolute_path

    # absolute, as calibrate's: the same run resumed from another folder is this run (probe 121: "predictions made
    # with another config" for --checkpoint ck.json, then ../ck.json)
    args.checkpoint = absolute_path(str(args.checkpoint)) if args.checkpoint is not None else None
    args.refine = [absolute_path(str(r)) for r in args.refine] if args.refine else args.refine
    setup = setup_evaluation(args.checkpoint, args.refine, method=args.method, perturbation=args.perturbation,
                             split=args.split, max_frames=args.max_frames, depth=args.depth, nsweeps=args.nsweeps,
                             split_flags=flags, overrides=user, given=given, fit_uncertainty=args.fit_uncertainty,
                             data=args.data, version=args.version)
    for note in setup.notes:
        print(note, file=sys.stderr)
    last, stage_paths = setup.last, setup.stage_paths
    if args.fit_uncertainty and not all(os.access(q, os.W_OK) for q in (last.path, Path(last.path).parent)):
        # the fit is written into the checkpoint at the end: said before the frames are read, not after (probe 27)
        raise OptionError("--fit-uncertainty", f"{last.path} cannot be written (it, or its folder, is read-only), "
                                               "and the fitted scale goes into it: copy the checkpoint to a folder "
                                               "you can write and pass the copy")
    from hybrid_calib.data.tables import version_dir
    from learned.depth import check_depth_source

    for root in args.data:  # once, before the frames (probe 71: every frame was skipped in turn, a line each)
        version_dir(root, args.version)  # a root that is not one is said as such, not as a --depth (probe 100)
        check_depth_source(str(setup.conf.get("depth", "")), root, given=bool(args.depth))
    frames = open_roots(args.data, args.version, lidar=setup.lidar, options={"nsweeps": setup.nsweeps})
    # other split flags than the checkpoint's: its training frames may fall in the "held-out" split (probe 55)
    stamps = [data_stamp(d, args.version)["digest"] for d in args.data]  # once: each hashes a root's tables
    overlap = training_overlap(last.path, frames, args.data, args.version, args.split, setup.conf.get("split_options"),
                               stamps)
    if overlap != 0 and args.fit_uncertainty:
        raise OptionError("--fit-uncertainty", f"{overlap_words(overlap, args.split)}: their errors would make the "
                                               "covariance look honest where it was fitted; fit with the "
                                               "checkpoint's own split (no --split-by / fraction flags), or on a "
                                               "root it never saw")
    if args.fit_uncertainty:  # before the frames are read: the fit's minimum (probe 117: refused after 74 s)
        from learned.evaluate import EvalConfig, eval_indices

        conf = merge(EvalConfig, setup.conf)
        n, need = len(eval_indices(frames, conf)), conf.fit_min_frames
        if 0 < n < need:
            raise OptionError("--fit-uncertainty", f"the {args.split} split holds {n} frame(s), fewer than {need}, "
                                                   "the fit's minimum (a variance from n frames is good to "
                                                   "sqrt(2/n)): fit on more validation frames (drop --max-frames, "
                                                   "add roots), or pass --set fit_min_frames=N to accept fewer")
    data = {"roots": [str(Path(d).resolve()) for d in args.data], "version": args.version, "nsweeps": setup.nsweeps,
            "stamps": stamps}
    # each frame scored as calibrate's learned methods score it (probe 87: the table said nothing of the real scene's
    # out-of-domain frames); a cascade's features are its refining pass's alone there, not scored here
    from learned.ood import ood_model_of

    ood, ood_note = ood_model_of(last.export, str(last.path)) if len(stage_paths) == 1 else (
        None, "out-of-domain score not computed for a cascade (calibrate scores its refining pass)")
    result = evaluate(setup.model, frames, setup.conf, args.out, checkpoint=" -> ".join(map(str, stage_paths)),
                      overwrite=args.overwrite, progress=not args.no_progress, data=data,
                      network=[checkpoint_digest(p) for p in stage_paths], ood=ood)
    plot_error_cdf(result, Path(args.out) / "errors_cdf.png")
    print(result.table())
    print(result.ood_words() or (ood_note if ood is None else "out-of-domain score: the frames kept from an earlier "
                                 "run into this folder were not scored (--overwrite scores every frame)"))
    notes = []  # kept in results.md / results.json too, beside the figures they qualify (probe 55: screen only)
    if args.split in ("all", "train") and (seen := trained_on(last.path, args.data, args.version, stamps)):
        notes.append(f"split {args.split} of {', '.join(seen)}, a root the checkpoint's training run read: these "
                     "frames include its training frames, so the table is no held-out measure (use --split test, or "
                     "a root it never saw)")
    if overlap != 0:
        notes.append(f"{overlap_words(overlap, args.split)}: the table is no held-out measure (drop the split "
                     "flags, or use a root it never saw)")
    if real := [str(d) for d in args.data if not simulated_root(d, args.version)]:
        notes.append(f"{', '.join(real)} holds no simulator truth: the errors and NEES of its frames are against "
                     "its calibrated_sensor tables (themselves a few tenths of a degree off), not the truth")
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    skipped_path = Path(args.out) / "skipped.json"  # frames with bad files, skipped by the export
    skipped = json.loads(skipped_path.read_text()) if skipped_path.is_file() else []
    unindexed = [rec for rec in skipped if rec.get("index") is None]  # samples the index left out (probe 100)
    failed = [rec for rec in skipped if rec.get("index") is not None]
    if failed:
        notes.append(f"{len(failed)} frame(s) skipped (their files could not be used; each, with why, in "
                     f"{skipped_path.name}): the table is over the {result.n_frames} frames left")
    if unindexed:
        notes.append(f"{len(unindexed)} sample(s) or record(s) of the tables hold no frame (each, with why, in "
                     f"{skipped_path.name}; first: {unindexed[0]['reason']})")
    if notes:
        annotate(args.out, result, notes)
    for rec in failed:
        print(f"skipped frame {rec['index']} ({rec['token']}): {rec['reason']}")
    if skipped:
        print(f"{len(failed)} frame(s) skipped, {len(unindexed)} sample(s) or record(s) of the tables hold no "
              f"frame; listed in {skipped_path}")
    u = result.uncertainty
    if u:
        print(f"exported covariance: mean NEES {u['nees_mean']:.2f} (6 if honest), coverage "
              f"{100 * u['coverage_95']:.1f} % (inside the 95 % ellipsoid; {u['n']} frames)")
    print(f"wrote {Path(args.out) / 'results.json'} and results.md")
    if args.fit_uncertainty:
        fit = fit_uncertainty(args.out, last.path, args.data, args.split, args.perturbation,
                              merge(EvalConfig, user).fit_min_frames)
        print(f"fitted cov_scale {', '.join(f'{v:.3g}' for v in fit.cov_scale)} -> written to {fit.checkpoint}")
        if fit.replaced:
            print(f"  it replaces cov_scale {fit.replaced[0]} ({fit.replaced[1]}); the old value is kept in the "
                  "checkpoint's export_history")
        if fit.stale:
            print(f"  note: export.{' and export.'.join(fit.stale)} were fitted with the earlier covariance scale; "
                  "refit them for this one (docs/benchmarks.md names the commands)")
    return 0
