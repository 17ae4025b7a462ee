import numpy as np
import pytest

from sianms_cli.synth import shapes
from sianms_cli.synth.appearance import Appearance, sample_appearance
from sianms_cli.synth.objects import KINDS, object_parts
from sianms_cli.synth.shapes import Parts, concat_parts, place_parts

SIZES = {"car": (1.95, 4.62, 1.73), "truck": (2.51, 6.93, 2.84), "bus": (2.93, 11.23, 3.47),
         "trailer": (2.90, 12.29, 3.87), "construction": (2.85, 6.37, 3.19),
         "pedestrian": (0.67, 0.73, 1.77), "bicycle": (0.6, 1.7, 1.28), "motorcycle": (0.77, 2.11, 1.47),
         "barrier": (2.53, 0.5, 0.98), "traffic_cone": (0.41, 0.41, 1.07), "building": (12.0, 20.0, 15.0),
         "tree": (5.0, 4.5, 9.0), "hedge": (0.4, 2.5, 1.2), "fence": (0.06, 2.5, 1.2),
         "street_light": (1.8, 0.4, 9.0), "utility_pole": (1.8, 0.3, 10.0), "sign": (0.6, 0.1, 2.85),
         "traffic_light": (0.36, 0.4, 3.5), "hydrant": (0.4, 0.3, 0.75), "bin": (0.5, 0.5, 1.0),
         "bollard": (0.18, 0.18, 0.95)}


def _bounds(parts):
    return (parts.center - parts.half_size).min(axis=0), (parts.center + parts.half_size).max(axis=0)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_parts_fill_the_annotation_box_exactly(kind, seed):
    w, l, h = SIZES[kind]
    parts = object_parts(kind, (w, l, h), sample_appearance(kind, np.random.default_rng(seed)))
    lo, hi = _bounds(parts)
    np.testing.assert_allclose(lo, [-l / 2, -w / 2, -h / 2], atol=1e-12)
    np.testing.assert_allclose(hi, [l / 2, w / 2, h / 2], atol=1e-12)
    assert np.all(parts.half_size > 0)
    assert parts.albedo.dtype == np.float32 and np.all((parts.albedo >= 0) & (parts.albedo <= 1))


def test_car_has_four_tyres_on_the_ground_and_a_glazed_cabin():
    parts = object_parts("car", SIZES["car"], Appearance("car"))
    tyres = parts.material == shapes.TYRE
    assert tyres.sum() == 4
    np.testing.assert_allclose((parts.center - parts.half_size)[tyres, 2], -SIZES["car"][2] / 2)
    glazing = parts.material == shapes.GREENHOUSE
    assert glazing.any()
    assert (parts.center + parts.half_size)[glazing, 2].max() == pytest.approx(SIZES["car"][2] / 2)


def test_rider_adds_a_person_to_a_bicycle():
    bare = object_parts("bicycle", SIZES["bicycle"], Appearance("bicycle", rider=False))
    ridden = object_parts("bicycle", SIZES["bicycle"], Appearance("bicycle", rider=True))
    assert not np.isin(bare.material, [shapes.SKIN, shapes.CLOTH]).any()
    assert (ridden.material == shapes.SKIN).sum() == 4  # neck, head and two hands
    assert len(ridden) > len(bare)


def test_child_head_is_a_larger_share_of_the_height():
    def head_share(h):
        parts = object_parts("pedestrian", (0.5, 0.5, h), Appearance("pedestrian"))
        skin = parts.material == shapes.SKIN
        return (2 * parts.half_size[skin, 2]).max() / h
    assert head_share(1.2) > head_share(1.8)


def test_tree_crown_is_lifted_over_the_road_side():
    """Below the overhead clearance the crown reaches only CROWN_KERB_SIDE towards -y (the
    road); the trunk stands at the box centre and the crown starts CROWN_BASE up."""
    w, l, h = SIZES["tree"]
    parts = object_parts("tree", (w, l, h), sample_appearance("tree", np.random.default_rng(0)))
    lo = parts.center - parts.half_size
    low = lo[:, 2] + h / 2 < shapes.OVERHEAD_CLEARANCE
    assert lo[low, 1].min() == pytest.approx(-shapes.CROWN_KERB_SIDE)
    trunk = np.argmin(lo[:, 2])
    np.testing.assert_allclose(parts.center[trunk, :2], 0.0, atol=1e-12)
    assert np.sort(lo[:, 2])[1] + h / 2 == pytest.approx(shapes.CROWN_BASE)


def test_street_light_pole_stands_at_its_documented_place():
    w, l, h = SIZES["street_light"]
    parts = object_parts("street_light", (w, l, h), sample_appearance("street_light", np.random.default_rng(0)))
    pole = np.argmax(parts.half_size[:, 2])
    assert parts.center[pole, 1] == pytest.approx(w / 2 - shapes.STREET_LIGHT_POLE_INSET)
    arm_top = (parts.center - parts.half_size)[:, 1].min()
    assert arm_top == pytest.approx(-w / 2)


def test_place_parts_rotates_about_the_object_centre():
    local = Parts([[1.0, 0.0, 0.5]], [[0.5, 0.2, 0.5]], [0.1], [0], [shapes.PAINT])
    placed = place_parts(local, np.array([10.0, 20.0, 1.0]), np.pi / 2, owner=7)
    np.testing.assert_allclose(placed.center, [[10.0, 21.0, 1.5]], atol=1e-12)
    np.testing.assert_allclose(placed.yaw, [0.1 + np.pi / 2])
    np.testing.assert_array_equal(placed.owner, [7])
    np.testing.assert_array_equal(placed.half_size, local.half_size)


def test_concat_parts_keeps_order_and_empty_list_is_empty():
    a = Parts([[0.0, 0, 0]], [[1.0, 1, 1]], [0.0], [0], [shapes.TYRE])
    b = Parts([[5.0, 0, 0], [6.0, 0, 0]], [[1.0, 1, 1]] * 2, [0.0, 0.0], [-1, -1], [shapes.FACADE] * 2)
    both = concat_parts([a, b])
    np.testing.assert_array_equal(both.center[:, 0], [0.0, 5.0, 6.0])
    np.testing.assert_array_equal(both.owner, [0, -1, -1])
    np.testing.assert_array_equal(both.albedo[0], shapes.MATERIAL_ALBEDO[shapes.TYRE])
    assert len(concat_parts([])) == 0


def test_invalid_input_is_rejected():
    with pytest.raises(ValueError, match="unknown object kind"):
        object_parts("tram", (2, 10, 3), Appearance("car"))
    with pytest.raises(ValueError, match="positive"):
        object_parts("car", (1.9, 0.0, 1.5), Appearance("car"))
    with pytest.raises(ValueError, match="rows"):
        Parts([[0.0, 0, 0]], [[1.0, 1, 1]], [0.0, 1.0], [0], [0])


def test_every_kind_has_one_builder():
    from sianms_cli.synth import objects
    assert set(KINDS) == set(objects._BUILDERS)
    assert len(KINDS) == len(set(KINDS))
