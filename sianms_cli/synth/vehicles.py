"""Shapes of vehicles (cars of eight models, trucks, buses, trailers, construction
plant) as cuboid parts; see shapes.py for the frame and the builder.

Every builder draws in metres in the object frame (x forward, y left, z up, box centre
at the origin) and lets `Builder.fitted` stretch the union of its parts onto the box, so
a detail may stand proud of a body face only inside the box's extents. Details differ by
side (a mark on one flank only) and by end (head lights and grille at the front, rear
lights, tow bar, spare wheel at the back), so the front, rear and side views of one
vehicle differ while its colour, model and details identify it in every view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sianms_cli.synth.appearance import TWO_TONE_ROOF, Appearance
from sianms_cli.synth.shapes import CONCRETE, GREENHOUSE, HEADLIGHT, METAL, PAINT, PAINT2, PLATE, REFLECTOR, \
    TAILLIGHT, TRIM, TYRE, Builder

# Amber albedo of indicator-style lamps (beacons, side markers) drawn with the TAILLIGHT material.
_AMBER = (0.60, 0.28, 0.02)
# Road dirt on the sills: a dull grey-brown (our own choice of tone).
_MUD = np.array([0.06, 0.05, 0.04], np.float32)
_CHROME = (0.55, 0.56, 0.58)  # linear albedo of a bright metal grille
_FACE = 0.02     # how far (m) a body face sits inside the box ends, leaving room for lamps and plates
_FLANK = 0.015   # how far (m) the body sides sit inside the box sides, leaving room for marks and hubs


@dataclass(frozen=True)
class CarModel:
    """Side-view proportions of one car model, nominal values before per-instance jitter.

    Heights are fractions of the box height h above the ground: clearance (underbody),
    nose (bonnet top at the front), belt (window sill under the cabin), tail (boot lid,
    tailgate or bed rim at the back). Positions along the length are fractions of the box
    length l in [-0.5, 0.5] (+ forward): roof_rear, roof_front (the flat roof);
    screen_front, screen_rear (base of the windscreen and of the rear screen: the glazing
    steps down to half height between them and the roof); glazed_from (glazing starts
    here; behind it a van's cargo sides are body-coloured). cabin_width: fraction of the
    box width; wheel_radius: fraction of h; wheel_front, wheel_rear: axle positions.
    headlight, taillight: (half width, half height) m of each lamp; grille: (half width as
    a fraction of w, half height m); open_bed: an open cargo bed behind the cab.
    """

    clearance: float
    nose: float
    belt: float
    tail: float
    roof_rear: float
    roof_front: float
    screen_front: float
    screen_rear: float
    glazed_from: float
    cabin_width: float
    wheel_radius: float
    wheel_front: float
    wheel_rear: float
    headlight: tuple[float, float]
    taillight: tuple[float, float]
    grille: tuple[float, float]
    open_bed: bool = False


# Our own estimates from typical side views of each body type (e.g. Toyota Camry, VW Golf,
# Volvo V60, Toyota RAV4, Ford F-150, Ford Transit, Honda Odyssey, BMW 2 Series), in the
# order of appearance.CAR_VARIANTS. Lamps: wide, thin lamps on sedans and coupes, tall
# vertical rear lamps on estates, vans and pickups.
CAR_MODELS = (
    CarModel(0.10, 0.55, 0.60, 0.63, -0.25, 0.06, 0.23, -0.38, -0.5, 0.84, 0.20, 0.31, -0.30,
             (0.20, 0.05), (0.19, 0.06), (0.25, 0.07)),                                  # sedan
    CarModel(0.10, 0.55, 0.60, 0.60, -0.34, 0.06, 0.21, -0.46, -0.5, 0.85, 0.21, 0.33, -0.33,
             (0.17, 0.07), (0.11, 0.10), (0.22, 0.06)),                                  # hatchback
    CarModel(0.10, 0.54, 0.59, 0.59, -0.46, 0.10, 0.26, -0.48, -0.5, 0.86, 0.20, 0.31, -0.30,
             (0.19, 0.06), (0.07, 0.15), (0.24, 0.07)),                                  # estate
    CarModel(0.15, 0.64, 0.64, 0.64, -0.40, 0.12, 0.27, -0.46, -0.5, 0.88, 0.22, 0.31, -0.31,
             (0.18, 0.08), (0.12, 0.09), (0.28, 0.12)),                                  # SUV
    CarModel(0.16, 0.66, 0.66, 0.60, -0.13, 0.12, 0.25, -0.13, -0.5, 0.86, 0.21, 0.34, -0.31,
             (0.15, 0.11), (0.06, 0.16), (0.32, 0.14), open_bed=True),                   # pickup
    CarModel(0.10, 0.46, 0.49, 0.49, -0.49, 0.33, 0.43, -0.49, 0.12, 0.94, 0.16, 0.37, -0.33,
             (0.13, 0.12), (0.07, 0.20), (0.30, 0.10)),                                  # van
    CarModel(0.10, 0.50, 0.53, 0.53, -0.44, 0.20, 0.36, -0.47, -0.5, 0.90, 0.18, 0.33, -0.31,
             (0.21, 0.09), (0.08, 0.17), (0.25, 0.07)),                                  # minivan
    CarModel(0.09, 0.58, 0.66, 0.67, -0.17, 0.00, 0.20, -0.35, -0.5, 0.80, 0.23, 0.32, -0.30,
             (0.23, 0.045), (0.22, 0.05), (0.20, 0.06)),                                 # coupe
)
"""Car models, index = `Appearance.variant` (names in appearance.CAR_VARIANTS)."""

# Per-instance spread of each jittered proportion (`VehicleDetails.jitter` order), our own
# estimate of the spread between makes of one body type: belt, cabin rear, cabin front
# (fractions), cabin width (fraction), bonnet height (fraction), wheel radius (fraction),
# headlight and rear-light size (relative).
_JITTER_SCALE = np.array([0.015, 0.015, 0.015, 0.02, 0.015, 0.008, 0.12, 0.12])
# A spoiler sits on the boot lid of cars whose rear screen ends ahead of this fraction of
# the length (a boot behind), at the roof's rear edge of the others.
_SPOILER_ON_BOOT_BEHIND = -0.4


@dataclass(frozen=True)
class _CarLines:
    """One car's outline in metres, object frame, after the per-instance jitter: heights z
    of the underbody (clearance), sill top, waist (top of the full-length body), nose,
    belt, tail and roof top (top); x of the roof's ends, of the screens' bases; y of the
    cabin's side (cabin_half) and of the body's flank (side_y); x of the body's end faces."""

    clearance: float
    sill: float
    waist: float
    nose: float
    belt: float
    tail: float
    top: float
    roof_rear: float
    roof_front: float
    screen_front: float
    screen_rear: float
    cabin_half: float
    side_y: float
    front: float
    rear: float


def _car_lines(m: CarModel, w: float, l: float, h: float, jitter: np.ndarray, rails: float) -> _CarLines:
    """The outline of model m in a w x l x h box with jitter (8,) already scaled, leaving
    `rails` metres on top for roof rails."""
    z0 = -h / 2
    clearance = z0 + m.clearance * h
    belt = z0 + (m.belt + jitter[0]) * h
    nose = min(z0 + (m.nose + jitter[4]) * h, belt)
    tail = z0 + (m.tail + jitter[0]) * h
    # A pickup's full-length body stops at its bed floor.
    waist = min(nose, belt, tail, z0 + 0.45 * h) if m.open_bed else min(nose, belt, tail)
    roof_rear = max((m.roof_rear + jitter[1]) * l, -l / 2 + _FACE)
    return _CarLines(
        clearance=clearance, sill=clearance + 0.09 * h, waist=waist, nose=nose, belt=belt, tail=tail,
        top=h / 2 - rails, roof_rear=roof_rear, roof_front=(m.roof_front + jitter[2]) * l,
        screen_front=min((m.screen_front + jitter[2]) * l, l / 2 - 0.3),
        screen_rear=max(min((m.screen_rear + jitter[1]) * l, roof_rear), -l / 2 + _FACE),
        cabin_half=min(m.cabin_width + jitter[3], 0.96) * w / 2, side_y=w / 2 - _FLANK,
        front=l / 2 - _FACE, rear=-l / 2 + _FACE)


def _car(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    m = CAR_MODELS[app.variant % len(CAR_MODELS)]
    d = app.vehicle
    jitter = np.asarray(d.jitter, np.float64) * _JITTER_SCALE
    rails = 0.05 if d.roof_rails else 0.0
    c = _car_lines(m, w, l, h, jitter, rails)
    sill_colour = np.asarray(app.base, np.float32) * (1 - d.dirt) + _MUD * d.dirt
    b.add((c.rear, -c.side_y, c.clearance), (c.front, c.side_y, c.sill), PAINT, sill_colour)
    b.add((c.rear, -c.side_y, c.sill), (c.front, c.side_y, c.waist), PAINT, app.base)
    _car_upper_body(b, m, c, app)
    _car_glazing(b, m, c, l, app)
    _car_wheels(b, m, w, l, h, app, jitter[5])
    _car_front(b, m, c, w, l, app, 1 + jitter[6])
    _car_rear(b, m, c, w, l, app, 1 + jitter[7])
    if d.decal_side:
        dx, half_len, dz, half_h = (float(v) for v in d.decal)
        y_in, y_out = d.decal_side * c.side_y, d.decal_side * (c.side_y + 0.006)
        z_mid = c.sill + dz * (c.waist - c.sill)
        half_z = min(half_h, 0.45) * (c.waist - c.sill)
        b.add(((dx - half_len) * l, min(y_in, y_out), z_mid - half_z),
              ((dx + half_len) * l, max(y_in, y_out), z_mid + half_z), PAINT2, d.decal_colour)
    if d.roof_rails:
        for side in (1.0, -1.0):
            y = side * 0.8 * c.cabin_half
            b.add((c.roof_rear + 0.08, y - 0.025, c.top), (c.roof_front - 0.08, y + 0.025, c.top + rails), METAL)


def _car_upper_body(b: Builder, m: CarModel, c: _CarLines, app: Appearance) -> None:
    """Bonnet, the body under the cabin and the boot (or an open bed) above the waist."""
    for (x_lo, x_hi), z_hi in (((c.screen_front, c.front), c.nose), ((c.screen_rear, c.screen_front), c.belt)):
        if z_hi > c.waist + 1e-6:
            b.add((x_lo, -c.side_y, c.waist), (x_hi, c.side_y, z_hi), PAINT, app.base)
    if not m.open_bed:
        if c.tail > c.waist + 1e-6 and c.screen_rear > c.rear + 0.05:
            b.add((c.rear, -c.side_y, c.waist), (c.screen_rear, c.side_y, c.tail), PAINT, app.base)
        return
    # Open bed: two side walls and a tailgate around a floor at the waist.
    wall = 0.06
    for side in (1.0, -1.0):
        y_out, y_in = side * c.side_y, side * (c.side_y - wall)
        b.add((c.rear, min(y_out, y_in), c.waist), (c.screen_rear - wall, max(y_out, y_in), c.tail), PAINT, app.base)
    b.add((c.rear, -c.side_y + wall, c.waist), (c.rear + wall, c.side_y - wall, c.tail), PAINT, app.base)


def _car_glazing(b: Builder, m: CarModel, c: _CarLines, l: float, app: Appearance) -> None:
    """The roof over the cabin and the half-height steps of the raked front and rear screens."""
    roof_colour = app.secondary if app.pattern == TWO_TONE_ROOF else app.base
    glazed_from = max(m.glazed_from * l, c.roof_rear)
    if glazed_from > c.roof_rear + 1e-6:
        # A panel van's cargo sides and roof, body-coloured and unglazed.
        b.add((c.roof_rear, -c.cabin_half, c.belt), (glazed_from, c.cabin_half, c.top), PAINT, app.base)
    b.add((glazed_from, -c.cabin_half, c.belt), (c.roof_front, c.cabin_half, c.top), GREENHOUSE, roof_colour)
    step = c.belt + 0.45 * (c.top - c.belt)
    b.add((c.roof_front, -c.cabin_half, c.belt), (c.screen_front, c.cabin_half, step), GREENHOUSE, roof_colour)
    if c.screen_rear < c.roof_rear - 0.05:
        b.add((c.screen_rear, -c.cabin_half, c.belt), (c.roof_rear, c.cabin_half, step), GREENHOUSE, roof_colour)


def _car_wheels(b: Builder, m: CarModel, w, l, h, app: Appearance, radius_jitter: float) -> None:
    """Four tyres, each with a hub standing 12 mm proud of it in the rim's colour and size."""
    d = app.vehicle
    r = float(np.clip((m.wheel_radius + radius_jitter) * h, 0.26, 0.48))
    tyre = 0.1
    hub = d.rim_size * r * 0.62
    for x in (m.wheel_front * l, m.wheel_rear * l):
        for side in (1.0, -1.0):
            b.add_center((x, side * (w / 2 - 0.012 - tyre), -h / 2 + r), (r, tyre, r), TYRE)
            b.add_center((x, side * (w / 2 - 0.006), -h / 2 + r), (hub, 0.006, hub), METAL, d.rim)


def _car_front(b: Builder, m: CarModel, c: _CarLines, w, l, app: Appearance, lamp_scale: float) -> None:
    """Bumper, grille, head lights and plate on the front face."""
    bumper_top = c.clearance + 0.17
    b.add((c.front - 0.01, -w / 2 + 0.03, c.clearance), (c.front + 0.014, w / 2 - 0.03, bumper_top), TRIM)
    grille_half_w, grille_half_h = m.grille[0] * w, m.grille[1]
    grille_top = min(bumper_top + 2 * grille_half_h, c.nose - 0.03)
    grille_material, grille_colour = (METAL, _CHROME) if app.vehicle.chrome_grille else (TRIM, None)
    b.add((c.front - 0.01, -grille_half_w, bumper_top), (c.front + 0.012, grille_half_w, grille_top),
          grille_material, grille_colour)
    lamp_w, lamp_h = m.headlight[0] * lamp_scale, m.headlight[1] * lamp_scale
    for side in (1.0, -1.0):
        b.add_center((l / 2 - 0.01, side * (w / 2 - 0.05 - lamp_w), c.nose - 0.05 - lamp_h), (0.01, lamp_w, lamp_h),
                     HEADLIGHT)
    b.add_center((l / 2 - 0.01, 0.0, c.clearance + 0.1), (0.01, 0.26, 0.06), PLATE)


def _car_rear(b: Builder, m: CarModel, c: _CarLines, w, l, app: Appearance, lamp_scale: float) -> None:
    """Bumper, rear lights, plate and the rear extra (spoiler, tow bar or spare wheel)."""
    d = app.vehicle
    bumper_top = c.clearance + 0.17
    b.add((c.rear - 0.014, -w / 2 + 0.03, c.clearance), (c.rear + 0.01, w / 2 - 0.03, bumper_top), TRIM)
    lamp_w, lamp_h = m.taillight[0] * lamp_scale, m.taillight[1] * lamp_scale
    lamp_z = max(c.tail - 0.05 - lamp_h, bumper_top + lamp_h + 0.02)
    for side in (1.0, -1.0):
        b.add_center((-l / 2 + 0.01, side * (w / 2 - 0.04 - lamp_w), lamp_z), (0.01, lamp_w, lamp_h), TAILLIGHT)
    b.add_center((-l / 2 + 0.01, 0.0, bumper_top + 0.1), (0.01, 0.26, 0.06), PLATE)
    if d.rear_extra == 1 and c.screen_rear > _SPOILER_ON_BOOT_BEHIND * l:
        b.add((c.rear, -0.42 * w, c.tail), (c.rear + 0.2, 0.42 * w, c.tail + 0.04), PAINT2, app.base)
    elif d.rear_extra == 1:
        b.add((max(c.roof_rear - 0.1, c.rear), -0.9 * c.cabin_half, c.top - 0.06),
              (c.roof_rear + 0.02, 0.9 * c.cabin_half, c.top - 0.005), PAINT2, app.base)
    elif d.rear_extra == 2:
        b.add((-l / 2 - 0.1, -0.04, c.clearance + 0.03), (c.rear + 0.05, 0.04, c.clearance + 0.11), METAL)
    elif d.rear_extra == 3:
        r = min(0.33, 0.45 * (c.tail - bumper_top))
        b.add_center((-l / 2 - 0.1, 0.0, bumper_top + 0.05 + r), (0.11, r, r), TYRE)


def _cab(b: Builder, w, front, cab_len, z0, cab_h, app, chrome: bool) -> None:
    """A lorry's cab from x = front - cab_len to front: body, glazing, bumper, grille, lamps, plate."""
    b.add((front - cab_len, -w / 2 + 0.02, z0 + 0.45), (front - 0.02, w / 2 - 0.02, z0 + 0.58 * cab_h), PAINT,
          app.base)
    b.add((front - cab_len, -w / 2 + 0.06, z0 + 0.58 * cab_h), (front - 0.25, w / 2 - 0.06, z0 + cab_h),
          GREENHOUSE, app.base)
    b.add((front - 0.05, -w / 2 + 0.05, z0 + 0.3), (front, w / 2 - 0.05, z0 + 0.62), TRIM)
    grille_material, grille_colour = (METAL, _CHROME) if chrome else (TRIM, None)
    b.add((front - 0.03, -0.3 * w, z0 + 0.7), (front - 0.005, 0.3 * w, z0 + 0.5 * cab_h), grille_material,
          grille_colour)
    for side in (1.0, -1.0):
        b.add_center((front - 0.01, side * (w / 2 - 0.3), z0 + 0.8), (0.01, 0.17, 0.08), HEADLIGHT)
    b.add_center((front - 0.005, 0.0, z0 + 0.48), (0.005, 0.26, 0.06), PLATE)


def _heavy_wheels(b: Builder, w, xs, z0, r, app, tyre=0.16) -> None:
    """Tyres at axle positions xs with hubs in the rim colour, 10 mm proud of the tyre."""
    hub = app.vehicle.rim_size * r * 0.62
    for x in xs:
        for side in (1.0, -1.0):
            b.add_center((x, side * (w / 2 - 0.01 - tyre), z0 + r), (r, tyre, r), TYRE)
            b.add_center((x, side * (w / 2 - 0.005), z0 + r), (hub, 0.005, hub), METAL, app.vehicle.rim)


def _rear_lamps(b: Builder, w, x_back, z, half=(0.12, 0.08)) -> None:
    """Two rear lamps of half width and height `half` (m) facing -x from x_back, centred at z."""
    for side in (1.0, -1.0):
        b.add_center((x_back + 0.01, side * (w / 2 - 0.2), z), (0.01, half[0], half[1]), TAILLIGHT)


def _truck(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """Variant 0: box body; 1: flatbed with a headboard and a tarpaulin load; 2: tipper."""
    variant = app.variant % 3
    z0 = -h / 2
    cab_len = min(2.3, 0.38 * l)
    cab_h = 0.8 * h if variant == 0 else h
    front = l / 2
    _cab(b, w, front, cab_len, z0, cab_h, app, app.vehicle.chrome_grille)
    cargo_front = front - cab_len - 0.12
    deck = z0 + 0.35 * h
    b.add((-l / 2 + 0.3, -w / 2 + 0.35, z0 + 0.35), (cargo_front, w / 2 - 0.35, deck), TRIM)
    if variant == 0:
        b.add((-l / 2 + 0.03, -w / 2, deck), (cargo_front, w / 2, h / 2), PAINT2, app.secondary)
        # Roller door on the back, a shade darker than the box.
        b.add((-l / 2, -w / 2 + 0.12, deck + 0.1), (-l / 2 + 0.03, w / 2 - 0.12, h / 2 - 0.12), METAL,
              np.asarray(app.secondary, np.float32) * np.float32(0.75))
    elif variant == 1:
        b.add((-l / 2, -w / 2, deck), (cargo_front, w / 2, deck + 0.15), METAL, (0.12, 0.12, 0.13))
        b.add((cargo_front - 0.1, -w / 2 + 0.05, deck + 0.15), (cargo_front, w / 2 - 0.05, z0 + 0.9 * cab_h),
              METAL)
        load_len = (0.45 + 0.1 * float(app.vehicle.jitter[0])) * (cargo_front + l / 2)
        b.add((cargo_front - 0.15 - load_len, -w / 2 + 0.1, deck + 0.15),
              (cargo_front - 0.15, w / 2 - 0.1, z0 + 0.75 * cab_h), PAINT2, app.secondary)
    else:
        wall = 0.07
        rim = z0 + 0.8 * h
        b.add((-l / 2 + 0.1, -w / 2, deck), (cargo_front, w / 2, deck + 0.12), PAINT2, app.secondary)
        for side in (1.0, -1.0):
            b.add((-l / 2 + 0.1, min(side * w / 2, side * (w / 2 - wall)), deck + 0.12),
                  (cargo_front, max(side * w / 2, side * (w / 2 - wall)), rim), PAINT2, app.secondary)
        b.add((-l / 2 + 0.1, -w / 2 + wall, deck + 0.12), (-l / 2 + 0.1 + wall, w / 2 - wall, rim), PAINT2,
              app.secondary)
        b.add((cargo_front - wall, -w / 2 + wall, deck + 0.12), (cargo_front, w / 2 - wall, rim), PAINT2,
              app.secondary)
        # The load (gravel, spoil) a little below the rim.
        b.add((-l / 2 + 0.1 + wall, -w / 2 + wall, deck + 0.12), (cargo_front - wall, w / 2 - wall, rim - 0.25),
              CONCRETE)
    _heavy_wheels(b, w, (front - 0.55 * cab_len, -l / 2 + 1.2, -l / 2 + 2.3), z0, 0.5, app)
    _rear_lamps(b, w, -l / 2 - 0.02, deck - 0.12)


def _trailer(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """A semi-trailer without its tractor, kingpin end at +x resting on its landing legs.

    Variant 0: box van with rear doors; 1: flatbed with a tarpaulin load; 2: tanker (a
    tank of three stacked boxes for its round section, a catwalk on top)."""
    variant = app.variant % 3
    z0 = -h / 2
    r = 0.5
    floor = z0 + min(1.25, 0.32 * h)
    chassis = floor - 0.25
    b.add((-l / 2 + 0.3, -0.55, chassis), (l / 2 - 0.4, 0.55, floor), TRIM)
    if variant == 0:
        b.add((-l / 2 + 0.03, -w / 2, floor), (l / 2, w / 2, h / 2), PAINT, app.base)
        b.add((-l / 2, -w / 2 + 0.06, floor + 0.05), (-l / 2 + 0.03, w / 2 - 0.06, h / 2 - 0.08), METAL,
              np.asarray(app.base, np.float32) * np.float32(0.8))
        b.add((-l / 2 - 0.01, -0.02, floor + 0.05), (-l / 2 + 0.03, 0.02, h / 2 - 0.08), TRIM)
    elif variant == 1:
        b.add((-l / 2, -w / 2, floor), (l / 2, w / 2, floor + 0.2), METAL, (0.10, 0.10, 0.11))
        # Two tarpaulin-covered loads with a gap, the rear one lower.
        load_len = (0.35 + 0.05 * float(app.vehicle.jitter[0])) * l
        b.add((l / 2 - 0.2 - load_len, -w / 2 + 0.05, floor + 0.2), (l / 2 - 0.2, w / 2 - 0.05, h / 2), PAINT2,
              app.secondary)
        b.add((l / 2 - 0.8 - 2 * load_len, -w / 2 + 0.15, floor + 0.2), (l / 2 - 0.6 - load_len, w / 2 - 0.15,
              floor + 0.6 * (h / 2 - floor)), PAINT2, app.secondary)
    else:
        tank_lo, tank_hi = floor - 0.1, h / 2 - 0.12
        band = 0.18 * (tank_hi - tank_lo)
        x_lo, x_hi = -l / 2 + 0.3, l / 2 - 0.1
        b.add((x_lo, -w / 2, tank_lo + band), (x_hi, w / 2, tank_hi - band), PAINT, app.base)
        b.add((x_lo + 0.2, -0.3 * w, tank_lo), (x_hi - 0.2, 0.3 * w, tank_lo + band), PAINT, app.base)
        b.add((x_lo + 0.2, -0.3 * w, tank_hi - band), (x_hi - 0.2, 0.3 * w, tank_hi), PAINT, app.base)
        b.add((x_lo + 0.5, -0.2 * w, tank_hi), (x_hi - 0.5, 0.2 * w, h / 2), METAL)
        b.add((-l / 2 + 0.05, -0.25, tank_lo + 0.3), (x_lo, 0.25, tank_hi - band), METAL)
    # Landing legs down at the kingpin end, on foot pads.
    leg_x = l / 2 - min(2.0, 0.2 * l)
    for side in (1.0, -1.0):
        b.add_center((leg_x, side * 0.85, (z0 + 0.05 + chassis) / 2), (0.06, 0.06, (chassis - z0 - 0.05) / 2), METAL)
        b.add_center((leg_x, side * 0.85, z0 + 0.025), (0.15, 0.12, 0.025), METAL)
    # Rear under-ride guard with a retro-reflective strip; tandem axles near the rear.
    b.add((-l / 2 + 0.05, -w / 2 + 0.15, z0 + 0.45), (-l / 2 + 0.15, w / 2 - 0.15, z0 + 0.6), METAL)
    b.add((-l / 2 + 0.035, -w / 2 + 0.15, z0 + 0.5), (-l / 2 + 0.05, w / 2 - 0.15, z0 + 0.56), REFLECTOR)
    _heavy_wheels(b, w, (-l / 2 + 1.3, -l / 2 + 2.6), z0, r, app)
    _rear_lamps(b, w, -l / 2 + 0.04, floor - 0.12)


def _construction(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    """Variant 0: tracked excavator (cab on its left, boom and bucket ahead); 1: wheel
    loader (bucket on arms ahead of a central cab); 2: road roller (drum ahead). Each has an
    amber beacon on the cab roof."""
    variant = app.variant % 3
    z0 = -h / 2
    dark = app.secondary
    if variant == 0:
        track_top = z0 + 0.28 * h
        for side in (1.0, -1.0):
            b.add((-0.45 * l, min(side * w / 2, side * (w / 2 - 0.6)), z0),
                  (0.12 * l, max(side * w / 2, side * (w / 2 - 0.6)), track_top), TRIM)
        house_lo, house_hi = track_top + 0.12, z0 + 0.62 * h
        b.add((-0.5 * l, -w / 2 + 0.05, house_lo), (0.02 * l, w / 2 - 0.05, house_hi), PAINT, app.base)
        b.add((-0.5 * l, -w / 2 + 0.05, house_lo), (-0.4 * l, w / 2 - 0.05, house_hi + 0.1), PAINT2, dark)
        cab_hi = h / 2 - 0.12
        b.add((-0.12 * l, w / 2 - 1.05, house_hi), (0.05 * l, w / 2 - 0.05, cab_hi), GREENHOUSE, app.base)
        b.add_center((-0.05 * l, w / 2 - 0.55, cab_hi + 0.06), (0.08, 0.08, 0.06), TAILLIGHT, _AMBER)
        # Boom rising ahead of the house, the arm hanging down, the bucket near the ground.
        boom_y = (-0.35, 0.1)
        b.add((0.02 * l, boom_y[0], house_lo + 0.2), (0.16 * l, boom_y[1], h / 2 - 0.35), PAINT, app.base)
        b.add((0.1 * l, boom_y[0], h / 2 - 0.55), (0.42 * l, boom_y[1], h / 2 - 0.2), PAINT, app.base)
        b.add((0.36 * l, boom_y[0] + 0.05, z0 + 0.3 * h), (0.44 * l, boom_y[1] - 0.05, h / 2 - 0.3), PAINT, app.base)
        b.add((0.32 * l, -0.6, z0), (0.5 * l, 0.35, z0 + 0.32 * h), METAL)
        return
    if variant == 1:
        r = 0.2 * h
        body_lo = z0 + 0.2 * h
        b.add((-0.5 * l, -w / 2 + 0.2, body_lo), (-0.05 * l, w / 2 - 0.2, z0 + 0.55 * h), PAINT, app.base)
        b.add((-0.5 * l, -w / 2 + 0.25, body_lo), (-0.44 * l, w / 2 - 0.25, z0 + 0.5 * h), PAINT2, dark)
        b.add((-0.2 * l, -w / 2 + 0.35, z0 + 0.55 * h), (0.02 * l, w / 2 - 0.35, h / 2 - 0.12), GREENHOUSE, app.base)
        b.add_center((-0.09 * l, 0.0, h / 2 - 0.06), (0.08, 0.08, 0.06), TAILLIGHT, _AMBER)
        b.add((-0.05 * l, -0.6, z0 + 0.3 * h), (0.08 * l, 0.6, z0 + 0.5 * h), PAINT2, dark)
        for side in (1.0, -1.0):
            b.add((0.05 * l, side * 0.55 - 0.12, z0 + 0.3 * h), (0.36 * l, side * 0.55 + 0.12, z0 + 0.45 * h), PAINT,
                  app.base)
        b.add((0.34 * l, -w / 2, z0 + 0.04), (0.5 * l, w / 2, z0 + 0.36 * h), METAL)
        _heavy_wheels(b, w - 0.3, (0.2 * l, -0.3 * l), z0, r, app, tyre=0.3)
        _rear_lamps(b, w - 0.4, -0.5 * l, z0 + 0.45 * h, (0.06, 0.06))
        return
    drum_r = 0.24 * h
    b.add((0.16 * l, -w / 2, z0), (0.5 * l, w / 2, z0 + 2 * drum_r), METAL, (0.18, 0.18, 0.19))
    b.add((0.14 * l, -w / 2 + 0.05, z0 + 2 * drum_r), (0.5 * l, w / 2 - 0.05, z0 + 2 * drum_r + 0.15), PAINT,
          app.base)
    b.add((-0.5 * l, -w / 2 + 0.2, z0 + 0.28 * h), (0.16 * l, w / 2 - 0.2, z0 + 0.58 * h), PAINT, app.base)
    b.add((-0.3 * l, -w / 2 + 0.3, z0 + 0.58 * h), (0.02 * l, w / 2 - 0.3, h / 2 - 0.12), GREENHOUSE, app.base)
    b.add_center((-0.14 * l, 0.0, h / 2 - 0.06), (0.08, 0.08, 0.06), TAILLIGHT, _AMBER)
    _heavy_wheels(b, w - 0.3, (-0.28 * l,), z0, 0.3 * h, app, tyre=0.25)
    _rear_lamps(b, w - 0.4, -0.5 * l, z0 + 0.45 * h, (0.06, 0.06))


def _bus(b: Builder, w: float, l: float, h: float, app: Appearance) -> None:
    z0 = -h / 2
    r = 0.52
    band_lo, band_hi = z0 + 0.42 * h, z0 + 0.88 * h
    b.add((-l / 2 + 0.02, -w / 2, z0 + 0.32), (l / 2 - 0.02, w / 2, band_lo), PAINT, app.base)
    b.add((-l / 2 + 0.02, -w / 2 + 0.02, band_lo), (l / 2 - 0.02, w / 2 - 0.02, band_hi),
          GREENHOUSE, app.base)
    b.add((-l / 2 + 0.02, -w / 2, band_hi), (l / 2 - 0.02, w / 2, h / 2), PAINT, app.base)
    _heavy_wheels(b, w, (l / 2 - 2.4, -l / 2 + 2.8), z0, r, app, tyre=0.15)
    for side in (1.0, -1.0):
        b.add_center((l / 2 - 0.01, side * (w / 2 - 0.35), z0 + 0.75), (0.01, 0.2, 0.09), HEADLIGHT)
        b.add_center((-l / 2 + 0.01, side * (w / 2 - 0.2), z0 + 1.0), (0.01, 0.12, 0.2), TAILLIGHT)
    b.add_center((l / 2 - 0.01, 0.0, z0 + 0.55), (0.01, 0.26, 0.06), PLATE)
    # Destination display over the windscreen; engine grille low on the back.
    b.add_center((l / 2 - 0.01, 0.0, (band_hi + h / 2) / 2), (0.01, 0.35 * w, 0.4 * (h / 2 - band_hi)), TAILLIGHT,
                 _AMBER)
    b.add((-l / 2, -0.35 * w, z0 + 0.4), (-l / 2 + 0.02, 0.35 * w, band_lo - 0.1), TRIM)


BUILDERS = {"car": _car, "truck": _truck, "bus": _bus, "trailer": _trailer, "construction": _construction}
"""Vehicle builders: kind -> f(builder, w, l, h, appearance)."""
