"""Shapes of vehicles (car, truck, bus) as cuboid parts; see shapes.py for the frame
and the builder."""

from __future__ import annotations

import numpy as np

from sianms_cli.synth.appearance import TWO_TONE_ROOF, Appearance
from sianms_cli.synth.shapes import GREENHOUSE, HEADLIGHT, PAINT, PAINT2, PLATE, TAILLIGHT, TRIM, TYRE, Builder


def _car(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    # Belt-line height, cabin span along x and cabin width by body style.
    belt, cab_rear, cab_front, cab_w = {
        0: (0.56, -0.33, 0.17, 0.84),   # sedan
        1: (0.55, -0.46, 0.12, 0.85),   # hatchback
        2: (0.58, -0.46, 0.19, 0.88),   # SUV
    }[app.variant % 3]
    z0 = -h / 2
    clearance = 0.11 * h
    r = float(np.clip(0.2 * h, 0.28, 0.42))
    tyre = 0.11
    body_top = z0 + belt * h
    roof_colour = app.secondary if app.pattern == TWO_TONE_ROOF else app.base
    b.add((-l / 2 + 0.02, -w / 2 + 0.015, z0 + clearance), (l / 2 - 0.02, w / 2 - 0.015, body_top),
          PAINT, app.base)
    b.add((cab_rear * l, -cab_w * w / 2, body_top), (cab_front * l, cab_w * w / 2, h / 2),
          GREENHOUSE, roof_colour)
    for x in (0.31 * l, -0.29 * l):
        for side in (1.0, -1.0):
            b.add_center((x, side * (w / 2 - tyre), z0 + r), (r, tyre, r), TYRE)
    light_z = body_top - 0.13
    for side in (1.0, -1.0):
        b.add_center((l / 2 - 0.01, side * (w / 2 - 0.30), light_z), (0.01, 0.17, 0.06), HEADLIGHT)
        b.add_center((-l / 2 + 0.01, side * (w / 2 - 0.20), light_z), (0.01, 0.14, 0.07), TAILLIGHT)
    plate_z = z0 + clearance + 0.22
    b.add_center((l / 2 - 0.01, 0.0, plate_z), (0.01, 0.26, 0.06), PLATE)
    b.add_center((-l / 2 + 0.01, 0.0, plate_z + 0.12), (0.01, 0.26, 0.06), PLATE)
    b.add((l / 2 - 0.03, -w / 2 + 0.03, z0 + clearance), (l / 2 - 0.01, w / 2 - 0.03, plate_z - 0.08),
          TRIM)


def _truck(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    z0 = -h / 2
    cab_len = min(2.3, 0.38 * l)
    cab_h = 0.8 * h
    r = 0.5
    front = l / 2
    b.add((front - cab_len, -w / 2 + 0.02, z0 + 0.45), (front - 0.02, w / 2 - 0.02, z0 + 0.58 * cab_h),
          PAINT, app.base)
    b.add((front - cab_len, -w / 2 + 0.06, z0 + 0.58 * cab_h), (front - 0.25, w / 2 - 0.06, z0 + cab_h),
          GREENHOUSE, app.base)
    cargo_front = front - cab_len - 0.12
    b.add((-l / 2, -w / 2, z0 + 0.35 * h), (cargo_front, w / 2, h / 2), PAINT2, app.secondary)
    b.add((-l / 2 + 0.3, -w / 2 + 0.35, z0 + 0.35), (cargo_front, w / 2 - 0.35, z0 + 0.35 * h), TRIM)
    for x in (front - 0.55 * cab_len, -l / 2 + 1.2, -l / 2 + 2.3):
        for side in (1.0, -1.0):
            b.add_center((x, side * (w / 2 - 0.17), z0 + r), (r, 0.16, r), TYRE)
    for side in (1.0, -1.0):
        b.add_center((front - 0.01, side * (w / 2 - 0.3), z0 + 0.75), (0.01, 0.17, 0.08), HEADLIGHT)
        b.add_center((-l / 2 - 0.01, side * (w / 2 - 0.2), z0 + 0.35 * h + 0.15), (0.01, 0.12, 0.08),
                     TAILLIGHT)
    b.add_center((front - 0.01, 0.0, z0 + 0.5), (0.01, 0.26, 0.06), PLATE)


def _bus(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    z0 = -h / 2
    r = 0.52
    band_lo, band_hi = z0 + 0.42 * h, z0 + 0.88 * h
    b.add((-l / 2 + 0.02, -w / 2, z0 + 0.32), (l / 2 - 0.02, w / 2, band_lo), PAINT, app.base)
    b.add((-l / 2 + 0.02, -w / 2 + 0.02, band_lo), (l / 2 - 0.02, w / 2 - 0.02, band_hi),
          GREENHOUSE, app.base)
    b.add((-l / 2 + 0.02, -w / 2, band_hi), (l / 2 - 0.02, w / 2, h / 2), PAINT, app.base)
    for x in (l / 2 - 2.4, -l / 2 + 2.8):
        for side in (1.0, -1.0):
            b.add_center((x, side * (w / 2 - 0.16), z0 + r), (r, 0.15, r), TYRE)
    for side in (1.0, -1.0):
        b.add_center((l / 2 - 0.01, side * (w / 2 - 0.35), z0 + 0.75), (0.01, 0.2, 0.09), HEADLIGHT)
        b.add_center((-l / 2 + 0.01, side * (w / 2 - 0.2), z0 + 1.0), (0.01, 0.12, 0.2), TAILLIGHT)
    b.add_center((l / 2 - 0.01, 0.0, z0 + 0.55), (0.01, 0.26, 0.06), PLATE)


BUILDERS = {"car": _car, "truck": _truck, "bus": _bus}
"""Vehicle builders: kind -> f(builder, w, l, h, appearance)."""
