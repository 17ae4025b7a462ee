import json
import shutil

import numpy as np
import pytest

from sianms_cli.geometry.quaternion import yaw_to_quat
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import OutputError
from sianms_cli.nuscenes.classes import CATEGORY_TO_DETECTION, DETECTION_CLASSES
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.reporting.dataset_summary import (
    InfoConfig,
    _headings_in_ego,
    azimuth_figures,
    camera_count_figures,
    class_range_figures,
    lidar_point_band_figures,
    distance_band_figures,
    format_summary,
    heading_to_axis_figures,
    run,
    summarize,
)
from sianms_cli.reporting.nuscenes_reference import REFERENCE


def test_camera_count_figures():
    figures = camera_count_figures(np.array([0, 1, 1, 2, 3, 1, 2, 0]))
    assert figures == {"boxes_3d": 8, "image_boxes": 10, "per_3d_box": 1.25, "share_imaged_by_2_or_more": 0.375,
                       "share_imaged_by_none": 0.25}
    assert camera_count_figures(np.zeros(0, dtype=int))["per_3d_box"] is None


def test_distance_bands_are_half_open_and_end_at_the_last_edge():
    distance = np.array([0.0, 9.99, 10.0, 19.0, 30.0, 49.9, 50.0, 80.0])
    cameras = np.array([2, 1, 2, 2, 1, 3, 2, 2])
    figures = distance_band_figures(distance, cameras, (0.0, 10.0, 20.0, 30.0, 50.0))
    assert figures == {
        "0-10": {"boxes_3d": 2, "share_imaged_by_2_or_more": 0.5},
        "10-20": {"boxes_3d": 2, "share_imaged_by_2_or_more": 1.0},
        "20-30": {"boxes_3d": 0, "share_imaged_by_2_or_more": None},
        "30-50": {"boxes_3d": 2, "share_imaged_by_2_or_more": 0.5},
    }


def test_class_range_figures_use_the_devkit_strict_range_and_the_val_bands():
    classes = np.array(["car", "car", "car", "pedestrian", "pedestrian", "barrier", "", "car"])
    distance = np.array([5.0, 49.99, 50.0, 39.0, 40.0, 25.0, 3.0, np.inf])  # inf: no LIDAR_TOP key frame
    lidar = np.array([0, 0, 3, 9, 0, 0, 0, 0])
    radar = np.array([0, 2, 0, 0, 0, 1, 0, 0])
    visibility = np.array(["1", "4", "4", "3", "4", "2", "1", "1"])
    figures = class_range_figures(classes, distance, 2, lidar, radar, visibility)
    assert figures["share_in_class_range"] == 4 / 7  # the unevaluated box counts nowhere
    assert figures["per_keyframe_in_class_range"] == 2.0
    assert figures["by_class"] == {
        "car": {"share_in_class_range": 0.5, "per_keyframe_in_class_range": 1.0,
                "share_without_lidar_or_radar_points": 0.5},  # in range: 5 m (empty), 49.99 m (radar)
        "pedestrian": {"share_in_class_range": 0.5, "per_keyframe_in_class_range": 0.5,
                       "share_without_lidar_or_radar_points": 0.0},  # the empty one at 40 m is out of range
        "barrier": {"share_in_class_range": 1.0, "per_keyframe_in_class_range": 0.5,
                    "share_without_lidar_or_radar_points": 0.0},
    }
    # in range: 5 (0-20), 25 (20-30), 39 (30-40), 49.99 (40-50)
    assert figures["distance_band_shares"] == {"0-20": 0.25, "20-30": 0.25, "30-40": 0.25, "40-50": 0.25}
    # in range: 5 m (no point), 49.99 m (radar only), 39 m pedestrian (LiDAR only), 25 m barrier (radar only)
    assert figures["share_without_lidar_points"] == 3 / 4
    assert figures["share_without_radar_points"] == 2 / 4
    assert figures["share_without_lidar_or_radar_points"] == 1 / 4
    assert set(REFERENCE["class_range_empty_shares"].value) <= set(figures)  # the reference names our figures
    assert figures["visibility_shares"] == {"v0-40": 1 / 4, "v40-60": 1 / 4, "v60-80": 1 / 4, "v80-100": 1 / 4}
    # the one fully visible in-range box is the car at 49.99 m; the v80-100 one at 50 m is out of range
    assert figures["share_fully_visible_by_distance_band"] == {"0-20": 0.0, "20-30": 0.0, "30-40": 0.0, "40-50": 1.0}
    assert figures["share_without_lidar_or_radar_points_by_distance_band"] == {
        "0-20": 1.0, "20-30": 0.0, "30-40": 0.0, "40-50": 0.0}
    assert set(REFERENCE["empty_share_by_distance_band"].value) == set(figures["distance_band_shares"])
    assert set(REFERENCE["empty_share_by_class"].value) == set(REFERENCE["share_in_class_range"].value) - {"all"}
    # the only empty in-range box (5 m car) is v0-40; the out-of-range v0-40 boxes do not count
    assert figures["share_without_lidar_or_radar_points_by_visibility"] == {
        "v0-40": 1.0, "v40-60": 0.0, "v60-80": 0.0, "v80-100": 0.0}
    assert set(REFERENCE["empty_share_by_visibility"].value) == set(figures["visibility_shares"])


