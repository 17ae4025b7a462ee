"""Dump reference facts about a nuScenes-format dataroot, computed by the official devkit only.

Usage (with the devkit venv's interpreter, see scripts/devkit_venv.sh):

    .devkit-venv/bin/python scripts/devkit_dump.py DATAROOT VERSION OUT.json \
        [--split NAME] [--max-samples N] [--nsweeps 10]

The devkit pins numpy<2 and therefore cannot be imported next to sianms. This script
runs in the devkit's own environment, imports nothing from sianms, and writes one
JSON file that our tests (numpy 2, our own loader and geometry) compare against:

- ``table_counts``: number of records per table, as the devkit loaded them;
- ``cameras``: for each key-frame sample (up to --max-samples) and each camera
  channel, the boxes of ``get_sample_data(..., box_vis_level=BoxVisibility.ANY)``
  with their 8 corners in the camera frame (8x3, devkit corner order) and their
  ``view_points(corners, K, normalize=True)`` image coordinates (8x2);
- ``lidar_files``: ``LidarPointCloud.from_file`` point count of every LIDAR_TOP
  sample_data (key frames and sweeps) whose file exists, plus missing/unreadable ones;
- ``multisweep``: for each of those key frames, ``LidarPointCloud.from_file_multisweep``
  with ``--nsweeps`` sweeps of LIDAR_TOP: its point count, the distinct time lags (s)
  and the mean point (reference LIDAR frame), which pins the sweeps' transform chain;
- ``annotation_points``: for each annotation of those key frames, the devkit's
  ``points_in_box`` count over the key-frame LIDAR_TOP points (box moved into the
  lidar frame exactly as ``get_sample_data`` does) next to the stored ``num_lidar_pts``;
- ``evaluation`` (with --split): ``DetectionEval`` / ``detection_cvpr_2019`` run with
  the split's own ground truth submitted as predictions, or with ``--results FILE``.

Non-finite floats (the devkit's NaN TP errors of traffic_cone / barrier) are written
as ``null`` so the file is strict JSON. The output is written to a temporary file in
the same folder and renamed when complete.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import json
import math
import os
import sys
import tempfile
import time
from collections import Counter
from typing import Any

import numpy as np

# The devkit's GT loader draws tqdm bars on stderr with no switch of its own; the dump
# is a batch tool driven by tests, so bars are silenced unless the caller asks for them.
os.environ.setdefault("TQDM_DISABLE", "1")

from nuscenes.eval.common.config import config_factory
from nuscenes.eval.common.loaders import get_samples_of_scenes, load_gt, load_gt_of_sample_tokens
from nuscenes.eval.detection.data_classes import DetectionBox
from nuscenes.eval.detection.evaluate import DetectionEval
from nuscenes.nuscenes import NuScenes
from nuscenes.utils.data_classes import LidarPointCloud
from nuscenes.utils.geometry_utils import BoxVisibility, points_in_box, view_points
from nuscenes.utils.splits import get_scenes_of_split, is_predefined_split

LIDAR_CHANNEL = "LIDAR_TOP"
EVAL_CONFIG = "detection_cvpr_2019"


class DumpError(Exception):
    """A problem with the input that ends the dump with one clear message."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line interface of the dump."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataroot", help="nuScenes-format dataroot (holds VERSION/, samples/, sweeps/, maps/)")
    parser.add_argument("version", help="table folder name, e.g. v1.0-mini")
    parser.add_argument("out", help="output JSON path")
    parser.add_argument("--split", default=None,
                        help="evaluation split: predefined (mini_val, val, ...) or a name from VERSION/splits.json; "
                             "without it the detection evaluation is skipped")
    parser.add_argument("--results", default=None,
                        help="with --split: evaluate this results file instead of the split's own GT")
    parser.add_argument("--max-samples", type=int, default=None,
                        help="limit the per-sample camera and annotation facts to the first N key frames")
    parser.add_argument("--nsweeps", type=int, default=10,
                        help="sweeps per key frame for from_file_multisweep (nuScenes detectors use 10)")
    return parser.parse_args(argv)


