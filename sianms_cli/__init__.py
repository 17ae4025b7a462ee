"""sianms: multi-camera 3D object detection research on nuScenes-format data."""

__version__ = "0.1.0"
