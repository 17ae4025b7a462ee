import dataclasses

import numpy as np
import pytest

from sianms_cli.synth import appearance, shapes
from sianms_cli.synth.appearance import (CAR_VARIANTS, CONSTRUCTION_VARIANTS, TRAILER_VARIANTS, TRUCK_VARIANTS,
                                         Appearance, VehicleDetails, sample_appearance)
from sianms_cli.synth.objects import object_parts
from sianms_cli.synth.vehicles import CAR_MODELS

CAR = (1.95, 4.62, 1.73)
HEAVY = {"truck": (2.51, 6.93, 2.84, TRUCK_VARIANTS), "trailer": (2.90, 12.29, 3.87, TRAILER_VARIANTS),
         "construction": (2.85, 6.37, 3.19, CONSTRUCTION_VARIANTS)}
_XS = np.linspace(-0.5, 0.5, 201)[1:-1]


def _bounds(parts):
    return parts.center - parts.half_size, parts.center + parts.half_size


def _side_profile(app: Appearance) -> np.ndarray:
    """(199,) height of the car's top surface (fraction of h) along x (fractions of l)."""
    w, l, h = CAR
    lo, hi = _bounds(object_parts("car", CAR, app))
    over = (lo[:, 0] / l <= _XS[:, None]) & (hi[:, 0] / l >= _XS[:, None])
    return np.where(over, hi[:, 2] / h + 0.5, 0.0).max(axis=1)


def _plain(app: Appearance) -> Appearance:
    """The same car without roof rails or a rear extra (they change the outline on purpose)."""
    return dataclasses.replace(app, vehicle=dataclasses.replace(app.vehicle, roof_rails=False, rear_extra=0))


def test_there_are_eight_car_models_with_their_names():
    assert len(CAR_MODELS) == len(CAR_VARIANTS) == 8
    assert {"sedan", "hatchback", "estate", "suv", "pickup", "van", "minivan", "coupe"} == set(CAR_VARIANTS)


def test_every_pair_of_car_models_has_a_distinct_side_outline():
    """Two models' top surfaces differ by more than 5 % of the height over at least 15 % of
    the length (nominal proportions, same box)."""
    profiles = np.array([_side_profile(Appearance("car", v)) for v in range(len(CAR_MODELS))])
    differs = (np.abs(profiles[:, None] - profiles[None]) > 0.05).mean(axis=-1)
    off_diagonal = differs[~np.eye(len(CAR_MODELS), dtype=bool)]
    assert off_diagonal.min() >= 0.15, differs


def test_jittered_cars_keep_their_models_outline():
    """Per-instance jitter moves a car's proportions, never far enough to look like another model."""
    nominal = np.array([_side_profile(Appearance("car", v)) for v in range(len(CAR_MODELS))])
    rng = np.random.default_rng(11)
    for _ in range(150):
        app = _plain(sample_appearance("car", rng))
        profile = _side_profile(app)
        assert np.abs(nominal - profile).mean(axis=1).argmin() == app.variant
        assert not np.array_equal(profile, nominal[app.variant]) or not app.vehicle.jitter.any()


def _unmirrored(parts) -> np.ndarray:
    """Indices of parts that have no mirror image across the x-z plane (same material, size)."""
    key = np.column_stack([parts.center, parts.half_size, parts.material])
    mirror = key.copy()
    mirror[:, 1] *= -1
    match = np.all(np.abs(key[:, None] - mirror[None]) < 1e-9, axis=-1).any(axis=1)
    return np.flatnonzero(~match)


@pytest.mark.parametrize("side", [1, -1])
def test_a_mark_sits_on_one_flank_only(side):
    details = VehicleDetails(decal_side=side, decal=np.array([0.1, 0.2, 0.5, 0.1], np.float32))
    w, l, h = CAR
    parts = object_parts("car", CAR, Appearance("car", 3, vehicle=details))
    odd = _unmirrored(parts)
    assert len(odd) == 1
    mark = odd[0]
    assert parts.material[mark] == shapes.PAINT2
    assert np.sign(parts.center[mark, 1]) == side
    # Thin and just proud of the body's flank (inside the box).
    assert parts.half_size[mark, 1] < 0.01
    body = np.argmax(parts.half_size[:, 0] * parts.half_size[:, 2] * (parts.material == shapes.PAINT))
    flank = parts.center[body, 1] + side * parts.half_size[body, 1]
    inner = parts.center[mark, 1] - side * parts.half_size[mark, 1]
    assert inner == pytest.approx(flank)
    assert len(_unmirrored(object_parts("car", CAR, Appearance("car", 3)))) == 0


def test_some_sampled_cars_carry_a_one_sided_mark():
    rng = np.random.default_rng(4)
    sides = np.array([sample_appearance("car", rng).vehicle.decal_side for _ in range(2000)])
    assert 0.08 < np.mean(sides != 0) < 0.16
    assert abs(np.mean(sides == 1) - np.mean(sides == -1)) < 0.03


@pytest.mark.parametrize("variant", range(len(CAR_MODELS)))
def test_front_and_rear_ends_of_a_car_differ(variant):
    w, l, h = CAR
    parts = object_parts("car", CAR, Appearance("car", variant))
    lo, hi = _bounds(parts)
    front = parts.material[hi[:, 0] > l / 2 - 0.03]
    rear = parts.material[lo[:, 0] < -l / 2 + 0.03]
    assert shapes.HEADLIGHT in front and shapes.TAILLIGHT not in front
    assert shapes.TAILLIGHT in rear and shapes.HEADLIGHT not in rear
    head = parts.half_size[parts.material == shapes.HEADLIGHT][0, 1:]
    tail = parts.half_size[parts.material == shapes.TAILLIGHT][0, 1:]
    assert not np.allclose(head, tail, rtol=0.05)


