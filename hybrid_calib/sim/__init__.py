"""Synthetic driving world with exact ground truth, written in the nuScenes format."""
