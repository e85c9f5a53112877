"""Sensor models: pinhole camera, automotive radar (ARS 408-like), spinning LiDAR."""
