"""The camera under night and rain, its auto exposure, clouds, glare and lens drops."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from sianms_cli.synth import camera, shapes
from sianms_cli.synth.appearance import CameraStyle, sample_appearance
from sianms_cli.synth.camera import render_camera
from sianms_cli.synth.conditions import Conditions
from sianms_cli.synth.shapes import Parts, concat_parts, empty_parts

W, H, F, CX, CY = 160, 120, 100.0, 80.0, 60.0
K = np.array([[F, 0.0, CX], [0.0, F, CY], [0.0, 0.0, 1.0]])
SUN = np.array([0.3, 0.2, 0.9])
# Camera 1.5 m above the origin looking along +x: camera x = -y, camera y = -z, camera z = +x.
CAM_TO_WORLD = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5],
                         [0.0, 0.0, 0.0, 1.0]])
NIGHT, RAIN, NIGHT_RAIN = Conditions(night=True), Conditions(rain=True), Conditions(night=True, rain=True)


def asphalt(xy):
    return np.full((len(xy), 3), 0.1)


def car_with_headlight():
    """A body facing the camera at 12 m with a headlight part on its near face."""
    return Parts([(13.0, 0.0, 1.0), (11.99, 0.3, 0.9)], [(1.0, 1.0, 0.6), (0.01, 0.5, 0.3)], [0.0, 0.0],
                 [0, 0], [shapes.PAINT, shapes.HEADLIGHT])


def render(parts, conditions=Conditions(), seed=0, style=None, sun=SUN, **kwargs):
    apps = [sample_appearance("car", np.random.default_rng(0))]
    return render_camera(parts, apps, asphalt, K, CAM_TO_WORLD, W, H, style or CameraStyle(), sun, 1,
                         np.random.default_rng(seed), conditions=conditions, **kwargs)


def test_night_is_darker_overall_but_a_headlight_is_bright():
    parts = car_with_headlight()
    day, night = render(parts), render(parts, NIGHT)
    headlight = (night.depth < 11.99) & (night.owner_map == 0)  # the lamp's face is at 11.98 m
    assert headlight.sum() > 20
    assert night.image.mean() < 0.5 * day.image.mean()
    assert night.image[headlight].mean() > 240
    assert night.image[headlight].mean() > day.image[headlight].mean() + 50


def ground_radiance(conditions, wetness=None):
    """Radiance of road points 5-60 m ahead of the camera, seen from 1.5 m, under conditions."""
    view = camera._make_view(K, CAM_TO_WORLD, W, H)
    lighting = camera._lighting(conditions, SUN / np.linalg.norm(SUN), 0, empty_parts(), view, None)
    if wetness is not None:
        lighting = dataclasses.replace(lighting, wetness=wetness)
    x = np.linspace(5.0, 60.0, 50)
    points = np.stack([x, np.zeros_like(x), np.full_like(x, -1.5)]).astype(np.float32)
    dirs = points / np.linalg.norm(points, axis=0)
    scene = SimpleNamespace(lighting=lighting, ground_shader=asphalt)
    return camera._ground_radiance(scene, view.origin[:2] + points[:2].T, points, dirs, np.zeros(len(x), bool))


def test_a_wet_road_mirrors_the_sky_and_more_so_at_grazing_angles():
    wet, dry = ground_radiance(RAIN), ground_radiance(RAIN, wetness=0.0)
    assert np.all(wet.mean(axis=0) > 1.5 * dry.mean(axis=0))
    # Fresnel: the farther (more grazing) road mirrors more.
    assert wet.mean(axis=0)[-1] > wet.mean(axis=0)[0]


def street_lamp(x=20.0):
    """A street-light luminaire (scenery, HEADLIGHT) 6 m up, x metres ahead."""
    return Parts([(x, 0.0, 6.0)], [(0.3, 0.2, 0.02)], [0.0], [-1], [shapes.HEADLIGHT])


def test_a_wet_road_mirrors_a_street_lamp_at_night():
    view = camera._make_view(K, CAM_TO_WORLD, W, H)
    parts = street_lamp()
    lighting = camera._lighting(NIGHT_RAIN, SUN, 0, parts, view, camera._emission(parts))
    image = np.zeros((3, H, W), np.float32)
    road = np.zeros((H, W), bool)
    road[int(CY) + 1:] = True
    lighting.glints.draw(image, road, view, 0.4)
    # The lamp's mirror image lies below the horizon in the image column of the lamp.
    v_mirror = int(CY + F * (6.0 + 1.5) / 20.0)
    assert image[:, v_mirror, int(CX)].min() > 0.1
    assert image[:, :int(CY) + 1].max() == 0.0  # nothing off the road
    assert camera._lighting(NIGHT, SUN, 0, parts, view, camera._emission(parts)).glints is None


def test_street_lamps_light_the_road_beneath_them_at_night():
    lit = render(street_lamp(15.0), NIGHT, style=CameraStyle())
    unlit = render(empty_parts(), NIGHT, style=CameraStyle())
    below = slice(int(CY + F * 1.5 / 15.0) - 2, int(CY + F * 1.5 / 15.0) + 3)
    assert lit.image[below, 70:90].mean() > unlit.image[below, 70:90].mean() + 20


def wall(height):
    """A dark wall across the view 8 m ahead, height metres tall."""
    return Parts([(8.0, 0.0, height / 2)], [(0.1, 30.0, height / 2)], [0.0], [-1], [shapes.TRIM])


def test_exposure_is_metered_per_frame():
    # The same sky in two frames: more of the dark wall in the second makes the meter
    # raise the gain, so the sky is brighter there.
    low, high = render(wall(2.0)), render(wall(3.0))
    sky = (low.depth == np.inf) & (high.depth == np.inf)
    assert sky.sum() > 1000
    assert high.image[sky].mean() > low.image[sky].mean() + 10
    # and per camera: the style's own offset adds to it.
    brighter = render(wall(2.0), style=CameraStyle(exposure_stops=0.3))
    assert brighter.image[sky].mean() > low.image[sky].mean() + 5


def test_white_balance_drifts_from_frame_to_frame():
    first, second = render(empty_parts(), seed=1), render(empty_parts(), seed=2)
    channel_means = [frame.image.reshape(-1, 3).mean(axis=0) for frame in (first, second)]
    ratio = channel_means[0] / channel_means[1]
    assert np.ptp(ratio) > 1e-3


def test_clouds_change_the_sky_but_not_the_geometry():
    parts = concat_parts([car_with_headlight(), Parts([(30.0, 8.0, 10.0)], [(5.0, 5.0, 10.0)], [0.3], [-1],
                                                      [shapes.FACADE])])
    a, b = render(parts, sky_seed=1), render(parts, sky_seed=7)  # a third and 44 % of the sky clouded
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.owner_map, b.owner_map)
    sky = a.depth == np.inf
    assert np.abs(a.image[sky].astype(int) - b.image[sky].astype(int)).mean() > 2


def test_flare_only_when_facing_the_sun():
    view = camera._make_view(K, CAM_TO_WORLD, W, H)

    def glare(sun):
        sun = np.asarray(sun, float) / np.linalg.norm(sun)
        lighting = dataclasses.replace(camera._lighting(Conditions(), sun, 0, empty_parts(), view, None),
                                       sky=dataclasses.replace(camera._sky(Conditions(), sun, 0), cover=0.0))
        image = np.zeros((3, H, W), np.float32)
        camera._lens_flare(image, lighting, view)
        return image

    ahead, just_outside, behind = glare([1.0, 0.0, 0.3]), glare([1.0, -1.0, 0.3]), glare([-1.0, 0.0, 0.3])
    assert ahead.mean() > 0.05
    assert 0.0 < just_outside.mean() < ahead.mean()  # 45 degrees right of the 39-degree half view
    assert behind.max() == 0.0
    assert glare([1.0, 0.0, 0.3]).mean() == ahead.mean()
    night_lighting = camera._lighting(NIGHT, np.array([1.0, 0.0, 0.3]) / np.hypot(1.0, 0.3), 0, empty_parts(),
                                      view, camera._emission(empty_parts()))
    image = np.zeros((3, H, W), np.float32)
    camera._lens_flare(image, night_lighting, view)
    assert image.max() == 0.0


def test_lens_drops_and_noise_are_deterministic_per_rng():
    parts = car_with_headlight()
    style = CameraStyle(noise_std=0.01, vignetting=0.2)
    for conditions in (RAIN, NIGHT_RAIN):
        a = render(parts, conditions, seed=3, style=style, motion_blur_px=5.0)
        b = render(parts, conditions, seed=3, style=style, motion_blur_px=5.0)
        c = render(parts, conditions, seed=4, style=style, motion_blur_px=5.0)
        assert a.image.tobytes() == b.image.tobytes()
        assert a.image.tobytes() != c.image.tobytes()


def test_motion_blur_smears_horizontally_at_night_only():
    parts = car_with_headlight()
    sharp, blurred = render(parts, NIGHT), render(parts, NIGHT, motion_blur_px=8.0)
    day_sharp, day_blurred = render(parts), render(parts, motion_blur_px=8.0)

    def lit_width(image):
        """Pixels per row brighter than the dark body: the headlight and its smear."""
        return (image.min(axis=2) > 120).sum(axis=1).max()

    # The headlight (10 px wide) smears over about 8 px more.
    assert lit_width(blurred.image) >= lit_width(sharp.image) + 5
    assert day_sharp.image.tobytes() == day_blurred.image.tobytes()
    side = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    # 100 px focal length, 10 m/s across the view, 20 ms at 10 m: 2 px.
    assert camera.motion_blur_length(K, side, [10.0, 0.0, 0.0], night=True) == pytest.approx(2.0)
    assert camera.motion_blur_length(K, CAM_TO_WORLD, [10.0, 0.0, 0.0], night=True) < 1e-6
    assert camera.motion_blur_length(K, side, [10.0, 0.0, 0.0], night=False) == 0.0
