"""Benchmark `sianms metrics` against nuscenes-devkit 1.2.0 on a validation-sized workload.

Writes (once, then reuses) a tables-only v1.0-trainval dataroot whose ``val`` split holds 150
scenes / 6,019 samples with 10 ground-truth boxes per class and sample (601,900 boxes, with
prev/next chains, attributes, boxes without points and bicycle racks), and a results file
with 20 predictions per class and sample (1,203,800 boxes: half near a ground-truth box of
their class, half anywhere within 60 m; scores on a 0.001 grid, so ties occur). Then, in the
same run, measures:

- ours, in a fresh child process: table loading, ``read_results``, ``evaluate`` (filters,
  matching, metrics), the matching + metrics alone, and the peak RSS;
- the devkit, in its own venv (``.devkit-venv`` or $SIANMS_DEVKIT_PYTHON) when present:
  ``NuScenes`` loading, ``DetectionEval(...)`` (results + GT loading and filters) and
  ``evaluate()``, and its peak RSS;

and prints both ratios (the devkit's ``evaluate()`` against our matching + metrics; results
file to metrics, tables loaded, on both sides), whether every number is equal, and ours peak
memory.

    python bench/metrics.py                      # full size (the devkit takes ~15 minutes)
    python bench/metrics.py --scenes 15          # a tenth of it
    python bench/metrics.py --no-devkit
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import json
import math
import multiprocessing
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from sianms_cli.metrics.boxes import ATTRIBUTE, DETECTION_NAMES, NO_ATTRIBUTE, empty_boxes
from sianms_cli.metrics.evaluate import evaluate
from sianms_cli.metrics.results import read_results, results_from_boxes, write_results
from sianms_cli.geometry.quaternion import yaw_to_quat
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.nuscenes.splits import splits_for_version
from sianms_cli.nuscenes.tables import SENSORS
from sianms_cli.nuscenes.writer import DatasetWriter, attribute_token, category_token, make_token
from sianms_cli.synth.nuscenes_rig import RIG_SINGAPORE, normalised_rig

VERSION = "v1.0-trainval"
SPLIT = "val"
GT_PER_CLASS = 10
PRED_PER_CLASS = 20
SAMPLE_PERIOD_US = 500_000
CATEGORY_OF = {
    "car": "vehicle.car", "truck": "vehicle.truck", "bus": "vehicle.bus.rigid", "trailer": "vehicle.trailer",
    "construction_vehicle": "vehicle.construction", "pedestrian": "human.pedestrian.adult",
    "motorcycle": "vehicle.motorcycle", "bicycle": "vehicle.bicycle", "traffic_cone": "movable_object.trafficcone",
    "barrier": "movable_object.barrier",
}
SIZE_OF = {
    "car": (1.95, 4.62, 1.73), "truck": (2.51, 6.93, 2.84), "bus": (2.93, 11.23, 3.47), "trailer": (2.90, 12.29, 3.87),
    "construction_vehicle": (2.85, 6.37, 3.19), "pedestrian": (0.67, 0.73, 1.77), "motorcycle": (0.77, 2.11, 1.47),
    "bicycle": (0.60, 1.70, 1.28), "traffic_cone": (0.41, 0.41, 1.07), "barrier": (2.53, 0.50, 0.98),
}
ATTRIBUTES_OF = {
    "pedestrian": ("pedestrian.moving", "pedestrian.standing"),
    "motorcycle": ("cycle.with_rider", "cycle.without_rider"),
    "bicycle": ("cycle.with_rider", "cycle.without_rider"), "traffic_cone": (), "barrier": (),
}
SENSOR_TOKEN = {sensor.channel: sensor.token for sensor in SENSORS}


def samples_per_scene(scenes: int) -> list[int]:
    """40 samples per scene, 41 for the first 19 of 150: 6,019 for the full val split."""
    extra = round(19 * scenes / 150)
    return [41 if i < extra else 40 for i in range(scenes)]


# --------------------------------------------------------------------------- workload


def write_dataroot(dataroot: Path, scenes: int, seed: int) -> None:
    """The tables of a val-sized dataset (no sensor files); deterministic."""
    rng = np.random.default_rng(seed)
    names = splits_for_version(VERSION)[SPLIT][:scenes]
    rig = normalised_rig(RIG_SINGAPORE)
    with DatasetWriter(dataroot, VERSION, overwrite=True) as writer:
        writer.add_static_tables()
        logs = []
        for scene_index, (name, count) in enumerate(zip(names, samples_per_scene(scenes))):
            log = make_token("log", name)
            logs.append(log)
            writer.add("log", {"token": log, "logfile": f"bench-{name}", "vehicle": "n015",
                               "date_captured": "2018-07-24", "location": "singapore-onenorth"})
            calibrations = {}
            for sensor in rig:
                token = make_token("calibrated_sensor", name, sensor.channel)
                calibrations[sensor.channel] = token
                writer.add("calibrated_sensor", {
                    "token": token, "sensor_token": SENSOR_TOKEN[sensor.channel],
                    "translation": list(sensor.translation), "rotation": list(sensor.rotation),
                    "camera_intrinsic": sensor.intrinsic(1.0).tolist() if sensor.focal else []})
            _write_scene(writer, rng, name, scene_index, count, calibrations)
        writer.add_map(make_token("map", "bench"), logs)


def _write_scene(writer, rng, name, scene_index, count, calibrations) -> None:
    t0 = 1_532_402_927_000_000 + scene_index * 100_000_000
    samples = [make_token("sample", name, k) for k in range(count)]
    heading = rng.uniform(-np.pi, np.pi)
    ego_xy = np.array([500.0 + 2000 * scene_index, 1000.0]) + np.outer(np.arange(count) * 4.0,
                                                                         [np.cos(heading), np.sin(heading)])
    writer.add("scene", {"token": make_token("scene", name), "name": name, "description": "bench",
                         "log_token": make_token("log", name), "nbr_samples": count,
                         "first_sample_token": samples[0], "last_sample_token": samples[-1]})
    ego_rotation = [float(np.cos(heading / 2)), 0.0, 0.0, float(np.sin(heading / 2))]
    for k, token in enumerate(samples):
        time_us = t0 + k * SAMPLE_PERIOD_US
        writer.add("sample", {"token": token, "timestamp": time_us, "prev": samples[k - 1] if k else "",
                              "next": samples[k + 1] if k + 1 < count else "",
                              "scene_token": make_token("scene", name)})
        pose = make_token("ego_pose", name, k)
        writer.add("ego_pose", {"token": pose, "timestamp": time_us, "rotation": ego_rotation,
                                "translation": [float(ego_xy[k, 0]), float(ego_xy[k, 1]), 0.0]})
        for channel, calibration in calibrations.items():
            camera = channel != "LIDAR_TOP"
            writer.add("sample_data", {
                "token": make_token("sample_data", name, k, channel), "sample_token": token, "ego_pose_token": pose,
                "calibrated_sensor_token": calibration, "timestamp": time_us,
                "fileformat": "jpg" if camera else "pcd", "is_key_frame": True,
                "height": 900 if camera else 0, "width": 1600 if camera else 0,
                "filename": f"samples/{channel}/bench__{channel}__{time_us}.{'jpg' if camera else 'pcd.bin'}",
                "prev": "", "next": ""})
    for label, detection_name in enumerate(DETECTION_NAMES):
        for j in range(GT_PER_CLASS):
            offset = rng.uniform(-45, 45, 2)
            drift = np.cumsum(rng.normal(0, 0.3, (count, 2)), axis=0)
            yaw = rng.uniform(-np.pi, np.pi)
            instance = make_token("instance", name, detection_name, j)
            tokens = [make_token("annotation", name, detection_name, j, k) for k in range(count)]
            writer.add("instance", {"token": instance, "category_token": category_token(CATEGORY_OF[detection_name]),
                                    "nbr_annotations": count, "first_annotation_token": tokens[0],
                                    "last_annotation_token": tokens[-1]})
            choices = ATTRIBUTES_OF.get(detection_name, ("vehicle.moving", "vehicle.parked", "vehicle.stopped"))
            attribute = [attribute_token(choices[rng.integers(len(choices))])] if choices else []
            for k, token in enumerate(tokens):
                xy = ego_xy[k] + offset + drift[k]
                writer.add("sample_annotation", {
                    "token": token, "sample_token": samples[k], "instance_token": instance, "visibility_token": "4",
                    "attribute_tokens": attribute, "translation": [float(xy[0]), float(xy[1]), 1.0],
                    "size": list(SIZE_OF[detection_name]), "rotation": yaw_to_quat(yaw + 0.01 * k).tolist(),
                    "prev": tokens[k - 1] if k else "", "next": tokens[k + 1] if k + 1 < count else "",
                    "num_lidar_pts": int(rng.integers(0, 50)) if rng.random() > 0.1 else 0, "num_radar_pts": 0})
            if detection_name == "bicycle" and j == 0:  # a rack around the first bicycle of every scene
                rack = make_token("instance", name, "rack")
                writer.add("instance", {"token": rack, "category_token": category_token("static_object.bicycle_rack"),
                                        "nbr_annotations": 1, "first_annotation_token": make_token("rack", name),
                                        "last_annotation_token": make_token("rack", name)})
                xy = ego_xy[0] + offset + drift[0]
                writer.add("sample_annotation", {
                    "token": make_token("rack", name), "sample_token": samples[0], "instance_token": rack,
                    "visibility_token": "4", "attribute_tokens": [], "translation": [float(xy[0]), float(xy[1]), 1.0],
                    "size": [3.0, 6.0, 1.5], "rotation": yaw_to_quat(yaw).tolist(), "prev": "", "next": "",
                    "num_lidar_pts": 20, "num_radar_pts": 0})


def write_predictions(dataroot: Path, out: Path, seed: int) -> None:
    """PRED_PER_CLASS predictions per class and sample: half near a GT box of the class."""
    rng = np.random.default_rng(seed + 1)
    db = NuScenesDB(dataroot, VERSION)
    from sianms_cli.metrics.dataset import ego_poses, eval_split, ground_truth

    split = eval_split(db, SPLIT)
    gt, _ = ground_truth(db, split)
    _, ego = ego_poses(db, split)
    samples, labels = len(split), len(DETECTION_NAMES)
    count = samples * labels * PRED_PER_CLASS
    boxes = empty_boxes(count)
    boxes["sample"] = np.repeat(np.arange(samples), labels * PRED_PER_CLASS)
    boxes["label"] = np.tile(np.repeat(np.arange(labels), PRED_PER_CLASS), samples)
    order = np.lexsort((gt["label"], gt["sample"]))  # GT_PER_CLASS per (sample, label), in that order
    gt = gt[order]
    near = np.tile(np.arange(PRED_PER_CLASS) < PRED_PER_CLASS // 2, samples * labels)
    source = (boxes["sample"] * labels + boxes["label"]) * GT_PER_CLASS + rng.integers(0, GT_PER_CLASS, count)
    noise = rng.normal(0, 1, (count, 2)) * rng.choice([0.2, 0.6, 1.5], (count, 1))
    angle, radius = rng.uniform(-np.pi, np.pi, count), rng.uniform(0, 60, count)
    anywhere = ego[boxes["sample"], :2] + np.c_[radius * np.cos(angle), radius * np.sin(angle)]
    boxes["translation"][:, :2] = np.where(near[:, None], gt["translation"][source, :2] + noise, anywhere)
    boxes["translation"][:, 2] = 1.0
    boxes["size"] = gt["size"][source] * rng.uniform(0.8, 1.2, (count, 3))
    boxes["rotation"] = yaw_to_quat(rng.uniform(-np.pi, np.pi, count))
    boxes["velocity"] = rng.normal(0, 2, (count, 2))
    boxes["score"] = np.round(rng.random(count), 3)
    boxes["attribute"] = np.where(gt["attribute"][source] >= 0, gt["attribute"][source], NO_ATTRIBUTE)
    boxes["attribute"][rng.random(count) < 0.2] = ATTRIBUTE["vehicle.parked"]
    boxes["attribute"][np.isin(boxes["label"], [8, 9])] = NO_ATTRIBUTE
    write_results(out, results_from_boxes(split.sample_tokens, boxes), overwrite=True)


def workload(folder: Path, scenes: int, seed: int) -> tuple[Path, Path]:
    """(dataroot, results file), written unless the stamp says they are there."""
    dataroot, results = folder / "dataroot", folder / "results.json"
    stamp = folder / "stamp.json"
    wanted = {"scenes": scenes, "seed": seed, "gt": GT_PER_CLASS, "pred": PRED_PER_CLASS, "format": 1}
    if stamp.is_file() and json.loads(stamp.read_text()) == wanted:
        return dataroot, results
    folder.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    write_dataroot(dataroot, scenes, seed)
    write_predictions(dataroot, results, seed)
    stamp.write_text(json.dumps(wanted))
    print(f"wrote the workload to {folder} in {time.perf_counter() - started:.0f} s", flush=True)
    return dataroot, results


# --------------------------------------------------------------------------- runs


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _rss_mib() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


class _RssSampler:
    """The largest resident set seen every few milliseconds while the block runs (Linux)."""

    def __enter__(self) -> "_RssSampler":
        self.peak, self._stop = _rss_mib(), threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(0.005):
            self.peak = max(self.peak, _rss_mib())

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, _rss_mib())


def _ours_child(dataroot: str, results_path: str, queue) -> None:
    times = {}
    started = time.perf_counter()
    db = NuScenesDB(dataroot, VERSION)
    times["tables"] = time.perf_counter() - started
    peak_loading_tables = _peak_mib()
    gc.collect()
    if sys.platform.startswith("linux"):  # hand the loader's freed JSON objects back, for a clean baseline
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    tables_mib = _rss_mib()
    with _RssSampler() as sampler:
        started = time.perf_counter()
        results = read_results(results_path)
        times["read_results"] = time.perf_counter() - started
        started = time.perf_counter()
        report = evaluate(db, SPLIT, results, "detection_cvpr_2019", ["all"])
        times["evaluate"] = time.perf_counter() - started
    times["matching_and_metrics"] = report.regions["all"].eval_time
    queue.put({"times": times, "peak_mib": _peak_mib(), "peak_loading_tables_mib": peak_loading_tables,
               "tables_mib": tables_mib, "peak_metrics_mib": sampler.peak,
               "summary": report.regions["all"].summary(), "boxes": report.serialize()["boxes"]})


def run_ours(dataroot: Path, results: Path) -> dict:
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_ours_child, args=(str(dataroot), str(results), queue))
    process.start()
    outcome = queue.get()
    process.join()
    return outcome


DEVKIT_SCRIPT = r"""
import json, os, resource, sys, tempfile, time
os.environ.setdefault("TQDM_DISABLE", "1")
from nuscenes import NuScenes
from nuscenes.eval.common.config import config_factory
from nuscenes.eval.detection.evaluate import DetectionEval
dataroot, version, split, results, out = sys.argv[1:6]
times = {}
t = time.perf_counter(); nusc = NuScenes(version=version, dataroot=dataroot, verbose=False)
times["tables"] = time.perf_counter() - t
with tempfile.TemporaryDirectory() as folder:
    t = time.perf_counter()
    evaluator = DetectionEval(nusc, config_factory("detection_cvpr_2019"), results, eval_set=split,
                              output_dir=folder, verbose=False)
    times["init"] = time.perf_counter() - t
    t = time.perf_counter(); metrics, _ = evaluator.evaluate(); times["evaluate"] = time.perf_counter() - t
