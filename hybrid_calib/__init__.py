"""hybrid-calib: target-free radar-camera extrinsic calibration.

Subpackages: ``sensors`` (camera, radar, LiDAR models), ``sim`` (synthetic driving world written
as nuScenes), ``data`` (nuScenes reader), ``calib`` (sliding-window / batch calibrator, drift,
Cramer-Rao bound), ``commands`` (the ``hybrid-calib`` command line).
"""

__version__ = "0.1.0"
