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

CAR_VARIANTS = ("sedan", "hatchback", "estate", "suv", "pickup", "van", "minivan", "coupe")
"""Car models, in the order of `Appearance.variant` (vehicles.CAR_MODELS holds their shapes)."""
TRUCK_VARIANTS = ("box", "flatbed", "tipper")
TRAILER_VARIANTS = ("box", "flatbed", "tanker")
CONSTRUCTION_VARIANTS = ("excavator", "loader", "roller")
REAR_EXTRAS = ("none", "spoiler", "tow_bar", "spare_wheel")
"""What a car carries on its rear (`VehicleDetails.rear_extra`)."""

HAIR_STYLES = ("short", "long", "ponytail", "bald")
SHORT_HAIR, LONG_HAIR, PONYTAIL, BALD = range(len(HAIR_STYLES))
HEADWEAR = ("none", "cap", "beanie", "hard_hat", "open_helmet", "full_face_helmet")
NO_HEADWEAR, CAP, BEANIE, HARD_HAT, OPEN_HELMET, FULL_FACE_HELMET = range(len(HEADWEAR))
LEGWEAR = ("trousers", "shorts", "skirt", "dress")
TROUSERS, SHORTS, SKIRT, DRESS = range(len(LEGWEAR))
TOP_STYLES = ("plain", "stripes", "logo_band", "open_jacket", "hi_vis_vest")
PLAIN_TOP, STRIPES, LOGO_BAND, OPEN_JACKET, HI_VIS_VEST = range(len(TOP_STYLES))
BAGS = ("none", "backpack", "shoulder_bag_left", "shoulder_bag_right", "handbag", "shopping_bag")
NO_BAG, BACKPACK_BAG, SHOULDER_BAG_LEFT, SHOULDER_BAG_RIGHT, HANDBAG, SHOPPING_BAG = range(len(BAGS))

CLUTTER_KINDS = ("tree", "hedge", "fence", "street_light", "utility_pole", "sign", "traffic_light",
                 "hydrant", "bin", "bollard")
"""Unannotated street furniture and vegetation (owner -1 scenery, placed by clutter.py)."""

_BLACK = np.zeros(3, np.float32)


@dataclass(frozen=True)
class VehicleDetails:
    """Per-instance details of a motor vehicle that differ by side and by end.

    jitter (8,) float32 standard-normal draws clipped to [-2, 2] that move the model's
    proportions (vehicles.py scales each: belt line, cabin rear, cabin front, cabin width,
    bonnet height, wheel radius, headlight size, rear-light size; zeros give the nominal
    model); rim (3,) linear albedo of the wheel hubs, rim_size their size as a fraction of
    the tyre radius; chrome_grille: bright metal instead of black plastic; roof_rails;
    rear_extra: index into `REAR_EXTRAS`; decal_side: +1 a decal or stripe on the left
    (+y) side only, -1 on the right (-y) side only, 0 none; decal (4,): its x centre and
    half length as fractions of the length, its z centre and half height as fractions of
    the body side's height; decal_colour (3,); dirt in [0, 1]: how far road dirt darkens
    the sills.
    """

    jitter: np.ndarray = field(default_factory=lambda: np.zeros(8, np.float32))
    rim: np.ndarray = field(default_factory=lambda: np.full(3, 0.35, np.float32))
    rim_size: float = 0.7
    chrome_grille: bool = False
    roof_rails: bool = False
    rear_extra: int = 0
    decal_side: int = 0
    decal: np.ndarray = field(default_factory=lambda: np.zeros(4, np.float32))
    decal_colour: np.ndarray = field(default_factory=lambda: np.full(3, 0.3, np.float32))
    dirt: float = 0.0


