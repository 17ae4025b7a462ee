import datetime as dt
import json

import numpy as np
import pytest

from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.reporting.dataset_summary import condition_counts, summarize
from sianms_cli.synth import generate, lidar, shapes
from sianms_cli.synth.conditions import NIGHT_SHARE, RAIN_SHARE, Conditions, civil_dusk_hour
from sianms_cli.synth.generate import SynthConfig, run
from sianms_cli.synth.lidar import scan_lidar
from sianms_cli.synth.shapes import Parts
from sianms_cli.synth.world import plan_scene

LIDAR_TO_WORLD = np.eye(4)
LIDAR_TO_WORLD[2, 3] = 1.84
NIGHT_AND_RAIN_SEED = 51  # scene 0 of this seed is a rainy night in Singapore (found with _scene_conditions)


def asphalt(xy):
    return np.full(len(xy), 0.1)


def test_night_and_rain_come_at_nuscenes_shares_and_independently():
    drawn = np.array([[c.night, c.rain] for c in (generate._scene_conditions(0, i) for i in range(2000))])
    night, rain = drawn.mean(axis=0)
    both = np.mean(drawn[:, 0] & drawn[:, 1])
    for share, expected in ((night, NIGHT_SHARE), (rain, RAIN_SHARE), (both, NIGHT_SHARE * RAIN_SHARE)):
        assert abs(share - expected) < 4 * np.sqrt(expected * (1 - expected) / 2000)


def test_descriptions_lead_with_the_conditions_as_nuscenes_writes_them():
    plan = plan_scene(np.random.default_rng(0), drive_side=+1)
    day = generate._describe(plan, "boston-seaport")
    assert day.startswith("Three lanes each way")
    assert condition_counts([day])["night"] == condition_counts([day])["rain"] == 0
    assert generate._describe(plan, "boston-seaport", Conditions(night=True)) == "Night, t" + day[1:]
    assert generate._describe(plan, "boston-seaport", Conditions(rain=True)) == "Rain, t" + day[1:]
    assert generate._describe(plan, "boston-seaport", Conditions(night=True, rain=True)) == "Night, rain, t" + day[1:]


def test_civil_dusk_matches_the_almanac():
    # Boston, 21 June 2018: civil twilight ends 20:59 EDT; Singapore all year near 19:30 SGT.
    assert civil_dusk_hour(172, "boston", -4) == pytest.approx(20 + 59 / 60, abs=3 / 60)
    assert civil_dusk_hour(300, "boston", -4) == pytest.approx(18 + 14 / 60, abs=3 / 60)  # 27 October
    assert 19.1 < civil_dusk_hour(172, "singapore", 8) < 19.8


def test_night_scenes_start_between_dusk_and_midnight_on_the_day_drawn_for_them():
    for index in range(40):
        for location, utc in (("boston-seaport", -4), ("singapore-onenorth", 8)):
            day_start = generate._scene_start(5, index, location)
            night_start = generate._scene_start(5, index, location, night=True)
            assert 7 <= day_start.hour < 18
            assert night_start.date() == day_start.date()
            hours = (night_start - dt.datetime.combine(night_start.date(), dt.time())).total_seconds() / 3600
            assert civil_dusk_hour(night_start.timetuple().tm_yday, location.split("-")[0], utc) <= hours < 24


def test_a_generated_rainy_night_says_so_and_is_captured_at_night(tmp_path):
    root = run(SynthConfig(scenes=1, scene_seconds=0.5, seed=NIGHT_AND_RAIN_SEED, sensors="none"), tmp_path / "d").out
    scene, = json.loads((root / "v1.0-mini" / "scene.json").read_text())
    log, = json.loads((root / "v1.0-mini" / "log.json").read_text())
    assert scene["description"].startswith("Night, rain, ")
    local = dt.datetime.strptime(log["logfile"][5:24], "%Y-%m-%d-%H-%M-%S")  # n015-YYYY-mm-dd-HH-MM-SS+0800
    dusk = civil_dusk_hour(local.timetuple().tm_yday, log["location"].split("-")[0], 8)
    assert dusk <= local.hour + local.minute / 60 < 24
    assert summarize(NuScenesDB(root, "v1.0-mini"), max_sweeps=0)["scene_conditions"] == {
        "night": 1, "rain": 1, "night_and_rain": 1, "share_night": 1.0, "share_rain": 1.0, "share_night_and_rain": 1.0}


def test_only_rain_scenes_get_rain_streams_for_their_lidar(tmp_path):
    config = SynthConfig(scenes=1, seed=NIGHT_AND_RAIN_SEED, sensors="none")
    plan = plan_scene(np.random.default_rng(0), drive_side=-1)
    rig = generate.normalised_rig(generate.RIG_SINGAPORE)
    wet = generate._SceneSensing(plan, rig, config, 0, tmp_path, "log", 0)
    dry = generate._SceneSensing(plan, rig, SynthConfig(scenes=1, seed=3, sensors="none"), 0, tmp_path, "log", 0)
    assert wet.conditions.rain and wet.lidar_rain_rng is not None and wet.sweep_rain_rng is not None
    assert not dry.conditions.rain and dry.lidar_rain_rng is None and dry.sweep_rain_rng is None


