import numpy as np
import pytest

from sianms_cli.synth.parking import bay_poses, car_park_depth
from sianms_cli.synth.road import (
    BAY_DEPTH,
    BAY_START,
    BAY_WIDTH,
    LANE_WIDTH,
    ROW_PITCH,
    CarPark,
    CrossSection,
    Intersection,
    Route,
    Street,
    value_noise,
)


def _route() -> Route:
    # 50 m straight, a left arc of radius 30 m over 40 m, then a right arc of radius 50 m.
    return Route(np.array([100.0, 200.0]), 0.3, np.array([50.0, 40.0, 60.0]), np.array([0.0, 1 / 30, -1 / 50]))


def test_straight_segment_pose_is_origin_plus_heading():
    route = _route()
    xy, heading = route.pose(np.array([0.0, 20.0]), 2.0)
    direction = np.array([np.cos(0.3), np.sin(0.3)])
    left = np.array([-np.sin(0.3), np.cos(0.3)])
    np.testing.assert_allclose(xy[0], [100.0, 200.0] + 2.0 * left)
    np.testing.assert_allclose(xy[1], [100.0, 200.0] + 20.0 * direction + 2.0 * left)
    np.testing.assert_allclose(heading, 0.3)


def test_arc_heading_turns_by_curvature_times_length():
    route = _route()
    _, heading = route.pose(np.array([90.0, 150.0]))
    assert heading[0] == pytest.approx(0.3 + 40 / 30)
    assert heading[1] == pytest.approx(0.3 + 40 / 30 - 60 / 50)


def test_arc_points_stay_on_their_circle():
    route = _route()
    s = np.linspace(50.0, 90.0, 9)
    xy, _ = route.pose(s, 0.0)
    start, heading = route.pose(np.array([50.0]))
    center = start[0] + 30.0 * np.array([-np.sin(heading[0]), np.cos(heading[0])])
    np.testing.assert_allclose(np.hypot(*(xy - center).T), 30.0)


def test_route_frame_inverts_pose():
    route = _route()
    rng = np.random.default_rng(0)
    s = rng.uniform(1.0, 149.0, 500)
    d = rng.uniform(-8.0, 8.0, 500)
    xy, _ = route.pose(s, d)
    s_back, d_back = route.to_route_frame(xy)
    np.testing.assert_allclose(s_back, s, atol=1e-9)
    np.testing.assert_allclose(d_back, d, atol=1e-9)


def test_lane_centres_follow_the_drive_side():
    right = CrossSection(lanes_per_direction=2, parking=True, drive_side=+1)
    left = CrossSection(lanes_per_direction=2, parking=True, drive_side=-1)
    assert right.lane_center(0, +1) == pytest.approx(-LANE_WIDTH / 2)
    assert right.lane_center(1, -1) == pytest.approx(1.5 * LANE_WIDTH)
    assert left.lane_center(0, +1) == pytest.approx(LANE_WIDTH / 2)
    assert right.kerb == pytest.approx(2 * 3.5 + 1.5 + 2.4)


def test_surface_classes_across_the_road():
    route = Route(np.zeros(2), 0.0, np.array([400.0]), np.array([0.0]))
    section = CrossSection(lanes_per_direction=1, parking=False, drive_side=+1)
    street = Street(route, section, (), center_line_yellow=True)
    kerb = section.kerb
    xy = np.array([[100.0, 1.0], [100.0, -(kerb - 0.2)], [100.0, kerb + 1.0], [100.0, -(section.pavement_outer + 2.0)]])
    klass, _, _ = street.surface(xy)
    np.testing.assert_array_equal(klass, [0, 0, 1, 2])


def test_double_yellow_centre_line_and_bright_lidar_paint():
    route = Route(np.zeros(2), 0.0, np.array([400.0]), np.array([0.0]))
    street = Street(route, CrossSection(1, False, +1), (), center_line_yellow=True)
    xy = np.array([[50.0, 0.15], [50.0, -0.15], [50.0, 0.0], [50.0, 1.5]])
    _, markings, yellow = street.surface(xy)
    np.testing.assert_array_equal(markings, [True, True, False, False])
    np.testing.assert_array_equal(yellow, [True, True, False, False])
    reflectivity = street.ground_reflectivity(xy)
    assert reflectivity[0] > 3 * reflectivity[2]


