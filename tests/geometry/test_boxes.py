import numpy as np
import pytest
from devkit_box import devkit_corners, devkit_points_in_box

from sianms_cli.geometry import boxes
from sianms_cli.geometry.boxes import box_corners, count_points_in_boxes, points_in_boxes, points_in_own_boxes
from sianms_cli.geometry.quaternion import quat_multiply, yaw_to_quat

IDENTITY = np.array([[1.0, 0.0, 0.0, 0.0]])
YAW_180 = np.array([[0.0, 0.0, 0.0, 1.0]])  # exact matrix diag(-1, -1, 1)


def random_boxes(n, seed):
    rng = np.random.default_rng(seed)
    center = rng.uniform(-10, 10, size=(n, 3))
    size = rng.uniform(0.5, 5.0, size=(n, 3))
    rotation = rng.normal(size=(n, 4))
    return center, size, rotation


def test_corner_order_axis_aligned():
    corners = box_corners([[1.0, 2.0, 3.0]], [[2.0, 4.0, 6.0]], IDENTITY)
    # half extents: l/2 = 2 along x, w/2 = 1 along y, h/2 = 3 along z.
    expected = [
        [3, 3, 6],  # front-left-top
        [3, 1, 6],  # front-right-top
        [3, 1, 0],  # front-right-bottom
        [3, 3, 0],  # front-left-bottom
        [-1, 3, 6],  # rear-left-top
        [-1, 1, 6],
        [-1, 1, 0],
        [-1, 3, 0],
    ]
    np.testing.assert_array_equal(corners, [expected])


def test_corner_order_yawed():
    corners = box_corners([[1.0, 2.0, 3.0]], [[2.0, 4.0, 6.0]], yaw_to_quat([np.pi / 2]))
    # Heading +y: the front-left-top corner (2, 1, 3) in the box frame is (-1, 2, 3).
    np.testing.assert_allclose(corners[0, 0], [0.0, 4.0, 6.0], atol=1e-15)
    np.testing.assert_allclose(corners[0, 6], [2.0, 0.0, 0.0], atol=1e-15)


def test_corners_match_devkit():
    center, size, rotation = random_boxes(20, seed=5)
    corners = box_corners(center, size, rotation)
    for n in range(20):
        np.testing.assert_allclose(
            corners[n], devkit_corners(center[n], size[n], rotation[n]).T, atol=1e-13
        )


def test_box_corners_empty():
    assert box_corners(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4))).shape == (0, 8, 3)


@pytest.mark.parametrize("rotation", [IDENTITY, YAW_180])
def test_points_in_boxes_inclusive_bounds(rotation):
    # Box spans x in [-2, 2], y in [-1, 1], z in [-1, 1] (symmetric, so yaw 180 is the same).
    center, size = np.zeros((1, 3)), np.array([[2.0, 4.0, 2.0]])
    points = np.array(
        [
            [0.0, 0.0, 0.0],
            [2.0, 1.0, 1.0],  # a corner
            [-2.0, -1.0, -1.0],  # the opposite corner
            [2.0, 0.0, 0.0],  # on a face
            [0.0, -1.0, 0.5],
            [2.0 + 2**-20, 0.0, 0.0],
            [0.0, -1.0 - 2**-20, 0.0],
            [0.0, 0.0, 1.0 + 2**-20],
        ]
    )
    inside = points_in_boxes(points, center, size, rotation)
    np.testing.assert_array_equal(inside, [[True] * 5 + [False] * 3])


def test_points_in_boxes_matches_devkit():
    center, size, rotation = random_boxes(30, seed=6)
    points = np.random.default_rng(7).uniform(-12, 12, size=(3000, 3))
    inside = points_in_boxes(points, center, size, rotation)
    assert inside.shape == (30, 3000) and inside.any()
    for n in range(30):
        expected = devkit_points_in_box(devkit_corners(center[n], size[n], rotation[n]), points.T)
        np.testing.assert_array_equal(inside[n], expected)


def test_points_in_boxes_chunking_gives_same_result(monkeypatch):
    center, size, rotation = random_boxes(13, seed=8)
    points = np.random.default_rng(9).uniform(-12, 12, size=(500, 3))
    whole = points_in_boxes(points, center, size, rotation)
    monkeypatch.setattr(boxes, "_CHUNK_BYTES", 24 * 500 * 3)  # three boxes per chunk
    np.testing.assert_array_equal(points_in_boxes(points, center, size, rotation), whole)


def test_points_in_boxes_empty_inputs():
    center, size, rotation = random_boxes(3, seed=10)
    assert points_in_boxes(np.zeros((0, 3)), center, size, rotation).shape == (3, 0)
    empty = points_in_boxes(np.ones((4, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)))
    assert empty.shape == (0, 4)


def test_count_points_in_boxes_counts_shared_points_twice():
    center = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    size = np.array([[2.0, 2.0, 2.0], [2.0, 2.0, 2.0]])
    rotation = np.repeat(IDENTITY, 2, axis=0)
    points = np.array([[0.5, 0.0, 0.0], [-0.5, 0.0, 0.0], [1.5, 0.0, 0.0], [5.0, 0.0, 0.0]])
    counts = count_points_in_boxes(points, center, size, rotation)
    assert counts.dtype == np.int64
    np.testing.assert_array_equal(counts, [2, 2])


@pytest.mark.parametrize("chunk_bytes", [72 * 5, 32 * 1024 * 1024])
def test_points_in_own_boxes_equal_the_one_box_test_bit_for_bit(monkeypatch, chunk_bytes):
    # Points on the corners, face centres and edges of tilted boxes, where only rounding
    # decides: the answer must be the one-box call's, whatever the other boxes.
    monkeypatch.setattr(boxes, "_CHUNK_BYTES", chunk_bytes)
    rng = np.random.default_rng(11)
    count = 40
    center = rng.normal(0, 20, (count, 3))
    size = rng.uniform(0.3, 6, (count, 3))
    tilt = np.concatenate([np.ones((count, 1)), rng.normal(0, 0.2, (count, 3))], axis=1)
    rotation = quat_multiply(yaw_to_quat(rng.uniform(-np.pi, np.pi, count)), tilt)
    points, owner = [], []
    for n in range(count):
        corners = box_corners(center[n], size[n], rotation[n])[0]
        on_box = np.concatenate([corners, 0.5 * (corners[[0, 1, 4, 2, 0, 3]] + corners[[2, 3, 6, 7, 5, 6]]),
                                 0.5 * (corners[boxes.BOX_EDGES[:, 0]] + corners[boxes.BOX_EDGES[:, 1]]),
                                 center[n] + rng.normal(0, 2, (20, 3))])
        points.append(on_box)
        owner.append(np.full(len(on_box), n))
    points, owner = np.concatenate(points), np.concatenate(owner)
    expected = np.concatenate([points_in_boxes(points[owner == n], center[n], size[n], rotation[n])[0]
                               for n in range(count)])
    assert np.array_equal(points_in_own_boxes(points, owner, center, size, rotation), expected)
    assert 0 < expected.sum() < len(expected)
    assert points_in_own_boxes(np.zeros((0, 3)), np.zeros(0, np.int64), center, size, rotation).shape == (0,)
