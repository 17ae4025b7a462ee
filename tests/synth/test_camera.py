import numpy as np
import pytest

from sianms_cli.synth import camera, shapes
from sianms_cli.synth.appearance import CameraStyle, camera_style, sample_appearance
from sianms_cli.synth.camera import coverage_counts, render_camera
from sianms_cli.synth.raycast import intersect_ground, intersect_parts
from sianms_cli.synth.shapes import Parts, concat_parts

W, H, F, CX, CY = 160, 120, 100.0, 80.0, 60.0
K = np.array([[F, 0.0, CX], [0.0, F, CY], [0.0, 0.0, 1.0]])
SUN = np.array([0.3, 0.2, 0.9])
# Camera 1.5 m above the origin looking along +x: camera x = -y, camera y = -z, camera z = +x.
CAM_TO_WORLD = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5],
                         [0.0, 0.0, 0.0, 1.0]])


def flat_ground(xy):
    return np.full((len(xy), 3), 0.1)


def cube(owner=0, center=(10.0, 0.0, 1.5), half=(1.0, 1.0, 1.0)):
    return Parts([center], [half], [0.0], [owner], [shapes.PAINT])


def render(parts, n_objects=1, style=None, seed=0):
    apps = [sample_appearance("car", np.random.default_rng(i)) for i in range(n_objects)]
    return render_camera(parts, apps, flat_ground, K, CAM_TO_WORLD, W, H, style or CameraStyle(),
                         SUN, n_objects, np.random.default_rng(seed))


def counts(parts, n_objects=1, pad_rows=0):
    return coverage_counts(parts, K, CAM_TO_WORLD, W, H, n_objects, pad_rows)


def predicted_front_face_mask(x_face, y_lo, y_hi, z_lo, z_hi):
    """Pixels whose centre projects inside the face x = x_face, y in [y_lo, y_hi], z in [z_lo, z_hi]."""
    u = np.arange(W) + 0.5
    v = np.arange(H) + 0.5
    y = -(u - CX) / F * x_face
    z = 1.5 - (v - CY) / F * x_face
    return ((z[:, None] >= z_lo) & (z[:, None] <= z_hi)) & ((y[None, :] >= y_lo) & (y[None, :] <= y_hi))


def test_cube_covers_exactly_its_projected_pixels():
    out = render(cube())
    expected = predicted_front_face_mask(9.0, -1.0, 1.0, 0.5, 2.5)
    # Face edges project to u, v in {68.89, 91.11}: columns and rows 69..90.
    assert expected.sum() == 22 * 22
    np.testing.assert_array_equal(out.owner_map == 0, expected)
    pixels = counts(cube())
    assert pixels.visible[0] == pixels.in_image[0] == pixels.whole[0] == 484
    assert out.depth[60, 80] == pytest.approx(9.0, abs=1e-5)


def test_occluder_reduces_visible_but_not_object_pixels():
    occluder = cube(owner=1, center=(5.0, 0.5, 1.6), half=(0.2, 0.5, 1.4))
    out = render(concat_parts([cube(), occluder]), n_objects=2)
    pixels = counts(concat_parts([cube(), occluder]), n_objects=2)
    # The occluder's face x = 4.8, y in [0, 1] spans u in [59.2, 80]: columns 59..79 hide the
    # cube's columns 69..79, leaving 90 - 80 + 1 = 11 of its 22 columns.
    assert pixels.in_image[0] == 484
    assert pixels.visible[0] == 22 * 11
    occluder_mask = predicted_front_face_mask(4.8, 0.0, 1.0, 0.2, 3.0)
    assert occluder_mask.sum() == 58 * 21
    assert pixels.in_image[1] == pixels.visible[1] == occluder_mask.sum()
    np.testing.assert_array_equal(out.owner_map == 1, occluder_mask)


def test_scenery_occludes_but_is_not_counted():
    occluder = cube(owner=-1, center=(5.0, 0.5, 1.6), half=(0.2, 0.5, 1.4))
    out = render(concat_parts([cube(), occluder]), n_objects=1)
    pixels = counts(concat_parts([cube(), occluder]))
    assert pixels.in_image[0] == 484
    assert pixels.visible[0] == 242
    assert np.all(out.owner_map[out.depth < 4.9] == -1)


