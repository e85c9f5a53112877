"""The classical half: sliding-window and batch calibration, drift detection, Cramer-Rao bound.

Modules: ``window`` (sliding-window calibrator), ``batch`` (whole drive, GTSAM or Ceres),
``schedule`` (convex start -> redescending kernel -> gated least squares), ``covariance``
(marginals, ``report_std``, degeneracy status), ``drift`` (reference chi-square test, step
detector), ``crb`` (Cramer-Rao bound), ``oracle`` (oracle correspondences), ``result`` (result
objects, JSON schema), ``pipeline`` (``hybrid-calib calibrate``). The figures of a run are drawn by
``hybrid_calib.plots.calibration`` (a higher layer; nothing here imports it).
"""

from hybrid_calib.calib.covariance import report_cov, report_std

__all__ = ["report_cov", "report_std"]
