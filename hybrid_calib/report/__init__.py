"""The uncertainty report: one self-contained HTML page per vehicle, and a fleet page linking them,
read from result files only (``calib.result``) and the data root for the images.

- ``write_report(result, out, vehicle=None, data=None, version=None, conf=None) -> Path``: a vehicle's
  page (verdict, extrinsic with 1-sigma, what the data could not pin, before / after on frames across
  the drive with the correspondences, estimate with its 3-sigma band, residual histograms, attention).
- ``write_fleet_page(results, out, design=None, flagged=(), reports=None, conf=None) -> Path``: the fleet
  page (fleet plot of offsets from the design mount, sortable table of vehicles with status and verdict,
  links to the per-vehicle pages).
- ``write_fleet_pages(summary, out) -> Path | None``: a fleet run's pages from its ``summary.json`` (the fleet
  page and a page per done vehicle).
- ``verdict_of(vehicle_result, tolerance) -> Verdict``: the verdict in words (``verdict``).

Figures come from ``hybrid_calib.plots`` (``plots.report``, ``plots.network``).
"""

from hybrid_calib.report.fleet import write_fleet_page, write_fleet_pages
from hybrid_calib.report.vehicle import ReportConfig, write_report
from hybrid_calib.report.verdict import Tolerance, Verdict, verdict_of

__all__ = ["ReportConfig", "Tolerance", "Verdict", "verdict_of", "write_fleet_page", "write_fleet_pages",
           "write_report"]
