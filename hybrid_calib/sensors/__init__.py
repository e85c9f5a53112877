"""What real data needs as well as the simulator: the pinhole camera model. (Radar point fields and
filters live in ``hybrid_calib.data``; the ray-cast radar and LiDAR models in ``hybrid_calib.sim``.)"""
