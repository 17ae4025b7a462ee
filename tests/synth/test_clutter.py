import numpy as np
import pytest

from sianms_cli.synth import shapes
from sianms_cli.synth.appearance import CLUTTER_KINDS, sample_appearance
from sianms_cli.synth.camera import coverage_counts
from sianms_cli.synth.clutter import KERB_STRIP, place_clutter, road_user_boxes
from sianms_cli.synth.lidar import scan_lidar
from sianms_cli.synth.road import CrossSection, Intersection, Route, Street
from sianms_cli.synth.objects import object_parts
from sianms_cli.synth.shapes import Parts, concat_parts, place_parts
from sianms_cli.synth.world import SCENE_SECONDS, plan_scene

SEEDS = range(6)


@pytest.fixture(scope="module")
def scenes():
    """(plan, clutter) of six seeded scenes, Boston and Singapore alternating."""
    out = []
    for seed in SEEDS:
        plan = plan_scene(np.random.default_rng(seed), drive_side=+1 if seed % 2 else -1)
        clutter = place_clutter(plan.street, np.random.default_rng(100 + seed), plan.buildings,
                                road_user_boxes(plan.agents, plan.route))
        out.append((plan, clutter))
    return out


def _footprint_points(parts: Parts, n: int = 5) -> np.ndarray:
    """(M, n*n, 2) a grid of points over each part's footprint, its edges included."""
    u = np.linspace(-1.0, 1.0, n)
    gx, gy = (g.ravel() for g in np.meshgrid(u, u))
    local_x = gx[None, :] * parts.half_size[:, :1]
    local_y = gy[None, :] * parts.half_size[:, 1:2]
    cos, sin = np.cos(parts.yaw)[:, None], np.sin(parts.yaw)[:, None]
    return np.stack([parts.center[:, :1] + cos * local_x - sin * local_y,
                     parts.center[:, 1:2] + sin * local_x + cos * local_y], axis=-1)


def test_every_clutter_kind_appears_in_the_seeded_scenes(scenes):
    kinds = set()
    for _, clutter in scenes:
        kinds |= set(clutter.kind.tolist())
        assert np.all(clutter.parts.owner == -1)
        assert len(clutter.item) == len(clutter.parts)
        np.testing.assert_array_equal(np.unique(clutter.item), np.arange(len(clutter.kind)))
    assert kinds == set(CLUTTER_KINDS)


def test_low_parts_stay_off_the_carriageway(scenes):
    """Below the overhead clearance no part reaches the asphalt of the street or of a
    crossing street; above it crowns, lamp arms and cross-arms may overhang the road."""
    for plan, clutter in scenes:
        parts = clutter.parts
        low = (parts.center[:, 2] - parts.half_size[:, 2]) < shapes.OVERHEAD_CLEARANCE
        points = _footprint_points(parts)[low].reshape(-1, 2)
        surface, _, _ = plan.street.surface(points)
        assert np.all(surface != 0)
        assert low.sum() < len(parts)  # something does overhang


def test_kerb_furniture_stays_out_of_the_walking_lines(scenes):
    for plan, clutter in scenes:
        furniture = ~np.isin(clutter.kind[clutter.item], ["hedge", "fence", "traffic_light", "bollard"])
        points = _footprint_points(clutter.parts)[furniture & (clutter.parts.center[:, 2] < 2.5)]
        s, d = plan.route.to_route_frame(points.reshape(-1, 2))
        inset = np.abs(d) - plan.street.section.kerb
        assert np.all((inset >= -1e-6) & (inset <= KERB_STRIP))


def _inside_box(points: np.ndarray, box: np.ndarray) -> np.ndarray:
    """Whether points (P,2) lie strictly inside the footprint of box x, y, z, w, l, h, yaw."""
    delta = points - box[:2]
    cos, sin = np.cos(box[6]), np.sin(box[6])
    along = delta[:, 0] * cos + delta[:, 1] * sin
    across = -delta[:, 0] * sin + delta[:, 1] * cos
    return (np.abs(along) < box[4] / 2) & (np.abs(across) < box[3] / 2)


def test_no_clutter_part_touches_a_road_user_over_the_scene(scenes):
    """Reference check, road user by road user, at every 2.5 s of the scene: no point of
    a clutter part's footprint lies inside a road user's box where their heights overlap."""
    for plan, clutter in scenes:
        parts = clutter.parts
        points = _footprint_points(parts, n=9)
        bottom, top = parts.center[:, 2] - parts.half_size[:, 2], parts.center[:, 2] + parts.half_size[:, 2]
        reach = np.linalg.norm(parts.half_size[:, :2], axis=1)
        for t in np.arange(0.0, SCENE_SECONDS + 1e-9, 2.5):
            center, yaw, _ = plan.agents.pose(plan.route, t)
            for box in np.column_stack([center, plan.agents.size, yaw]):
                near = np.hypot(*(parts.center[:, :2] - box[:2]).T) < reach + np.hypot(box[3], box[4])
                near &= (bottom < box[5]) & (top > 0.0)
                for m in np.flatnonzero(near):
                    assert not _inside_box(points[m], box).any(), (plan.agents.category, t,
                                                                   clutter.kind[clutter.item[m]])