def test_lidar_points_by_distance_split_the_mean():
    distance = np.array([3.0, 9.99, 10.0, 45.0, 70.0, np.inf])
    points = np.array([900, 100, 40, 2, 0, 0])
    figures = lidar_point_band_figures(distance, points)
    assert list(figures) == ["0-10", "10-20", "20-30", "30-40", "40-50", "50-inf"]
    assert figures["0-10"] == {"share": 2 / 6, "mean": 500.0, "median": 500.0, "part_of_mean": 1000 / 6}
    assert figures["20-30"] == {"share": 0.0, "mean": None, "median": None, "part_of_mean": 0.0}
    assert figures["50-inf"]["share"] == 2 / 6  # an annotation without a LIDAR_TOP key frame is at inf
    assert sum(v["part_of_mean"] for v in figures.values()) == pytest.approx(points.mean())


def test_published_class_range_figures_add_up():
    """The per-class val figures are shares of one total: they must sum back to it."""
    per_keyframe = REFERENCE["per_keyframe_in_class_range"].value
    assert sum(v for k, v in per_keyframe.items() if k != "all") == pytest.approx(per_keyframe["all"], rel=0.01)
    assert per_keyframe["car"] == pytest.approx(9.9, abs=0.05)  # the reference's stated cars within 50 m
    assert sum(REFERENCE["class_range_distance_band_shares"].value.values()) == pytest.approx(1.0)
    attributes = REFERENCE["vehicle_attribute_shares"].value
    assert sum(attributes.values()) == pytest.approx(1.0)
    assert round(100 * attributes["vehicle.parked"], 1) == 52.3  # the reference's stated mini share


def test_azimuth_histogram_and_fore_aft_share():
    degrees = np.array([1.0, 14.0, 20.0, 90.0, 179.0, -170.0, -164.0, -100.0])
    xy = np.c_[np.cos(np.radians(degrees)), np.sin(np.radians(degrees))] * 20.0
    figures = azimuth_figures(xy)
    expected = np.zeros(24, dtype=int)
    np.add.at(expected, [12, 12, 13, 18, 23, 0, 1, 5], 1)
    assert figures["counts_from_minus_180"] == expected.tolist()
    # within 15 deg of ahead or behind: 1, 14, 179, -170 (-164 is 16 deg from behind)
    assert figures["share_within_15deg_of_fore_aft_axis"] == 4 / 8
    assert figures["empty_bins"] == 24 - 7
    assert azimuth_figures(np.zeros((0, 2)))["share_within_15deg_of_fore_aft_axis"] is None


def test_heading_to_axis_folds_onto_0_45():
    headings = np.radians([0.0, 91.0, -178.0, 44.0, 46.0, 270.0, 4.0, 6.0])
    figures = heading_to_axis_figures(headings)
    # folded: 0, 1, 2, 44, 44, 0, 4, 6
    assert figures["counts_from_0"] == [5, 1, 0, 0, 0, 0, 0, 0, 2]
    assert figures["share_within_5deg_of_axis"] == 5 / 8


def test_headings_in_ego_subtract_the_ego_yaw():
    heading = _headings_in_ego(yaw_to_quat(np.radians([100.0, -170.0])), yaw_to_quat(np.radians([90.0, 170.0])))
    assert np.degrees(heading) == pytest.approx([10.0, 20.0])


