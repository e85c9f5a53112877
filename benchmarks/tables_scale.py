"""How the nuScenes reader scales with the size of a root's tables: the real scene's tables replicated K times.

A user points the tool at a whole nuScenes version (v1.0-trainval: 850 scenes, its sample_data.json about 1.4 GB);
the repository holds one real scene. Each copy here is scene-0916's tables with every token suffixed (one log, so
one vehicle, per copy), its sample_data's files reached through a symlink per copy (``cNNN/samples/...``), so the
copies are distinct recordings to the reader. Measures, per K: the JSON size, the index build
(``NuScenesRadarCamera``: the tables read and checked, no sensor file read) in seconds, and the process's peak
resident memory; each K in a fresh process.

    PYTHONPATH=. .venv/bin/python benchmarks/tables_scale.py --copies 10 50 200 --work /tmp/tables_scale

Prints a markdown table; ``--work`` keeps the roots (delete it after).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

SHARED = ("sensor", "category", "attribute", "visibility")  # vocabulary tables: their tokens are not a recording's
LINKS = ("token", "prev", "next", "first_sample_token", "last_sample_token")


def replicate(src: Path, version: str, copies: int, out: Path) -> Path:
    """``out``: a root whose tables hold ``copies`` copies of ``src``'s (fresh tokens, one log / vehicle / scene name
    each); its sensor files are ``src``'s, through the symlink ``out/cNNN`` per copy."""
    (out / version).mkdir(parents=True, exist_ok=True)
    vocabulary = {r["token"] for t in SHARED if (src / version / f"{t}.json").is_file()
                  for r in json.loads((src / version / f"{t}.json").read_text())}

    def rename(v, i: int):
        return v if not isinstance(v, str) or not v or v in vocabulary else f"{v}c{i:03d}"

    for i in range(copies):
        if not (out / f"c{i:03d}").exists():
            os.symlink(src.resolve(), out / f"c{i:03d}")
    for f in sorted((src / version).glob("*.json")):
        records = json.loads(f.read_text())
        if f.stem in SHARED:
            (out / version / f.name).write_text(json.dumps(records))
            continue
        rows = []
        for i in range(copies):
            for r in records:
                r2 = {k: rename(v, i) if k in LINKS or k.endswith("_token") else
                      [rename(x, i) for x in v] if k.endswith("_tokens") and isinstance(v, list) else v
                      for k, v in r.items()}
                if f.stem == "sample_data":
                    r2["filename"] = f"c{i:03d}/{r['filename']}"
                elif f.stem == "scene":
                    r2["name"] = f"{r['name']}-c{i:03d}"
                elif f.stem == "log":
                    r2["vehicle"] = f"{r['vehicle']}-c{i:03d}"
                rows.append(r2)
        (out / version / f.name).write_text(json.dumps(rows))
    return out


MEASURE = """
import json, resource, sys, time
from hybrid_calib.data.nuscenes import NuScenesRadarCamera
t = time.perf_counter()
ds = NuScenesRadarCamera(sys.argv[1], sys.argv[2], conf={"check_images": False})
s = time.perf_counter() - t
print(json.dumps({"index_s": s, "frames": len(ds.frames), "vehicles": len(ds.frames_by_vehicle()),
                  "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=Path(__file__).resolve().parents[2] / "shared" / "data"
                   / "nuscenes-scene-0916", help="the real root to replicate (default: ../shared's scene-0916)")
    p.add_argument("--version", default="v1.0-mini")
    p.add_argument("--copies", type=int, nargs="+", default=[10, 50, 200])
    p.add_argument("--work", type=Path, required=True, help="where the replicated roots are written")
    a = p.parse_args()
    print("| copies (scenes) | tables JSON (MB) | keyframes | vehicles | index build (s) | peak RSS (MB) |")
    print("|---|---|---|---|---|---|")
    for k in a.copies:
        root = replicate(a.data, a.version, k, a.work / f"x{k}")
        size = sum(f.stat().st_size for f in (root / a.version).glob("*.json")) / 1e6
        run = subprocess.run([sys.executable, "-c", MEASURE, str(root), a.version], capture_output=True, text=True,
                             check=True, env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
        r = json.loads(run.stdout.strip().splitlines()[-1])
        print(f"| {k} | {size:.0f} | {r['frames']} | {r['vehicles']} | {r['index_s']:.2f} | {r['peak_rss_mb']:.0f} |",
              flush=True)


if __name__ == "__main__":
    main()