def test_buildings_are_not_entered(scenes):
    for plan, clutter in scenes:
        points = _footprint_points(clutter.parts, n=9)
        for b in plan.buildings:
            box = np.array([b.center[0], b.center[1], 0.0, b.size[0], b.size[1], 1.0, b.yaw])
            assert not _inside_box(points.reshape(-1, 2), box).any()


def test_same_seed_same_clutter():
    plan = plan_scene(np.random.default_rng(3), drive_side=+1)
    a = place_clutter(plan.street, np.random.default_rng(7), plan.buildings)
    b = place_clutter(plan.street, np.random.default_rng(7), plan.buildings)
    c = place_clutter(plan.street, np.random.default_rng(8), plan.buildings)
    np.testing.assert_array_equal(a.kind, b.kind)
    for name in ("center", "half_size", "yaw", "material", "albedo"):
        np.testing.assert_array_equal(getattr(a.parts, name), getattr(b.parts, name))
    assert len(a.parts) != len(c.parts) or not np.array_equal(a.parts.center, c.parts.center)


def test_lidar_returns_hit_clutter(scenes):
    """A sweep from the start of a scene's drive: returns above the ground with owner -1
    come from clutter parts (the scan holds nothing else)."""
    plan, clutter = scenes[1]
    xy, yaw = plan.ego.pose(plan.route, 0.0)
    lidar_to_world = np.eye(4)
    lidar_to_world[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]]
    lidar_to_world[:3, 3] = [xy[0], xy[1], 1.84]
    scan = scan_lidar(clutter.parts, lidar_to_world, np.random.default_rng(0), lambda p: np.full(len(p), 0.1),
                      azimuth_steps=360, range_noise_std=0.0, dropout=0.0)
    returned = np.linalg.norm(scan.points[:, :3], axis=1) > 0.05  # rays with no return carry no point
    above = returned & (scan.points[:, 2] > -1.84 + 0.05)
    assert above.sum() > 50
    assert np.all(scan.owner == -1)
    world = scan.points[above, :3] @ lidar_to_world[:3, :3].T + lidar_to_world[:3, 3]
    parts = clutter.parts
    c, s = np.cos(parts.yaw), np.sin(parts.yaw)
    delta = world[:, None, :] - parts.center[None]
    local = np.stack([c * delta[..., 0] + s * delta[..., 1], -s * delta[..., 0] + c * delta[..., 1], delta[..., 2]], -1)
    on_part = np.all(np.abs(local) <= parts.half_size[None] + 1e-3, axis=2).any(axis=1)
    assert on_part.all()


def test_a_tree_occludes_a_car_in_the_image():
    """A car 15 m ahead of a camera, a tree trunk and crown between: the car's visible
    pixels drop, its projected pixels do not."""
    K = np.array([[100.0, 0.0, 80.0], [0.0, 100.0, 60.0], [0.0, 0.0, 1.0]])
    cam_to_world = np.array([[0.0, 0.0, 1.0, 0.0], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 1.5], [0.0, 0.0, 0.0, 1.0]])
    car = place_parts(object_parts("car", (1.95, 4.62, 1.73), sample_appearance("car", np.random.default_rng(0))),
                      np.array([15.0, 0.0, 0.865]), np.pi / 2, owner=0)
    tree = place_parts(object_parts("tree", (4.0, 4.0, 8.0), sample_appearance("tree", np.random.default_rng(0))),
                       np.array([7.0, 0.3, 4.0]), 0.0, owner=-1)

    clear = coverage_counts(car, K, cam_to_world, 160, 120, 1)
    hidden = coverage_counts(concat_parts([car, tree]), K, cam_to_world, 160, 120, 1)
    assert clear.visible[0] > 100
    assert hidden.in_image[0] == clear.in_image[0]
    assert hidden.visible[0] < 0.9 * clear.visible[0]


def test_signals_stand_at_the_corners_of_a_turning_junction_once():
    """Where the route turns, the corners lie half a metre beyond the turn (the junction's
    half_span), and a 4-way junction's two crossing streets share one set of signals."""
    route = Route(np.zeros(2), 0.0, np.array([100.0, 15.0 * np.pi / 2, 100.0]), np.array([0.0, 1 / 15, 0.0]))
    s, half_span = 100.0 + 15.0 * np.pi / 4, 15.0 * np.pi / 4 + 2.0
    corner = np.array([115.0, 0.0])  # where the incoming and outgoing centrelines meet
    junctions = (Intersection(s, corner, np.pi / 2, arms=(-1,), half_span=half_span),
                 Intersection(s, corner, 0.0, arms=(1,), half_span=half_span))
    street = Street(route, CrossSection(1, True, 1), junctions, center_line_yellow=True)
    clutter = place_clutter(street, np.random.default_rng(0))
    signals = np.flatnonzero(clutter.kind == "traffic_light")
    assert len(signals) == 4
    centres = np.stack([clutter.parts.center[clutter.item == i, :2].mean(axis=0) for i in signals])
    along, _ = route.to_route_frame(centres)
    np.testing.assert_allclose(np.sort(np.abs(along - s)), half_span + 0.5, atol=0.6)