def _street():
    """A wall of plates ahead, a dark car body beside, a facade behind: (M,) parts over asphalt."""
    return Parts([[10.5, 0.0, 2.0], [-8.0, 5.0, 0.8], [0.0, -20.0, 3.0]], [[0.5, 5.0, 2.0], [2.0, 1.0, 0.8],
                 [10.0, 1.0, 3.0]], [0.0, 0.3, 0.0], [0, 1, -1], [shapes.PLATE, shapes.TYRE, shapes.FACADE])


def test_rain_leaves_the_dry_draws_alone():
    dry = scan_lidar(_street(), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt)
    again = scan_lidar(_street(), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt, rain_rng=None)
    wet = scan_lidar(_street(), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt, rain_rng=np.random.default_rng(1))
    for field in ("points", "owner", "returned"):
        np.testing.assert_array_equal(getattr(again, field), getattr(dry, field))
    # Every wet return is a dry one, dimmed, or a raindrop: rain only removes, dims and adds near points.
    same = wet.returned & dry.returned & np.all(wet.points[:, :3] == dry.points[:, :3], axis=1)
    drop = wet.returned & ~same
    assert np.all(wet.points[same, 3] <= dry.points[same, 3])
    assert np.all(wet.owner[drop] == -1)
    assert np.all(wet.points[drop, 4] == dry.points[drop, 4])  # rings stay


def test_rain_loses_a_few_per_cent_of_returns_most_on_the_road_and_adds_weak_near_drops():
    dry = scan_lidar(_street(), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt)
    wet = scan_lidar(_street(), LIDAR_TO_WORLD, np.random.default_rng(0), asphalt, rain_rng=np.random.default_rng(1))
    same = wet.returned & dry.returned & np.all(wet.points[:, :3] == dry.points[:, :3], axis=1)
    lost = dry.returned & ~same
    assert 0.02 < lost.sum() / dry.returned.sum() < 0.10
    ground = dry.returned & (dry.owner == -1) & (dry.points[:, 2] < -1.5)  # the road, 1.84 m below the sensor
    plate = dry.owner == 0  # bright licence-plate material
    assert lost[ground].mean() > 2 * lost[plate].mean()
    drop = wet.returned & ~same
    distance = np.linalg.norm(wet.points[drop, :3], axis=1)
    assert 30 < drop.sum() < 300  # ~0.3 % of the 34.7k rays
    assert np.all((distance >= lidar.RAIN_DROP_RANGE_M[0] - 1e-5) & (distance <= lidar.RAIN_DROP_RANGE_M[1] + 1e-5))
    assert np.all(wet.points[drop, 3] <= lidar.RAIN_DROP_INTENSITY[1])


def test_info_counts_conditions_from_description_words():
    descriptions = ["Night, big street, bus stop, high speed", "Rain, peds, parking lot", "Night, rain, turn right",
                    "Wait at intersection, train station", "Heavy rainy day, drain on the road", "Nighttime, wet road"]
    counts = condition_counts(descriptions)
    assert (counts["night"], counts["rain"], counts["night_and_rain"]) == (3, 3, 1)
    assert counts["share_rain"] == pytest.approx(0.5)
    assert condition_counts([])["share_night"] is None


def test_moving_vehicles_trail_spray_in_rain_and_parked_ones_do_not():
    # Two cars 8 m to the left, heading +x: one at 15 m/s, one parked 8 m to the right.
    center = np.array([[0.0, 8.0, 0.8], [0.0, -8.0, 0.8]])
    spray = lidar.spray_behind(center, np.zeros(2), np.array([[1.9, 4.6, 1.6]] * 2), np.array([15.0, 0.0]))
    empty = shapes.concat_parts([])
    wet = scan_lidar(empty, LIDAR_TO_WORLD, np.random.default_rng(0), asphalt, rain_rng=np.random.default_rng(1),
                     spray=spray)
    plain = scan_lidar(empty, LIDAR_TO_WORLD, np.random.default_rng(0), asphalt, rain_rng=np.random.default_rng(1))
    xyz = wet.points[:, :3] + LIDAR_TO_WORLD[:3, 3]  # the world frame: the sensor is not turned
    length, height = lidar.RAIN_SPRAY_LENGTH_M, lidar.RAIN_SPRAY_HEIGHT_M
    in_cloud = [(np.abs(xyz[:, 0] + 2.3 + length / 2) <= length / 2 + 1e-3) & (np.abs(xyz[:, 1] - y) <= 0.951)
                & (xyz[:, 2] > 0.1) & (xyz[:, 2] <= height + 1e-3) & wet.returned  # above the road
                for y in (8.0, -8.0)]
    assert in_cloud[0].sum() > 5 and in_cloud[1].sum() == 0
    assert np.all(wet.points[in_cloud[0], 3] <= lidar.RAIN_DROP_INTENSITY[1])
    assert wet.returned.sum() <= plain.returned.sum() + in_cloud[0].sum()