@dataclass(frozen=True)
class Appearance:
    """The look of one object instance.

    kind: object kind (see `objects.KINDS`); variant: body style (car: model index into
    `CAR_VARIANTS`; truck, trailer, construction: index into `TRUCK_VARIANTS`,
    `TRAILER_VARIANTS`, `CONSTRUCTION_VARIANTS`; person: 0 long sleeves, 1 short sleeves;
    barrier: 0 concrete, 1 plastic);
    base, secondary (3,) linear albedo of the main and the second colour; pattern: index
    into `PATTERNS`; pattern_param (4,): side stripe (height as a fraction of the part,
    half width m, -, -), lower body (split height fraction, -, -, -), decal (x and z centre
    as fractions in [-0.5, 0.5] of the part, half width m, half height m); glass (3,)
    albedo of the glazing; gloss in [0, 1] clear-coat strength; skin, hair, top, bottom
    (3,) for people and riders (helmet in `secondary`); rider: a bicycle or motorcycle
    carries a rider; vehicle: per-instance details of motor vehicles (`VehicleDetails`).
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
    vehicle: VehicleDetails = field(default_factory=lambda: VehicleDetails())
    # People and riders (people.py draws them): styles index the tuples below; accent (3,)
    # is the second clothing colour (open jacket, stripes, logo band, bag), shoes (3,) the
    # footwear; gait_phase in [0, 1) the instant of the walking or pedalling cycle.
    hair_style: int = 0
    headwear: int = 0
    legwear: int = 0
    top_style: int = 0
    bag: int = 0
    accent: np.ndarray = field(default_factory=lambda: _BLACK.copy())
    shoes: np.ndarray = field(default_factory=lambda: _BLACK.copy())
    gait_phase: float = 0.0


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
_SHOES = _palette({
    "black": (45, (25, 25, 27)), "white": (25, (225, 225, 220)), "brown": (15, (85, 60, 40)),
    "grey": (10, (110, 110, 115)), "blue": (5, (40, 60, 120)),
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
            "bottom": _pick(_BOTTOM, rng), "accent": _pick(_TOP, rng), "shoes": _pick(_SHOES, rng)}


# Shares of clothing and hair styles: our own estimate of mixed-season street wear in the
# nuScenes cities (Boston, Singapore); no published statistics were found.
_SHORT_SLEEVES = 0.45
_LEGWEAR_SHARE = (0.64, 0.16, 0.12, 0.08)       # trousers, shorts, skirt, dress
_TOP_STYLE_SHARE = (0.55, 0.12, 0.08, 0.25)     # plain, stripes, logo band, open jacket
_HAIR_STYLE_SHARE = (0.50, 0.28, 0.12, 0.10)    # short, long, ponytail, bald
_HEADWEAR_SHARE = (0.84, 0.10, 0.06)            # none, cap, beanie
_BAG_SHARE = (0.40, 0.25, 0.09, 0.09, 0.08, 0.09)  # none, backpack, shoulder L/R, handbag, shopping
# Helmets: our own estimate of urban cycling (about half of cyclists wear one); motorcycle
# helmets are compulsory in both cities, full-face ones the majority (our estimate).
_BICYCLE_HELMET = 0.5
_FULL_FACE = 0.7
_HI_VIS = _srgb_to_linear((205, 230, 40)).astype(np.float32)
_HARD_HAT = _palette({"white": (40, (235, 235, 230)), "yellow": (35, (235, 200, 30)),
                      "orange": (25, (235, 110, 25))})


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


# Car model mix, in the order of CAR_VARIANTS: our own estimate for nuScenes's streets,
# Boston (55 % of scenes) and Singapore (45 %). US sales are about half SUVs and crossovers,
# a fifth sedans and other cars and a few per cent minivans and vans (Kelley Blue Book
# segment reports 2019-2022); Singapore registers mostly sedans and SUVs, more MPVs and
# hardly any pickups (LTA new registrations by vehicle make and type). Streets hold older
# cars than today's sales, so sedans keep a larger share, and nuScenes labels pick-ups
# vehicle.truck (annotator instructions), so few of them are "vehicle.car".
_CAR_MODEL_SHARE = np.array([0.30, 0.08, 0.03, 0.40, 0.03, 0.04, 0.08, 0.04])
# Typical length and height (m) of each model, from the makers' figures of the examples in
# vehicles.CAR_MODELS (Camry, Golf, V60, RAV4, F-150, Transit Custom, Odyssey, 2 Series),
# and the spread of one body type across makes (our own estimate). A car whose box is drawn
# 1.40 m tall is then a sedan or a coupe, not a van squashed into it.
_CAR_MODEL_LENGTH_HEIGHT = np.array([[4.88, 1.45], [4.26, 1.46], [4.76, 1.43], [4.60, 1.69],
                                     [5.89, 1.96], [4.97, 1.98], [5.16, 1.74], [4.54, 1.39]])
_CAR_MODEL_SPREAD = np.array([0.35, 0.10])
# Per model (CAR_VARIANTS order): share with roof rails, and shares of the rear extras
# (none, spoiler, tow bar, spare wheel on the tailgate). Our own estimate of city streets:
# rails come on most estates and many SUVs, tow bars on pickups and US SUVs, rear spares
# on older off-roaders only.
_ROOF_RAILS = np.array([0.02, 0.10, 0.60, 0.45, 0.0, 0.25, 0.35, 0.0])
_REAR_EXTRA_SHARE = np.array([
    [0.92, 0.06, 0.02, 0.00],  # sedan
    [0.72, 0.25, 0.03, 0.00],  # hatchback
    [0.90, 0.02, 0.08, 0.00],  # estate
    [0.78, 0.02, 0.14, 0.06],  # SUV
    [0.65, 0.00, 0.35, 0.00],  # pickup
    [0.85, 0.00, 0.15, 0.00],  # van
    [0.93, 0.02, 0.05, 0.00],  # minivan
    [0.55, 0.45, 0.00, 0.00],  # coupe
])
# Wheel hubs: silver alloys, dark alloys, grey steel-wheel covers, white or gold alloys
# (our own estimate of the street mix); sRGB tones of typical finishes.
_RIM = _palette({"silver": (60, (175, 178, 182)), "dark": (20, (40, 40, 44)),
                 "steel": (15, (110, 112, 115)), "white": (3, (225, 225, 222)),
                 "gold": (2, (170, 140, 80))})
# One-sided marks for `_ONE_SIDED_MARK` of cars (a sticker, a stripe, a repaired panel in
# primer or another colour, a scrape): our own estimate, no published figure.
_ONE_SIDED_MARK = 0.12
_MARK = _palette({"primer_grey": (30, (125, 125, 120)), "black": (25, (25, 25, 28)),
                  "white": (20, (235, 235, 232)), "red": (10, (170, 30, 30)),
                  "blue": (10, (35, 75, 160)), "yellow": (5, (225, 190, 40))})
# Share of cars with visibly dirty sills (our own estimate; more after rain and in winter).
_DIRTY = 0.25


def _vehicle_details(model: int, rng: np.random.Generator) -> VehicleDetails:
    """Details of one car of model index `model` (see `VehicleDetails`)."""
    jitter = np.clip(rng.normal(0.0, 1.0, 8), -2.0, 2.0).astype(np.float32)
    side = 0
    if rng.uniform() < _ONE_SIDED_MARK:
        side = 1 if rng.uniform() < 0.5 else -1
    # A mark is a long thin stripe or a shorter panel-sized patch.
    stripe = rng.uniform() < 0.5
    decal = np.array([rng.uniform(-0.25, 0.25), rng.uniform(0.2, 0.35) if stripe else rng.uniform(0.06, 0.14),
                      rng.uniform(0.35, 0.75), rng.uniform(0.04, 0.08) if stripe else rng.uniform(0.15, 0.3)])
    dirt = float(rng.uniform(0.3, 0.8)) if rng.uniform() < _DIRTY else 0.0
    return VehicleDetails(
        jitter=jitter, rim=_pick(_RIM, rng, 0.1, 0.02), rim_size=float(rng.uniform(0.55, 0.9)),
        chrome_grille=bool(rng.uniform() < 0.3), roof_rails=bool(rng.uniform() < _ROOF_RAILS[model]),
        rear_extra=int(rng.choice(4, p=_REAR_EXTRA_SHARE[model])), decal_side=side,
        decal=decal.astype(np.float32), decal_colour=_pick(_MARK, rng), dirt=dirt)


def _car_model_share(size_wlh) -> np.ndarray:
    """(8,) probability of each car model: the street mix, or, given the box size (3,) w, l,
    h, the mix weighted by how likely each model is to have that length and height."""
    if size_wlh is None:
        return _CAR_MODEL_SHARE
    length_height = np.asarray(size_wlh, np.float64)[1:]
    z = (length_height - _CAR_MODEL_LENGTH_HEIGHT) / _CAR_MODEL_SPREAD
    log_weight = np.log(_CAR_MODEL_SHARE) - 0.5 * (z * z).sum(axis=1)
    weight = np.exp(log_weight - log_weight.max())
    return weight / weight.sum()


def _sample_car(rng: np.random.Generator, size_wlh=None) -> Appearance:
    idx, base = _pick_indexed(_CAR, rng)
    name = _CAR_NAMES[idx]
    variant = int(rng.choice(len(CAR_VARIANTS), p=_car_model_share(size_wlh)))
    pattern, secondary, param = _car_pattern(rng, base)
    gloss = rng.uniform(0.6, 0.9) if name in _METALLIC else rng.uniform(0.3, 0.6)
    return Appearance("car", variant, base, secondary, pattern, param, _glass(rng), float(gloss),
                      vehicle=_vehicle_details(variant, rng))


# Heavy-vehicle variants (TRUCK_VARIANTS, TRAILER_VARIANTS, CONSTRUCTION_VARIANTS orders):
# our own estimate of city streets and nuScenes's construction sites: box bodies for
# deliveries, tippers at sites, flatbeds; box (van) trailers dominate US freight, then
# flatbeds and tankers; excavators are the most common plant at street works.
_TRUCK_SHARE = np.array([0.60, 0.15, 0.25])
_TRAILER_SHARE = np.array([0.60, 0.25, 0.15])
_CONSTRUCTION_SHARE = np.array([0.45, 0.30, 0.25])
# Trailers: white box vans and steel or aluminium tanks dominate (our own estimate).
_TRAILER = _palette({
    "white": (55, (232, 232, 228)), "silver": (20, (175, 178, 180)), "grey": (8, (110, 112, 116)),
    "blue": (6, (35, 65, 140)), "red": (6, (160, 30, 28)), "black": (5, (28, 28, 30)),
})
# Construction plant: manufacturers' liveries (yellow: Caterpillar, Komatsu, Volvo, JCB;
# orange: Hitachi, Doosan; others rarer); shares are our own estimate.
_CONSTRUCTION = _palette({
    "yellow": (55, (235, 180, 20)), "orange": (20, (230, 110, 20)), "white": (10, (230, 230, 225)),
    "red": (5, (180, 35, 30)), "green": (5, (60, 120, 60)), "blue": (5, (40, 80, 160)),
})


def _heavy_details(rng: np.random.Generator) -> VehicleDetails:
    """Details of a truck, trailer or construction vehicle: proportions, hubs and dirt."""
    jitter = np.clip(rng.normal(0.0, 1.0, 8), -2.0, 2.0).astype(np.float32)
    dirt = float(rng.uniform(0.2, 0.8)) if rng.uniform() < 0.5 else 0.0
    return VehicleDetails(jitter=jitter, rim=_pick(_RIM, rng, 0.1, 0.02), rim_size=float(rng.uniform(0.5, 0.75)),
                          chrome_grille=bool(rng.uniform() < 0.3), dirt=dirt)


def _sample_truck(rng: np.random.Generator) -> Appearance:
    base = _pick(_TRUCK, rng)
    secondary = _pick(_TRUCK, rng)
    variant = int(rng.choice(len(TRUCK_VARIANTS), p=_TRUCK_SHARE))
    pattern = DECAL if rng.uniform() < 0.4 else SOLID
    param = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.2), rng.uniform(0.5, 1.5),
                      rng.uniform(0.3, 0.6)], np.float32)
    return Appearance("truck", variant, base, secondary, pattern, param, _glass(rng),
                      float(rng.uniform(0.2, 0.5)), vehicle=_heavy_details(rng))


def _sample_trailer(rng: np.random.Generator) -> Appearance:
    """base: the body (box, tank, deck); secondary: the load of a flatbed."""
    variant = int(rng.choice(len(TRAILER_VARIANTS), p=_TRAILER_SHARE))
    base = _pick(_TRAILER, rng)
    secondary = _pick(_TRUCK, rng)
    pattern = DECAL if variant == 0 and rng.uniform() < 0.3 else SOLID
    param = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.2), rng.uniform(1.0, 3.0),
                      rng.uniform(0.3, 0.8)], np.float32)
    return Appearance("trailer", variant, base, secondary, pattern, param, _glass(rng),
                      float(rng.uniform(0.2, 0.6)), vehicle=_heavy_details(rng))


def _sample_construction(rng: np.random.Generator) -> Appearance:
    """base: the machine's livery; secondary: the counterweight and arm joints (dark)."""
    variant = int(rng.choice(len(CONSTRUCTION_VARIANTS), p=_CONSTRUCTION_SHARE))
    base = _pick(_CONSTRUCTION, rng, 0.1, 0.03)
    secondary = (_srgb_to_linear((40, 40, 42)) * np.exp(rng.normal(0.0, 0.1))).astype(np.float32)
    return Appearance("construction", variant, base, secondary, SOLID, np.zeros(4, np.float32), _glass(rng),
                      float(rng.uniform(0.1, 0.3)), vehicle=_heavy_details(rng))


