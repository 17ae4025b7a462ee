import platform

import numpy as np
import pytest

from sianms_cli.synth import lidar, shapes
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


def returns(scan):
    """The points that are returns (the others are no-return rays stored at the origin)."""
    return lidar.LidarScan(scan.points[scan.returned], scan.owner[scan.returned], scan.returned[scan.returned])


def test_every_ray_is_stored_and_no_return_lies_at_the_origin():
    scan = scan_lidar(wall(), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt)
    assert len(scan.points) == 1084 * 32
    np.testing.assert_array_equal(scan.points[:, 4], np.tile(np.arange(32), 1084))  # whole columns
    lost = scan.points[~scan.returned]
    assert len(lost) > 5000  # sky, dropouts
    np.testing.assert_array_equal(lost[:, :4], 0.0)
    assert np.all(scan.owner[~scan.returned] == -1)
    assert np.all(np.linalg.norm(scan.points[scan.returned, :3], axis=1) > 1.0)


def test_car_windows_return_only_near_normal_incidence():
    # A glass pane facing the sensor, seen head-on in its middle and obliquely at its sides.
    pane = Parts([[10.5, 0.0, 2.0]], [[0.5, 20.0, 2.0]], [0.0], [0], [shapes.GREENHOUSE])
    scan = returns(scan_lidar(pane, LIDAR_TO_WORLD, np.random.default_rng(9), asphalt, dropout=0.0))
    p = scan.points[scan.owner == 0]
    cos_incidence = p[:, 0] / np.linalg.norm(p[:, :3], axis=1)
    assert len(p) > 20 and np.all(cos_incidence > np.cos(np.radians(10.5)))


def test_empty_ground_ring_ranges():
    scan = returns(scan_lidar(concat_parts([]), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt,
                              range_noise_std=0.0, dropout=0.0))
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
    scan = returns(scan_lidar(concat_parts([]), LIDAR_TO_WORLD, np.random.default_rng(1), asphalt,
                              range_noise_std=std))
    ring = scan.points[:, 4].astype(int)
    el = np.radians(HDL32E_ELEVATIONS_DEG[ring])
    rng_m = np.linalg.norm(scan.points[:, :3], axis=1)
    np.testing.assert_array_less(np.abs(rng_m - HEIGHT / np.sin(-el)), 5 * std)
    assert 15_000 < len(scan.points) < 27_000


def test_points_on_a_wall_lie_on_its_face_with_plate_intensity():
    std = 0.02
    scan = returns(scan_lidar(wall(), LIDAR_TO_WORLD, np.random.default_rng(2), asphalt, range_noise_std=std))
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
    scan = returns(scan_lidar(concat_parts([]), LIDAR_TO_WORLD, np.random.default_rng(4), asphalt,
                              range_noise_std=0.0, dropout=0.0))
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


def boxes(rng, count):
    """Random yaw-rotated cuboids around a sensor at the origin, some enclosing it."""
    center = np.column_stack([rng.uniform(-30, 30, (count, 2)), rng.uniform(0.0, 4.0, count)])
    return Parts(center, rng.uniform(0.2, 6.0, (count, 3)), rng.uniform(-np.pi, np.pi, count),
                 np.arange(count), np.zeros(count, int))


def moving_poses(speed, seconds):
    """LIDAR poses (C,4,4) of a sensor driving along x and turning at 0.5 rad/s."""
    yaw = 0.5 * seconds
    poses = np.tile(LIDAR_TO_WORLD, (len(seconds), 1, 1))
    poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = np.cos(yaw), -np.sin(yaw), np.sin(yaw), np.cos(yaw)
    poses[:, 0, 3] = speed * seconds
    return poses


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_raster_cull_finds_every_hit_of_testing_all_pairs(seed):
    rng = np.random.default_rng(seed)
    parts = boxes(rng, 40)
    steps = 360
    seconds = np.linspace(-0.05, 0.0, steps)
    poses = moving_poses(12.0, seconds)
    reference = poses[-1]
    dirs_lidar, _ = lidar.beam_directions(steps, 0.7)
    dirs = np.einsum("cij,cbj->cbi", poses[:, :3, :3], dirs_lidar.reshape(steps, 32, 3)).reshape(-1, 3)
    origins = np.repeat(poses[:, :3, 3] - reference[:3, 3], 32, axis=0)
    level = lidar._level_frame(reference)
    inflate = np.full(len(parts), np.linalg.norm(origins, axis=1).max() + 1e-3)
    margins = lidar._direction_margins(dirs, level, 0.7, steps)
    ray, part = lidar.candidate_pairs(parts, reference[:3, 3], level, inflate, 0.7, steps, *margins)
    local = Parts(parts.center - reference[:3, 3], parts.half_size, parts.yaw, parts.owner, parts.material)
    t_max = np.full(len(dirs), np.float32(100.0))
    culled = lidar._nearest_hits(ray, part, origins, dirs, local, t_max, None)
    every_ray, every_part = (a.ravel() for a in np.meshgrid(np.arange(len(dirs)), np.arange(len(parts)), indexing="ij"))
    everything = lidar._nearest_hits(every_ray, every_part, origins, dirs, local, t_max, None)
    assert np.isfinite(everything[0]).sum() > 1000
    for got, expected in zip(culled, everything):
        np.testing.assert_array_equal(got, expected)


