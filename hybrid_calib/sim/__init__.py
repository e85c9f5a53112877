"""Synthetic driving world with exact ground truth, written in the nuScenes format.

Holds its own sensor models: ``radar`` (ARS 408-like, ray-cast) and ``lidar`` (HDL-32E-like, ray-cast);
the pinhole camera that real data needs too is ``hybrid_calib.sensors.camera``.
"""
