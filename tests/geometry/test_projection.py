import numpy as np
import pytest

from sianms_cli.errors import SianmsError
from sianms_cli.geometry.projection import (
    BoxVisibility,
    box_in_image,
    occlusion_fractions,
    project_boxes_to_image,
    view_points,
)

K = np.array([[100.0, 0.0, 100.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])
IMAGE = (200, 100)


def cuboid(x, y, z):
    """(8, 3) corners of the axis-aligned box [x0, x1] x [y0, y1] x [z0, z1] (camera frame)."""
    return np.array([[a, b, c] for a in x for b in y for c in z], dtype=np.float64)


def test_view_points_perspective():
    projected = view_points(np.array([[1.0, 2.0, 10.0], [-4.0, 0.0, 2.0]]), K)
    np.testing.assert_allclose(projected, [[110.0, 70.0, 1.0], [-100.0, 50.0, 1.0]])


def test_view_points_without_normalisation():
    projected = view_points(np.array([[1.0, 2.0, 10.0]]), K, normalize=False)
    np.testing.assert_array_equal(projected, [[1100.0, 700.0, 10.0]])


def test_view_points_pads_3x4_and_4x4():
    view34 = np.array([[1.0, 0, 0, 5], [0, 1, 0, 6], [0, 0, 1, 7]])
    points = np.array([[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(view_points(points, view34, normalize=False), [[6, 8, 10]])
    view44 = np.vstack([view34, [0, 0, 0, 1]])
    np.testing.assert_array_equal(view_points(points, view44, normalize=True), [[0.6, 0.8, 1.0]])


def test_view_points_mirrors_points_behind_like_the_devkit():
    np.testing.assert_allclose(view_points(np.array([[1.0, 0.0, -10.0]]), K), [[90.0, 50.0, 1.0]])


def test_view_points_rejects_large_matrix():
    with pytest.raises(SianmsError):
        view_points(np.zeros((1, 3)), np.eye(5))


def test_project_boxes_to_image_hand_cases():
    corners = np.stack(
        [
            cuboid((-1, 1), (-0.5, 0.5), (10, 12)),  # fully inside
            cuboid((8, 12), (-0.5, 0.5), (10, 20)),  # straddles the right border
            cuboid((-1, 1), (-0.5, 0.5), (-1, 1)),  # straddles the near plane
            cuboid((-1, 1), (-0.5, 0.5), (-5, -3)),  # behind
            cuboid((30, 32), (-0.5, 0.5), (10, 12)),  # in front, right of the image
        ]
    )
    boxes2d, truncation, valid = project_boxes_to_image(corners, K, IMAGE, near=0.5)
    # Inside: u = 100 x / z + 100 over x = +-1, z = 10 -> [90, 110]; v = 100 y / z + 50 -> [45, 55].
    # Border: u from 100 * 8 / 20 + 100 = 140 to 100 * 12 / 10 + 100 = 220, v in [45, 55];
    #   unclipped area 80 * 10, clipped [140, 200] -> 60 * 10, truncation 1 - 600 / 800.
    # Near plane: the z-edges cut at z = 0.5 -> u in [-100, 300], v in [-50, 150];
    #   unclipped 400 * 200, clipped to the whole image 200 * 100, truncation 0.75.
    np.testing.assert_allclose(
        boxes2d,
        [[90, 45, 110, 55], [140, 45, 200, 55], [0, 0, 200, 100], [0, 0, 0, 0], [0, 0, 0, 0]],
        atol=1e-12,
    )
    np.testing.assert_allclose(truncation, [0.0, 0.25, 0.75, 1.0, 1.0], atol=1e-12)
    np.testing.assert_array_equal(valid, [True, True, True, False, False])


def test_project_boxes_to_image_default_near_plane():
    corners = cuboid((-1, 1), (-0.5, 0.5), (-1, 1))[None]
    _, truncation, valid = project_boxes_to_image(corners, K, IMAGE)
    # At z = 0.1: u in [-900, 1100], v in [-450, 550]; 20000 of 2000 * 1000 pixels remain.
    assert valid[0]
    assert truncation[0] == pytest.approx(1 - 20000 / 2e6, abs=1e-12)


def test_project_boxes_to_image_oblique_near_cut():
    # A cube turned 30 deg about y crosses the near plane with slanted edges; the result
    # must be the extent of the kept corners and of the edge/plane intersections.
    cube = cuboid((-1, 1), (-1, 1), (-1, 1))
    angle = np.radians(30.0)
    rot_y = np.array(
        [[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]]
    )
    corners = cube @ rot_y.T + [0.0, 0.0, 1.2]
    near = 0.5
    kept = [c for c in corners if c[2] >= near]
    for a in range(8):
        for b in range(8):
            # In cuboid() order, corners sharing an edge differ in exactly one index bit.
            if bin(a ^ b).count("1") == 1 and corners[a, 2] < near <= corners[b, 2]:
                t = (near - corners[a, 2]) / (corners[b, 2] - corners[a, 2])
                kept.append(corners[a] + t * (corners[b] - corners[a]))
    assert len(kept) > 8  # some edges were cut
    uv = np.array([[100 * p[0] / p[2] + 100, 100 * p[1] / p[2] + 50] for p in kept])
    big = np.array([[100.0, 0.0, 5e4], [0.0, 100.0, 5e4], [0.0, 0.0, 1.0]])
    boxes2d, _, valid = project_boxes_to_image(corners[None], big, (1e5, 1e5), near=near)
    expected = np.concatenate([uv.min(axis=0), uv.max(axis=0)]) + [5e4 - 100, 5e4 - 50] * 2
    assert valid[0]
    np.testing.assert_allclose(boxes2d[0], expected)


def test_project_boxes_in_front_equals_corner_extent():
    big = np.array([[100.0, 0.0, 5e4], [0.0, 100.0, 5e4], [0.0, 0.0, 1.0]])
    corners = np.random.default_rng(11).uniform(-3, 3, size=(50, 8, 3)) + [0.0, 0.0, 8.0]
    boxes2d, truncation, valid = project_boxes_to_image(corners, big, (1e5, 1e5))
    uv = view_points(corners.reshape(-1, 3), big)[:, :2].reshape(50, 8, 2)
    assert valid.all()
    np.testing.assert_allclose(boxes2d, np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1))
    np.testing.assert_allclose(truncation, 0.0, atol=1e-12)


def test_project_boxes_rejects_non_positive_near():
    with pytest.raises(SianmsError):
        project_boxes_to_image(cuboid((0, 1), (0, 1), (1, 2))[None], K, IMAGE, near=0.0)


def test_box_in_image_levels():
    corners = np.stack(
        [
            cuboid((-1, 1), (-0.5, 0.5), (10, 12)),  # fully visible
            cuboid((8, 12), (-0.5, 0.5), (10, 20)),  # partly visible
            cuboid((-1, 1), (-0.5, 0.5), (0.05, 12)),  # a corner closer than 0.1 m
            cuboid((-0.01, 0.01), (-0.01, 0.01), (0.5, 0.8)),  # in front, all within 1 m
            cuboid((-1, 1), (-0.5, 0.5), (-5, -3)),  # behind
        ]
    )
    np.testing.assert_array_equal(
        box_in_image(corners, K, IMAGE, BoxVisibility.ANY), [True, True, False, False, False]
    )
    np.testing.assert_array_equal(
        box_in_image(corners, K, IMAGE, BoxVisibility.ALL), [True, False, False, False, False]
    )
    np.testing.assert_array_equal(box_in_image(corners, K, IMAGE, BoxVisibility.NONE), [True] * 5)


def test_box_in_image_corner_on_border_is_not_visible():
    # The rightmost corners (x = -12, z = 12) project to u = 0 exactly: strict bounds.
    corners = cuboid((-30, -12), (-0.5, 0.5), (10, 12))[None]
    assert not box_in_image(corners, K, IMAGE)[0]


def test_box_in_image_level_names():
    corners = cuboid((8, 12), (-0.5, 0.5), (10, 20))[None]
    assert box_in_image(corners, K, IMAGE, "any")[0]
    assert not box_in_image(corners, K, IMAGE, "ALL")[0]
    assert box_in_image(corners, K, IMAGE, 1)[0]
    with pytest.raises(SianmsError):
        box_in_image(corners, K, IMAGE, "some")
    with pytest.raises(SianmsError):
        box_in_image(corners, K, IMAGE, 7)


def test_occlusion_by_nearer_boxes_only():
    boxes = np.array([[0, 0, 10, 10], [5, 0, 15, 10], [100, 100, 110, 110]], dtype=float)
    occlusion = occlusion_fractions(boxes, np.array([10.0, 5.0, 1.0]))
    assert occlusion[0] == pytest.approx(0.5)  # right half covered by the nearer box 1
    assert occlusion[1] == 0.0 and occlusion[2] == 0.0
    assert occlusion_fractions(boxes[:1], np.array([1.0])).tolist() == [0.0]
