"""The real nuScenes value of each `sianms info` figure, with where it comes from.

Each value is a published figure with its source (listed in docs/synthetic_world.md#nuscenes-figures);
"derived" marks arithmetic on cited numbers, "third-party" a public analysis not by the dataset
authors. ``value`` is in the unit of our figure (shares in [0, 1]), a dict for a figure per
class or per bin, or None where nuScenes publishes only a shape (the text then gives the
uniform baseline and the published shape); ``text`` is how the report prints it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class Reference:
    """One published figure of real nuScenes."""

    value: float | dict[str, float] | None
    text: str
    source: str


REFERENCE: dict[str, Reference] = {
    "image_boxes_per_3d_box": Reference(
        1_416_337 / 1_166_187, "1.215",
        "v1.0-trainval, 1,416,337 2-D from 1,166,187 3-D boxes by export_2d_annotations_as_json.py; "
        "nuscenes-devkit#457"),
    "human_image_boxes_per_3d_box": Reference(
        255_254 / 222_164, "1.149", "v1.0-trainval humans, 255,254 2-D from 222,164 3-D boxes; nuscenes-devkit#457"),
    "share_imaged_by_2_or_more": Reference(
        (1_416_337 - 1_166_187) / 1_166_187, ">= 21.4 %",
        "derived lower bound from nuscenes-devkit#457 if no box spans 3 images"),
    "human_share_imaged_by_2_or_more": Reference(
        (255_254 - 222_164) / 222_164, ">= 14.9 %", "derived lower bound from nuscenes-devkit#457, humans"),
    "car_share_in_overlap": Reference(
        None, "~11-13 % if azimuths were uniform",
        "derived: Set A overlap sectors 39.3 deg at 20 m, 47.4 deg at 50 m of 360 deg; no published count"),
    "car_share_within_15deg_of_fore_aft_axis": Reference(
        None, "16.7 % if uniform; real cars concentrate ahead and behind",
        "paper:nuScenes SM Fig. 10 (shape only)"),
    "car_share_heading_within_5deg_of_axis": Reference(
        None, "11.1 % if uniform; real headings peak at the axes",
        "paper:nuScenes SM Fig. 12 (shape only)"),
    "lidar_points_per_annotation": Reference(58.8, "58.8", "v1.0-mini; nuscenes-devkit#219"),
    "share_annotations_without_lidar_points": Reference(
        3_466 / 18_538, "18.7 %", "v1.0-mini, 3,466 of 18,538; nuscenes-devkit#313"),
    "radar_points_per_annotation": Reference(0.85, "0.85", "v1.0-mini; nuscenes-devkit#219"),
    "class_range_empty_shares": Reference(
        {"share_without_lidar_points": 0.1201, "share_without_radar_points": 0.6119,
         "share_without_lidar_or_radar_points": 0.0943},
        "12.0 / 61.2 / 9.4 %", "third-party, v1.0-val in-range boxes (reiyah-measure)"),
    "lidar_points_per_sweep": Reference(34_000.0, "~34k", "HDL-32E sweep files; NVIDIA ncore nuScenes page"),
    "objects_per_keyframe": Reference(1_166_187 / 34_149, "34.1", "derived, v1.0-trainval 1,166,187 / 34,149"),
    "objects_per_keyframe_by_class": Reference(
        {"car": 493_322 / 34_149, "pedestrian": 220_194 / 34_149, "barrier": 152_087 / 34_149,
         "traffic_cone": 97_959 / 34_149, "truck": 88_519 / 34_149, "trailer": 24_860 / 34_149,
         "bus": 16_321 / 34_149, "construction_vehicle": 14_671 / 34_149, "motorcycle": 12_617 / 34_149,
         "bicycle": 11_859 / 34_149},
        "per class below", "derived, v1.0-trainval detection-class counts / 34,149 keyframes"),
    "share_in_class_range": Reference(
        {"all": 134_565 / 187_528, "car": 0.74, "pedestrian": 0.75, "bicycle": 0.87, "motorcycle": 0.80,
         "traffic_cone": 0.80, "barrier": 0.63, "truck": 0.62, "bus": 0.66, "trailer": 0.59,
         "construction_vehicle": 0.60},
        "71.8 %, per class below",
        "third-party, v1.0-val: 134,565 of 187,528 boxes inside the class ranges (reiyah-measure); derived"),
    "per_keyframe_in_class_range": Reference(
        {"all": 134_565 / 6_019, **{name: share * 134_565 / 6_019 for name, share in (
            ("car", 0.442), ("pedestrian", 0.191), ("barrier", 0.126), ("traffic_cone", 0.093), ("truck", 0.073),
            ("trailer", 0.018), ("bus", 0.015), ("bicycle", 0.015), ("motorcycle", 0.015),
            ("construction_vehicle", 0.012))}},
        "22.4, per class below",
        "third-party, v1.0-val: 134,565 in-range boxes over 6,019 keyframes, times each class's share of them "
        "(reiyah-measure); derived"),
    "class_range_distance_band_shares": Reference(
        {"0-20": 54_626 / 134_565, "20-30": 38_242 / 134_565, "30-40": 26_385 / 134_565, "40-50": 15_312 / 134_565},
        "40.6 / 28.4 / 19.6 / 11.4 %",
        "third-party, v1.0-val in-range boxes (reiyah-measure)"),
    "visibility_shares": Reference(
        {"v0-40": 0.239, "v40-60": 0.102, "v60-80": 0.139, "v80-100": 0.521},
        "v0-40 23.9 %, v40-60 10.2 %, v60-80 13.9 %, v80-100 52.1 %",
        "third-party, val boxes within class range (reiyah-measure)"),
    "vehicle_attribute_shares": Reference(
        {"vehicle.moving": 2_715 / 8_934, "vehicle.parked": 4_674 / 8_934, "vehicle.stopped": 1_545 / 8_934},
        "moving 30.4 %, parked 52.3 %, stopped 17.3 %",
        "v1.0-mini, 2,715 / 4,674 / 1,545 of 8,934 vehicle attributes (list_attributes); no trainval table"),
    "empty_share_by_distance_band": Reference(
        {"0-20": 0.040, "20-30": 0.100, "30-40": 0.138, "40-50": 0.198},
        "4.0 / 10.0 / 13.8 / 19.8 %", "third-party, val boxes within class range (reiyah-measure)"),
    "empty_share_by_class": Reference(
        {"traffic_cone": 0.154, "bicycle": 0.110, "car": 0.109, "pedestrian": 0.085, "motorcycle": 0.077,
         "barrier": 0.060, "construction_vehicle": 0.054, "truck": 0.052, "trailer": 0.047, "bus": 0.011},
        "in range, per keyframe and empty share per class below; empty: in-range boxes without LiDAR or radar",
        "third-party, val boxes within class range (reiyah-measure)"),
    "empty_share_by_visibility": Reference(
        {"v0-40": 0.270, "v40-60": 0.071, "v60-80": 0.045, "v80-100": 0.032},
        "v0-40 27.0 %, v40-60 7.1 %, v60-80 4.5 %, v80-100 3.2 %",
        "third-party, val boxes within class range (reiyah-measure)"),
    "share_keyframes_go_straight": Reference(
        0.739, "73.9 %; 86.7 % by this rule",
        "Li et al., arXiv 2312.03031, go-straight share of the planning scenarios, rule not stated; VAD's "
        "command rule on val's 5,119 key frames with 3 s ahead: 7.8 % right, 5.6 % left, third-party count"),
    "scene_share_night": Reference(
        0.116, "11.6 %", "v1.0-trainval scene descriptions saying night, ~99 of 850; nuScenes paper §2 "
        "(Caesar et al., CVPR 2020), not re-counted here"),
    "scene_share_rain": Reference(
        0.194, "19.4 %", "v1.0-trainval scene descriptions saying rain, ~165 of 850; nuScenes paper §2 "
        "(Caesar et al., CVPR 2020), not re-counted here"),
}


def reference_json() -> dict:
    """Every reference value as JSON, so an ``info`` output says what it was held against."""
    return {key: asdict(reference) for key, reference in REFERENCE.items()}


def reference_per_name(key: str) -> dict[str, float]:
    """The value of figure ``key``, one of those published per class or per bin."""
    value = REFERENCE[key].value
    assert isinstance(value, dict), key
    return value