def load_devkit(dataroot: str, version: str) -> NuScenes:
    """Load the tables with the devkit, turning any failure into one clear message."""
    if not os.path.isdir(os.path.join(dataroot, version)):
        raise DumpError(f"{os.path.join(dataroot, version)} is not a folder: no '{version}' tables in {dataroot}")
    try:
        return NuScenes(version=version, dataroot=dataroot, verbose=False)
    except Exception as exc:  # the devkit signals bad data with assorted exception types
        raise DumpError(f"nuscenes-devkit cannot load {dataroot} (version {version}): "
                        f"{type(exc).__name__}: {exc}") from exc


def table_counts(nusc: NuScenes) -> dict[str, int]:
    """Number of records in each of the devkit's tables."""
    return {name: len(getattr(nusc, name)) for name in nusc.table_names}


def keyframe_samples(nusc: NuScenes, max_samples: int | None) -> list[dict]:
    """The sample records in table order, cut to ``max_samples`` when given."""
    samples = list(nusc.sample)
    return samples if max_samples is None else samples[:max_samples]


def channel_modality(nusc: NuScenes, sd_token: str) -> str:
    """Sensor modality (camera, lidar, radar) of one sample_data record."""
    return nusc.get("sample_data", sd_token)["sensor_modality"]


def camera_boxes(nusc: NuScenes, samples: list[dict]) -> list[dict]:
    """Visible boxes per key-frame camera image, in the camera frame and in pixels."""
    images = []
    for sample in samples:
        for channel, sd_token in sorted(sample["data"].items()):
            if channel_modality(nusc, sd_token) != "camera":
                continue
            sd_record = nusc.get("sample_data", sd_token)
            data_path, boxes, intrinsic = nusc.get_sample_data(sd_token, box_vis_level=BoxVisibility.ANY)
            box_facts = []
            for box in boxes:
                corners_cam = box.corners()  # 3x8, devkit corner order
                corners_img = view_points(corners_cam, intrinsic, normalize=True)[:2]
                box_facts.append({
                    "annotation_token": box.token,
                    "corners_cam": corners_cam.T.tolist(),
                    "corners_img": corners_img.T.tolist(),
                })
            images.append({
                "sample_token": sample["token"],
                "channel": channel,
                "sample_data_token": sd_token,
                "filename": sd_record["filename"],
                "image_path": data_path,
                "image_exists": os.path.isfile(data_path),
                "width": sd_record["width"],
                "height": sd_record["height"],
                "camera_intrinsic": np.asarray(intrinsic).tolist(),
                "boxes": box_facts,
            })
    return images


def read_lidar(nusc: NuScenes, sd_token: str) -> LidarPointCloud:
    """The devkit's reading of one LIDAR_TOP file."""
    return LidarPointCloud.from_file(nusc.get_sample_data_path(sd_token))


def lidar_point_counts(nusc: NuScenes) -> dict[str, Any]:
    """Point count of every LIDAR_TOP file that exists; missing and unreadable files listed apart."""
    counts: dict[str, int] = {}
    missing: list[str] = []
    unreadable: dict[str, str] = {}
    for sd_record in nusc.sample_data:
        if sd_record["channel"] != LIDAR_CHANNEL:
            continue
        token = sd_record["token"]
        if not os.path.isfile(nusc.get_sample_data_path(token)):
            missing.append(token)
            continue
        try:
            counts[token] = int(read_lidar(nusc, token).nbr_points())
        except Exception as exc:  # a corrupt file is a fact to report, not a reason to stop
            unreadable[token] = f"{type(exc).__name__}: {exc}"
    return {"point_counts": counts, "missing": missing, "unreadable": unreadable}


def multisweep(nusc: NuScenes, samples: list[dict], nsweeps: int) -> list[dict]:
    """The devkit's multi-sweep point cloud of each key frame's LIDAR_TOP, summarised (key
    frames whose LiDAR file is absent, as in a tables-only dataset, are left out)."""
    facts = []
    for sample in samples:
        if LIDAR_CHANNEL not in sample["data"]:
            continue
        if not os.path.exists(nusc.get_sample_data_path(sample["data"][LIDAR_CHANNEL])):
            continue
        cloud, lags = LidarPointCloud.from_file_multisweep(nusc, sample, LIDAR_CHANNEL, LIDAR_CHANNEL,
                                                           nsweeps=nsweeps)
        facts.append({
            "sample_token": sample["token"],
            "n_points": int(cloud.nbr_points()),
            "time_lags": sorted({round(float(lag), 6) for lag in lags[0]}),
            "mean_point": cloud.points[:3].astype(np.float64).mean(axis=1).tolist(),
        })
    return facts


