import numpy as np
import pytest

from sianms_cli.synth.appearance import (CameraStyle, camera_style, sample_appearance,
                                         stack_appearances)
from sianms_cli.synth.objects import KINDS


@pytest.mark.parametrize("kind", KINDS)
def test_same_seed_same_appearance(kind):
    a = sample_appearance(kind, np.random.default_rng(5))
    b = sample_appearance(kind, np.random.default_rng(5))
    for name in ("base", "secondary", "pattern_param", "glass", "skin", "hair", "top", "bottom"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert (a.variant, a.pattern, a.gloss, a.rider) == (b.variant, b.pattern, b.gloss, b.rider)


def test_car_colours_are_mostly_achromatic():
    # White, black, grey and silver make 81 % of the palette's shares.
    rng = np.random.default_rng(0)
    bases = np.array([sample_appearance("car", rng).base for _ in range(4000)])
    chroma = (bases.max(axis=1) - bases.min(axis=1)) / bases.max(axis=1)
    share = np.mean(chroma < 0.45)
    assert 0.78 < share < 0.85
    assert np.all((bases > 0) & (bases <= 0.9))


def test_rider_share_and_override():
    rng = np.random.default_rng(1)
    riders = [sample_appearance("bicycle", rng).rider for _ in range(3000)]
    assert abs(np.mean(riders) - 0.413) < 0.03
    assert sample_appearance("motorcycle", rng, rider=True).rider
    assert not sample_appearance("bicycle", rng, rider=False).rider


def test_people_have_clothes_skin_and_hair():
    a = sample_appearance("pedestrian", np.random.default_rng(2))
    for colour in (a.skin, a.hair, a.top, a.bottom):
        assert colour.shape == (3,) and np.all(colour > 0)


def test_unknown_kind_is_rejected():
    with pytest.raises(ValueError, match="unknown object kind"):
        sample_appearance("tram", np.random.default_rng(0))


def test_stack_appearances_pads_with_a_plain_look():
    rng = np.random.default_rng(3)
    apps = [sample_appearance("car", rng), sample_appearance("bus", rng)]
    table = stack_appearances(apps, 4)
    assert table.glass.shape == (4, 3) and table.pattern.shape == (4,)
    np.testing.assert_array_equal(table.secondary[1], apps[1].secondary)
    np.testing.assert_array_equal(table.pattern[2:], [0, 0])


def test_camera_style_ranges_and_determinism():
    styles = [camera_style(np.random.default_rng(s)) for s in range(200)]
    exposure = np.array([s.exposure_stops for s in styles])
    wb = np.array([s.white_balance for s in styles])
    assert np.all(np.abs(exposure) <= 0.3) and exposure.std() > 0.1
    assert np.all((wb >= 0.93) & (wb <= 1.07))
    a, b = camera_style(np.random.default_rng(9)), camera_style(np.random.default_rng(9))
    assert (a.exposure_stops, a.noise_std, a.vignetting) == (b.exposure_stops, b.noise_std, b.vignetting)
    np.testing.assert_array_equal(a.white_balance, b.white_balance)
    assert isinstance(styles[0], CameraStyle)
