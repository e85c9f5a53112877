"""Shared argument parsing of the examples: where to write and how big a simulated drive to make."""

import argparse
from pathlib import Path


def example_args(doc: str, frames: int = 20, **extra: int) -> argparse.Namespace:
    """``--out DIR`` (default ``outputs/examples``), ``--frames N`` keyframes per simulated drive and
    ``--image-scale S`` (camera = nuScenes CAM_FRONT 1600x900 scaled by S); each ``extra`` name=default
    adds an integer option ``--name``."""
    p = argparse.ArgumentParser(description=doc.splitlines()[0])
    p.add_argument("--out", type=Path, default=Path("outputs/examples"), help="output folder")
    p.add_argument("--frames", type=int, default=frames, help=f"keyframes per simulated drive (default {frames})")
    p.add_argument("--image-scale", type=float, default=0.5, help="camera image scale (default 0.5: 800x450)")
    for name, default in extra.items():
        p.add_argument(f"--{name.replace('_', '-')}", type=int, default=default, help=f"default {default}")
    return p.parse_args()