def annotation_points(nusc: NuScenes, samples: list[dict]) -> list[dict]:
    """Devkit points_in_box count of each key-frame annotation next to its num_lidar_pts."""
    facts = []
    for sample in samples:
        if not sample["anns"]:
            continue
        lidar_token = sample["data"].get(LIDAR_CHANNEL)
        points = None
        if lidar_token is not None and os.path.isfile(nusc.get_sample_data_path(lidar_token)):
            points = read_lidar(nusc, lidar_token).points[:3]
        boxes_lidar = {}
        if lidar_token is not None:
            # get_sample_data with selected annotations moves each box global -> ego -> lidar,
            # the same path the devkit takes for its own boxes of this sweep.
            _, boxes, _ = nusc.get_sample_data(lidar_token, selected_anntokens=sample["anns"])
            boxes_lidar = {box.token: box for box in boxes}
        for ann_token in sample["anns"]:
            annotation = nusc.get("sample_annotation", ann_token)
            box = boxes_lidar.get(ann_token)
            inside = None
            if points is not None and box is not None:
                inside = int(points_in_box(box, points).sum())
            facts.append({
                "annotation_token": ann_token,
                "sample_token": sample["token"],
                "lidar_sample_data_token": lidar_token,
                "category_name": annotation["category_name"],
                "points_in_box": inside,
                "num_lidar_pts": annotation["num_lidar_pts"],
            })
    return facts


def split_sample_tokens(nusc: NuScenes, split: str) -> list[str]:
    """Sample tokens of a predefined or custom (splits.json) split, in sample-table order."""
    return get_samples_of_scenes(get_scenes_of_split(split, nusc), nusc)


def ground_truth_boxes(nusc: NuScenes, split: str, sample_tokens: list[str]):
    """GT of the split loaded the way DetectionEval loads it for that kind of split."""
    if is_predefined_split(split):
        return load_gt(nusc, split, DetectionBox, verbose=False)
    return load_gt_of_sample_tokens(nusc, sample_tokens, DetectionBox, verbose=False)


def gt_as_results(gt_boxes, sample_tokens: list[str]) -> dict:
    """A results submission that repeats the GT, every split sample present.

    Each box gets its own score (descending in load order) so the devkit's tie
    order cannot influence the outcome. Each box also carries its GT ``num_pts``
    (an optional key of the results format): the devkit drops GT boxes without
    points but keeps predictions without the key (they read as -1), so a zero-point
    GT box submitted bare would count as a false positive and pull AP below 1.
    With ``num_pts`` the same filter removes it from both sides.
    """
    total = sum(len(gt_boxes.boxes.get(token, [])) for token in sample_tokens)
    results: dict[str, list[dict]] = {}
    rank = 0
    for token in sample_tokens:
        entries = []
        for box in gt_boxes.boxes.get(token, []):
            rank += 1
            entries.append({
                "sample_token": token,
                "translation": [float(v) for v in box.translation],
                "size": [float(v) for v in box.size],
                "rotation": [float(v) for v in box.rotation],
                "velocity": [float(v) for v in box.velocity],
                "detection_name": box.detection_name,
                "detection_score": 1.0 - rank / (total + 1),
                "attribute_name": box.attribute_name,
                "num_pts": int(box.num_pts),
            })
        results[token] = entries
    meta = {"use_camera": True, "use_lidar": False, "use_radar": False, "use_map": False, "use_external": False}
    return {"meta": meta, "results": results}


def boxes_per_class(eval_boxes, sample_tokens: list[str]) -> dict[str, int]:
    """Number of boxes of each detection class over the given samples."""
    counter = Counter(box.detection_name for token in sample_tokens for box in eval_boxes.boxes.get(token, []))
    return dict(sorted(counter.items()))


