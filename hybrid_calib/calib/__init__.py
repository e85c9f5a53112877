"""The classical half: sliding-window and batch calibration, drift detection, Cramer-Rao bound."""
