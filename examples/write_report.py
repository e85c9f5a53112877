"""Write one vehicle's HTML report from a calibration result.

Shows ``hybrid_calib.report.write_report``: a self-contained page (verdict in words, extrinsic with
its 1-sigma, the trajectory and the step test, radar points on camera frames) from any
``result.json``; here of a quick ``oracle`` calibration (the simulator's true reflectors) of one
simulated drive.

    .venv/bin/python examples/write_report.py --out outputs/examples/report --frames 20
"""

from _common import example_args

from hybrid_calib.hybrid import run_calibration
from hybrid_calib.report import write_report
from hybrid_calib.sim.drive import SimConfig
from hybrid_calib.sim.simulate import simulate

args = example_args(__doc__)
root = simulate(SimConfig(scenario="urban", vehicles=1, frames=args.frames, image_scale=args.image_scale),
                args.out / "sim")
run = run_calibration(root, "v1.0-sim", args.out / "calibration", {"method": "oracle", "start": "R1"})
for name in run.vehicles:
    page = write_report(args.out / "calibration" / "result.json", args.out / f"report-{name}.html", vehicle=name)
    print(f"{name}: {page}")