def _sample_bus(rng: np.random.Generator) -> Appearance:
    base = _pick(_BUS, rng)
    secondary = _pick(_BUS, rng)
    pattern = int(rng.choice([SOLID, SIDE_STRIPE, LOWER_BODY, DECAL], p=[0.3, 0.3, 0.2, 0.2]))
    param = {SOLID: [0, 0, 0, 0],
             SIDE_STRIPE: [rng.uniform(0.3, 0.7), rng.uniform(0.06, 0.15), 0, 0],
             LOWER_BODY: [rng.uniform(0.3, 0.5), 0, 0, 0],
             DECAL: [rng.uniform(-0.3, 0.3), 0.0, rng.uniform(1.0, 2.5), rng.uniform(0.2, 0.35)]}
    return Appearance("bus", 0, base, secondary, pattern, np.array(param[pattern], np.float32),
                      _glass(rng), float(rng.uniform(0.3, 0.6)), vehicle=_heavy_details(rng))


def _sample_pedestrian(rng: np.random.Generator, workwear: bool) -> Appearance:
    colours = _person_colours(rng)
    sleeves = int(rng.uniform() < _SHORT_SLEEVES)
    legwear = int(rng.choice(len(LEGWEAR), p=_LEGWEAR_SHARE))
    top_style = int(rng.choice(4, p=_TOP_STYLE_SHARE))
    hair_style = int(rng.choice(len(HAIR_STYLES), p=_HAIR_STYLE_SHARE))
    headwear = int(rng.choice(3, p=_HEADWEAR_SHARE))
    bag = int(rng.choice(len(BAGS), p=_BAG_SHARE))
    secondary = _pick(_TOP, rng)
    if workwear:
        top_style, headwear, secondary, legwear = HI_VIS_VEST, HARD_HAT, _pick(_HARD_HAT, rng), TROUSERS
        colours["accent"] = _HI_VIS.copy()
    if legwear == DRESS:
        colours["bottom"] = colours["top"]
    return Appearance("pedestrian", sleeves, colours["top"], secondary,
                      BACKPACK if bag == BACKPACK_BAG else SOLID, np.zeros(4, np.float32),
                      gloss=0.0, hair_style=hair_style, headwear=headwear, legwear=legwear,
                      top_style=top_style, bag=bag, gait_phase=float(rng.uniform()), **colours)


