"""``hybrid-calib report``: one self-contained HTML page of a calibration result (``hybrid_calib.report``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from hybrid_calib.commands import nonnegative_int, reject_set_keys, version_name
from hybrid_calib.config import parse_overrides
from hybrid_calib.errors import OptionError, check_out_dir, check_out_not_in_dataset, page_target

HELP = "write a self-contained HTML report (verdict, extrinsic +- 1 sigma, pictures) of a calibration result"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("result", type=Path, help="a result.json written by hybrid-calib calibrate / demo")
    p.add_argument("--vehicle", default=None, help="vehicle to report (needed when the result holds several)")
    p.add_argument("--data", type=Path, default=None,
                   help="nuScenes root for the camera frames (default: the run's own data root, when it is there)")
    p.add_argument("--version", type=version_name,
                   default=None, help="version folder under --data (default: the run's)")
    p.add_argument("--checkpoint", default="", help="network checkpoint for the attention figure (default: the "
                                                    "one the result names, if any)")
    p.add_argument("--frames", type=nonnegative_int, default=3, help="camera frames shown before / after (default: 3)")
    # dest out_html: --out is a file here, not the output directory the CLI checks for other commands
    p.add_argument("--out", dest="out_html", type=Path, required=True, help="the HTML file to write, e.g. report.html")
    p.add_argument("--set", action="extend", nargs="+", metavar="KEY=VALUE", default=[],
                   help="ReportConfig overrides, e.g. tolerance.rot_deg=0.3 tolerance.trans_cm=3 (the verdict's "
                   "tolerance per camera axis; default: the one the calibration used, drift.tolerance_rot_deg / "
                   "drift.tolerance_trans_cm: 0.5 deg and 2 cm)")


def run(args: argparse.Namespace) -> int:
    from hybrid_calib.report import write_report
    from hybrid_calib.report.html import page_lock

    args.out_html = page_target(args.out_html)  # a link: its target is the page, checked and locked (probe 70)
    check_arguments(args)
    overrides = parse_overrides(args.set)
    # the flags set them (probe 79: --set frames / checkpoint were overwritten by the flags' defaults in silence)
    reject_set_keys(overrides, {"frames": "--frames", "checkpoint": "--checkpoint"})
    overrides.update(frames=args.frames, checkpoint=args.checkpoint)
    # one run per page (probe 60: two runs onto one page both said "wrote" and one vehicle's page was lost)
    with page_lock(args.out_html, "report", reentrant=False):
        path = write_report(args.result, args.out_html, args.vehicle, args.data, args.version, overrides)
    print(f"wrote {path}")
    return 0


def check_arguments(args: argparse.Namespace) -> None:
    """``OptionError`` for paths given explicitly that cannot work (the defaults degrade to a note in the
    page instead): ``--out`` a directory or below a file, ``--data`` / ``--checkpoint`` not there."""
    from hybrid_calib.report.html import is_html

    out = args.out_html
    if out.is_dir():
        raise OptionError("--out", f"{out} is a directory; --out is the HTML file to write, e.g. {out / 'report.html'}")
    if out.suffix.lower() not in (".html", ".htm"):  # a slip (--out result.json) replaced the input with the page
        raise OptionError("--out", f"{out} is not an .html file name; --out is the HTML page to write, e.g. "
                                   f"{out.with_suffix('.html')}")
    if out.exists() and not is_html(out):
        raise OptionError("--out", f"{out} exists and is not an HTML page, so it is not replaced; pass another file "
                                   "name, or move it away")
    check_out_dir(out.parent)
    check_out_not_in_dataset(out.parent)  # the run's root or any other: a page among a dataset's files
    if args.data is not None and not args.data.is_dir():
        raise OptionError("--data", f"{args.data} is not a directory; pass the nuScenes root of the run's frames, or "
                                    "leave --data out to use the run's own root")
    if args.checkpoint and not Path(args.checkpoint).exists():
        raise OptionError("--checkpoint", f"{args.checkpoint} does not exist; pass a ckpt-NNNN.json, or leave "
                                          "--checkpoint out to use the one the result names")
    if args.checkpoint:  # given, so it must load, weights too (the result's own degrades to a note in the page)
        from learned.checkpoint import load_model

        load_model(args.checkpoint)
