"""What finding replayed rows costs the sliding window per frame (``factors.correspondences.SeenRows`` and
``Correspondences.doubled_rows``): 1200 frames of 100 random rows (radar points 2-80 m, pixels in an 800 x 450 image,
sigma 6 px), each matched against the last 1000 frames, added, and checked for doubled rows.

    PYTHONPATH=. .venv/bin/python benchmarks/repeat_rows.py [--frames 1200] [--rows 100] [--memory 1000]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from factors.correspondences import Correspondences, SeenRows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=1200)
    ap.add_argument("--rows", type=int, default=100)
    ap.add_argument("--memory", type=int, default=1000)
    a = ap.parse_args()
    rng = np.random.default_rng(0)
    K = np.array([[800, 0, 400], [0, 800, 225], [0, 0, 1.0]])
    seen, t_match, t_add, t_doubled = SeenRows(a.memory), 0.0, 0.0, 0.0
    for i in range(a.frames):
        c = Correspondences(np.c_[rng.uniform(2, 80, (a.rows, 2)), np.zeros(a.rows)],
                            rng.uniform(0, [800, 450], (a.rows, 2)), np.full(a.rows, 6.0), np.ones(a.rows), K,
                            f"f{i}", i)
        t = time.perf_counter()
        seen.match(c)
        t_match += time.perf_counter() - t
        t = time.perf_counter()
        seen.add(c)
        t_add += time.perf_counter() - t
        t = time.perf_counter()
        c.doubled_rows()
        t_doubled += time.perf_counter() - t
    n = a.frames / 1e3
    print(f"per {a.rows}-row frame against up to {a.memory} frames: match {t_match / n:.2f} ms, add {t_add / n:.2f} "
          f"ms, doubled_rows {t_doubled / n:.3f} ms")


if __name__ == "__main__":
    main()