def _sample_cycle(kind: str, rng: np.random.Generator, rider: bool | None) -> Appearance:
    """A bicycle or motorcycle; the rider's helmet colour is `secondary`."""
    motor = kind == "motorcycle"
    base = _pick(_TRUCK if motor else _FRAME, rng)
    if rider is None:
        # nuScenes mini: cycle.without_rider 58.7 %, with_rider 41.3 %.
        rider = bool(rng.uniform() < 0.413)
    colours = _person_colours(rng)
    helmet = _pick(_FRAME, rng)
    if motor:
        headwear = FULL_FACE_HELMET if rng.uniform() < _FULL_FACE else OPEN_HELMET
        top_style = OPEN_JACKET if rng.uniform() < 0.3 else PLAIN_TOP
    else:
        headwear = OPEN_HELMET if rng.uniform() < _BICYCLE_HELMET else NO_HEADWEAR
        top_style = int(rng.choice(4, p=_TOP_STYLE_SHARE))
    return Appearance(kind, int(rng.integers(2)), base, helmet, SOLID, np.zeros(4, np.float32),
                      gloss=0.5, rider=rider, hair_style=int(rng.choice(len(HAIR_STYLES), p=_HAIR_STYLE_SHARE)),
                      headwear=headwear, legwear=TROUSERS, top_style=top_style,
                      gait_phase=float(rng.uniform()), **colours)


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


