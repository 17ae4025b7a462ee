"""Car parks beside the route: one to three rows of bays behind the pavement, perpendicular
(90 degrees) or diagonal (60 or 45 degrees) to the road, the way petrol-station forecourts
(one row), supermarkets and the open lots of Boston's Seaport and Singapore's estates (rows
behind rows, an aisle between) park cars.

They put parked cars at headings that are neither along nor across the ego's road and at
azimuths between ahead and abeam, where the cameras overlap: nuScenes' car orientations
peak at the road's axes but are not confined to them (nuScenes paper, supplement
Fig. 12). The rows behind the first put cars 10-30 m from the road's edge, where a car 20-50 m
ahead or behind lies in the sectors two cameras share. Bay geometry follows common practice:
2.4-2.6 m wide, 5 m deep, 6 m aisles.
"""

from __future__ import annotations

import numpy as np

from sianms_cli.synth.road import BAY_DEPTH, BAY_START, ROW_PITCH, CarPark, Street

CAR_PARKS_PER_SCENE = 3.0
"""Poisson mean of car parks along the ego's drive (was 2): Boston Seaport was, in 2018, a
district of open surface lots between the new blocks, and Singapore's estates park in open lots
beside the road; our estimate, no published count."""
BAY_ANGLES = np.radians([90.0, 60.0, 45.0])
BAY_ANGLE_SHARES = [1 / 3, 1 / 3, 1 / 3]
"""No published mix of bay angles for the nuScenes cities: equal shares (our choice, the least
informed prior; before, half the bays were perpendicular, which put too many parked cars along
the ego's axes against nuScenes' spread of orientations, SM Fig. 12)."""
ROWS = (1, 2, 3)
ROW_SHARES = (0.4, 0.3, 0.3)
"""Rows of bays per car park: forecourts and kerb-side lots have one, the open surface lots of
the Seaport and the estates' lots several (our estimate from aerial views of both cities, no
published count). Before, every car park had one row, which kept parked cars within 10 m of
the pavement, in the street's canyon."""


def car_park_depth(rows: int) -> float:
    """Metres from the pavement's outer edge to the back of a car park of ``rows`` rows."""
    return BAY_START + (rows - 1) * ROW_PITCH + BAY_DEPTH + 1.0


def choose_car_parks(rng: np.random.Generator, street: Street, s_from: float, s_to: float) -> tuple[CarPark, ...]:
    """Car parks 25-60 m long near the ego's drive [s_from, s_to] (route arc lengths), each on
    one straight stretch, clear of junctions and of each other; a candidate that is not is
    dropped, so the count varies."""
    parks: list[CarPark] = []
    for _ in range(int(rng.poisson(CAR_PARKS_PER_SCENE))):
        side = int(rng.choice([-1, 1]))
        length = float(rng.uniform(25.0, 60.0))
        s0 = float(rng.uniform(s_from - 40.0, s_to + 20.0))
        angle = float(rng.choice(BAY_ANGLES, p=BAY_ANGLE_SHARES))
        rows = int(rng.choice(ROWS, p=ROW_SHARES))
        park = CarPark(side, s0, s0 + length, car_park_depth(rows), angle, rows)
        if _fits(park, street, parks):
            parks.append(park)
    return tuple(parks)


def _fits(park: CarPark, street: Street, parks: list[CarPark]) -> bool:
    """On one straight segment of the route, 4 m clear of junctions and of other car parks."""
    route = street.route
    span = np.linspace(park.s0, park.s1, 16)
    straight = bool(np.all(route.curvature_at(span) == 0.0)) and park.s0 > 0.0 and park.s1 < route.length
    clear = not street.near_intersection(span, margin=4.0).any()
    apart = all(other.side != park.side or other.s1 + 4.0 < park.s0 or park.s1 + 4.0 < other.s0 for other in parks)
    return straight and clear and apart


def bay_poses(park: CarPark, pavement_outer: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres of the bays of ``park`` as route arc length (B,) and offset (B,), and the yaw
    (B,) of a car parked nose-in relative to the route heading; row by row from the road.

    Bay ``k`` of a row lies between the bay lines through ``s0 + k * spacing`` and the next,
    which run across the row at ``angle`` to the road; only bays whose lines end before ``s1``
    count. Every row repeats the first one's lines, ``ROW_PITCH`` further in.
    """
    slant = 1.0 / np.tan(park.angle)
    reach = BAY_START + BAY_DEPTH  # how far into the car park the first row's bay lines go
    count = max(int(np.floor((park.s1 - park.s0 - reach * slant) / park.bay_spacing)), 0)
    across = BAY_START + BAY_DEPTH / 2
    s = np.tile(park.s0 + (np.arange(count) + 0.5) * park.bay_spacing + across * slant, park.rows)
    d = park.side * (pavement_outer + across + np.repeat(np.arange(park.rows) * ROW_PITCH, count))
    yaw = np.full(count * park.rows, park.side * park.angle)
    return s, d, yaw