def test_crossing_street_is_asphalt_beyond_the_pavement():
    route = Route(np.zeros(2), 0.0, np.array([400.0]), np.array([0.0]))
    section = CrossSection(1, True, +1)
    crossing = Intersection(200.0, np.array([200.0, 0.0]), np.pi / 2)
    street = Street(route, section, (crossing,), center_line_yellow=False)
    far_along_crossing = np.array([[200.0, section.pavement_outer + 20.0], [230.0, section.pavement_outer + 20.0]])
    klass, _, _ = street.surface(far_along_crossing)
    np.testing.assert_array_equal(klass, [0, 2])
    assert street.near_intersection(np.array([195.0, 260.0]), margin=1.0).tolist() == [True, False]


def test_curvature_at_follows_the_segments():
    route = _route()
    np.testing.assert_array_equal(route.curvature_at(np.array([-5.0, 10.0, 60.0, 100.0, 500.0])),
                                  [0.0, 0.0, 1 / 30, -1 / 50, -1 / 50])


def _turn_street(arms_4way: bool) -> tuple[Street, CrossSection]:
    """The route heads +x, turns left on a radius of 15 m and heads +y; the corner is (115, 0)."""
    route = Route(np.zeros(2), 0.0, np.array([100.0, 15.0 * np.pi / 2, 100.0]), np.array([0.0, 1 / 15, 0.0]))
    section = CrossSection(1, False, +1)
    s = 100.0 + 15.0 * np.pi / 4
    corner = np.array([115.0, 0.0])
    junctions = [Intersection(s, corner, np.pi / 2, arms=(-1,), half_span=15.0 * np.pi / 4 + 2.0)]
    if arms_4way:
        junctions.append(Intersection(s, corner, 0.0, arms=(1,), half_span=15.0 * np.pi / 4 + 2.0))
    return Street(route, section, tuple(junctions), center_line_yellow=True), section


def test_turn_junction_paves_only_the_arms_off_the_route():
    beyond = np.array([[150.0, 0.0]])  # straight on, past the corner
    behind = np.array([[115.0, -40.0]])  # the crossing street's arm opposite the outgoing road
    # On the outgoing road's pavement, where a crossing street with both arms would be asphalt.
    outside = np.array([[115.0 + 6.5, 40.0]])
    t_street, section = _turn_street(arms_4way=False)
    assert section.kerb < 6.5 < section.pavement_outer
    klass, _, _ = t_street.surface(np.concatenate([beyond, behind, outside]))
    np.testing.assert_array_equal(klass, [2, 0, 1])
    four_way, _ = _turn_street(arms_4way=True)
    klass, _, _ = four_way.surface(np.concatenate([beyond, behind, outside]))
    np.testing.assert_array_equal(klass, [0, 0, 1])


def test_turn_junction_spans_the_whole_turn_and_has_no_zebras():
    street, _ = _turn_street(arms_4way=True)
    junction = street.intersections[0]
    assert not junction.through and Intersection(0.0, np.zeros(2), 0.0).through
    inside = np.array([100.0 - 1.0, 100.0 + 15.0 * np.pi / 2 + 1.0])
    assert street.near_intersection(inside, margin=0.0).tolist() == [True, True]
    assert street.near_intersection(np.array([80.0]), margin=0.0).tolist() == [False]
    s = np.linspace(90.0, 140.0, 200)
    xy, _ = street.route.pose(s, 0.25)  # where zebra stripes would be painted
    _, markings, _ = street.surface(xy)
    assert not markings.any()


def test_car_park_is_asphalt_with_slanted_bay_lines():
    route = Route(np.zeros(2), 0.0, np.array([400.0]), np.array([0.0]))
    section = CrossSection(1, False, +1)
    park = CarPark(side=-1, s0=100.0, s1=140.0, depth=6.5, angle=np.pi / 4)
    street = Street(route, section, (), center_line_yellow=True, car_parks=(park,))
    y = -(section.pavement_outer + 3.0)
    klass, markings, _ = street.surface(np.array([[120.0, y], [160.0, y], [120.0, -(section.pavement_outer + 7.0)]]))
    np.testing.assert_array_equal(klass, [0, 2, 2])
    assert park.bay_spacing == pytest.approx(BAY_WIDTH * np.sqrt(2))
    # Along a bay line the paint continues: s grows with the distance into the car park. The points
    # lie mid-paint (0.06 m past the line's start; 0.12 m wide): on its start an ulp of np.tan
    # would decide, which differs between numpy releases.
    across = np.array([1.5, 2.0, 4.0])
    on_line = np.column_stack([100.06 + 3 * park.bay_spacing + across, -(section.pavement_outer + across)])
    _, markings, _ = street.surface(on_line)
    assert markings.all()
    assert street.in_car_park(np.array([120.0, 120.0]), np.array([y, -y])).tolist() == [True, False]