def test_points_of_a_moving_sensor_are_motion_compensated():
    # The sensor drives at 15 m/s and turns during the sweep; the wall's points, expressed in
    # the sensor frame at the sweep's time (its last column), still lie on the wall's face.
    steps = 1084
    seconds = np.linspace(-0.05, 0.0, steps)
    poses = moving_poses(15.0, seconds)
    scan = scan_lidar(wall(), poses[-1], np.random.default_rng(7), asphalt, range_noise_std=0.0, dropout=0.0,
                      start_azimuth=np.pi, column_poses=poses, column_seconds=seconds)
    on = scan.owner == 0
    assert on.sum() > 500
    np.testing.assert_allclose(scan.points[on, 0], 10.0, atol=1e-4)
    np.testing.assert_allclose(scan.points[~on & scan.returned, 2], -HEIGHT, atol=1e-4)  # the ground stays flat


def test_a_moving_part_is_where_it_is_when_its_column_fires():
    steps = 1084
    seconds = np.linspace(-0.05, 0.0, steps)
    speed = 20.0  # the wall moves away along x
    start = 0.6
    scan = scan_lidar(wall(), LIDAR_TO_WORLD, np.random.default_rng(8), asphalt, range_noise_std=0.0, dropout=0.0,
                      start_azimuth=start, column_seconds=seconds, part_velocity=np.array([[speed, 0.0, 0.0]]))
    p = scan.points[scan.owner == 0]
    column = np.round((start - np.arctan2(p[:, 1], p[:, 0])) / (2 * np.pi / steps)).astype(int) % steps
    np.testing.assert_allclose(p[:, 0], 10.0 + speed * seconds[column], atol=1e-4)
    assert np.ptp(p[:, 0]) > 0.1  # the sweep smears it


def numpy_nearest_entries(ray, part, origins, dirs, parts: Parts, t_max, motion, chunk):
    """The nearest entry per ray with numpy's arrays (raycast.slab_interval on every pair), chunk by chunk:
    what lidar._nearest_entries must equal to the bit, ties included."""
    half = parts.half_size.astype(np.float32)
    c, s = np.cos(parts.yaw), np.sin(parts.yaw)
    t_best = np.full(len(dirs), np.inf, np.float32)
    part_best = np.full(len(dirs), -1, np.int64)
    for start in range(0, len(ray), chunk):
        rr, pp = ray[start:start + chunk], part[start:start + chunk]
        (t_near, t_far, _), _ = lidar._pair_slabs(rr, pp, origins, dirs, parts.center, half, c, s, motion)
        t = np.where((t_near <= t_far) & (t_near > np.float32(1e-4)) & (t_near < t_max[rr]), t_near, np.inf)
        hit = np.isfinite(t)
        rr, pp, t = rr[hit], pp[hit], t[hit]
        t_new = t_best.copy()
        np.minimum.at(t_new, rr, t)
        win = (t == t_new[rr]) & (t < t_best[rr])
        part_best[rr[win]] = pp[win]
        t_best = t_new
    return t_best, part_best


@pytest.mark.parametrize("moving", [False, True])
def test_nearest_entries_equal_numpys_to_the_bit_with_ties_and_chunks(moving):
    rng = np.random.default_rng(5)
    count = 300
    parts = boxes(rng, count)
    # Stacks of equal boxes (a composite object's coplanar faces) make rays meet parts at the same t.
    parts = Parts(np.concatenate([parts.center, parts.center[:50]]), np.concatenate([parts.half_size,
                  parts.half_size[:50]]), np.concatenate([parts.yaw, parts.yaw[:50]]),
                  np.arange(count + 50), np.zeros(count + 50, int))
    steps = 360
    dirs, _ = lidar.beam_directions(steps, 0.2)
    origins = rng.normal(0.0, 0.05, (len(dirs), 3))
    every_ray, every_part = (a.ravel() for a in np.meshgrid(np.arange(len(dirs)), np.arange(len(parts)),
                                                             indexing="ij"))
    chosen = rng.uniform(size=len(every_ray)) < 0.3
    ray, part = every_ray[chosen], every_part[chosen]
    t_max = np.full(len(dirs), np.float32(45.0))
    motion = lidar.PartMotion(rng.normal(0.0, 8.0, (len(parts), 3)), rng.uniform(-0.05, 0.0, len(dirs))) \
        if moving else None
    chunk = 7_919  # a prime: chunk boundaries fall between the pairs of one ray
    expected = numpy_nearest_entries(ray, part, origins, dirs, parts, t_max, motion, chunk)
    half = parts.half_size.astype(np.float32)
    got = lidar._nearest_entries(ray, part, origins, dirs, parts.center, half, np.cos(parts.yaw), np.sin(parts.yaw),
                                 moving, motion.velocity if moving else np.zeros((0, 3)),
                                 motion.ray_seconds if moving else np.zeros(0), t_max, np.float32(1e-4), chunk)
    assert (expected[1] >= 0).sum() > 500 and (expected[1] >= count).sum() > 20  # the copies win some rays
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])
    normal = lidar._face_normals(got[2], got[1], np.cos(parts.yaw), np.sin(parts.yaw))
    np.testing.assert_array_equal(normal, numpy_face_normals(got[1], origins, dirs, parts, motion))
    assert {0, 1, 2, 3} < set(got[2][got[2] >= 0].tolist())  # through the four sides and a horizontal face


