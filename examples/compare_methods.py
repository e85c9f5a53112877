"""Compare calibration methods on the same starts: pure network, averaged network, hybrid.

Shows ``hybrid_calib.compare.compare``: every method runs the same (vehicle, R1 start) trials on
one network-output cache and writes ``OUT/compare/compare.json`` / ``compare.md`` (the paper's error table,
95 % coverage and NEES of the reported covariance, time per frame) and ``error_vs_frames.png`` (the simulated
drive in ``OUT/sim``).

    .venv/bin/python examples/compare_methods.py --out outputs/examples/compare --frames 20 --trials 2
"""

from _common import example_args

from hybrid_calib.compare import compare
from hybrid_calib.sim.drive import SimConfig
from hybrid_calib.sim.simulate import simulate

args = example_args(__doc__, trials=2)
root = simulate(SimConfig(scenario="urban", vehicles=1, frames=args.frames, image_scale=args.image_scale),
                args.out / "sim")
summary = compare([root], "v1.0-sim", args.out / "compare",
                  {"trials": args.trials, "methods": ["pure", "pure-avg", "hybrid"]}, progress=False)
for method, s in summary.methods.items():
    m, c = s.mean, s.consistency
    print(f"{method:9s}: rotation {m['rot_mean_deg']:.3f} deg, translation {m['trans_norm_cm']:.2f} cm (mean of "
          f"{s.trials} trials); inconclusive {s.inconclusive_fraction:.0%}; 95 % coverage {c['coverage_95']:.0%}, "
          f"mean NEES {c['nees_mean']:.1f}")
print(f"table: {args.out / 'compare' / 'compare.md'}")