def test_ground_depth_and_sky():
    out = render(cube())
    # Row 100 looks down by (100.5 - 60) / 100 per metre ahead: the ground is 1.5 / 0.405 ahead.
    assert out.depth[100, 10] == pytest.approx(1.5 / 0.405, rel=1e-6)
    assert np.isinf(out.depth[0, 0]) and out.owner_map[0, 0] == -1
    assert out.image.shape == (H, W, 3) and out.image.dtype == np.uint8
    assert out.owner_map.dtype == np.int32 and out.depth.dtype == np.float32


def test_same_seed_same_image_and_style_changes_only_pixels():
    style = camera_style(np.random.default_rng(4))
    a, b = render(cube(), style=style, seed=3), render(cube(), style=style, seed=3)
    np.testing.assert_array_equal(a.image, b.image)
    other = render(cube(), style=camera_style(np.random.default_rng(5)), seed=3)
    np.testing.assert_array_equal(a.owner_map, other.owner_map)
    assert np.abs(a.image.astype(int) - other.image.astype(int)).mean() > 1.0


def test_face_turned_to_the_sun_is_brighter_than_the_face_in_shade():
    apps = [sample_appearance("car", np.random.default_rng(0))]

    def mean_cube_level(sun):
        out = render_camera(cube(), apps, flat_ground, K, CAM_TO_WORLD, W, H, CameraStyle(), sun, 1,
                            np.random.default_rng(0))
        return out.image[out.owner_map == 0].astype(float).mean()
    # The visible face looks along -x: lit by a sun behind the camera, in shade with the sun behind the cube.
    assert mean_cube_level(np.array([-1.0, 0.0, 0.3])) > mean_cube_level(np.array([1.0, 0.0, 0.3])) + 20


def test_empty_scene_renders_ground_and_sky():
    out = render(concat_parts([]), n_objects=0)
    assert counts(concat_parts([]), n_objects=0).whole.shape == (0,) and np.all(out.owner_map == -1)
    assert np.isfinite(out.depth[-1]).all() and np.isinf(out.depth[0]).all()


def test_large_part_cast_as_a_block_covers_exactly_its_projected_pixels():
    # 100 x 100 pixels: more than camera._BLOCK_AREA, so cast as a 2-D block, not as pairs.
    out = render(cube(center=(3.0, 0.0, 1.5)))
    expected = predicted_front_face_mask(2.0, -1.0, 1.0, 0.5, 2.5)
    assert expected.sum() > camera._BLOCK_AREA
    np.testing.assert_array_equal(out.owner_map == 0, expected)
    pixels = counts(cube(center=(3.0, 0.0, 1.5)))
    assert pixels.in_image[0] == pixels.visible[0] == pixels.whole[0] == expected.sum()


def street_scene(seed=0, n=40):
    """Objects and scenery of random sizes and yaws around the camera, none within 1 m of it."""
    rng = np.random.default_rng(seed)
    center = np.column_stack([rng.uniform(2, 40, n), rng.uniform(-15, 15, n), rng.uniform(0.2, 3, n)])
    owner = np.where(rng.uniform(size=n) < 0.7, rng.integers(0, 5, n), -1)
    return Parts(center, rng.uniform(0.1, 2.5, (n, 3)), rng.uniform(-np.pi, np.pi, n), owner,
                 rng.integers(0, len(shapes.MATERIALS), n))


def test_nearest_surfaces_match_the_generic_intersector():
    parts = street_scene()
    out = render(parts, n_objects=5)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays_cam = np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(W * H)])
    dirs = (CAM_TO_WORLD[:3, :3] @ rays_cam).T
    origin = CAM_TO_WORLD[:3, 3]
    t_ground = intersect_ground(origin, dirs, t_max=camera.GROUND_RANGE / np.linalg.norm(dirs, axis=1))
    t, part, _, _ = intersect_parts(origin, dirs, parts, t_max=t_ground)
    on_part = t < t_ground
    owner = np.where(on_part, parts.owner[np.maximum(part, 0)], -1)
    depth = np.where(on_part, t, t_ground)
    assert on_part.mean() > 0.2 and (owner >= 0).mean() > 0.05
    np.testing.assert_array_equal(out.owner_map.ravel(), owner)
    np.testing.assert_allclose(out.depth.ravel(), depth, rtol=1e-5)


