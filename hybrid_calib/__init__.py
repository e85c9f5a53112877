"""hybrid-calib: target-free radar-camera extrinsic calibration.

Subpackages, lowest layer first (imports run downward only; ``tests/test_layering.py`` keeps it so):
``geometry`` / ``config`` / ``errors`` / ``metrics`` / ``perturbation``; ``data`` (nuScenes reader)
and ``sensors`` (pinhole camera); ``sim`` (synthetic driving world written as nuScenes, with its
ray-cast radar and LiDAR models); ``calib`` (sliding-window / batch calibrator, drift, Cramer-Rao
bound); ``plots`` (every figure); ``commands`` (the ``hybrid-calib`` command line and the demo).
"""

__version__ = "0.1.0"