def test_summary_figures_are_consistent(tiny_dataroot):
    db = NuScenesDB(tiny_dataroot, "v1.0-mini")
    summary = summarize(db, max_sweeps=0)
    image = summary["image_boxes"]
    assert len(image["cameras"]) == 6
    assert image["boxes_3d"] == summary["annotations"] == sum(image["boxes_by_camera_count"])
    assert image["image_boxes"] == sum(k * n for k, n in enumerate(image["boxes_by_camera_count"]))
    assert image["per_3d_box"] == pytest.approx(image["image_boxes"] / image["boxes_3d"])
    assert set(image["by_class"]) <= set(DETECTION_CLASSES)
    evaluated = sum(count for name, count in summary["annotations_per_category"].items()
                    if name in CATEGORY_TO_DETECTION)
    assert sum(figures["boxes_3d"] for figures in image["by_class"].values()) == evaluated
    humans = sum(count for name, count in summary["annotations_per_category"].items() if name.startswith("human."))
    assert image["humans"]["boxes_3d"] == humans
    by_distance = image["cars_within_50m_with_points_by_distance"]
    assert sum(band["boxes_3d"] for band in by_distance.values()) == round(
        summary["cars_per_keyframe_within_50m"] * summary["samples"])
    assert sum(summary["car_azimuth_within_50m"]["counts_from_minus_180"]) == \
        summary["car_heading_to_axis_within_50m"]["boxes"]
    by_class = summary["objects_per_keyframe_by_class"]
    cars = summary["annotations_per_category"].get("vehicle.car", 0)
    assert by_class["car"] == pytest.approx(cars / summary["samples"])
    assert set(summary["nuscenes_reference"]) == set(REFERENCE)
    in_range = summary["class_range"]
    assert in_range["per_keyframe_in_class_range"] == pytest.approx(
        sum(figures["per_keyframe_in_class_range"] for figures in in_range["by_class"].values()))
    assert in_range["by_class"]["car"]["per_keyframe_in_class_range"] * summary["samples"] >= round(
        summary["cars_per_keyframe_within_50m"] * summary["samples"])  # adds the cars without points


def test_text_report_holds_each_figure_against_nuscenes(tiny_dataroot):
    text = format_summary(summarize(NuScenesDB(tiny_dataroot, "v1.0-mini"), max_sweeps=0))
    for key, reference in REFERENCE.items():
        assert f"| nuScenes {reference.text} ({reference.source})" in text, key
    assert "3-D boxes imaged by >= 2 cameras: " in text
    assert "cars within 50 m with LiDAR points imaged by >= 2 cameras: 0-10 m" in text
    assert "in-range boxes by distance 0-20 / 20-30 / 30-40 / 40-50 m: " in text


def test_run_writes_the_json_it_returns(tiny_dataroot, tmp_path):
    out = tmp_path / "info.json"
    summary = run(InfoConfig(str(tiny_dataroot), max_sweeps=0), out)
    assert json.loads(out.read_text()) == json.loads(json.dumps(summary))


def test_run_names_a_file_where_the_out_folder_should_be(tiny_dataroot, tmp_path):
    (tmp_path / "t.sh").write_text("")
    with pytest.raises(OutputError) as caught:
        run(InfoConfig(str(tiny_dataroot), max_sweeps=0), tmp_path / "t.sh" / "x.json")
    assert str(caught.value) == f"cannot write {tmp_path}/t.sh: not a folder"


def test_a_contact_sheet_that_cannot_be_drawn_leaves_no_out_either(tiny_dataroot, tmp_path):
    """--out had been written before --contact-sheet's name was checked or its images read: a rerun
    with the cause mended was then refused ("exists; pass --overwrite")."""
    with pytest.raises(SianmsError, match="use a .png, .jpg, .jpeg file name"):
        run(InfoConfig(str(tiny_dataroot), max_sweeps=0), tmp_path / "info.json", contact_sheet=tmp_path / "sheet.gif")
    assert list(tmp_path.iterdir()) == []
    data = shutil.copytree(tiny_dataroot, tmp_path / "data")
    for image in (data / "samples" / "CAM_FRONT").glob("*.jpg"):
        image.write_bytes(b"not a jpeg")
    with pytest.raises(DataFormatError):
        run(InfoConfig(str(data), max_sweeps=0), tmp_path / "info.json", contact_sheet=tmp_path / "sheet.png")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["data"]
    summary = run(InfoConfig(str(tiny_dataroot), max_sweeps=0), tmp_path / "info.json",
                  contact_sheet=tmp_path / "sheet.png")
    assert json.loads((tmp_path / "info.json").read_text())["contact_sheet"] == summary["contact_sheet"]
    assert summary["contact_sheet"]["path"] == str(tmp_path / "sheet.png") and (tmp_path / "sheet.png").is_file()


@pytest.mark.parametrize("name", ["sheet.jpg", "sheet.png"])
def test_a_contact_sheet_that_does_not_fit_on_the_disk_leaves_neither_file(tiny_dataroot, full_disk, name):
    """Pillow's JPEG encoder took the full disk's short write for success: a cut-off picture, exit 0
    (and with --overwrite it replaced a good one); --out had been written before the sheet."""
    from sianms_cli.io import OutputError
    from sianms_cli.reporting.contact_sheet import write_contact_sheet

    (full_disk / "pad").write_bytes(bytes(244 * 1024))
    with pytest.raises(OutputError, match=f"cannot write {full_disk / name}: No space left on device"):
        run(InfoConfig(str(tiny_dataroot), max_sweeps=0), full_disk / "info.json", contact_sheet=full_disk / name)
    with pytest.raises(OutputError, match="No space left on device"):
        write_contact_sheet(tiny_dataroot, "v1.0-mini", full_disk / name)
    assert sorted(path.name for path in full_disk.iterdir()) == ["pad"]
