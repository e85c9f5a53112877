"""Data layer: nuScenes-format files and tables -> synchronised radar-camera frames."""
