"""`sianms synth`: write a synthetic dataset in the nuScenes v1.0 on-disk format (docs/synthetic_world.md).

Scenes are generated one after the other and streamed to disk: a scene is planned (street,
traffic, ego drive), then every keyframe is sensed (the LiDAR sweeps since the previous keyframe
and the keyframe's own ray-cast, the six cameras rendered with a depth buffer) and its sensor
files written; once the scene's last keyframe is done its table records are appended. Memory
is therefore bounded by one scene. Nine non-key LiDAR sweeps lie between two keyframes, on one
prev/next chain, each column fired from the ego pose of its own time and the points expressed
in the sensor frame at the sweep's timestamp; ``--sensors none`` casts only keyframe sweeps
(for ``num_lidar_pts``) and lists no sweep record.

Sensors use a true calibration that differs from the written record (:func:`rig.true_calibration`);
``num_lidar_pts`` is counted from the written records exactly as the devkit counts it
(:mod:`devkit_count`). Each scene draws from its own generator seeded by ``(seed, scene
index)``, and night, rain and radar from streams of their own (:mod:`conditions`), so the same
seed gives byte-identical files and a dry day scene does not depend on the weather code.

The dataroot is built in a hidden staging folder beside ``out`` and renamed into place only
when complete, with a marker file, :data:`MARKER_NAME`; ``overwrite`` replaces only an empty
folder or one holding the marker and nothing but what synth writes.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import re
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Generator, Iterator

import numpy as np

from sianms_cli import io
from sianms_cli.errors import OutputExistsError, SianmsError, check_seed, check_workers
from sianms_cli.geometry.quaternion import matrix_to_quat, yaw_to_quat
from sianms_cli.geometry.transforms import make_transform
from sianms_cli.nuscenes.splits import splits_for_version
from sianms_cli.nuscenes.tables import CAMERA_CHANNELS, SENSORS, TABLE_NAMES, check_version_name
from sianms_cli.nuscenes.sensors import write_jpeg, write_pcd_bin
from sianms_cli.nuscenes.writer import DatasetWriter, attribute_token, category_token, make_token
from sianms_cli.processes import worker_pool
from sianms_cli.progress import SILENT, Progress
from sianms_cli.synth.appearance import camera_style, sample_appearance
from sianms_cli.synth.camera import CameraRender, CoverageCounts, coverage_counts, motion_blur_length, render_camera
from sianms_cli.synth.clutter import clutter_parts, road_user_boxes
from sianms_cli.synth.conditions import Conditions, civil_dusk_hour, sample_conditions
from sianms_cli.synth.devkit_count import boxes_in_sensor_frame, count_points_in_boxes
from sianms_cli.synth.lidar import scan_lidar, spray_behind
from sianms_cli.synth.marker import MARKER_NAME, make_marker, read_marker
from sianms_cli.synth.nuscenes_rig import (
    CAMERA_TRIGGER_OFFSET_US,
    FULL_IMAGE_SIZE,
    LIDAR_CHANNEL,
    LIDAR_HZ,
    RIG_BOSTON,
    RIG_SINGAPORE,
    SensorCalibration,
    as_rotation,
    as_translation,
    lidar_column_seconds,
    lidar_start_azimuth,
    normalised_rig,
    true_calibration,
)
from sianms_cli.synth.objects import object_parts
from sianms_cli.synth.radar import radar_returns, returns_at_10_m
from sianms_cli.synth.shapes import Parts, concat_parts, place_parts
from sianms_cli.synth.world import (
    ANNOTATION_RADIUS,
    KEYFRAME_HZ,
    SCENE_SECONDS,
    SHAPE_KIND,
    ScenePlan,
    plan_scene,
)

DATAROOT_FOLDERS = ("samples", "sweeps", "maps")  # a dataroot's data folders
VERSION_FILES = frozenset({*(f"{name}.json" for name in TABLE_NAMES), "splits.json"})  # what synth writes there

SENSOR_MODES = ("all", "none")
RENDER_RADIUS = 130.0  # objects farther than this from the ego are not drawn or scanned
SINGLE_POINT_SIGHTING_RANGE = 30.0
"""Metres from the ego within which one LiDAR point on an object is a sighting; beyond, a sighting
takes two (our choice, set against v1.0-val before any method was run on it: inside the devkit's
class ranges lie 71.8 % of the val boxes, 75 % of the pedestrians, 80 % of the cones, 74 % of the
cars; docs/synthetic_world.md#nuscenes-figures). Counting every single point a sighting, as the annotation instructions
read (>= 1 LiDAR or radar point), followed small objects out to 80 m on one return and put only
62 % of the boxes, 54 % of the pedestrians and 55 % of the cones of seed 11's 40 scenes in range;
two points everywhere dropped the near, heavily occluded objects too (in-range boxes without a
point 8.7 % against val's 12.0 %). A single far return is what a camera cannot confirm. Radar
returns (:mod:`radar`) are counted on the boxes but do not sight an object: at the return rate set
against val, letting them start and end tracks added 16 % more boxes to seed 13's 120 scenes
(cars 13.8 -> 15.9, pedestrians 6.4 -> 7.4 per keyframe; trainval 14.5 and 6.5), nearly all
beyond the class ranges."""
SHAPE_MARGIN = 0.04  # annotated boxes enclose the object's surface with this margin (m)
VISIBILITY_SCALE = 0.125  # image scale of the coverage casts that measure visibility (either --sensors)
VISIBILITY_PAD = 1.0
"""Rows added above and below each coverage cast, in image heights. nuScenes' visibility is the
share of the whole object visible in the six images (nuscenes-devkit schema: "fraction of
annotation visible in all 6 images"); what lies above or below every camera's field of view, as
the lower part of a car alongside the ego does, is not visible. The padded canvas reaches ~47 deg
above and below the axes of the five 70-deg cameras (the back camera's: ~60), beyond which only
the tops of vehicles within a metre or two of a camera would reach."""
VISIBILITY_BINS = (0.4, 0.6, 0.8)  # upper bounds of visibility tokens "1", "2", "3"
AZIMUTH_STEPS = 1084  # HDL-32E columns per revolution at 20 Hz (see lidar.py)
SWEEPS_BETWEEN_KEYFRAMES = int(round(LIDAR_HZ / KEYFRAME_HZ)) - 1  # 9 non-key-frame LiDAR sweeps

SENSOR_TOKENS = {sensor.channel: sensor.token for sensor in SENSORS}
LOCATIONS = {  # location -> (vehicle, rig, drive side, UTC offset)
    "boston-seaport": ("n008", RIG_BOSTON, +1, "-0400"),
    "singapore-onenorth": ("n015", RIG_SINGAPORE, -1, "+0800"),
    "singapore-queenstown": ("n015", RIG_SINGAPORE, -1, "+0800"),
    "singapore-hollandvillage": ("n015", RIG_SINGAPORE, -1, "+0800"),
}
LOCATION_SHARES = (0.55, 0.215, 0.135, 0.10)  # keyframes by location, nuScenes paper §2


@dataclass(frozen=True)
class SynthConfig:
    """What `sianms synth` writes. Defaults give a v1.0-mini-like dataset.

    Checked when built, so a bad option fails before anything is written; messages name
    the CLI flag.
    """

    version: str = "v1.0-mini"
    scenes: int | None = None  # None: 10 for v1.0-mini, required otherwise
    image_scale: float = 0.5
    seed: int = 0
    sensors: str = "all"
    scene_seconds: float = SCENE_SECONDS  # shorter scenes are the first keyframes of full ones

    def __post_init__(self) -> None:
        check_version_name(self.version)
        if not 0 < self.scene_seconds <= SCENE_SECONDS or self.keyframes < 1:
            raise SianmsError(f"--scene-seconds must be in (0, {SCENE_SECONDS:g}] and hold at least one keyframe "
                              f"(one every {1 / KEYFRAME_HZ:g} s), got {self.scene_seconds}")
        if self.sensors not in SENSOR_MODES:
            raise SianmsError(f"--sensors must be one of {', '.join(SENSOR_MODES)}, got '{self.sensors}'")
        if not 0.05 <= self.image_scale <= 1.0:
            raise SianmsError(f"--image-scale must be in [0.05, 1], got {self.image_scale}")
        check_seed(self.seed)
        self.scene_names()  # --scenes: at least 1, no more than the version has, required beyond mini

    @property
    def keyframes(self) -> int:
        return int(round(self.scene_seconds * KEYFRAME_HZ))

    def scene_names(self) -> list[str]:
        """Scene names, chosen so the devkit's predefined splits resolve (see module doc)."""
        return scene_names_for(self.version, self.scenes)


@dataclass(frozen=True)
class SynthResult:
    """What :func:`run` wrote: the dataroot, its version folder and its size."""

    out: Path
    version: str
    scenes: int
    samples: int


def scene_names_for(version: str, count: int | None) -> list[str]:
    """Scene names for ``count`` scenes of ``version``.

    v1.0-mini: the ten real mini scene names (sorted; any first N include mini_train and,
    from N = 2, mini_val scenes). v1.0-trainval / v1.0-test: names from the devkit's
    train and val lists (test list for v1.0-test), val getting 150/850 of them and at
    least one from two scenes on. Any other version: ``scene-0001`` onwards, split by
    the ``splits.json`` written beside the tables.
    """
    if count is not None and count < 1:
        raise SianmsError(f"--scenes must be at least 1, got {count}")
    official = splits_for_version(version)
    if version.endswith("mini"):
        names = sorted(official["mini_train"] + official["mini_val"])
        if count is not None and count > len(names):
            raise SianmsError(f"{version} has {len(names)} scenes; --scenes {count} asks for more")
        return names[: count or len(names)]
    if count is None:
        raise SianmsError(f"--scenes is required for version {version}")
    if version.endswith(("test", "trainval")):
        parts = ("test",) if version.endswith("test") else ("train", "val")
        total = sum(len(official[part]) for part in parts)
        if count > total:
            shares = ", ".join(f"{len(official[part])} {part}" for part in parts)
            raise SianmsError(f"{version} has {total} scenes ({shares}); --scenes {count} asks for more")
    if version.endswith("test"):
        return official["test"][:count]
    if version.endswith("trainval"):
        val_count = min(len(official["val"]), max(round(count * 150 / 850), 1 if count >= 2 else 0))
        return sorted(official["train"][:count - val_count] + official["val"][:val_count])
    if count > MAX_CUSTOM_SCENES:
        raise SianmsError(f"--scenes must be at most {MAX_CUSTOM_SCENES:,} for version {version}, got {count}")
    return [f"scene-{i:04d}" for i in range(1, count + 1)]


MAX_CUSTOM_SCENES = 10_000  # ten times nuScenes' 1,000: more is a typo that would run for weeks or exhaust memory


def custom_splits(names: list[str]) -> dict[str, list[str]]:
    """``splits.json`` content for a version the devkit has no predefined splits for."""
    val_count = max(1, round(len(names) * 0.2)) if len(names) >= 2 else 0
    return {"synth_train": names[: len(names) - val_count], "synth_val": names[len(names) - val_count:]}


def run(
    config: SynthConfig,
    out: str | Path,
    *,
    overwrite: bool = False,
    progress: Progress = SILENT,
    workers: int = 1,
) -> SynthResult:
    """Write the dataset to ``out`` (the dataroot).

    Everything is written to a staging folder beside ``out`` and published when complete;
    a failure or an interrupt stops the workers, then removes the staging folder, so no
    half-written dataroot is ever left. ``workers`` processes sense scenes in parallel;
    records are still written in scene order, so the output does not depend on ``workers``.
    """
    check_workers(workers)
    out = io.real_path(out)  # through a symbolic link: replace the folder it names, not the link
    check_output(out, overwrite=overwrite)
    seen = io.snapshot(out)  # publishing refuses an OUT that changed meanwhile, deleting nothing
    names = config.scene_names()

    def write(staging: Path) -> None:
        _write_dataset(staging, config, names, progress, workers)
        check_output(out, overwrite=overwrite)  # again, for a clear reason: OUT may have changed during a long run

    io.build_folder(out, write, seen)
    return SynthResult(out, config.version, len(names), len(names) * config.keyframes)


def check_output(out: Path, *, overwrite: bool) -> None:
    """Refuse an ``out`` that publishing must not replace (see the module doc)."""
    if io.is_inside_working_folder(out):
        raise SianmsError(f"{out}: is the working folder or one of its parents; synth replaces its output "
                          "folder as a whole, so give --out a folder below it")
    if not out.exists():
        return
    if not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a folder")
    entries = sorted(out.iterdir())
    if not entries:
        return
    if not overwrite:
        raise OutputExistsError(f"{out}: exists and is not empty; pass --overwrite to replace an earlier "
                                "sianms synth output")
    if _marked_version(out) is None:
        raise OutputExistsError(f"{out}: not replaced: it has no valid {MARKER_NAME}, so it is not an earlier "
                                f"sianms synth output (it holds '{entries[0].name}'); remove it yourself or "
                                "choose another --out")
    foreign = foreign_dataset_entry(out)
    if foreign is not None:
        raise OutputExistsError(f"{out}: not replaced: '{foreign.relative_to(out)}' is not something sianms "
                                "synth writes; remove it yourself or choose another --out")


def foreign_dataset_entry(out: Path) -> Path | None:
    """The first path in a dataroot that `sianms synth` does not write, or None: what deleting the
    folder would take of someone else's (a dataroot without synth's marker is all someone else's)."""
    version = _marked_version(out)
    if version is None:
        return out
    return next((foreign for entry in sorted(out.iterdir()) if (foreign := _foreign_within(entry, version))), None)


def _marked_version(dataroot: Path) -> str | None:
    """The version folder an earlier run's marker names; None when there is no valid marker."""
    marker = read_marker(dataroot)
    config = marker.get("config") if marker is not None else None
    version = config.get("version") if isinstance(config, dict) else None
    return version if isinstance(version, str) else None


def _foreign_within(entry: Path, version: str) -> Path | None:
    """The first path at or under a top-level entry of a marked dataroot that synth does not
    write (links never are), or None: publishing deletes the whole tree, and a user may have put
    things into synth's folders (the map expansion goes into ``maps/``)."""
    if entry.is_symlink():
        return entry
    if entry.name == MARKER_NAME:
        return None if entry.is_file() else entry
    if entry.name not in (version, *DATAROOT_FOLDERS) or not entry.is_dir():
        return entry
    if entry.name == version:
        return io.first_foreign_file(entry, lambda file: file.name in VERSION_FILES)
    if entry.name == "maps":
        return io.first_foreign_file(entry, lambda file: _MAP_FILE.fullmatch(file.name) is not None)
    for channel in sorted(entry.iterdir()):
        extension = "jpg" if channel.name in CAMERA_CHANNELS else "pcd.bin" if channel.name == "LIDAR_TOP" else None
        if extension is None or channel.is_symlink() or not channel.is_dir():
            return channel
        pattern = re.compile(rf"{_LOGFILE}__{channel.name}__[0-9]+\.{re.escape(extension)}")
        foreign = io.first_foreign_file(channel, lambda file: pattern.fullmatch(file.name) is not None)
        if foreign is not None:
            return foreign
    return None


# The names synth gives its files (_SensorWriter, NuScenesWriter.add_map): a user's photo.jpg
# in samples/CAM_FRONT is not one of them, and --overwrite refuses rather than deletes it.
_LOGFILE = r"n[0-9]{3}-[0-9]{4}(?:-[0-9]{2}){5}[+-][0-9]{4}"
_MAP_FILE = re.compile(r"[0-9a-f]{32}\.png")


def _write_dataset(staging: Path, config: SynthConfig, names: list[str], progress: Progress, workers: int) -> None:
    """Every table, map and sensor file of the dataset, then the marker, under ``staging``."""
    with DatasetWriter(staging, config.version) as writer:
        writer.add_static_tables()
        if not splits_for_version(config.version):
            writer.write_splits(custom_splits(names))
        _write_maps(writer, config)
        progress.start(len(names) * config.keyframes, "sample", "synth")
        jobs = [(staging, config, index, name) for index, name in enumerate(names)]
        with closing(_sensed_scenes(jobs, workers, progress)) as scenes:
            for records in scenes:
                for table, record in records:
                    writer.add(table, record)
    resolved = dataclasses.replace(config, scenes=len(names))
    io.write_json(staging / MARKER_NAME, make_marker(dataclasses.asdict(resolved)))


_SceneJob = tuple[Path, SynthConfig, int, str]
"""One scene to sense: the staging folder, the config, the scene's index and name (:func:`_scene_records`)."""


def _sensed_scenes(jobs: list[_SceneJob], workers: int, progress: Progress
                   ) -> Generator[list[tuple[str, dict]], None, None]:
    """Records of every scene, in scene order, sensed here or in ``workers`` processes.

    Progress advances per keyframe here, per scene from workers. Closing the iterator early
    (the caller failed or was interrupted) terminates the workers before the caller cleans up.
    """
    if workers == 1 or len(jobs) == 1:
        for job in jobs:
            yield _scene_records(*job, on_keyframe=progress.advance)
        return
    with worker_pool(min(workers, len(jobs))) as pool:
        for job, records in zip(jobs, pool.imap(_sense_scene, jobs)):
            progress.advance(job[1].keyframes)
            yield records


def _sense_scene(job: _SceneJob) -> list[tuple[str, dict]]:
    """:func:`_scene_records` of one job, in a worker process."""
    return _scene_records(*job)


def _write_maps(writer: DatasetWriter, config: SynthConfig) -> None:
    """One map record per location, listing the logs (one per scene) recorded there."""
    by_location: dict[str, list[str]] = {location: [] for location in LOCATIONS}
    for index, name in enumerate(config.scene_names()):
        by_location[_scene_location(config.seed, index)].append(_log_token(config.seed, name))
    for location, logs in by_location.items():
        writer.add_map(make_token("map", location), logs)


def _scene_rng(seed: int, index: int, stream: str) -> np.random.Generator:
    """Independent generators per scene and purpose, stable when other code draws more."""
    return np.random.default_rng([seed, index, sum(map(ord, stream))])


def _scene_location(seed: int, index: int) -> str:
    rng = _scene_rng(seed, index, "location")
    return str(rng.choice(list(LOCATIONS), p=LOCATION_SHARES))


def _scene_conditions(seed: int, index: int) -> Conditions:
    """Night and rain of one scene, from their own stream (no other stream changes)."""
    return sample_conditions(_scene_rng(seed, index, "conditions"))


def _log_token(seed: int, name: str) -> str:
    return make_token("log", seed, name)


@dataclass
class _Frame:
    """What a keyframe contributes to the annotation table, before the scene is complete."""

    annotated: np.ndarray  # (N,) bool: agent within the annotation radius
    ego_xy: np.ndarray  # (N,2) box centres in the ego frame (x forward, y left), metres
    center: np.ndarray  # (N,3)
    yaw: np.ndarray  # (N,)
    rotation: np.ndarray  # (N,4) yaw quaternions, the annotation records' values
    attributes: np.ndarray  # (N,) names
    lidar_points: np.ndarray  # (N,) int64 points inside each box
    visibility: np.ndarray  # (N,) visible share of the whole object across all cameras, NaN when unseen
    unoccluded: np.ndarray  # (N,) share of its pixels in the images not hidden by anything nearer, NaN when unseen


def _scene_records(staging: Path, config: SynthConfig, index: int, name: str,
                   on_keyframe: Callable[[], object] | None = None) -> list[tuple[str, dict]]:
    """Sense every keyframe of one scene, writing its sensor files; return its table records."""
    return list(_scene_record_stream(staging, config, index, name, on_keyframe))


def _scene_record_stream(staging: Path, config: SynthConfig, index: int, name: str,
                         on_keyframe: Callable[[], object] | None) -> Iterator[tuple[str, dict]]:
    seed = config.seed
    location = _scene_location(seed, index)
    vehicle, published_rig, drive_side, utc = LOCATIONS[location]
    rig = _perturbed_rig(normalised_rig(published_rig), _scene_rng(seed, index, "calibration"))
    plan = plan_scene(_scene_rng(seed, index, "plan"), drive_side)
    conditions = _scene_conditions(seed, index)
    start = _scene_start(seed, index, location, conditions.night)
    logfile = f"{vehicle}-{start.strftime('%Y-%m-%d-%H-%M-%S')}{utc}"
    start_us = int(start.timestamp() * 1e6)
    log_token = _log_token(seed, name)
    yield "log", {"token": log_token, "logfile": logfile, "vehicle": vehicle,
                  "date_captured": start.strftime("%Y-%m-%d"), "location": location}

    calibration_tokens = {c.channel: make_token("calibrated_sensor", seed, name, c.channel) for c in rig}
    scale = config.image_scale
    image_size = (round(FULL_IMAGE_SIZE[0] * scale), round(FULL_IMAGE_SIZE[1] * scale))
    for calibration in rig:
        camera = calibration.channel != LIDAR_CHANNEL
        yield "calibrated_sensor", {
            "token": calibration_tokens[calibration.channel],
            "sensor_token": SENSOR_TOKENS[calibration.channel],
            "translation": list(calibration.translation),
            "rotation": list(calibration.rotation),
            "camera_intrinsic": calibration.intrinsic(scale).tolist() if camera else [],
        }

    scene = _SceneSensing(plan, rig, config, index, staging, logfile, start_us)
    n_keyframes = config.keyframes
    frames = []
    sample_tokens = [make_token("sample", seed, name, k) for k in range(n_keyframes)]
    scene_token = make_token("scene", seed, name)
    sample_data_records: dict[str, list[dict]] = {channel: [] for channel in CAMERA_CHANNELS + (LIDAR_CHANNEL,)}
    for k in range(n_keyframes):
        if k > 0 and config.sensors == "all":
            for j in range(1, SWEEPS_BETWEEN_KEYFRAMES + 1):
                sample_data, ego_pose = scene.sense_sweep(k, j, sample_tokens[k], calibration_tokens)
                sample_data_records[LIDAR_CHANNEL].append(sample_data)
                yield "ego_pose", ego_pose
        frame, records = scene.sense_keyframe(k, sample_tokens[k], calibration_tokens, image_size)
        frames.append(frame)
        for channel, (sample_data, ego_pose) in records.items():
            sample_data_records[channel].append(sample_data)
            yield "ego_pose", ego_pose
        if on_keyframe is not None:
            on_keyframe()

    for k, token in enumerate(sample_tokens):
        yield "sample", {
            "token": token,
            "timestamp": start_us + _keyframe_offset_us(k),
            "scene_token": scene_token,
            "prev": sample_tokens[k - 1] if k > 0 else "",
            "next": sample_tokens[k + 1] if k + 1 < n_keyframes else "",
        }
    for channel_records in sample_data_records.values():
        for k, record in enumerate(channel_records):
            record["prev"] = channel_records[k - 1]["token"] if k > 0 else ""
            record["next"] = channel_records[k + 1]["token"] if k + 1 < len(channel_records) else ""
            yield "sample_data", record
    yield from _annotation_records(plan, frames, sample_tokens, seed, name, _scene_rng(seed, index, "radar"))
    yield "scene", {
        "token": scene_token,
        "name": name,
        "description": _describe(plan, location, conditions),
        "log_token": log_token,
        "nbr_samples": n_keyframes,
        "first_sample_token": sample_tokens[0],
        "last_sample_token": sample_tokens[-1],
    }


def _keyframe_offset_us(k: int) -> int:
    return int(round(k * 1e6 / KEYFRAME_HZ))


def _sweep_offset_us(k: int, j: int) -> int:
    """Time of sweep ``j`` (1..9) after keyframe ``k - 1``, from the scene start (µs)."""
    return _keyframe_offset_us(k - 1) + int(round(j * 1e6 / LIDAR_HZ))


def _scene_start(seed: int, index: int, location: str, night: bool = False) -> dt.datetime:
    """A plausible local capture time in 2018 (May to October): daytime (07:00-18:00), or for a
    night scene between the end of civil twilight at ``location`` and midnight.

    A night scene keeps the day drawn for it and takes its hour from a stream of its own, so
    day scenes start exactly when they did before scenes had conditions."""
    rng = _scene_rng(seed, index, "time")
    day = dt.datetime(2018, 5, 1) + dt.timedelta(days=int(rng.integers(0, 180)))
    seconds = int(rng.integers(7 * 3600, 18 * 3600))
    if night:
        utc_offset_hours = int(LOCATIONS[location][3][:3])  # "-0400" -> -4: Boston is on EDT until November
        dusk = civil_dusk_hour(day.timetuple().tm_yday, location.split("-")[0], utc_offset_hours)
        seconds = int(_scene_rng(seed, index, "night-time").integers(int(np.ceil(dusk * 3600)), 24 * 3600))
    return day + dt.timedelta(seconds=seconds)


def _perturbed_rig(rig: tuple[SensorCalibration, ...], rng: np.random.Generator) -> tuple[SensorCalibration, ...]:
    """Per-log calibration: real rigs differ by a few millimetres and tenths of a degree."""
    perturbed = []
    for calibration in rig:
        translation = np.asarray(calibration.translation) + rng.normal(0.0, 0.005, 3)
        rotation = np.asarray(calibration.rotation) + rng.normal(0.0, 0.0015, 4)
        rotation /= np.linalg.norm(rotation)
        perturbed.append(dataclasses.replace(
            calibration,
            translation=as_translation(translation),
            rotation=as_rotation(rotation),
        ))
    return tuple(perturbed)


def _describe(plan: ScenePlan, location: str, conditions: Conditions = Conditions()) -> str:
    """Free text as nuScenes scene descriptions are: the place and what the ego does, led by the
    conditions as nuScenes writes them ("Night, rain, ..."; nothing on a dry day)."""
    street = plan.street
    lanes = ("one lane", "two lanes", "three lanes")[street.section.lanes_per_direction - 1]
    parts = conditions.words() + [f"{lanes} each way" + (", median" if street.section.median > 0 else "")]
    turns = [i for i in street.intersections if not i.through]
    if turns:
        side = "left" if float(plan.route.curvature_at(np.array([turns[0].s]))[0]) > 0 else "right"
        parts.append(f"ego turns {side} at a {'4-way' if len(turns) > 1 else 'T'} junction")
    if any(i.through for i in street.intersections):
        parts.append("intersection")
        if any(path is not None for path in plan.agents.path):
            parts.append("turning traffic")
    if plan.ego.shift[0] != 0.0:
        parts.append("ego changes lane")
    if np.any(plan.agents.shift[:, 0] != 0.0):
        parts.append("lane changes and parking manoeuvres")
    if street.car_parks:
        parts.append("car park")
    if plan.roadworks:
        parts.append("roadworks with barriers and cones")
    if plan.ego.speed == 0.0:
        parts.append("ego waiting")
    parts.append("busy" if plan.busyness > 0.7 else "light traffic")
    text = f"{', '.join(parts)}, {location.split('-')[0].capitalize()}"
    return text[0].upper() + text[1:]


class _SceneSensing:
    """The sensors of one scene: poses, parts of every object, renders and scans."""

    def __init__(self, plan: ScenePlan, rig, config: SynthConfig, index: int, staging: Path,
                 logfile: str, start_us: int) -> None:
        self.plan = plan
        self.config = config
        self.staging = staging
        self.logfile = logfile
        self.start_us = start_us
        self.calibration = {c.channel: c for c in rig}  # as written
        self.conditions = _scene_conditions(config.seed, index)
        residual_rng = _scene_rng(config.seed, index, "calibration-residual")
        self.true_calibration = {c.channel: true_calibration(c, residual_rng) for c in rig}  # as sensed
        lidar = self.true_calibration[LIDAR_CHANNEL]
        self.lidar_to_ego = make_transform(lidar.rotation, lidar.translation)
        self.start_azimuth = lidar_start_azimuth(lidar, self.true_calibration["CAM_FRONT"], AZIMUTH_STEPS)
        rng = _scene_rng(config.seed, index, "appearance")
        agents = plan.agents
        self.appearances = [
            sample_appearance(SHAPE_KIND[category], rng, rider=bool(rider), size_wlh=_shape_size(size),
                              workwear=category == "human.pedestrian.construction_worker")
            for category, rider, size in zip(agents.category, agents.rider, agents.size)
        ]
        self.local_parts = concat_parts([
            _owned(object_parts(SHAPE_KIND[category], _shape_size(size), appearance), owner)
            for owner, (category, size, appearance) in enumerate(zip(agents.category, agents.size, self.appearances))
        ])
        buildings = concat_parts([
            _owned(object_parts("building", b.size, sample_appearance("building", rng)), -1,
                   (b.center[0], b.center[1], b.size[2] / 2), b.yaw)
            for b in plan.buildings])
        clutter = clutter_parts(plan.street, _scene_rng(config.seed, index, "clutter"), plan.buildings,
                                road_user_boxes(plan.agents, plan.route))
        self.scenery = concat_parts([buildings, clutter])
        # Street clutter casts shadows as the road users do (trees and poles darken the road
        # and the cars beside them); buildings do not (see camera._shadow_casters).
        self.scenery_casts_shadow = np.concatenate([np.zeros(len(buildings.owner), bool),
                                                    np.ones(len(clutter.owner), bool)])
        style_rng = _scene_rng(config.seed, index, "camera-style")
        self.styles = {channel: camera_style(style_rng) for channel in CAMERA_CHANNELS}
        self.sun = _sun_direction(_scene_rng(config.seed, index, "sun"))
        # Separate streams, so the LiDAR (and num_lidar_pts) is the same with --sensors none.
        self.lidar_rng = _scene_rng(config.seed, index, "lidar-noise")
        self.sweep_rng = _scene_rng(config.seed, index, "lidar-sweeps")
        # Rain's LiDAR effects draw from streams of their own, so dry scenes scan as before.
        rain = self.conditions.rain
        self.lidar_rain_rng = _scene_rng(config.seed, index, "lidar-rain") if rain else None
        self.sweep_rain_rng = _scene_rng(config.seed, index, "lidar-rain-sweeps") if rain else None
        self.is_vehicle = np.char.startswith(plan.agents.category.astype(str), "vehicle.")  # (N,) throw spray
        self.camera_rng = _scene_rng(config.seed, index, "camera-noise")

    def sense_keyframe(self, k: int, sample_token: str, calibration_tokens: dict, image_size) -> tuple[_Frame, dict]:
        """LiDAR scan and camera renders of keyframe ``k``; writes the sensor files."""
        plan = self.plan
        t = k / KEYFRAME_HZ
        timestamp = self.start_us + _keyframe_offset_us(k)
        center, yaw, speed = plan.agents.pose(plan.route, t)
        ego_to_global = self._ego_to_global(t)
        distance = np.hypot(*(center[:, :2] - ego_to_global[:2, 3]).T)
        near = distance < RENDER_RADIUS

        records = {}
        scan = self._scan(t, center, yaw, near, self.lidar_rng, self.lidar_rain_rng)
        records[LIDAR_CHANNEL] = self._sample_data(LIDAR_CHANNEL, sample_token, timestamp, ego_to_global,
                                                   calibration_tokens, (0, 0), scan.points)
        rotation = yaw_to_quat(yaw)
        lidar_points = np.zeros(len(center), dtype=np.int64)
        lidar_points[near] = self._num_lidar_pts(scan.points, records[LIDAR_CHANNEL][1], center[near],
                                                 plan.agents.size[near], rotation[near])

        visible, in_image, whole = np.zeros(len(center)), np.zeros(len(center)), np.zeros(len(center))
        for channel in CAMERA_CHANNELS:
            camera_time_us = timestamp + CAMERA_TRIGGER_OFFSET_US[channel]
            t_camera = (camera_time_us - self.start_us) / 1e6
            center_c, yaw_c, _ = plan.agents.pose(plan.route, t_camera)
            ego_c = self._ego_to_global(t_camera)
            parts = self._parts_at(center_c, yaw_c, near)
            counts = self._coverage(channel, parts, ego_c)
            visible += counts.visible
            in_image += counts.in_image
            whole += counts.whole
            image = self._render(channel, parts, ego_c).image if self.config.sensors == "all" else None
            records[channel] = self._sample_data(channel, sample_token, camera_time_us, ego_c,
                                                 calibration_tokens, image_size, image)
        with np.errstate(invalid="ignore", divide="ignore"):
            visibility = np.where(whole > 0, visible / whole, np.nan)
            unoccluded = np.where(in_image > 0, visible / in_image, np.nan)
        ego_xy = (center[:, :2] - ego_to_global[:2, 3]) @ ego_to_global[:2, :2]
        frame = _Frame(distance < ANNOTATION_RADIUS, ego_xy, center, yaw, rotation,
                       plan.agents.attributes(speed), lidar_points, visibility, unoccluded)
        return frame, records

    def sense_sweep(self, k: int, j: int, sample_token: str, calibration_tokens: dict) -> tuple[dict, dict]:
        """LiDAR sweep ``j`` (1..9) after keyframe ``k - 1``: writes its file under sweeps/;
        returns its sample_data and ego_pose records."""
        offset_us = _sweep_offset_us(k, j)
        t = offset_us / 1e6
        center, yaw, _ = self.plan.agents.pose(self.plan.route, t)
        ego_to_global = self._ego_to_global(t)
        near = np.hypot(*(center[:, :2] - ego_to_global[:2, 3]).T) < RENDER_RADIUS
        scan = self._scan(t, center, yaw, near, self.sweep_rng, self.sweep_rain_rng)
        return self._sample_data(LIDAR_CHANNEL, sample_token, self.start_us + offset_us, ego_to_global,
                                 calibration_tokens, (0, 0), scan.points, sweep=j)

    def _scan(self, t: float, center: np.ndarray, yaw: np.ndarray, near: np.ndarray, rng: np.random.Generator,
              rain_rng: np.random.Generator | None):
        """One LiDAR sweep whose last column fires at ``t``: each column from the ego pose of
        its own time, moving objects where they are then (their velocity over the sweep);
        in rain when ``rain_rng`` is given (see :func:`lidar.scan_lidar`), with spray behind the
        near vehicles."""
        seconds = lidar_column_seconds(AZIMUTH_STEPS)
        earlier, _, _ = self.plan.agents.pose(self.plan.route, t + seconds[0])
        velocity = (center - earlier) / -seconds[0]
        parts = self._parts_at(center, yaw, near)
        part_velocity = np.where((parts.owner >= 0)[:, None], velocity[np.maximum(parts.owner, 0)], 0.0)
        column_poses = self._ego_poses(t, seconds) @ self.lidar_to_ego
        spray = None
        if rain_rng is not None:
            vehicles = near & self.is_vehicle
            spray = spray_behind(center[vehicles], yaw[vehicles], self.plan.agents.size[vehicles],
                                 np.hypot(*velocity[vehicles, :2].T))
        return scan_lidar(parts, self._ego_to_global(t) @ self.lidar_to_ego, rng,
                          ground_reflectivity=self.plan.street.ground_reflectivity, azimuth_steps=AZIMUTH_STEPS,
                          start_azimuth=self.start_azimuth, column_poses=column_poses, column_seconds=seconds,
                          part_velocity=part_velocity, rain_rng=rain_rng, spray=spray)

    def _ego_poses(self, t: float, seconds: np.ndarray) -> np.ndarray:
        """(C,4,4) ego to global at times ``t + seconds`` (seconds in [-0.05, 0]): position and
        yaw interpolated linearly between the poses at the first and the last column."""
        xy0, yaw0 = self.plan.ego.pose(self.plan.route, t + seconds[0])
        xy1, yaw1 = self.plan.ego.pose(self.plan.route, t)
        fraction = (seconds - seconds[0]) / (seconds[-1] - seconds[0])
        yaw = yaw0 + fraction * np.angle(np.exp(1j * (yaw1 - yaw0)))
        xy = xy0 + fraction[:, None] * (np.asarray(xy1) - xy0)
        cos, sin = np.cos(yaw), np.sin(yaw)
        poses = np.zeros((len(seconds), 4, 4))
        poses[:, 0, 0], poses[:, 0, 1], poses[:, 1, 0], poses[:, 1, 1] = cos, -sin, sin, cos
        poses[:, 2, 2] = poses[:, 3, 3] = 1.0
        poses[:, :2, 3] = xy
        return poses

    def _num_lidar_pts(self, points: np.ndarray, ego_pose: dict, center: np.ndarray, size: np.ndarray,
                       rotation: np.ndarray) -> np.ndarray:
        """Points of the key-frame sweep in each box, counted from the records as the devkit does."""
        lidar = self.calibration[LIDAR_CHANNEL]
        corners = boxes_in_sensor_frame(center, size, rotation, ego_pose["translation"], ego_pose["rotation"],
                                        lidar.translation, lidar.rotation)
        return count_points_in_boxes(points[:, :3], corners)

    def _ego_to_global(self, t: float) -> np.ndarray:
        xy, yaw = self.plan.ego.pose(self.plan.route, t)
        return make_transform(yaw_to_quat(np.array(yaw)), np.array([xy[0], xy[1], 0.0]))

    def _parts_at(self, center: np.ndarray, yaw: np.ndarray, near: np.ndarray) -> Parts:
        """Every near object's parts posed in the global frame, plus the buildings."""
        local = self.local_parts
        keep = near[local.owner]
        owner = local.owner[keep]
        cos, sin = np.cos(yaw[owner]), np.sin(yaw[owner])
        lc = local.center[keep]
        world = np.column_stack([cos * lc[:, 0] - sin * lc[:, 1], sin * lc[:, 0] + cos * lc[:, 1], lc[:, 2]])
        posed = dataclasses.replace(
            local,
            center=world + center[owner],
            half_size=local.half_size[keep],
            yaw=local.yaw[keep] + yaw[owner],
            owner=owner,
            material=local.material[keep],
            albedo=None if local.albedo is None else local.albedo[keep],
        )
        return concat_parts([posed, self.scenery])

    def _cam_to_global(self, channel: str, ego_to_global: np.ndarray) -> np.ndarray:
        calibration = self.true_calibration[channel]
        return ego_to_global @ make_transform(calibration.rotation, calibration.translation)

    def _coverage(self, channel: str, parts: Parts, ego_to_global: np.ndarray) -> CoverageCounts:
        """The objects' pixels in one camera, at VISIBILITY_SCALE with VISIBILITY_PAD."""
        width, height = round(FULL_IMAGE_SIZE[0] * VISIBILITY_SCALE), round(FULL_IMAGE_SIZE[1] * VISIBILITY_SCALE)
        return coverage_counts(parts, self.true_calibration[channel].intrinsic(VISIBILITY_SCALE),
                               self._cam_to_global(channel, ego_to_global), width, height, len(self.appearances),
                               pad_rows=round(VISIBILITY_PAD * height))

    def _render(self, channel: str, parts: Parts, ego_to_global: np.ndarray) -> CameraRender:
        cam_to_global = self._cam_to_global(channel, ego_to_global)
        scale = self.config.image_scale
        width, height = round(FULL_IMAGE_SIZE[0] * scale), round(FULL_IMAGE_SIZE[1] * scale)
        casts_shadow = np.concatenate([np.ones(len(parts.owner) - len(self.scenery_casts_shadow), bool),
                                       self.scenery_casts_shadow])
        intrinsic = self.true_calibration[channel].intrinsic(scale)
        # The ego's planned speed along its heading (its acceleration is small over a scene).
        ego_velocity = ego_to_global[:3, 0] * self.plan.ego.speed
        return render_camera(parts, self.appearances, self.plan.street.ground_albedo,
                             intrinsic, cam_to_global, width, height,
                             self.styles[channel], self.sun, len(self.appearances), self.camera_rng,
                             casts_shadow=casts_shadow, conditions=self.conditions, sky_seed=self.start_us,
                             motion_blur_px=motion_blur_length(intrinsic, cam_to_global, ego_velocity,
                                                               self.conditions.night))

    def _sample_data(self, channel, sample_token, timestamp, ego_to_global, calibration_tokens, image_size, data,
                     sweep: int = 0):
        """sample_data and ego_pose records of one sensor reading; writes its file.

        sweep: 0 for a key frame (under samples/), j > 0 for sweep j after the previous key frame
        (under sweeps/; sample_token is then the following key frame's sample, as in nuScenes)."""
        token = make_token("sample_data", sample_token, channel, *(("sweep", sweep) if sweep else ()))
        lidar = channel == LIDAR_CHANNEL
        extension = "pcd.bin" if lidar else "jpg"
        folder = "sweeps" if sweep else "samples"
        filename = f"{folder}/{channel}/{self.logfile}__{channel}__{timestamp}.{extension}"
        if data is not None and self.config.sensors == "all":
            (write_pcd_bin if lidar else write_jpeg)(self.staging / filename, data)
        ego_pose = {
            "token": token,
            "timestamp": timestamp,
            "rotation": [float(v) for v in matrix_to_quat(ego_to_global[:3, :3])],
            "translation": [float(v) for v in ego_to_global[:3, 3]],
        }
        sample_data = {
            "token": token,
            "sample_token": sample_token,
            "ego_pose_token": token,
            "calibrated_sensor_token": calibration_tokens[channel],
            "timestamp": timestamp,
            "fileformat": "pcd" if lidar else "jpg",
            "is_key_frame": not sweep,
            "height": 0 if lidar else image_size[1],
            "width": 0 if lidar else image_size[0],
            "filename": filename,
            "prev": "",
            "next": "",
        }
        return sample_data, ego_pose


def _owned(parts: Parts, owner: int, center=None, yaw: float = 0.0) -> Parts:
    """Parts of one object tagged with its owner; scenery is posed once here, ``center`` being
    its box centre (x, y, half its height: it stands on the ground)."""
    if center is None:
        return dataclasses.replace(parts, owner=np.full(len(parts.owner), owner, dtype=np.int32))
    return place_parts(parts, np.asarray(center, dtype=np.float64), yaw, owner)


def _shape_size(size_wlh: np.ndarray) -> np.ndarray:
    """The object's own extent inside its annotated box (annotators enclose the surface)."""
    return np.asarray(size_wlh) - np.array([2 * SHAPE_MARGIN, 2 * SHAPE_MARGIN, SHAPE_MARGIN])


def _sun_direction(rng: np.random.Generator) -> np.ndarray:
    """Unit vector towards the sun: elevation 25-70 degrees, any azimuth."""
    elevation = rng.uniform(np.radians(25), np.radians(70))
    azimuth = rng.uniform(-np.pi, np.pi)
    return np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])


def _visibility_token(fraction: np.ndarray) -> np.ndarray:
    """nuScenes visibility token "1".."4" (0-40, 40-60, 60-80, 80-100 % visible); unseen -> "1"."""
    return np.array([str(i) for i in np.digitize(np.nan_to_num(fraction, nan=0.0), VISIBILITY_BINS) + 1])


def _annotation_records(plan: ScenePlan, frames: list[_Frame], sample_tokens: list[str], seed: int, name: str,
                        radar_rng: np.random.Generator):
    """sample_annotation and instance records of a scene.

    An object is annotated from the first keyframe in which the LiDAR saw it within the
    annotation radius to the last one, in every keyframe between where it lies within the
    radius: annotators keep an object through a temporary occlusion (interpolated tracks,
    hence some boxes with no point, as in nuScenes; nuscenes-devkit#313, #808, #831) but
    neither start a track before anything saw the object nor carry it on after the last
    sighting (the annotation rule is >= 1 LiDAR or radar point, nuScenes' annotator instructions;
    beyond ``SINGLE_POINT_SIGHTING_RANGE`` a sighting takes two points; radar returns, drawn
    here by :mod:`radar` from ``radar_rng``, are counted but sight nothing: see
    ``SINGLE_POINT_SIGHTING_RANGE``). Annotating the whole time an object was within 80 m
    instead gave 30 % boxes without a point, nuScenes 12-19 % (docs/synthetic_world.md#nuscenes-figures).
    """
    annotated = np.stack([f.annotated for f in frames])  # (K, N)
    points = np.stack([f.lidar_points for f in frames])
    ego_xy = np.stack([f.ego_xy for f in frames])
    near = np.hypot(ego_xy[..., 0], ego_xy[..., 1]) < SINGLE_POINT_SIGHTING_RANGE
    strength = returns_at_10_m([SHAPE_KIND[c] for c in plan.agents.category])
    radar = radar_returns(radar_rng, strength, ego_xy, np.stack([f.unoccluded for f in frames]))
    seen = annotated & (points >= np.where(near, 1, 2))
    k = np.arange(len(frames))[:, None]
    first = np.where(seen, k, len(frames)).min(axis=0)
    last = np.where(seen, k, -1).max(axis=0)
    keep = annotated & (k >= first) & (k <= last)
    agents = plan.agents
    for owner in np.flatnonzero(keep.any(axis=0)):
        keyframes = np.flatnonzero(keep[:, owner])
        instance = make_token("instance", seed, name, int(owner))
        tokens = [make_token("sample_annotation", instance, int(k)) for k in keyframes]
        for j, keyframe in enumerate(keyframes):
            frame = frames[keyframe]
            attribute = frame.attributes[owner]
            yield "sample_annotation", {
                "token": tokens[j],
                "sample_token": sample_tokens[keyframe],
                "instance_token": instance,
                "visibility_token": str(_visibility_token(frame.visibility[owner:owner + 1])[0]),
                "attribute_tokens": [attribute_token(attribute)] if attribute else [],
                "translation": [float(v) for v in frame.center[owner]],
                "size": [float(v) for v in agents.size[owner]],
                "rotation": [float(v) for v in frame.rotation[owner]],
                "prev": tokens[j - 1] if j > 0 else "",
                "next": tokens[j + 1] if j + 1 < len(tokens) else "",
                "num_lidar_pts": int(frame.lidar_points[owner]),
                "num_radar_pts": int(radar[keyframe, owner]),
            }
        yield "instance", {
            "token": instance,
            "category_token": category_token(agents.category[owner]),
            "nbr_annotations": len(tokens),
            "first_annotation_token": tokens[0],
            "last_annotation_token": tokens[-1],
        }
