import numpy as np
import pytest

from sianms_cli.synth import shapes
from sianms_cli.synth.appearance import BAGS, FULL_FACE_HELMET, HAIR_STYLES, HARD_HAT, HI_VIS_VEST, LEGWEAR, \
    LOGO_BAND, NO_HEADWEAR, OPEN_HELMET, OPEN_JACKET, SHORTS, SHOULDER_BAG_LEFT, SHOULDER_BAG_RIGHT, STRIPES, \
    TOP_STYLES, TROUSERS, Appearance, sample_appearance
from sianms_cli.synth.objects import object_parts
from sianms_cli.synth.people import cycle_geometry, riding_pose, walking_pose

ADULT = (0.67, 0.73, 1.77)
BICYCLE = (0.6, 1.7, 1.6)
MOTORCYCLE = (0.77, 2.11, 1.6)
# Distinct colours, so that each garment's parts can be picked out by their albedo.
SKIN, TOP, BOTTOM, ACCENT, SHOES = (np.array(c, np.float32) for c in
                                    ((0.5, 0.3, 0.2), (0.1, 0.1, 0.6), (0.1, 0.5, 0.1), (0.7, 0.7, 0.1),
                                     (0.6, 0.05, 0.05)))


def _person(kind="pedestrian", **fields):
    return Appearance(kind, skin=SKIN, top=TOP, bottom=BOTTOM, accent=ACCENT, shoes=SHOES, **fields)


def _coloured(parts, colour):
    return np.flatnonzero(np.all(parts.albedo == colour, axis=1))


def _lo_hi(parts, idx):
    return parts.center[idx] - parts.half_size[idx], parts.center[idx] + parts.half_size[idx]


def _overlap(a_lo, a_hi, b_lo, b_hi, axes):
    return all(a_lo[k] <= b_hi[k] and b_lo[k] <= a_hi[k] for k in axes)


@pytest.mark.parametrize("phase", [0.05, 0.3, 0.55, 0.95])
def test_walking_pose_has_one_leg_forward_and_the_arms_swinging_opposite(phase):
    h = 1.75
    pose = walking_pose(h, 0.75, phase)
    front, back = (0, 1) if phase < 0.5 else (1, 0)
    assert pose.ankle[front, 0] > pose.ankle[back, 0] + 0.25
    assert pose.knee[front, 0] > pose.pelvis[0]
    assert pose.knee[back, 0] < pose.pelvis[0]
    # The front knee is a little bent: ahead of the straight hip-ankle line.
    line = pose.ankle[front] - pose.pelvis
    to_knee = pose.knee[front] - pose.pelvis
    assert line[0] * to_knee[1] - line[1] * to_knee[0] > 0
    # The arm on the front leg's side swings back, the other one forward.
    assert pose.wrist[front, 0] < pose.wrist[back, 0]
    assert pose.elbow[front, 0] < 0 < pose.elbow[back, 0]
    # The lower foot stands on the ground; the feet reach the asked span.
    assert pose.ankle[:, 1].min() == pytest.approx(0.039 * h)
    heel_to_toe = pose.toe[:, 0].max() - (pose.ankle[:, 0].min() - 0.3 * 0.152 * h)
    assert heel_to_toe == pytest.approx(0.75, abs=1e-3)


def test_walker_parts_put_the_shoes_apart_and_the_left_one_ahead_early_in_the_cycle():
    for phase, ahead in ((0.2, 1.0), (0.7, -1.0)):
        parts = object_parts("pedestrian", ADULT, _person(gait_phase=phase))
        shoes = _coloured(parts, SHOES)
        assert len(shoes) == 2
        lo, hi = _lo_hi(parts, shoes)
        front = int(np.argmax(parts.center[shoes, 0]))
        assert hi[1 - front, 0] < lo[front, 0]  # disjoint along x
        assert np.sign(parts.center[shoes[front], 1]) == ahead
        np.testing.assert_allclose(lo[:, 2].min(), -ADULT[2] / 2)


def test_shorts_bare_the_shins_and_trousers_cover_them():
    for legwear, bare in ((TROUSERS, False), (SHORTS, True)):
        parts = object_parts("pedestrian", ADULT, _person(legwear=legwear))
        skin = _coloured(parts, SKIN)
        low_skin = skin[parts.center[skin, 2] < -0.3]  # below the knees' height in a 1.77 m box
        assert (len(low_skin) > 0) == bare


