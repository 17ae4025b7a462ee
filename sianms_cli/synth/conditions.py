"""Lighting and weather of a synthetic scene: day or night, dry or rain.

Shares follow nuScenes v1.0-trainval, whose scene descriptions mention "night" in about
11.6 % and "rain" in about 19.4 % of the 850 scenes; the two are drawn independently, so
about 2.3 % of scenes are rainy nights. The words are the ones nuScenes descriptions use,
so a filter written for real data ("night" in description) works on synthetic data too.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NIGHT_SHARE = 0.116
RAIN_SHARE = 0.194

# Where the nuScenes logs were driven, (latitude, longitude) in degrees: Boston Seaport and
# Singapore's One North, Queenstown and Holland Village lie within 5 km of one another, so one
# point per city places the sun within a minute.
CITY_COORDINATES = {"boston": (42.35, -71.05), "singapore": (1.30, 103.80)}
# Night starts at the end of civil twilight (sun 6 degrees below the horizon): the sky is dark
# and street lights, headlights and tail lights carry the scene.
CIVIL_DUSK_SUN_ELEVATION_DEG = -6.0


@dataclass(frozen=True)
class Conditions:
    """night: the sun is down (street lights, headlights); rain: wet road, overcast sky."""

    night: bool = False
    rain: bool = False

    def words(self) -> list[str]:
        """The words a nuScenes description uses for these conditions, in order."""
        return [word for word, on in (("night", self.night), ("rain", self.rain)) if on]


def sample_conditions(rng: np.random.Generator) -> Conditions:
    """Night and rain drawn independently at their nuScenes shares."""
    night, rain = rng.uniform(size=2) < (NIGHT_SHARE, RAIN_SHARE)
    return Conditions(night=bool(night), rain=bool(rain))


def civil_dusk_hour(day_of_year: int, city: str, utc_offset_hours: float) -> float:
    """Local clock time (hours after midnight) at which civil twilight ends in ``city`` (a key
    of :data:`CITY_COORDINATES`) on ``day_of_year`` (1 = 1 January), at a clock ``utc_offset_hours``
    ahead of UTC. NOAA's low-precision solar formulas (declination and equation of time as
    Fourier series of the year angle; NOAA Global Monitoring Laboratory, "General Solar
    Position Calculations"), good to a minute or two: Boston on 21 June gives 20:59 EDT, as
    almanacs do. Valid where the sun does set (any latitude of ours)."""
    latitude, longitude = (np.radians(v) for v in CITY_COORDINATES[city])
    gamma = 2.0 * np.pi / 365.0 * (day_of_year - 1)
    declination = (0.006918 - 0.399912 * np.cos(gamma) + 0.070257 * np.sin(gamma)
                   - 0.006758 * np.cos(2 * gamma) + 0.000907 * np.sin(2 * gamma)
                   - 0.002697 * np.cos(3 * gamma) + 0.00148 * np.sin(3 * gamma))
    equation_of_time_min = 229.18 * (0.000075 + 0.001868 * np.cos(gamma) - 0.032077 * np.sin(gamma)
                                     - 0.014615 * np.cos(2 * gamma) - 0.040849 * np.sin(2 * gamma))
    cos_hour_angle = ((np.sin(np.radians(CIVIL_DUSK_SUN_ELEVATION_DEG)) - np.sin(latitude) * np.sin(declination))
                      / (np.cos(latitude) * np.cos(declination)))
    hour_angle_deg = np.degrees(np.arccos(cos_hour_angle))
    solar_noon_min = 720.0 - 4.0 * np.degrees(longitude) - equation_of_time_min + 60.0 * utc_offset_hours
    return float((solar_noon_min + 4.0 * hour_angle_deg) / 60.0)