def test_band_tile_and_chunk_sizes_do_not_change_the_render(monkeypatch):
    parts = street_scene(seed=1)
    style = camera_style(np.random.default_rng(2))
    reference = render(parts, n_objects=5, style=style)
    reference_counts = counts(parts, n_objects=5, pad_rows=30)
    monkeypatch.setattr(camera, "_BAND_PIXELS", 1000)
    monkeypatch.setattr(camera, "_CHUNK", 777)
    monkeypatch.setattr(camera, "_BLOCK_AREA", 50)
    small = render(parts, n_objects=5, style=style)
    for name in ("image", "owner_map", "depth"):
        np.testing.assert_array_equal(getattr(small, name), getattr(reference, name), err_msg=name)
    small_counts = counts(parts, n_objects=5, pad_rows=30)
    for name in ("visible", "in_image", "whole"):
        np.testing.assert_array_equal(getattr(small_counts, name), getattr(reference_counts, name), err_msg=name)


def test_objects_cast_shadows_on_the_ground_and_scenery_does_not():
    def render_overhead_sun(owner):
        return render_camera(cube(owner=owner), [], flat_ground, K, CAM_TO_WORLD, W, H, CameraStyle(),
                             np.array([0.0, 0.0, 1.0]), 1, np.random.default_rng(0)).image.astype(float)
    # With the sun overhead the cube's shadow is the ground x in [9, 11], y in [-1, 1]:
    # rows 74-76 below the cube; the same rows far to the side are lit.
    shadow, lit = np.s_[74:77, 72:88], np.s_[74:77, 10:30]
    image = render_overhead_sun(owner=0)
    assert image[shadow].mean() < image[lit].mean() - 20
    image = render_overhead_sun(owner=-1)
    assert abs(image[shadow].mean() - image[lit].mean()) < 3


def test_scenery_casts_shadows_where_the_caller_says_so():
    """Street clutter (owner -1, like buildings) casts a shadow when ``casts_shadow`` marks it."""
    def render_overhead_sun(casts):
        return render_camera(cube(owner=-1), [], flat_ground, K, CAM_TO_WORLD, W, H, CameraStyle(),
                             np.array([0.0, 0.0, 1.0]), 1, np.random.default_rng(0),
                             casts_shadow=casts).image.astype(float)
    shadow, lit = np.s_[74:77, 72:88], np.s_[74:77, 10:30]
    n_parts = len(cube(owner=-1).owner)
    image = render_overhead_sun(np.ones(n_parts, bool))
    assert image[shadow].mean() < image[lit].mean() - 20
    image = render_overhead_sun(np.zeros(n_parts, bool))
    assert abs(image[shadow].mean() - image[lit].mean()) < 3


def test_sensor_noise_has_the_style_standard_deviation():
    # One seed for both: the frame's white-balance drift comes first from the same rng.
    clean = render(cube(), style=CameraStyle(), seed=5).image.astype(float)
    noisy = render(cube(), style=CameraStyle(noise_std=0.01), seed=5).image.astype(float)
    mid = (clean > 20) & (clean < 235)
    noise = (noisy - clean)[mid]
    assert abs(noise.mean()) < 0.1
    assert noise.std() == pytest.approx(2.55, rel=0.1)


def test_coverage_counts_see_what_the_render_sees():
    """Objects and scenery around the camera: the visible pixels are the render's, padded or
    not (the padding casts no scenery, so it changes no pixel of the image)."""
    parts = street_scene(seed=3)
    out = render(parts, n_objects=5)
    pixels = counts(parts, n_objects=5)
    owners = out.owner_map[out.owner_map >= 0]
    assert (parts.owner < 0).any() and len(np.unique(owners)) == 5
    np.testing.assert_array_equal(pixels.visible, np.bincount(owners, minlength=5))
    padded = counts(parts, n_objects=5, pad_rows=40)
    np.testing.assert_array_equal(padded.visible, pixels.visible)
    np.testing.assert_array_equal(padded.in_image, pixels.in_image)
    assert np.all(padded.whole >= padded.in_image)


def test_the_padded_canvas_counts_what_the_image_edges_cut_off():
    """A cube 2 m ahead, its face 2 m tall: rows 9.5 .. 110.5 of the 120 fit in the image;
    from 1.5 m up to 3.5 m the face runs 100 rows above and 0 below the centre row 60."""
    near = cube(center=(3.0, 0.0, 2.5))  # face x = 2, z in [1.5, 3.5]: v = 60 - 100 * (z - 1.5) / 2
    expected = predicted_front_face_mask(2.0, -1.0, 1.0, 1.5, 3.5)
    columns = expected.any(axis=0).sum()
    pixels = counts(near, pad_rows=H)
    assert columns == 100
    assert pixels.in_image[0] == pixels.visible[0] == expected.sum() == 60 * columns
    assert pixels.whole[0] == 100 * columns  # rows -40 .. 59: the 40 above the image count too
    assert counts(near).whole[0] == expected.sum()  # without padding, only the image
