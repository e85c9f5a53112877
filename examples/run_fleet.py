"""Run a small fleet through the Python API: simulate vehicles, calibrate each as a resumable job.

Shows ``hybrid_calib.fleet.driver.run_fleet`` (engine local or process): one job per vehicle, a
manifest that makes a rerun resume, and the fleet view (``summary.json`` / ``summary.md``: verdict
against the vehicle's tables, step alarms inside the drive, fleet outliers), then the HTML pages
(``fleet.html`` and a ``report.html`` per vehicle) with ``report.write_fleet_pages``.

    .venv/bin/python examples/run_fleet.py --out outputs/examples/fleet --frames 20 --vehicles 3
"""

from _common import example_args

from hybrid_calib.fleet.driver import FleetOptions, run_fleet
from hybrid_calib.report import write_fleet_pages
from hybrid_calib.sim.drive import SimConfig
from hybrid_calib.sim.simulate import simulate


def main() -> None:
    args = example_args(__doc__, vehicles=3, workers=1)
    root = simulate(SimConfig(scenario="urban", vehicles=args.vehicles, frames=args.frames,
                              image_scale=args.image_scale), args.out / "sim")
    engine = "process" if args.workers > 1 else "local"
    summary = run_fleet([str(root)], None, "v1.0-sim", "oracle", args.out / "fleet",
                        options=FleetOptions(engine, args.workers, plots=False))
    for jid, r in summary["vehicles"].items():
        status = str(r.get("status")).split(":")[0]
        print(f"{jid}: {r['state']}; status {status}; flags {', '.join(r['flags']) or 'none'}")
    print(f"counts: {summary['counts']}")
    print(f"fleet page: {write_fleet_pages(summary, args.out / 'fleet')}")


if __name__ == "__main__":  # the process engine re-imports this module in its workers
    main()