def test_lamp_shapes_vary_between_models():
    aspects = [m.taillight[1] / m.taillight[0] for m in CAR_MODELS]
    assert max(aspects) > 3 * min(aspects)  # tall vertical rear lamps against wide thin ones


def test_rear_extras_and_rails_stay_inside_the_box():
    w, l, h = CAR
    for extra in range(len(appearance.REAR_EXTRAS)):
        for variant in range(len(CAR_MODELS)):
            details = VehicleDetails(rear_extra=extra, roof_rails=True)
            lo, hi = _bounds(object_parts("car", CAR, Appearance("car", variant, vehicle=details)))
            np.testing.assert_allclose(lo.min(axis=0), [-l / 2, -w / 2, -h / 2], atol=1e-12)
            np.testing.assert_allclose(hi.max(axis=0), [l / 2, w / 2, h / 2], atol=1e-12)
    spare = object_parts("car", CAR, Appearance("car", 3, vehicle=VehicleDetails(rear_extra=3)))
    tyre_lo = _bounds(spare)[0][spare.material == shapes.TYRE]
    assert np.sum(tyre_lo[:, 2] > -h / 2 + 0.05) == 1  # the spare hangs on the tailgate
    assert np.argmin(tyre_lo[:, 0]) == np.argmax(tyre_lo[:, 2])


def test_part_counts_stay_modest():
    rng = np.random.default_rng(5)
    counts = [len(object_parts("car", CAR, sample_appearance("car", rng))) for _ in range(300)]
    assert max(counts) <= 30
    for kind, (w, l, h, _) in HEAVY.items():
        assert max(len(object_parts(kind, (w, l, h), sample_appearance(kind, rng))) for _ in range(30)) <= 30


@pytest.mark.parametrize("kind", sorted(HEAVY))
def test_heavy_vehicle_variants_fill_their_boxes(kind):
    w, l, h, names = HEAVY[kind]
    outlines = []
    for variant in range(len(names)):
        app = dataclasses.replace(sample_appearance(kind, np.random.default_rng(variant)), variant=variant)
        parts = object_parts(kind, (w, l, h), app)
        lo, hi = _bounds(parts)
        np.testing.assert_allclose(lo.min(axis=0), [-l / 2, -w / 2, -h / 2], atol=1e-12)
        np.testing.assert_allclose(hi.max(axis=0), [l / 2, w / 2, h / 2], atol=1e-12)
        assert np.all(parts.half_size > 0)
        outlines.append(np.round(np.column_stack([lo, hi, parts.material]), 6).tobytes())
    assert len(set(outlines)) == len(names)


@pytest.mark.parametrize("variant", range(len(TRAILER_VARIANTS)))
def test_trailer_rests_on_landing_legs_at_the_front_and_wheels_at_the_rear(variant):
    w, l, h, _ = HEAVY["trailer"]
    parts = object_parts("trailer", (w, l, h), Appearance("trailer", variant))
    lo, hi = _bounds(parts)
    on_ground = lo[:, 2] < -h / 2 + 1e-9
    assert np.all(parts.center[on_ground & (parts.material == shapes.TYRE), 0] < -l / 4)
    legs = on_ground & (parts.material == shapes.METAL) & (parts.center[:, 0] > l / 4)
    assert legs.sum() >= 2
    assert not np.any(on_ground & (parts.center[:, 0] > -l / 4) & (parts.material == shapes.TYRE))


def test_excavator_cab_sits_on_one_side():
    w, l, h, _ = HEAVY["construction"]
    parts = object_parts("construction", (w, l, h), Appearance("construction", 0))
    cab = parts.material == shapes.GREENHOUSE
    assert cab.sum() == 1 and abs(parts.center[cab, 1][0]) > 0.2 * w


def test_model_and_variant_shares_match_the_stated_mix():
    rng = np.random.default_rng(6)
    models = np.array([sample_appearance("car", rng).variant for _ in range(6000)])
    share = np.bincount(models, minlength=len(CAR_VARIANTS)) / len(models)
    np.testing.assert_allclose(share, appearance._CAR_MODEL_SHARE, atol=0.02)
    assert abs(share.sum() - 1.0) < 1e-12
    trucks = np.array([sample_appearance("truck", rng).variant for _ in range(2000)])
    np.testing.assert_allclose(np.bincount(trucks, minlength=3) / len(trucks), appearance._TRUCK_SHARE, atol=0.035)


@pytest.mark.parametrize("kind", ["car", "truck", "bus", "trailer", "construction"])
def test_same_seed_same_vehicle(kind):
    size = CAR if kind == "car" else (2.8, 9.0, 3.3)
    a = object_parts(kind, size, sample_appearance(kind, np.random.default_rng(8)))
    b = object_parts(kind, size, sample_appearance(kind, np.random.default_rng(8)))
    for name in ("center", "half_size", "material", "albedo"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_a_car_model_fits_the_box_it_fills():
    rng = np.random.default_rng(4)
    low = [CAR_VARIANTS[sample_appearance("car", rng, size_wlh=(1.8, 4.7, 1.40)).variant] for _ in range(300)]
    tall = [CAR_VARIANTS[sample_appearance("car", rng, size_wlh=(2.0, 5.0, 2.00)).variant] for _ in range(300)]
    assert np.isin(low, ["sedan", "hatchback", "estate", "coupe"]).mean() > 0.9
    assert np.isin(tall, ["pickup", "van", "minivan", "suv"]).mean() > 0.9
    assert "van" in tall and "sedan" in low
