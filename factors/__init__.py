"""Robust radar-image factors on the extrinsic T_cam_radar (GTSAM), and the same residuals in Ceres."""
