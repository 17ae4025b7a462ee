import numpy as np
import pytest

from sianms_cli.synth import shapes
from sianms_cli.synth.lidar import HDL32E_ELEVATIONS_DEG, MATERIAL_REFLECTIVITY, scan_lidar
from sianms_cli.synth.shapes import Parts, concat_parts

HEIGHT = 1.84
LIDAR_TO_WORLD = np.eye(4)
LIDAR_TO_WORLD[2, 3] = HEIGHT


def asphalt(xy):
    return np.full(len(xy), 0.1)


def wall(material=shapes.PLATE):
    # Face x = 10, y in [-5, 5], z in [0, 4].
    return Parts([[10.5, 0.0, 2.0]], [[0.5, 5.0, 2.0]], [0.0], [0], [material])


def test_elevations():
    assert len(HDL32E_ELEVATIONS_DEG) == 32
    assert HDL32E_ELEVATIONS_DEG[0] == -30.67 and HDL32E_ELEVATIONS_DEG[-1] == pytest.approx(10.67)
    np.testing.assert_allclose(np.diff(HDL32E_ELEVATIONS_DEG), 41.34 / 31)


def test_empty_ground_ring_ranges():
    scan = scan_lidar(concat_parts([]), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt,
                      range_noise_std=0.0, dropout=0.0)
    ring = scan.points[:, 4].astype(int)
    horizontal = np.hypot(scan.points[:, 0], scan.points[:, 1])
    expected = HEIGHT / np.tan(-np.radians(HDL32E_ELEVATIONS_DEG[ring]))
    np.testing.assert_allclose(horizontal, expected, rtol=1e-5)
    np.testing.assert_allclose(scan.points[:, 2], -HEIGHT, atol=1e-5)
    assert np.all(HDL32E_ELEVATIONS_DEG[ring] < 0)
    assert set(range(16)) <= set(ring.tolist())
    assert np.all(scan.owner == -1)


def test_empty_ground_with_noise_stays_within_noise():
    std = 0.02
    scan = scan_lidar(concat_parts([]), LIDAR_TO_WORLD, np.random.default_rng(1), asphalt,
                      range_noise_std=std)
    ring = scan.points[:, 4].astype(int)
    el = np.radians(HDL32E_ELEVATIONS_DEG[ring])
    rng_m = np.linalg.norm(scan.points[:, :3], axis=1)
    np.testing.assert_array_less(np.abs(rng_m - HEIGHT / np.sin(-el)), 5 * std)
    assert 15_000 < len(scan.points) < 27_000


def test_points_on_a_wall_lie_on_its_face_with_plate_intensity():
    std = 0.02
    scan = scan_lidar(wall(), LIDAR_TO_WORLD, np.random.default_rng(2), asphalt, range_noise_std=std)
    on = scan.owner == 0
    p = scan.points[on]
    assert on.sum() > 500
    np.testing.assert_array_less(np.abs(p[:, 0] - 10.0), 5 * std)
    assert np.all(np.abs(p[:, 1]) <= 5.0 + 5 * std)
    assert np.all((p[:, 2] >= -HEIGHT - 5 * std) & (p[:, 2] <= 4.0 - HEIGHT + 5 * std))
    cos_inc = p[:, 0] / np.linalg.norm(p[:, :3], axis=1)
    ratio = p[:, 3] / (255.0 * MATERIAL_REFLECTIVITY[shapes.PLATE] * cos_inc)
    assert np.all((ratio > 0.75) & (ratio < 1.3))
    assert np.all(p[:, 3] == np.round(p[:, 3]))


def test_tyre_returns_are_weaker_than_plate_returns():
    plate = scan_lidar(wall(shapes.PLATE), LIDAR_TO_WORLD, np.random.default_rng(3), asphalt)
    tyre = scan_lidar(wall(shapes.TYRE), LIDAR_TO_WORLD, np.random.default_rng(3), asphalt)
    assert tyre.points[tyre.owner == 0, 3].mean() < 0.1 * plate.points[plate.owner == 0, 3].mean()


def test_firing_order_is_column_major_clockwise():
    scan = scan_lidar(concat_parts([]), LIDAR_TO_WORLD, np.random.default_rng(4), asphalt,
                      range_noise_std=0.0, dropout=0.0)
    az = np.unwrap(np.arctan2(scan.points[:, 1], scan.points[:, 0]))
    step = np.diff(az)
    assert np.all(step <= 1e-6)
    same_column = np.abs(step) < 1e-6
    assert np.all(np.diff(scan.points[:, 4])[same_column] > 0)
    assert az[0] - az[-1] == pytest.approx(2 * np.pi * 1083 / 1084, abs=1e-4)


def test_same_seed_same_scan():
    a = scan_lidar(wall(), LIDAR_TO_WORLD, np.random.default_rng(5), asphalt)
    b = scan_lidar(wall(), LIDAR_TO_WORLD, np.random.default_rng(5), asphalt)
    c = scan_lidar(wall(), LIDAR_TO_WORLD, np.random.default_rng(6), asphalt)
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.owner, b.owner)
    assert a.points.dtype == np.float32 and a.points.shape[1] == 5 and a.owner.dtype == np.int32
    assert len(a.points) != len(c.points) or not np.array_equal(a.points, c.points)