def numpy_face_normals(part_best, origins, dirs, parts: Parts, motion):
    """The outward normal of the face each ray enters its part through, with numpy's arrays: the
    slab of largest entry, first of equal ones (argmax over raycast.slab_interval's t_lo)."""
    rr = np.flatnonzero(part_best >= 0)
    pp = part_best[rr]
    half = parts.half_size.astype(np.float32)
    c, s = np.cos(parts.yaw), np.sin(parts.yaw)
    (_, _, t_lo), d = lidar._pair_slabs(rr, pp, origins, dirs, parts.center, half, c, s, motion)
    axis = np.argmax(np.stack(t_lo, axis=1), axis=1)
    sign = np.where(np.take_along_axis(np.stack(d, axis=1), axis[:, None], 1)[:, 0] > 0, -1.0, 1.0)
    n_local = np.zeros((len(rr), 3))
    n_local[np.arange(len(rr)), axis] = sign
    normal = np.zeros((len(dirs), 3))
    normal[rr] = np.column_stack([c[pp] * n_local[:, 0] - s[pp] * n_local[:, 1],
                                  s[pp] * n_local[:, 0] + c[pp] * n_local[:, 1], n_local[:, 2]])
    return normal


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64"), reason="einsum's summation order is x86-64's")
def test_columns_turn_as_numpys_einsum_turned_them_to_the_bit():
    rotations = np.random.default_rng(4).normal(size=(1084, 3, 3))  # any matrices: the arithmetic is the point
    dirs, _ = lidar.beam_directions(1084, 0.3)
    dirs = dirs.reshape(1084, 32, 3)
    turned = lidar._turn_columns(rotations, dirs)
    np.testing.assert_array_equal(turned, np.einsum("cij,cbj->cbi", rotations, dirs))
    x_plus_y_first = (rotations[:, None, :, 0] * dirs[:, :, None, 0] + rotations[:, None, :, 1] * dirs[:, :, None, 1]) \
        + rotations[:, None, :, 2] * dirs[:, :, None, 2]
    assert not np.array_equal(turned, x_plus_y_first)  # the order matters to the bit


def test_raster_pairs_list_each_block_part_by_part_column_by_column():
    k_lo = np.array([-2, 1081, 5, 7])  # a block before the first column and one past the last wrap around
    n_col = np.array([3, 4, 0, 2])
    b_lo, n_beam = np.array([0, 30, 4, 10]), np.array([2, 2, 3, 0])
    reach, t_max = np.full(4, -np.inf), np.full(1084 * 32, np.inf)
    ray, part = lidar._raster_pairs(k_lo, n_col, b_lo, n_beam, 1084, 32, reach, t_max)
    assert part.tolist() == [0] * 6 + [1] * 8  # no pair for a block without columns or beams
    assert ray.tolist()[:6] == [c * 32 + b for c in (1082, 1083, 0) for b in (0, 1)]
    assert ray.tolist()[6:] == [c * 32 + 30 + b for c in (1081, 1082, 1083, 0) for b in (0, 1)]


def test_raster_pairs_leave_out_parts_beyond_a_rays_reach():
    k_lo, n_col, b_lo, n_beam = np.array([0, 0]), np.array([2, 2]), np.array([0, 0]), np.array([2, 2])
    t_max = np.full(1084 * 32, 50.0)
    t_max[[1, 32]] = 20.0  # rays 1 and 32 meet the ground at 20 m
    ray, part = lidar._raster_pairs(k_lo, n_col, b_lo, n_beam, 1084, 32, np.array([20.0, 30.0]), t_max)
    assert list(zip(part.tolist(), ray.tolist())) == [(0, 0), (0, 1), (0, 32), (0, 33), (1, 0), (1, 33)]
