"""2D detections per camera image: projected ground truth, simulated and external
detectors, association with the ground truth, backbones and ROI Align.

Boxes are (N, 4) float arrays [x1, y1, x2, y2] in pixels of the original camera image
(origin top-left, an image of size (W, H) spans [0, W] x [0, H]).
"""
