"""The hybrid (layer 6): the network and the factor graph in one closed loop, with an honest noise
model for the network's measurements; the only package that imports both ``learned`` and
``hybrid_calib.calib``.

Entry points (plain data in, the one result type out):
  ``run_vehicle(data, version, vehicle, conf) -> calib.result.VehicleResult``
  ``run_calibration(data, version, out, conf, overwrite=False, on_vehicle=None) -> CalibrationRun``
with ``conf`` a ``HybridConfig`` (or a dict of overrides): method hybrid | pure | pure-avg | oracle.
"""

from hybrid_calib.hybrid.loop import METHODS, HybridConfig, run_calibration, run_vehicle

__all__ = ["METHODS", "HybridConfig", "run_calibration", "run_vehicle"]
