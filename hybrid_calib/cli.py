"""``hybrid-calib``: one command with subcommands, a thin layer over typed functions."""

from __future__ import annotations

import argparse
import importlib
import sys

from hybrid_calib.errors import HybridCalibError

# subcommand name -> module in hybrid_calib.commands (each has HELP, add_arguments, run).
COMMANDS: dict[str, str] = {
    "simulate": "simulate",
    "demo": "demo",
    "inspect": "inspect",
    "train": "train",
    "evaluate": "evaluate",
    "calibrate": "calibrate",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hybrid-calib", description="Target-free radar-camera extrinsic calibration.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module in COMMANDS.items():
        mod = importlib.import_module(f"hybrid_calib.commands.{module}")
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except HybridCalibError as e:
        print(f"hybrid-calib {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
