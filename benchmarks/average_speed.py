"""What pure-avg costs on a long drive: one ``hybrid.average.robust_average`` of F estimates (pure-avg averages every
earlier frame's network estimate again at each frame, so a drive of N frames costs the sum over F = 1..N).

Random estimates scattered by 0.01 (rad, m) around the identity with a covariance of 1e-4, the average's defaults.
Prints the milliseconds of one average per F and the seconds a drive of ``--drive`` frames spends averaging (the
sum, interpolated linearly in F between the measured sizes).

    PYTHONPATH=. .venv/bin/python benchmarks/average_speed.py --sizes 100 500 1000 2400 --drive 2400
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None) -> int:
    from hybrid_calib.geometry import se3_exp
    from hybrid_calib.hybrid.average import robust_average

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--sizes", type=int, nargs="+", default=[100, 500, 1000, 2400])
    p.add_argument("--drive", type=int, default=2400, help="frames of the drive whose averaging time is summed")
    p.add_argument("--repeats", type=int, default=3, help="the fastest of this many averages per size")
    args = p.parse_args(argv)
    g = np.random.default_rng(0)
    ms = []
    for F in args.sizes:
        Ts = np.stack([se3_exp(g.normal(size=6) * 0.01) for _ in range(F)])
        covs = np.tile(np.eye(6) * 1e-4, (F, 1, 1))
        best = float("inf")
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            robust_average(Ts, covs)
            best = min(best, time.perf_counter() - t0)
        ms.append(1e3 * best)
        print(f"{F} estimates: one average {ms[-1]:.1f} ms")
    per_frame = np.interp(np.arange(1, args.drive + 1), args.sizes, ms)
    print(f"a {args.drive}-frame pure-avg drive: {per_frame.sum() / 1e3:.0f} s of averaging (the sum over its frames)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
