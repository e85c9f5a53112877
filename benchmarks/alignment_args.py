"""The command line shared by the alignment benchmarks (``lidar_alignment.py``, ``lever_arm.py``): drives, output,
trials, and the start error each trial draws around the truth."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def parser(doc: str, trans_default: float, conf_name: str) -> argparse.ArgumentParser:
    """The shared options (the caller adds its own ``--frames``)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True, type=Path)
    ap.add_argument("--version", default="v1.0-sim")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--trials", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trans", type=float, default=trans_default,
                    help="start translation error, uniform +- m per radar axis")
    ap.add_argument("--rot", type=float, nargs=3, default=[0.7, 0.7, 0.25],
                    help="start rotation error std about radar x, y, z, deg")
    ap.add_argument("--set", nargs="*", default=[], help=f"{conf_name} overrides")
    return ap


def start_error(rng: np.random.Generator, args, trans_scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(6,) a right perturbation [rad, m] drawn as ``--rot`` / ``--trans`` say (translation scaled per radar axis)."""
    return np.concatenate([np.radians(args.rot) * rng.standard_normal(3),
                           rng.uniform(-args.trans, args.trans, 3) * np.asarray(trans_scale)])