def sample_appearance(kind: str, rng: np.random.Generator, rider: bool | None = None,
                      size_wlh=None, workwear: bool = False) -> Appearance:
    """Sample one instance's look with realistic colour frequencies.

    kind: one of `objects.KINDS`; rng: the only source of randomness (same state, same
    result); rider: for "bicycle" and "motorcycle", force a rider on (True) or off (False);
    None samples it with the nuScenes share (41 % with rider); size_wlh (3,): for "car",
    the box the car will fill, so that its model fits it (None: the street mix alone);
    workwear: for "pedestrian", a hi-vis vest and a hard hat (construction workers).
    Raises ValueError for an unknown kind.
    """
    if kind == "car":
        return _sample_car(rng, size_wlh)
    if kind == "truck":
        return _sample_truck(rng)
    if kind == "bus":
        return _sample_bus(rng)
    if kind == "trailer":
        return _sample_trailer(rng)
    if kind == "construction":
        return _sample_construction(rng)
    if kind == "pedestrian":
        return _sample_pedestrian(rng, workwear)
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

    exposure_stops: exposure offset in stops (multiplies linear radiance by 2**stops), on
    top of the auto exposure metered per frame by the renderer; white_balance (3,)
    per-channel linear gains, around which each frame's white balance drifts; noise_std: standard deviation of the
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
