"""One car seen from two directions: the pixels differ, the identity (body colour) stays."""

import dataclasses

import numpy as np

from sianms_cli.synth.appearance import CameraStyle, sample_appearance
from sianms_cli.synth.camera import render_camera
from sianms_cli.synth.objects import object_parts
from sianms_cli.synth.shapes import place_parts

W, H, F = 320, 240, 200.0
K = np.array([[F, 0.0, W / 2], [0.0, F, H / 2], [0.0, 0.0, 1.0]])
# 1.5 m above the origin looking along +x (camera x = -y, y = -z, z = +x).
CAM_TO_WORLD = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]])
SUN = np.array([-0.4, 0.5, 0.75])
SIZE = (1.9, 4.6, 1.6)


def asphalt(xy):
    return np.full((len(xy), 3), 0.08)


def car_pixels(base_srgb, yaw: float) -> np.ndarray:
    """(P,3) uint8 pixels of a car of body colour base_srgb, 9 m ahead, turned by yaw."""
    look = sample_appearance("car", np.random.default_rng(11), size_wlh=SIZE)
    look = dataclasses.replace(look, base=((np.asarray(base_srgb) / 255.0) ** 2.2).astype(np.float32))
    parts = place_parts(object_parts("car", SIZE, look), np.array([9.0, 0.0, SIZE[2] / 2]), yaw, owner=0)
    out = render_camera(parts, [look], asphalt, K, CAM_TO_WORLD, W, H, CameraStyle(), SUN, 1,
                        np.random.default_rng(0))
    return out.image[out.owner_map == 0]


def body_chromaticity(pixels: np.ndarray) -> np.ndarray:
    """(3,) mean r, g, b shares of the most saturated half of the pixels (the paint, not the
    glass, tyres and trim)."""
    rgb = pixels.astype(float) + 1.0
    saturation = (rgb.max(axis=1) - rgb.min(axis=1)) / rgb.max(axis=1)
    paint = rgb[saturation >= np.median(saturation)]
    return (paint / paint.sum(axis=1, keepdims=True)).mean(axis=0)


def test_front_and_side_views_differ_but_keep_the_body_colour():
    red_end, red_side = car_pixels((160, 22, 25), 0.0), car_pixels((160, 22, 25), np.pi / 2)
    blue_side = car_pixels((30, 60, 130), np.pi / 2)
    # the two views differ in what is seen (lamps, grille, glass, flank) and in the shading
    assert len(red_side) > 1.3 * len(red_end)
    assert np.abs(red_end.mean(axis=0) - red_side.mean(axis=0)).max() > 3.0
    # ... while the paint's chromaticity stays close, and far from another car's
    same = np.abs(body_chromaticity(red_end) - body_chromaticity(red_side)).max()
    other = np.abs(body_chromaticity(red_side) - body_chromaticity(blue_side)).max()
    assert same < 0.03 and other > 10 * same
