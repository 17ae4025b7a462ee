"""2D detections per camera image: the Detector protocol with the simulated and external
detectors, association with the 2D ground truth, backbones, ROI Align and ROI features.

Nothing here knows 3D: the ground truth arrives as 2D boxes with classes, truncation,
occlusion and distance (:class:`~sianms_cli.detection2d.detections.GroundTruth2D`).
Boxes are (N, 4) float arrays [x1, y1, x2, y2] in pixels of the original camera image
(origin top-left, an image of size (W, H) spans [0, W] x [0, H]).
"""