def detection_evaluation(nusc: NuScenes, split: str, results: str | None = None) -> dict[str, Any]:
    """Run DetectionEval on the split with a results file, or its own GT submitted as predictions."""
    try:
        sample_tokens = split_sample_tokens(nusc, split)
    except (ValueError, KeyError, AssertionError) as exc:
        raise DumpError(f"split '{split}' is not usable: {exc}") from exc
    if not sample_tokens:
        raise DumpError(f"split '{split}' holds no sample of this dataroot")
    gt_boxes = ground_truth_boxes(nusc, split, sample_tokens)
    if results is None:
        submission = gt_as_results(gt_boxes, sample_tokens)
    else:
        with open(results) as handle:
            submission = json.load(handle)
    with tempfile.TemporaryDirectory(prefix="devkit_eval_") as workdir:
        result_path = results or os.path.join(workdir, "results.json")
        if results is None:
            with open(result_path, "w") as handle:
                json.dump(submission, handle)
        try:
            evaluator = DetectionEval(nusc, config_factory(EVAL_CONFIG), result_path, eval_set=split,
                                      output_dir=os.path.join(workdir, "eval"), verbose=False)
            metrics, _ = evaluator.evaluate()
        except Exception as exc:  # report what the devkit objected to, in one line
            raise DumpError(f"DetectionEval failed on split '{split}': {type(exc).__name__}: {exc}") from exc
    summary = metrics.serialize()
    return {
        "split": split,
        "config": EVAL_CONFIG,
        "n_samples": len(sample_tokens),
        "n_predictions": sum(len(v) for v in submission["results"].values()),
        "label_aps": summary["label_aps"],
        "mean_dist_aps": summary["mean_dist_aps"],
        "label_tp_errors": summary["label_tp_errors"],
        "mean_ap": summary["mean_ap"],
        "nd_score": summary["nd_score"],
        "gt_boxes_per_class": boxes_per_class(gt_boxes, sample_tokens),
        "gt_boxes_per_class_evaluated": boxes_per_class(evaluator.gt_boxes, sample_tokens),
    }


def finite_or_none(value: Any) -> Any:
    """Replace NaN/inf floats by None (recursively) so the output is strict JSON."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: finite_or_none(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(item) for item in value]
    return value


def write_json_atomic(path: str, payload: dict) -> None:
    """Write JSON to a temporary file beside ``path`` and rename it into place."""
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    handle, tmp_path = tempfile.mkstemp(prefix=".devkit_dump_", suffix=".json.tmp", dir=folder)
    try:
        with os.fdopen(handle, "w") as stream:
            json.dump(finite_or_none(payload), stream, allow_nan=False)
        os.replace(tmp_path, path)
    except BaseException:
        os.unlink(tmp_path)
        raise


def dump(args: argparse.Namespace) -> dict[str, Any]:
    """Collect every fact into one dictionary."""
    started = time.perf_counter()
    nusc = load_devkit(args.dataroot, args.version)
    samples = keyframe_samples(nusc, args.max_samples)
    facts: dict[str, Any] = {
        "table_counts": table_counts(nusc),
        "cameras": camera_boxes(nusc, samples),
        "lidar_files": lidar_point_counts(nusc),
        "multisweep": multisweep(nusc, samples, args.nsweeps),
        "annotation_points": annotation_points(nusc, samples),
        "evaluation": detection_evaluation(nusc, args.split, args.results) if args.split else None,
    }
    facts["meta"] = {
        "dataroot": os.path.abspath(args.dataroot),
        "version": args.version,
        "split": args.split,
        "results": args.results,
        "max_samples": args.max_samples,
        "nsweeps": args.nsweeps,
        "n_samples_dumped": len(samples),
        "devkit_version": importlib.metadata.version("nuscenes-devkit"),
        "numpy_version": np.__version__,
        "seconds": round(time.perf_counter() - started, 3),
    }
    return facts


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        facts = dump(args)
    except DumpError as exc:
        print(f"devkit_dump: error: {exc}", file=sys.stderr)
        return 2
    write_json_atomic(args.out, facts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
