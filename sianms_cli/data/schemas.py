"""Parquet schemas of the prepared cache (``sianms prepare``), versioned in the file metadata.

Three datasets, one zstd Parquet file per shard (a shard is one scene):

- ``detections/``: one row per 2D detection of one camera image, with its association to
  the ground truth and its ROI feature;
- ``frustums/``: one row per detection, its LiDAR frustum points in the frustum frame with
  per-point labels, and the associated box's parameters;
- ``pairs/``: one row per instance detected in both cameras of a contiguous pair in one
  sample (reference detection in the first camera of the pair in clockwise order, positive
  in the second).

Every file's schema metadata holds ``sianms.dataset`` and ``sianms.schema_version``; the
detections files also hold ``sianms.roi_feature_shape`` ("C,PH,PW") and
``sianms.roi_feature_dtype`` ("<f2"). ROI features are raw little-endian float16 bytes in a
fixed-size binary column so every Parquet reader (pyarrow, pandas, polars, DuckDB) reads them;
decode with :func:`sianms_cli.data.cache.decode_roi_features`.
"""

from __future__ import annotations

import pyarrow as pa

SCHEMA_VERSION = 1
DATASETS = ("detections", "frustums", "pairs")

_ID = [
    ("detection_id", pa.string()),  # "<sample_data_token>_<index>", unique in the dataset
    ("scene_token", pa.string()),
    ("sample_token", pa.string()),
    ("sample_data_token", pa.string()),
    ("camera", pa.string()),
]


def detections_schema(feature_bytes: int) -> pa.Schema:
    """Schema of ``detections/``; ``feature_bytes`` = C * PH * PW * 2."""
    fields = _ID + [
        ("scene_name", pa.string()),
        ("detection_index", pa.int32()),  # rank in its image by descending score
        ("x1", pa.float32()), ("y1", pa.float32()), ("x2", pa.float32()), ("y2", pa.float32()),
        ("score", pa.float32()),
        ("class", pa.string()),
        ("source", pa.string()),  # "detector", or "ground_truth" for a projected missed object
        ("image_width", pa.int32()), ("image_height", pa.int32()),
        ("instance_token", pa.string()),  # associated ground truth; null when none
        ("annotation_token", pa.string()),
        ("iou", pa.float32()),  # with the associated projected box; 0 when none
        ("gt_truncation", pa.float32()),
        ("gt_occlusion", pa.float32()),
        ("gt_distance", pa.float32()),  # metres, camera to box centre
        # the pairs "CAM_A|CAM_B" of this camera whose overlap holds the GT centre
        ("overlap_pairs", pa.list_(pa.string())),
        ("roi_feature", pa.binary(feature_bytes)),
    ]
    return pa.schema(fields)


FRUSTUMS_SCHEMA = pa.schema(_ID + [
    ("class", pa.string()),
    ("score", pa.float32()),
    ("source", pa.string()),
    ("instance_token", pa.string()),
    ("rot_angle", pa.float32()),  # frustum_angle: camera -> frustum frame rotation about y
    ("num_points", pa.int32()),
    ("x", pa.list_(pa.float32())),  # frustum frame (camera frame rotated by rot_angle), metres
    ("y", pa.list_(pa.float32())),
    ("z", pa.list_(pa.float32())),
    ("intensity", pa.list_(pa.float32())),
    ("time_lag", pa.list_(pa.float32())),  # seconds before the key frame (0 for its own sweep)
    ("label", pa.list_(pa.int8())),  # 1 inside the associated GT box, else 0
    # associated GT box (null without one): camera frame and frustum frame; size (w, l, h)
    ("box_center_cam", pa.list_(pa.float32())),
    ("box_size", pa.list_(pa.float32())),
    ("box_rotation_cam", pa.list_(pa.float32())),  # quaternion (w, x, y, z)
    ("box_heading_cam", pa.float32()),  # F-PointNets ry = atan2(-v_z, v_x) of the length axis
    ("box_center_frustum", pa.list_(pa.float32())),
    ("box_heading_frustum", pa.float32()),  # ry - rot_angle
])

PAIRS_SCHEMA = pa.schema([
    ("scene_token", pa.string()),
    ("sample_token", pa.string()),
    ("instance_token", pa.string()),
    ("class", pa.string()),
    ("pair", pa.string()),  # "CAM_A|CAM_B", contiguous, clockwise
    ("camera_a", pa.string()),
    ("camera_b", pa.string()),
    ("reference_detection_id", pa.string()),  # in camera_a
    ("positive_detection_id", pa.string()),  # in camera_b
    ("reference_source", pa.string()),
    ("positive_source", pa.string()),
    ("center_in_overlap", pa.bool_()),  # THE overlap rule on the box centre
])


def with_metadata(schema: pa.Schema, dataset: str, extra: dict[str, str] | None = None) -> pa.Schema:
    """``schema`` with the sianms metadata of ``dataset``."""
    metadata = {"sianms.dataset": dataset, "sianms.schema_version": str(SCHEMA_VERSION), **(extra or {})}
    return schema.with_metadata({k.encode(): v.encode() for k, v in metadata.items()})


def cache_schemas(feature_shape: tuple[int, int, int], backbone: str) -> dict[str, pa.Schema]:
    """The schemas of the three datasets of one cache, metadata included, by dataset name.

    Args:
        feature_shape: (C, PH, PW) of one ROI feature, stored as little-endian float16.
        backbone: the backbone's name, recorded with the features.
    """
    channels, height, width = (int(v) for v in feature_shape)
    metadata = {"sianms.roi_feature_shape": f"{channels},{height},{width}", "sianms.roi_feature_dtype": "<f2",
                "sianms.backbone": backbone}
    return {
        "detections": with_metadata(detections_schema(channels * height * width * 2), "detections", metadata),
        "frustums": with_metadata(FRUSTUMS_SCHEMA, "frustums"),
        "pairs": with_metadata(PAIRS_SCHEMA, "pairs"),
    }