summary = metrics.serialize()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
with open(out, "w") as handle:
    json.dump({"times": times, "peak_mib": peak, "summary": summary}, handle)
"""


def devkit_python(given: str | None) -> Path:
    repo = Path(__file__).resolve().parents[1]
    return Path(given or os.environ.get("SIANMS_DEVKIT_PYTHON") or repo / ".devkit-venv" / "bin" / "python")


def run_devkit(python: Path, dataroot: Path, results: Path) -> dict:
    with tempfile.TemporaryDirectory() as folder:
        script, out = Path(folder) / "run.py", Path(folder) / "out.json"
        script.write_text(DEVKIT_SCRIPT)
        done = subprocess.run([str(python), str(script), str(dataroot), VERSION, SPLIT, str(results), str(out)],
                              capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"devkit run failed:\n{done.stdout}\n{done.stderr}")
        return json.loads(out.read_text())


def compare(ours: dict, theirs: dict) -> tuple[int, float, list]:
    """(numbers compared, max |difference|, mismatches) over APs, TP errors, means, mAP, NDS."""
    count, worst, mismatches = 0, 0.0, []

    def walk(a, b, path):
        nonlocal count, worst
        if isinstance(b, dict):
            for key in b:
                walk(a[key], b[key], f"{path}/{key}")
            return
        count += 1
        if isinstance(b, float) and math.isnan(b):
            if not (isinstance(a, float) and math.isnan(a)):
                mismatches.append((path, a, b))
            return
        worst = max(worst, abs(a - b))
        if abs(a - b) > 1e-9:
            mismatches.append((path, a, b))

    for key in ("label_aps", "mean_dist_aps", "mean_ap", "label_tp_errors", "tp_errors", "tp_scores", "nd_score"):
        walk(ours[key], theirs[key], key)
    return count, worst, mismatches


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=150, help="val scenes (150: 6,019 samples)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workdir", default=os.path.join(tempfile.gettempdir(), "sianms-bench-metrics"),
                        help="where the workload is written and reused")
    parser.add_argument("--no-devkit", action="store_true", help="skip the devkit run")
    parser.add_argument("--devkit-python", default=None, help="the devkit venv's interpreter")
    args = parser.parse_args(argv)

    folder = Path(args.workdir) / f"scenes{args.scenes}-seed{args.seed}"
    dataroot, results = workload(folder, args.scenes, args.seed)
    ours = run_ours(dataroot, results)
    t = ours["times"]
    end_to_end = t["read_results"] + t["evaluate"]
    gt, pred = ours["boxes"]["gt"], ours["boxes"]["pred"]
    print(f"workload: {sum(samples_per_scene(args.scenes))} samples, {gt['loaded']} GT and {pred['loaded']} "
          f"predictions ({gt['kept']} and {pred['kept']} after the filters), results file "
          f"{results.stat().st_size / 2**20:.0f} MiB")
    print(f"ours:   tables {t['tables']:.1f} s | read_results {t['read_results']:.1f} s | "
          f"evaluate {t['evaluate']:.2f} s (matching + metrics {t['matching_and_metrics']:.2f} s)")
    print(f"ours memory: peak RSS {ours['peak_metrics_mib']:.0f} MiB during read_results + evaluate, of which "
          f"{ours['tables_mib']:.0f} MiB are the loaded tables; the table loader's own transient peak "
          f"{ours['peak_loading_tables_mib']:.0f} MiB; process peak {ours['peak_mib']:.0f} MiB")
    python = devkit_python(args.devkit_python)
    if args.no_devkit or not python.is_file():
        print("devkit: skipped"
              + ("" if args.no_devkit else f" (no interpreter at {python}; run scripts/devkit_venv.sh)"))
        return 0
    print("devkit: running (this takes a while at full size) ...", flush=True)
    theirs = run_devkit(python, dataroot, results)
    d = theirs["times"]
    print(f"devkit: tables {d['tables']:.1f} s | DetectionEval(...) {d['init']:.1f} s | "
          f"evaluate() {d['evaluate']:.1f} s | peak RSS {theirs['peak_mib']:.0f} MiB")
    print(f"ratio devkit/ours: evaluate() vs matching + metrics {d['evaluate'] / t['matching_and_metrics']:.0f}x; "
          f"results file -> metrics, tables loaded: {(d['init'] + d['evaluate']) / end_to_end:.0f}x "
          f"({d['init'] + d['evaluate']:.0f} s vs {end_to_end:.1f} s)")
    count, worst, mismatches = compare(ours["summary"], theirs["summary"])
    verdict = "identical (within 1e-9)" if not mismatches else f"{len(mismatches)} DIFFER, e.g. {mismatches[:3]}"
    print(f"numbers: {count} compared, max |difference| {worst:.3g}: {verdict}")
    print(f"mAP {ours['summary']['mean_ap']:.6f} (devkit {theirs['summary']['mean_ap']:.6f}), "
          f"NDS {ours['summary']['nd_score']:.6f} (devkit {theirs['summary']['nd_score']:.6f})")
    return 0 if not mismatches else 1


if __name__ == "__main__":
    sys.exit(main())
