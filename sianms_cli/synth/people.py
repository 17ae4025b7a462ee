"""Shapes of people and of two-wheelers with or without a rider as cuboid parts; see
shapes.py for the frame and the builder."""

from __future__ import annotations

import numpy as np

from sianms_cli.synth.appearance import BACKPACK, Appearance
from sianms_cli.synth.shapes import CLOTH, HAIR, HEADLIGHT, METAL, PAINT, PAINT2, SKIN, TAILLIGHT, TRIM, TYRE, \
    Builder, ring


def _person(b: Builder, h: float, stride: float, x0: float, z_feet: float, app: Appearance,
            seated: bool = False) -> None:
    """A person of height h standing (or seated on a saddle at hip height) at x0, z_feet."""
    child = h < 1.45
    head_h = (0.16 if child else 0.13) * h
    leg_h = 0.47 * h
    torso_top = h - head_h - 0.03 * h
    torso_hw = 0.15 if child else 0.19
    torso_hx = 0.09 if child else 0.11
    sleeves = app.top if app.variant % 2 == 0 else app.skin
    if seated:
        # Thighs forward to the handlebar side, shins down to the pedals.
        hip = z_feet + leg_h
        for side, shift in ((1.0, stride), (-1.0, -stride)):
            b.add((x0, side * 0.1 - 0.07, hip - 0.07), (x0 + 0.35, side * 0.1 + 0.07, hip + 0.07),
                  CLOTH, app.bottom)
            b.add((x0 + 0.25 + shift, side * 0.1 - 0.06, z_feet), (x0 + 0.37 + shift, side * 0.1 + 0.06,
                  hip), CLOTH, app.bottom)
        arm_x = (x0 + 0.05, x0 + 0.55)
    else:
        for side, shift in ((1.0, stride), (-1.0, -stride)):
            b.add_center((x0 + shift, side * 0.09, z_feet + leg_h / 2), (0.075, 0.075, leg_h / 2),
                         CLOTH, app.bottom)
            b.add_center((x0 + shift + 0.04, side * 0.09, z_feet + 0.03), (0.12, 0.06, 0.03), TRIM)
        arm_x = None
    b.add((x0 - torso_hx, -torso_hw, z_feet + leg_h), (x0 + torso_hx, torso_hw, z_feet + torso_top),
          CLOTH, app.top)
    arm_lo = z_feet + leg_h + 0.04 * h
    for side, shift in ((1.0, -stride), (-1.0, stride)):
        y = side * (torso_hw + 0.05)
        if arm_x is None:
            b.add_center((x0 + 0.6 * shift, y, (arm_lo + z_feet + torso_top) / 2),
                         (0.05, 0.05, (z_feet + torso_top - arm_lo) / 2), CLOTH, sleeves)
        else:
            b.add((arm_x[0], y - 0.05, z_feet + torso_top - 0.12), (arm_x[1], y + 0.05,
                  z_feet + torso_top - 0.02), CLOTH, sleeves)
    head_c = (x0, 0.0, z_feet + h - head_h / 2)
    b.add_center(head_c, (0.095, 0.08, head_h / 2), SKIN, app.skin)
    hair_material, hair_colour = (PAINT2, app.secondary) if seated else (HAIR, app.hair)
    b.add((x0 - 0.11, -0.095, z_feet + h - 0.45 * head_h), (x0 + 0.07, 0.095, z_feet + h),
          hair_material, hair_colour)
    if app.pattern == BACKPACK and not seated:
        b.add((x0 - torso_hx - 0.16, -0.15, z_feet + leg_h + 0.12 * h),
              (x0 - torso_hx, 0.15, z_feet + torso_top - 0.03), PAINT2, app.secondary)


def _pedestrian(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    _person(b, h, stride=max(0.0, l / 2 - 0.12), x0=0.0, z_feet=-h / 2, app=app)


def _cycle(b: Builder, w: float, l: float, h: float, app: Appearance, motor: bool) -> None:
    r = 0.3 if motor else 0.34
    wheelbase = l - 2 * r
    z0 = -h / 2
    axle = z0 + r
    thick = 0.07 if motor else 0.025
    ring(b, wheelbase / 2, axle, r, 0.06 if motor else 0.02, thick, TYRE)
    ring(b, -wheelbase / 2, axle, r, 0.06 if motor else 0.02, thick, TYRE)
    frame_top = axle + (0.55 if motor else 0.45)
    seat_x = -0.18 * wheelbase
    bar_x = 0.42 * wheelbase
    if motor:
        b.add((-0.3 * wheelbase, -0.16, axle - 0.1), (0.3 * wheelbase, 0.16, axle + 0.3), METAL)
        b.add((0.0, -0.18, axle + 0.3), (0.35 * wheelbase, 0.18, frame_top), PAINT, app.base)
        b.add((-0.45 * wheelbase, -0.15, axle + 0.3), (0.0, 0.15, frame_top - 0.08), TRIM)
        b.add((-wheelbase / 2 - 0.1, -0.1, axle + 0.2), (-0.3 * wheelbase, 0.1, axle + 0.35), PAINT,
              app.base)
        b.add_center((wheelbase / 2 + 0.05, 0.0, frame_top), (0.03, 0.09, 0.06), HEADLIGHT)
        b.add_center((-wheelbase / 2 - 0.11, 0.0, axle + 0.32), (0.01, 0.07, 0.04), TAILLIGHT)
    else:
        b.add((seat_x, -0.02, frame_top - 0.04), (bar_x - 0.05, 0.02, frame_top), PAINT, app.base)
        b.add((seat_x - 0.02, -0.02, axle), (seat_x + 0.02, 0.02, frame_top), PAINT, app.base)
        b.add((-wheelbase / 2, -0.02, axle - 0.02), (seat_x, 0.02, axle + 0.02), PAINT, app.base)
        b.add((seat_x, -0.02, axle - 0.02), (bar_x - 0.05, 0.02, axle + 0.04), PAINT, app.base)
        b.add((seat_x - 0.1, -0.07, frame_top + 0.06), (seat_x + 0.1, 0.07, frame_top + 0.1), TRIM)
        b.add((seat_x - 0.015, -0.015, frame_top), (seat_x + 0.015, 0.015, frame_top + 0.06), METAL)
    fork_x = wheelbase / 2 - 0.05
    b.add((fork_x - 0.02, -0.03, axle), (fork_x + 0.02, 0.03, frame_top + 0.18), METAL)
    b.add((fork_x - 0.03, -w / 2, frame_top + 0.15), (fork_x + 0.03, w / 2, frame_top + 0.2), TRIM)
    if app.rider:
        seat_top = frame_top + (0.0 if motor else 0.1)
        rider_h = float(np.clip(h - (seat_top - z0) + 0.47 * 1.75, 1.5, 1.9))
        z_feet = seat_top - 0.47 * rider_h
        _person(b, rider_h, stride=0.08, x0=seat_x, z_feet=z_feet, app=app, seated=True)


BUILDERS = {
    "pedestrian": _pedestrian,
    "bicycle": lambda b, w, l, h, app: _cycle(b, w, l, h, app, motor=False),
    "motorcycle": lambda b, w, l, h, app: _cycle(b, w, l, h, app, motor=True),
}
"""Builders of people and two-wheelers: kind -> f(builder, w, l, h, appearance)."""