@pytest.mark.parametrize("bag, side", [(SHOULDER_BAG_LEFT, 1.0), (SHOULDER_BAG_RIGHT, -1.0)])
def test_shoulder_bag_hangs_on_one_side_only(bag, side):
    parts = object_parts("pedestrian", ADULT, _person(bag=bag))
    bag_parts = _coloured(parts, ACCENT)
    assert len(bag_parts) == 2  # bag and strap
    assert np.all(side * parts.center[bag_parts, 1] > 0)
    lo, hi = _lo_hi(parts, bag_parts)
    assert np.all(side * np.where(side > 0, lo[:, 1], hi[:, 1]) > 0)


def test_top_styles_draw_the_second_colour_where_they_belong():
    def accent(**fields):
        parts = object_parts("pedestrian", ADULT, _person(**fields))
        return parts, _coloured(parts, ACCENT)

    _, plain = accent()
    assert len(plain) == 0
    parts, stripes = accent(top_style=STRIPES)
    lo, hi = _lo_hi(parts, stripes)
    assert len(stripes) == 3 and np.all(lo[:, 0] < 0) and np.all(hi[:, 0] > 0)  # round the torso
    parts, logo = accent(top_style=LOGO_BAND)
    assert len(logo) == 1 and parts.center[logo[0], 0] > 0  # on the chest only
    parts, jacket = accent(top_style=OPEN_JACKET)
    shirt = _coloured(parts, TOP)
    assert len(shirt) == 1 and parts.center[shirt[0], 0] > parts.center[jacket, 0].max() - 0.2
    assert len(jacket) >= 5  # trunk and both sleeves
    parts, _ = accent(top_style=HI_VIS_VEST, headwear=HARD_HAT)
    assert (parts.material == shapes.REFLECTOR).sum() == 2
    assert parts.material[np.argmax(parts.center[:, 2] + parts.half_size[:, 2])] == shapes.PAINT2


@pytest.mark.parametrize("kind, size", [("bicycle", BICYCLE), ("motorcycle", MOTORCYCLE)])
def test_rider_hands_are_on_the_grips_and_feet_on_the_pedals(kind, size):
    parts = object_parts(kind, size, _person(kind, rider=True, headwear=OPEN_HELMET, gait_phase=0.3))
    bar = int(np.argmax(np.where(parts.material == shapes.TRIM, parts.half_size[:, 1], 0)))
    bar_lo, bar_hi = _lo_hi(parts, bar)
    skin = _coloured(parts, SKIN)
    hands = skin[np.abs(parts.center[skin, 1]) > 0.15]
    assert len(hands) == 2 and set(np.sign(parts.center[hands, 1])) == {-1.0, 1.0}
    for hand in hands:
        assert _overlap(*_lo_hi(parts, hand), bar_lo, bar_hi, axes=(0, 2))
    metal = np.flatnonzero(parts.material == shapes.METAL)
    for shoe in _coloured(parts, SHOES):
        s_lo, s_hi = _lo_hi(parts, shoe)
        assert any(_overlap(s_lo, s_hi, *_lo_hi(parts, m), axes=(0, 1, 2)) for m in metal)


@pytest.mark.parametrize("motor", [False, True])
@pytest.mark.parametrize("phase", [0.0, 0.25, 0.5, 0.75])
@pytest.mark.parametrize("h", [1.5, 1.9])
def test_riding_pose_reaches_its_targets_with_bent_knees_and_elbows(motor, phase, h):
    g = cycle_geometry(2.0, 1.6, motor, phase)
    hip = g.saddle + np.array([0.02, 0.09])
    pose = riding_pose(h, hip, g.grips, g.foot_rests, g.foot_y)
    shoulder = pose.shoulder
    arm = np.hypot(*(pose.elbow - shoulder).T) + np.hypot(*(pose.wrist - pose.elbow).T)
    np.testing.assert_allclose(arm, (0.186 + 0.146) * h)  # the grips are within reach, not clamped
    thigh = np.hypot(*(pose.knee - pose.pelvis).T)
    shin = np.hypot(*(pose.ankle - pose.knee).T)
    np.testing.assert_allclose(thigh, shin)
    np.testing.assert_allclose(thigh + shin, (0.52 - 0.039) * h)
    np.testing.assert_allclose(pose.ankle, g.foot_rests + [-0.25 * 0.152 * h, 0.039 * h])
    assert pose.pelvis[1] <= hip[1]
    assert np.all(pose.knee[:, 0] > pose.pelvis[0])  # knees ahead
    assert np.all(pose.elbow[:, 1] < shoulder[1])
    assert pose.neck[0] > pose.pelvis[0] + 0.1  # leaning forward


