"""Duplicate handling for `sianms eval`: NMS variants, siaNMS matching, multi-view frustum aggregation."""
