"""The camera image's own out-of-domain test (``learned.ood.image_structure``) on the images of nuScenes roots.

    PYTHONPATH=. python benchmarks/image_structure.py --data ROOT [ROOT ...] [--version VERSION] [--hw 96 200]

Every CAM_FRONT image of each root (keyframes and sweeps, read through the root's ``sample_data`` table) is resized
to the network's input (``--hw``, H W; the shipped small networks' 96 x 200) as the network's dataset does (area
interpolation) and measured: the lag-1 correlation of neighbouring pixels' grey levels. Prints, per root, the count,
min / 5th percentile / median and how many fall under ``learned.ood.MIN_IMAGE_STRUCTURE`` (flagged out of domain
whatever the network makes of them). Nothing is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def camera_images(root: Path, version: str) -> list[Path]:
    """Paths of the CAM_FRONT images ``root``'s ``sample_data`` table names (keyframes and sweeps) that are on disk
    (a nuScenes subset often holds the keyframes only)."""
    tables = root / version
    sensors = {s["token"]: s["channel"] for s in json.loads((tables / "sensor.json").read_text())}
    cams = {c["token"] for c in json.loads((tables / "calibrated_sensor.json").read_text())
            if sensors.get(c["sensor_token"]) == "CAM_FRONT"}
    return sorted(p for r in json.loads((tables / "sample_data.json").read_text())
                  if r["calibrated_sensor_token"] in cams and (p := root / r["filename"]).is_file())


def main(argv: list[str] | None = None) -> int:
    import cv2

    from learned.ood import MIN_IMAGE_STRUCTURE, image_structure

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", nargs="+", required=True, type=Path)
    ap.add_argument("--version", default="", help="tables folder (default: the root's v1.0-* folder)")
    ap.add_argument("--hw", nargs=2, type=int, default=(96, 200), metavar=("H", "W"))
    a = ap.parse_args(argv)
    print(f"| root | images | min | 5 % | median | under {MIN_IMAGE_STRUCTURE:g} |\n|---|---|---|---|---|---|")
    for root in a.data:
        version = a.version or next((p.name for p in sorted(root.glob("v1.0-*")) if p.is_dir()), "")
        values = []
        for path in camera_images(root, version):
            im = cv2.imread(str(path))
            if im is None:
                print(f"  {path}: does not read; left out", file=sys.stderr)
                continue
            values.append(image_structure(cv2.resize(im, (a.hw[1], a.hw[0]), interpolation=cv2.INTER_AREA)))
        v = np.asarray(values)
        if not len(v):
            print(f"| {root} | 0 | | | | |")
            continue
        print(f"| {root} | {len(v)} | {v.min():.3f} | {np.percentile(v, 5):.3f} | {np.median(v):.3f} | "
              f"{int(np.sum(v < MIN_IMAGE_STRUCTURE))} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
