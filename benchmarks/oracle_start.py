"""Does the oracle's batch solve depend on its start? The same oracle rows (``bench_oracle``'s: world heights,
pixel noise, 20 % outliers, one noise seed per run) solved from the truth, from an R1 and from an R2 start; the
camera-axis errors (deg, cm) and the reported rotation stds printed per vehicle and seed, one JSON line each.

    PYTHONPATH=. .venv/bin/python benchmarks/oracle_start.py --data SIM --seeds 1 2 3 --frames 100

Used for issue 10's highway roll (docs/benchmarks.md, "The lateral height slope measured in the world"): if the
estimates agree across starts, a roll error that repeats over a drive's noise seeds is the drive's (its scene), not
the solver's.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    from bench_oracle import factor_config, on_road

    from factors.config import RadarPixelFactorConfig
    from hybrid_calib.calib.batch import solve_batch
    from hybrid_calib.calib.covariance import report_basis
    from hybrid_calib.calib.oracle import OracleConfig, oracle_from_frame
    from hybrid_calib.config import merge
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.errors import DataError
    from hybrid_calib.geometry import local
    from hybrid_calib.perturbation import perturbed_start

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path, required=True, help="a v1.0-sim root (hybrid-calib simulate)")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="noise seeds per vehicle")
    p.add_argument("--frames", type=int, default=100)
    a = p.parse_args(argv)
    ds = NuScenesRadarCamera(a.data, "v1.0-sim", conf={"check_images": False, "skip_empty_radar": False})
    fc = factor_config(RadarPixelFactorConfig().elevation_model, "world")
    fconf = merge(RadarPixelFactorConfig, fc)
    oconf = OracleConfig(n_per_frame=100, sigma_px=2.0, outlier_frac=0.2, elevation="world",
                         elevation_model=fconf.elevation_model, elevation_beam_deg=fconf.elevation_beam_deg,
                         elevation_mean_deg=fconf.elevation_mean_deg,
                         reflector_height_mean_m=fconf.reflector_height_mean_m,
                         reflector_height_std_m=fconf.reflector_height_std_m)
    for vehicle, idx in sorted(ds.frames_by_vehicle().items()):
        data = [ds[i] for i in idx[: a.frames]]
        fcv = on_road(fc, data, "world")  # the heights from the road, as calibrate measures them
        for seed in a.seeds:
            g = np.random.default_rng(seed)
            frames, truths = [], []
            for f in data:
                try:
                    c, t = oracle_from_frame(f, oconf, g)
                except DataError:  # a frame with no real reflector in view
                    continue
                frames.append(c)
                truths.append(t)
            T = truths[-1].T_cam_radar
            B = report_basis(T)
            row = {"vehicle": vehicle, "seed": seed}
            starts = {"truth": T, "R1": perturbed_start(T, np.random.default_rng([seed, 1]), "R1"),
                      "R2": perturbed_start(T, np.random.default_rng([seed, 2]), "R2")}
            for name, T0 in starts.items():
                est = solve_batch(frames, T0, {"schedule": {"final_gate": 3.0}, "factor": fcv}).estimate
                e = B @ local(T, est.T)
                C = B @ np.asarray(est.cov) @ B.T
                row[name] = {"err_deg_cm": [round(float(np.degrees(x)), 4) for x in e[:3]]
                             + [round(float(x * 100), 2) for x in e[3:]],
                             "rot_std_deg": [round(float(np.degrees(np.sqrt(C[i, i]))), 4) for i in range(3)]}
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
