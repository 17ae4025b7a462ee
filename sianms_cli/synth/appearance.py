"""Per-instance appearance and per-camera style of the synthetic world.

An `Appearance` is sampled once per object instance and reused in every frame and every
camera, so the same car keeps its colour, pattern and body style across contiguous
cameras; a `CameraStyle` is sampled once per camera and changes exposure, white balance,
noise and vignetting, so the same object is never rendered identically twice.
All colours are linear RGB albedos in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PATTERNS = ("solid", "two_tone_roof", "side_stripe", "lower_body", "decal", "backpack")
SOLID, TWO_TONE_ROOF, SIDE_STRIPE, LOWER_BODY, DECAL, BACKPACK = range(len(PATTERNS))

CAR_VARIANTS = ("sedan", "hatchback", "suv")

CLUTTER_KINDS = ("tree", "hedge", "fence", "street_light", "utility_pole", "sign", "traffic_light",
                 "hydrant", "bin", "bollard")
"""Unannotated street furniture and vegetation (owner -1 scenery, placed by clutter.py)."""

_BLACK = np.zeros(3, np.float32)


@dataclass(frozen=True)
class Appearance:
    """The look of one object instance.

    kind: object kind (see `objects.KINDS`); variant: body style (car: 0 sedan, 1 hatchback,
    2 SUV; person: 0 long sleeves, 1 short sleeves; barrier: 0 concrete, 1 plastic);
    base, secondary (3,) linear albedo of the main and the second colour; pattern: index
    into `PATTERNS`; pattern_param (4,): side stripe (height as a fraction of the part,
    half width m, -, -), lower body (split height fraction, -, -, -), decal (x and z centre
    as fractions in [-0.5, 0.5] of the part, half width m, half height m); glass (3,)
    albedo of the glazing; gloss in [0, 1] clear-coat strength; skin, hair, top, bottom
    (3,) for people and riders (helmet in `secondary`); rider: a bicycle or motorcycle
    carries a rider.
    """

    kind: str
    variant: int = 0
    base: np.ndarray = field(default_factory=lambda: np.full(3, 0.5, np.float32))
    secondary: np.ndarray = field(default_factory=lambda: np.full(3, 0.3, np.float32))
    pattern: int = SOLID
    pattern_param: np.ndarray = field(default_factory=lambda: np.zeros(4, np.float32))
    glass: np.ndarray = field(default_factory=lambda: np.array([0.04, 0.05, 0.06], np.float32))
    gloss: float = 0.5
    skin: np.ndarray = field(default_factory=lambda: _BLACK.copy())
    hair: np.ndarray = field(default_factory=lambda: _BLACK.copy())
    top: np.ndarray = field(default_factory=lambda: _BLACK.copy())
    bottom: np.ndarray = field(default_factory=lambda: _BLACK.copy())
    rider: bool = False


@dataclass(frozen=True)
class AppearanceTable:
    """Appearances of N objects as aligned arrays (row i = object index i).

    secondary (N,3), glass (N,3) float32 linear albedo; pattern (N,) int16;
    pattern_param (N,4) float32; gloss (N,) float32.
    """

    secondary: np.ndarray
    glass: np.ndarray
    pattern: np.ndarray
    pattern_param: np.ndarray
    gloss: np.ndarray


def stack_appearances(appearances, n_objects: int) -> AppearanceTable:
    """Stack a sequence of `Appearance` (index = object index) into an `AppearanceTable`
    of n_objects rows; rows past the end of the sequence get a plain grey look."""
    default = Appearance(kind="car")
    rows = list(appearances)[:n_objects]
    rows += [default] * (n_objects - len(rows))
    return AppearanceTable(
        secondary=np.array([a.secondary for a in rows], np.float32).reshape(-1, 3),
        glass=np.array([a.glass for a in rows], np.float32).reshape(-1, 3),
        pattern=np.array([a.pattern for a in rows], np.int16),
        pattern_param=np.array([a.pattern_param for a in rows], np.float32).reshape(-1, 4),
        gloss=np.array([a.gloss for a in rows], np.float32),
    )


def _srgb_to_linear(srgb) -> np.ndarray:
    c = np.asarray(srgb, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _palette(entries: dict[str, tuple[float, tuple[int, int, int]]]):
    """(shares normalised to 1, linear colours) of a {name: (share, sRGB)} table."""
    names = list(entries)
    share = np.array([entries[n][0] for n in names], np.float64)
    colours = np.array([_srgb_to_linear(entries[n][1]) for n in names])
    return share / share.sum(), colours


# Global new-car colour shares, rounded from the Axalta Global Automotive Color Popularity
# Report 2021 (white 35, black 19, grey 18, silver 9, blue 7, red 7, brown/beige 2,
# green 1, yellow/gold 1, other 1 per cent); sRGB tones are typical paint swatches.
_CAR = _palette({
    "white": (35, (235, 236, 232)), "black": (19, (22, 23, 26)), "grey": (18, (92, 95, 100)),
    "silver": (9, (170, 173, 176)), "blue": (7, (30, 60, 130)), "red": (7, (160, 22, 25)),
    "beige": (2, (170, 150, 115)), "green": (1, (35, 80, 50)), "yellow": (1, (215, 170, 30)),
    "orange": (1, (210, 95, 25)),
})
_CAR_NAMES = ("white", "black", "grey", "silver", "blue", "red", "beige", "green", "yellow",
              "orange")
_METALLIC = {"grey", "silver", "blue"}
# Truck cabs and cargo boxes, bus liveries and bicycle frames: fleet-style palettes chosen
# by us (no published statistics); white and grey dominate commercial vehicles.
_TRUCK = _palette({
    "white": (50, (232, 232, 228)), "silver": (12, (170, 173, 176)), "grey": (10, (90, 92, 96)),
    "blue": (10, (35, 65, 140)), "red": (8, (165, 30, 28)), "black": (5, (25, 25, 28)),
    "yellow": (3, (220, 175, 35)), "green": (2, (40, 95, 55)),
})
_BUS = _palette({
    "white": (30, (230, 230, 225)), "red": (20, (175, 30, 30)), "blue": (15, (30, 70, 150)),
    "green": (12, (40, 120, 70)), "yellow": (10, (225, 180, 40)), "silver": (8, (170, 173, 176)),
    "purple": (5, (110, 50, 120)),
})
_FRAME = _palette({
    "black": (30, (25, 25, 28)), "white": (15, (230, 230, 228)), "silver": (15, (170, 172, 175)),
    "red": (10, (170, 30, 30)), "blue": (15, (35, 75, 160)), "green": (5, (40, 110, 60)),
    "orange": (5, (220, 110, 30)), "yellow": (5, (220, 190, 40)),
})
# Street clothing shares are our own rough estimate of city street wear (dark tops and
# blue/black trousers dominate); no published statistics were found.
_TOP = _palette({
    "black": (28, (28, 28, 30)), "white": (12, (225, 225, 222)), "grey": (14, (120, 120, 124)),
    "navy": (12, (30, 40, 80)), "blue": (6, (60, 110, 180)), "red": (6, (170, 35, 40)),
    "green": (5, (50, 100, 60)), "beige": (7, (190, 165, 130)), "brown": (4, (100, 70, 45)),
    "yellow": (3, (225, 195, 60)), "pink": (3, (220, 130, 160)),
})
_BOTTOM = _palette({
    "jeans": (35, (50, 70, 110)), "black": (35, (25, 25, 28)), "grey": (10, (100, 100, 105)),
    "beige": (10, (180, 160, 125)), "brown": (5, (95, 70, 50)), "white": (5, (220, 220, 215)),
})
_HAIR = _palette({
    "black": (50, (22, 18, 16)), "dark_brown": (25, (55, 38, 26)), "brown": (10, (100, 70, 45)),
    "blond": (8, (190, 160, 110)), "grey": (7, (150, 148, 145)),
})
# Facades: render, brick, concrete and glass-metal tones of city streets.
_FACADE = _palette({
    "beige": (25, (200, 185, 160)), "white": (15, (225, 222, 215)), "grey": (20, (140, 140, 138)),
    "brick": (15, (150, 80, 60)), "ochre": (8, (200, 160, 100)), "dark": (7, (70, 72, 78)),
    "pastel_blue": (5, (160, 180, 195)), "pastel_green": (5, (170, 190, 160)),
})

# Street furniture and vegetation: our own choice of common tones (no published shares).
# Foliage in summer greens; signs mostly white regulatory and blue / green guide plates.
_FOLIAGE = _palette({"green": (60, (70, 100, 45)), "dark_green": (30, (45, 75, 35)),
                     "yellow_green": (10, (110, 125, 55))})
_BARK = _palette({"brown": (70, (85, 70, 55)), "grey": (30, (110, 105, 95))})
_FURNITURE = _palette({"black": (35, (30, 30, 32)), "grey": (35, (120, 122, 125)),
                       "dark_green": (20, (35, 65, 48)), "steel": (10, (165, 168, 170))})
_POLE = _palette({"wood": (60, (100, 80, 60)), "concrete": (40, (165, 162, 152))})
_SIGN = _palette({"white": (45, (235, 235, 230)), "red": (20, (185, 30, 30)), "blue": (15, (30, 80, 165)),
                  "yellow": (10, (235, 195, 40)), "green": (10, (20, 115, 65))})
_HYDRANT = _palette({"red": (50, (185, 35, 28)), "yellow": (35, (225, 185, 35)), "silver": (15, (175, 175, 172))})


def _pick_indexed(palette, rng: np.random.Generator, lightness_sigma: float = 0.12,
                  hue_sigma: float = 0.04) -> tuple[int, np.ndarray]:
    """Index and colour drawn from a palette, with a small per-instance lightness and hue
    jitter so that same-family colours differ a little between instances but stay close."""
    share, colours = palette
    idx = int(rng.choice(len(share), p=share))
    c = colours[idx] * np.exp(rng.normal(0.0, lightness_sigma)) * np.exp(rng.normal(0.0, hue_sigma, 3))
    return idx, np.clip(c, 0.004, 0.9).astype(np.float32)


def _pick(palette, rng: np.random.Generator, lightness_sigma: float = 0.12,
          hue_sigma: float = 0.04) -> np.ndarray:
    return _pick_indexed(palette, rng, lightness_sigma, hue_sigma)[1]


def _skin(rng: np.random.Generator) -> np.ndarray:
    # A continuum from light to dark skin tones (sRGB 255,220,195 down to 95,60,45).
    t = rng.uniform(0.0, 1.0)
    light, dark = _srgb_to_linear((240, 200, 175)), _srgb_to_linear((95, 62, 45))
    return (light * (1 - t) + dark * t).astype(np.float32)


def _person_colours(rng: np.random.Generator) -> dict:
    return {"skin": _skin(rng), "hair": _pick(_HAIR, rng), "top": _pick(_TOP, rng),
            "bottom": _pick(_BOTTOM, rng)}


def _glass(rng: np.random.Generator) -> np.ndarray:
    tint = _srgb_to_linear((40, 48, 55)) * np.exp(rng.normal(0.0, 0.25))
    return np.clip(tint * np.exp(rng.normal(0.0, 0.05, 3)), 0.0, 1.0).astype(np.float32)


def _car_pattern(rng: np.random.Generator, base: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    # Most cars are one colour; the rest carry a contrasting roof, stripe, lower body or logo.
    pattern = int(rng.choice([SOLID, TWO_TONE_ROOF, SIDE_STRIPE, LOWER_BODY, DECAL],
                             p=[0.8, 0.06, 0.05, 0.05, 0.04]))
    light = float(base.mean()) > 0.25
    dark = _srgb_to_linear((20, 20, 22)).astype(np.float32)
    white = _srgb_to_linear((235, 235, 232)).astype(np.float32)
    if pattern == SIDE_STRIPE:
        secondary = _pick(_CAR, rng)
        if abs(float(secondary.mean()) - float(base.mean())) < 0.1:
            secondary = dark if light else white
        param = np.array([rng.uniform(0.45, 0.75), rng.uniform(0.03, 0.08), 0.0, 0.0])
    elif pattern == LOWER_BODY:
        secondary = _srgb_to_linear((45, 45, 48)).astype(np.float32) if light else \
            _srgb_to_linear((150, 150, 150)).astype(np.float32)
        param = np.array([rng.uniform(0.25, 0.4), 0.0, 0.0, 0.0])
    elif pattern == DECAL:
        secondary = _pick(_BUS, rng)
        param = np.array([rng.uniform(-0.2, 0.2), rng.uniform(0.0, 0.2), rng.uniform(0.3, 0.6),
                          rng.uniform(0.12, 0.22)])
    else:
        secondary = dark if light else white
        param = np.zeros(4)
    return pattern, secondary, param.astype(np.float32)


def _sample_car(rng: np.random.Generator) -> Appearance:
    idx, base = _pick_indexed(_CAR, rng)
    name = _CAR_NAMES[idx]
    variant = int(rng.choice(3, p=[0.4, 0.3, 0.3]))
    pattern, secondary, param = _car_pattern(rng, base)
    gloss = rng.uniform(0.6, 0.9) if name in _METALLIC else rng.uniform(0.3, 0.6)
    return Appearance("car", variant, base, secondary, pattern, param, _glass(rng), float(gloss))


def _sample_truck(rng: np.random.Generator) -> Appearance:
    base = _pick(_TRUCK, rng)
    secondary = _pick(_TRUCK, rng)
    pattern = DECAL if rng.uniform() < 0.4 else SOLID
    param = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.2), rng.uniform(0.5, 1.5),
                      rng.uniform(0.3, 0.6)], np.float32)
    return Appearance("truck", 0, base, secondary, pattern, param, _glass(rng),
                      float(rng.uniform(0.2, 0.5)))


def _sample_bus(rng: np.random.Generator) -> Appearance:
    base = _pick(_BUS, rng)
    secondary = _pick(_BUS, rng)
    pattern = int(rng.choice([SOLID, SIDE_STRIPE, LOWER_BODY, DECAL], p=[0.3, 0.3, 0.2, 0.2]))
    param = {SOLID: [0, 0, 0, 0],
             SIDE_STRIPE: [rng.uniform(0.3, 0.7), rng.uniform(0.06, 0.15), 0, 0],
             LOWER_BODY: [rng.uniform(0.3, 0.5), 0, 0, 0],
             DECAL: [rng.uniform(-0.3, 0.3), 0.0, rng.uniform(1.0, 2.5), rng.uniform(0.2, 0.35)]}
    return Appearance("bus", 0, base, secondary, pattern, np.array(param[pattern], np.float32),
                      _glass(rng), float(rng.uniform(0.3, 0.6)))


def _sample_pedestrian(rng: np.random.Generator) -> Appearance:
    colours = _person_colours(rng)
    variant = int(rng.integers(2))
    backpack = rng.uniform() < 0.25
    secondary = _pick(_TOP, rng)
    return Appearance("pedestrian", variant, colours["top"], secondary,
                      BACKPACK if backpack else SOLID, np.zeros(4, np.float32),
                      gloss=0.0, **colours)


def _sample_cycle(kind: str, rng: np.random.Generator, rider: bool | None) -> Appearance:
    base = _pick(_FRAME if kind == "bicycle" else _TRUCK, rng)
    if rider is None:
        # nuScenes mini: cycle.without_rider 58.7 %, with_rider 41.3 %.
        rider = bool(rng.uniform() < 0.413)
    colours = _person_colours(rng)
    helmet = _pick(_FRAME, rng)
    return Appearance(kind, int(rng.integers(2)), base, helmet, SOLID, np.zeros(4, np.float32),
                      gloss=0.5, rider=rider, **colours)


def _sample_static(kind: str, rng: np.random.Generator) -> Appearance:
    if kind == "barrier":
        variant = int(rng.uniform() < 0.35)
        base = _srgb_to_linear((170, 168, 160)) * np.exp(rng.normal(0.0, 0.1))
        if variant == 1:
            base = _srgb_to_linear((200, 30, 25))
        return Appearance(kind, variant, base.astype(np.float32), gloss=0.0)
    if kind == "traffic_cone":
        return Appearance(kind, 0, _srgb_to_linear((240, 90, 20)).astype(np.float32), gloss=0.2)
    return Appearance(kind, int(rng.integers(4)), _pick(_FACADE, rng, 0.1, 0.03),
                      _pick(_FACADE, rng, 0.1, 0.03), gloss=0.0)


def _sample_clutter(kind: str, rng: np.random.Generator) -> Appearance:
    """Street furniture and vegetation: `base` is the main colour (foliage, paint, sign
    plate), `secondary` the second one (bark, hydrant cap)."""
    base, secondary = {
        "tree": (_FOLIAGE, _BARK), "hedge": (_FOLIAGE, _FOLIAGE), "fence": (_FURNITURE, _FURNITURE),
        "street_light": (_FURNITURE, _FURNITURE), "utility_pole": (_POLE, _POLE), "sign": (_SIGN, _FURNITURE),
        "traffic_light": (_FURNITURE, _FURNITURE), "hydrant": (_HYDRANT, _HYDRANT), "bin": (_FURNITURE, _FURNITURE),
        "bollard": (_FURNITURE, _FURNITURE),
    }[kind]
    return Appearance(kind, 0, _pick(base, rng), _pick(secondary, rng), gloss=0.0)


def sample_appearance(kind: str, rng: np.random.Generator, rider: bool | None = None) -> Appearance:
    """Sample one instance's look with realistic colour frequencies.

    kind: one of `objects.KINDS`; rng: the only source of randomness (same state, same
    result); rider: for "bicycle" and "motorcycle", force a rider on (True) or off (False);
    None samples it with the nuScenes share (41 % with rider). Raises ValueError for an
    unknown kind.
    """
    if kind == "car":
        return _sample_car(rng)
    if kind == "truck":
        return _sample_truck(rng)
    if kind == "bus":
        return _sample_bus(rng)
    if kind == "pedestrian":
        return _sample_pedestrian(rng)
    if kind in ("bicycle", "motorcycle"):
        return _sample_cycle(kind, rng, rider)
    if kind in ("barrier", "traffic_cone", "building"):
        return _sample_static(kind, rng)
    if kind in CLUTTER_KINDS:
        return _sample_clutter(kind, rng)
    raise ValueError(f"unknown object kind {kind!r}")


@dataclass(frozen=True)
class CameraStyle:
    """One camera's rendering of radiance into pixels.

    exposure_stops: exposure offset in stops (multiplies linear radiance by 2**stops);
    white_balance (3,) per-channel linear gains; noise_std: standard deviation of the
    additive sensor noise in sRGB units of [0, 1]; vignetting: relative darkening at the
    image corners (0 = none).
    """

    exposure_stops: float = 0.0
    white_balance: np.ndarray = field(default_factory=lambda: np.ones(3, np.float32))
    noise_std: float = 0.0
    vignetting: float = 0.0


def camera_style(rng: np.random.Generator) -> CameraStyle:
    """A random camera style: exposure within +-0.3 stops, white-balance gains within a
    few per cent, sensor noise 0.6-1.6 % and corner vignetting 10-30 %."""
    return CameraStyle(
        exposure_stops=float(rng.uniform(-0.3, 0.3)),
        white_balance=np.clip(1.0 + rng.normal(0.0, 0.025, 3), 0.93, 1.07).astype(np.float32),
        noise_std=float(rng.uniform(0.006, 0.016)),
        vignetting=float(rng.uniform(0.1, 0.3)),
    )