def test_rows_of_bays_repeat_the_first_row_behind_an_aisle():
    route = Route(np.zeros(2), 0.0, np.array([400.0]), np.array([0.0]))
    section = CrossSection(1, False, +1)
    park = CarPark(side=+1, s0=100.0, s1=140.0, depth=car_park_depth(3), angle=np.pi / 3, rows=3)
    street = Street(route, section, (), center_line_yellow=True, car_parks=(park,))
    outer = section.pavement_outer
    s, d, yaw = bay_poses(park, outer)
    per_row = len(s) // 3
    assert per_row == int((40.0 - (BAY_START + BAY_DEPTH) / np.tan(np.pi / 3)) // park.bay_spacing)
    np.testing.assert_allclose(np.unique(d), outer + BAY_START + BAY_DEPTH / 2 + ROW_PITCH * np.arange(3))
    np.testing.assert_array_equal(s[:per_row], s[per_row:2 * per_row])  # straight behind each other
    np.testing.assert_allclose(yaw, np.pi / 3)
    assert park.in_bay_row(d - outer).all() and street.in_car_park(s, d).all()
    # The aisle between two rows is asphalt of the car park without paint; the back row has lines.
    aisle = outer + BAY_START + BAY_DEPTH + 3.0
    assert not park.in_bay_row(np.array([aisle - outer]))[0]
    assert park.in_bay_row(np.array([2 * ROW_PITCH + BAY_START + 1.0, 3 * ROW_PITCH + BAY_START + 1.0])).tolist() \
        == [True, False]
    across = np.array([1.5, 2.0, 4.0]) + 2 * ROW_PITCH
    first_row_across = across - 2 * ROW_PITCH
    on_line = np.column_stack([100.0 + 3 * park.bay_spacing + first_row_across / np.tan(np.pi / 3), outer + across])
    _, markings, _ = street.surface(on_line)
    assert markings.all()
    klass, markings, _ = street.surface(np.array([[120.0, aisle]]))
    assert klass[0] == 0 and not markings[0]


def test_albedo_is_deterministic_and_in_range():
    route = _route()
    street = Street(route, CrossSection(2, True, -1), (), center_line_yellow=False)
    xy = np.random.default_rng(3).uniform(-50, 250, (2000, 2))
    a, b = street.ground_albedo(xy), street.ground_albedo(xy)
    np.testing.assert_array_equal(a, b)
    assert a.shape == (2000, 3) and a.min() >= 0.0 and a.max() <= 1.0


def test_value_noise_is_continuous_and_bounded():
    xy = np.column_stack([np.linspace(0, 10, 10001), np.full(10001, 3.3)])
    noise = value_noise(xy, 1.0, seed=7)
    assert noise.min() >= 0.0 and noise.max() <= 1.0
    assert np.max(np.abs(np.diff(noise))) < 0.01  # no jumps between 1 mm steps
    assert noise.std() > 0.05


def test_a_single_point_of_a_route_is_its_pose():
    route = Route(np.array([3.0, 4.0]), 0.7, np.array([50.0, 20.0, 30.0, 10.0]), np.array([0.0, 0.05, -0.1, 0.0]))
    for s in (-5.0, 0.0, 10.0, 50.0, 60.0, 75.0, 99.0, 120.0):  # before, on and beyond every segment
        xy, heading = route.pose(np.array([s]))
        np.testing.assert_allclose(route.point(s), (xy[0, 0], xy[0, 1], heading[0]), atol=1e-9)


# The ground's per-point loops are numba kernels; datasets written when they were numpy array
# expressions must be written again to the bit. These are those expressions.

def array_route_frame(route: Route, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    from sianms_cli.synth.road import _segment_coordinates
    points, headings = route._segment_starts
    best_s, best_d, best_cost = np.zeros(len(xy)), np.full(len(xy), np.inf), np.full(len(xy), np.inf)
    for start, point, heading, length, curvature in zip(route.starts, points, headings, route.lengths,
                                                        route.curvatures):
        u, d = _segment_coordinates(xy[:, 0], xy[:, 1], point, heading, length, curvature)
        excess = np.maximum(np.maximum(-u, u - length), 0.0)
        cost = excess * excess + d * d
        better = cost < best_cost
        best_cost = np.where(better, cost, best_cost)
        best_s = np.where(better, start + np.clip(u, 0.0, length), best_s)
        best_d = np.where(better, d, best_d)
    return best_s, best_d


def array_crossing_streets(street: Street, xy: np.ndarray) -> tuple[np.ndarray, ...]:
    centers = np.stack([i.center for i in street.intersections])
    headings = np.array([i.heading for i in street.intersections])
    delta = xy[:, None, :] - centers[None]
    cos, sin = np.cos(headings), np.sin(headings)
    along = delta[..., 0] * cos + delta[..., 1] * sin
    across = -delta[..., 0] * sin + delta[..., 1] * cos
    kerb = street.section.kerb
    limits = np.array([i.along_limits() for i in street.intersections])
    on_arms = (along > limits[:, 0]) & (along < limits[:, 1])
    on_crossing = (np.abs(across) < 7.0) & on_arms
    pavement = (np.abs(across) < 7.0 + 4.5) & (np.abs(along) > kerb) & on_arms
    junction = on_crossing & (np.abs(along) < kerb)
    on_dash = along - np.floor(along / 9.0) * 9.0 < 3.0
    dashes = on_crossing & (np.abs(along) > kerb) & on_dash & (np.abs(across) < 0.08)
    return tuple(mask.any(axis=1) for mask in (on_crossing, pavement, junction, dashes))


def array_value_noise(xy: np.ndarray, scale: float, seed: int) -> np.ndarray:
    grid = xy / scale
    cell = np.floor(grid)
    frac = grid - cell
    frac = frac * frac * (3.0 - 2.0 * frac)
    ix, iy = cell[:, 0].astype(np.int64), cell[:, 1].astype(np.int64)

    def lattice(dx: int, dy: int) -> np.ndarray:
        with np.errstate(over="ignore"):
            h = (ix + dx).astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
            h ^= (iy + dy).astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F) + np.uint64(seed)
            h ^= h >> np.uint64(31)
            h *= np.uint64(0xBF58476D1CE4E5B9)
            h ^= h >> np.uint64(29)
        return (h >> np.uint64(11)).astype(np.float64) / float(1 << 53)

    bottom = lattice(0, 0) * (1 - frac[:, 0]) + lattice(1, 0) * frac[:, 0]
    top = lattice(0, 1) * (1 - frac[:, 0]) + lattice(1, 1) * frac[:, 0]
    return bottom * (1 - frac[:, 1]) + top * frac[:, 1]


def ground_points(rng: np.random.Generator, center: np.ndarray, count: int = 20_000) -> np.ndarray:
    """Points scattered over 300 m around ``center``, a tenth of them on a 1 cm grid (on the
    boundaries of paint and lattice cells)."""
    xy = center + rng.uniform(-150.0, 150.0, (count, 2))
    xy[: count // 10] = np.round(xy[: count // 10], 2)
    return xy


@pytest.mark.parametrize("arms_4way", [False, True])
def test_ground_kernels_equal_their_array_expressions_to_the_bit(arms_4way):
    street, _ = _turn_street(arms_4way)
    for route, xy in ((street.route, ground_points(np.random.default_rng(1), np.array([115.0, 0.0]))),
                      (_route(), ground_points(np.random.default_rng(2), np.array([150.0, 250.0])))):
        for got, expected in zip(route.to_route_frame(xy), array_route_frame(route, xy)):
            np.testing.assert_array_equal(got, expected)
    rng = np.random.default_rng(3)
    on_centre_line = np.column_stack([115.0 + rng.uniform(-0.1, 0.1, 3000), rng.uniform(-150.0, 150.0, 3000)])
    xy = np.concatenate([ground_points(rng, np.array([115.0, 0.0])), on_centre_line])
    masks = street.crossing_streets(xy)
    assert all(mask.sum() > 20 for mask in masks)  # every mask is exercised
    for got, expected in zip(masks, array_crossing_streets(street, xy)):
        np.testing.assert_array_equal(got, expected)
    for scale, seed in ((0.35, 11), (4.0, 23), (40.0, 5)):
        np.testing.assert_array_equal(value_noise(xy, scale, seed), array_value_noise(xy, scale, seed))