def test_riders_wear_helmets_and_motorcyclists_always_do():
    rng = np.random.default_rng(4)
    motor = [sample_appearance("motorcycle", rng, rider=True).headwear for _ in range(200)]
    assert set(motor) == {OPEN_HELMET, FULL_FACE_HELMET}
    bicycle = [sample_appearance("bicycle", rng, rider=True).headwear for _ in range(400)]
    assert set(bicycle) == {OPEN_HELMET, NO_HEADWEAR} and 0.4 < np.mean(np.equal(bicycle, OPEN_HELMET)) < 0.6
    for kind, size in (("bicycle", BICYCLE), ("motorcycle", MOTORCYCLE)):
        for headwear in (OPEN_HELMET, FULL_FACE_HELMET):
            parts = object_parts(kind, size, _person(kind, rider=True, headwear=headwear))
            top = np.argmax(parts.center[:, 2] + parts.half_size[:, 2])
            assert parts.material[top] == shapes.PAINT2
    face = object_parts("motorcycle", MOTORCYCLE, _person("motorcycle", rider=True, headwear=FULL_FACE_HELMET))
    open_face = object_parts("motorcycle", MOTORCYCLE, _person("motorcycle", rider=True, headwear=OPEN_HELMET))
    assert len(_coloured(face, SKIN)) == len(_coloured(open_face, SKIN)) - 1  # the face is hidden


@pytest.mark.parametrize("kind, size", [("pedestrian", ADULT), ("pedestrian", (0.45, 0.4, 1.1)),
                                        ("pedestrian", (0.9, 1.1, 2.1)), ("bicycle", BICYCLE),
                                        ("motorcycle", MOTORCYCLE)])
def test_every_sampled_look_fills_its_box_exactly_with_a_modest_part_count(kind, size):
    w, l, h = size
    rng = np.random.default_rng(11)
    looks = [sample_appearance(kind, rng, rider=True) if kind != "pedestrian" else sample_appearance(kind, rng)
             for _ in range(60)]
    bare = len(object_parts(kind, size, Appearance(kind))) if kind != "pedestrian" else 0
    for app in looks:
        parts = object_parts(kind, size, app)
        lo, hi = _lo_hi(parts, slice(None))
        np.testing.assert_allclose(lo.min(axis=0), [-l / 2, -w / 2, -h / 2], atol=1e-12)
        np.testing.assert_allclose(hi.max(axis=0), [l / 2, w / 2, h / 2], atol=1e-12)
        assert np.all(parts.half_size > 0)
        assert 15 <= len(parts) - bare <= 35


def test_same_seed_same_figure():
    for kind in ("pedestrian", "bicycle", "motorcycle"):
        a, b = (object_parts(kind, ADULT if kind == "pedestrian" else BICYCLE,
                             sample_appearance(kind, np.random.default_rng(8), rider=True)) for _ in range(2))
        for name in ("center", "half_size", "material", "albedo"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_pedestrian_looks_cover_every_style_and_only_workers_wear_hi_vis_and_hard_hats():
    rng = np.random.default_rng(5)
    looks = [sample_appearance("pedestrian", rng) for _ in range(3000)]
    for field, names in (("bag", BAGS), ("legwear", LEGWEAR), ("top_style", TOP_STYLES[:-1]),
                         ("hair_style", HAIR_STYLES)):
        assert {getattr(a, field) for a in looks} == set(range(len(names)))
    assert not any(a.top_style == HI_VIS_VEST or a.headwear == HARD_HAT for a in looks)
    workers = [sample_appearance("pedestrian", rng, workwear=True) for _ in range(20)]
    assert all(a.top_style == HI_VIS_VEST and a.headwear == HARD_HAT for a in workers)


@pytest.mark.parametrize("bag", range(len(BAGS)))
def test_a_walker_of_the_mean_adult_size_is_not_stretched_to_fill_its_box(bag):
    """The stride spans the box's length and the arms its width, so the fit to the box
    leaves the trunk at its natural 0.38 x 0.22 m and the stature at the box height."""
    parts = object_parts("pedestrian", ADULT, _person(bag=bag))
    trunk = _coloured(parts, TOP)
    trunk = trunk[np.argmax(parts.half_size[trunk, 1])]
    np.testing.assert_allclose(2 * parts.half_size[trunk, :2], [0.22, 0.38], rtol=0.05)
