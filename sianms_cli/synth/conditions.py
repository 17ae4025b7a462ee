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
