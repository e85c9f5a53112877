"""RC-AutoCalib (CVPR 2025) in PyTorch: dual-perspective radar-camera calibration network."""
