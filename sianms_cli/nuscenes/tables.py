"""The nuScenes v1.0 schema as data: the 13 tables, the kind of every field, the fixed vocabularies.

Facts from the nuScenes schema (the schema document of nutonomy/nuscenes-devkit 1.2.0 and the
devkit's loader). Only fields real nuScenes has are listed; a record's fields
appear here in the order real table files use. The loader validates every table file against
:data:`SCHEMAS` and the writer checks every record against it with :func:`check_value`.

Not listed: ``category.index``, present only in releases that ship lidarseg/panoptic labels; the
loader ignores it (and any other field outside the schema) and the writer never writes it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import NamedTuple

from sianms_cli.errors import SianmsError
from sianms_cli.json_stream import is_finite_number

TABLE_NAMES: tuple[str, ...] = (
    "category",
    "attribute",
    "visibility",
    "instance",
    "sensor",
    "calibrated_sensor",
    "ego_pose",
    "log",
    "scene",
    "sample",
    "sample_data",
    "sample_annotation",
    "map",
)
"""The 13 tables, in the order nuscenes-devkit loads them."""

_VERSION_NAME = re.compile(r"[A-Za-z0-9._-]+")


def check_version_name(version: str) -> str:
    """``version`` when it is a safe version folder name; otherwise a SianmsError naming ``--version``.

    The version names the tables' folder inside the dataroot, so it must be one path component
    of letters, digits, '.', '_' and '-', and not '.' or '..': then no version, however it was
    typed, reads or writes outside the dataroot.
    """
    if not isinstance(version, str) or not _VERSION_NAME.fullmatch(version) or version in (".", ".."):
        raise SianmsError(
            f"--version must be one folder name of letters, digits, '.', '_' and '-' "
            f"(not '.' or '..'), got {version!r}"
        )
    return version

FIELD_KINDS = (
    "token", "str", "int", "bool", "vector", "intrinsic", "ref", "optional_ref", "ref_list",
)


@dataclass(frozen=True)
class Field:
    """The kind of value one field holds.

    ``kind`` is one of:

    - ``token``: the record's own primary key, a non-empty string unique in its table;
    - ``str``: any string; ``int``: an integer in the int64 range (not a bool); ``bool``;
    - ``vector``: a list of ``length`` finite numbers (ints are accepted where floats are meant);
    - ``intrinsic``: a 3x3 nested list of finite numbers, or ``[]`` for a sensor without one;
    - ``ref``: the token of a record of ``table``; ``optional_ref``: the same, or ``""`` for none;
    - ``ref_list``: a list of tokens of records of ``table`` (possibly empty).
    """

    kind: str
    length: int = 0
    table: str | None = None

    def __post_init__(self) -> None:
        assert self.kind in FIELD_KINDS, self.kind
        assert (self.table is not None) == self.kind.endswith(("ref", "ref_list")), self
        assert (self.length > 0) == (self.kind == "vector"), self

    @property
    def referenced_table(self) -> str:
        """The table a token reference (``ref``, ``optional_ref``, ``ref_list``) points into."""
        assert self.table is not None, self  # __post_init__: every reference kind names its table
        return self.table


TOKEN = Field("token")
STR = Field("str")
INT = Field("int")
BOOL = Field("bool")
INTRINSIC = Field("intrinsic")


def vector(length: int) -> Field:
    """A list of ``length`` finite numbers."""
    return Field("vector", length=length)


def ref(table: str) -> Field:
    """The token of a record of ``table``."""
    return Field("ref", table=table)


def optional_ref(table: str) -> Field:
    """The token of a record of ``table``, or ``""`` (chain ends, unannotated visibility)."""
    return Field("optional_ref", table=table)


def ref_list(table: str) -> Field:
    """A list of tokens of records of ``table``."""
    return Field("ref_list", table=table)


SCHEMAS: dict[str, dict[str, Field]] = {
    "category": {"token": TOKEN, "name": STR, "description": STR},
    "attribute": {"token": TOKEN, "name": STR, "description": STR},
    "visibility": {"description": STR, "token": TOKEN, "level": STR},
    "instance": {
        "token": TOKEN,
        "category_token": ref("category"),
        "nbr_annotations": INT,
        "first_annotation_token": ref("sample_annotation"),
        "last_annotation_token": ref("sample_annotation"),
    },
    "sensor": {"token": TOKEN, "channel": STR, "modality": STR},
    "calibrated_sensor": {
        "token": TOKEN,
        "sensor_token": ref("sensor"),
        "translation": vector(3),
        "rotation": vector(4),
        "camera_intrinsic": INTRINSIC,
    },
    "ego_pose": {"token": TOKEN, "timestamp": INT, "rotation": vector(4), "translation": vector(3)},
    "log": {"token": TOKEN, "logfile": STR, "vehicle": STR, "date_captured": STR, "location": STR},
    "scene": {
        "token": TOKEN,
        "log_token": ref("log"),
        "nbr_samples": INT,
        "first_sample_token": ref("sample"),
        "last_sample_token": ref("sample"),
        "name": STR,
        "description": STR,
    },
    "sample": {
        "token": TOKEN,
        "timestamp": INT,
        "prev": optional_ref("sample"),
        "next": optional_ref("sample"),
        "scene_token": ref("scene"),
    },
    "sample_data": {
        "token": TOKEN,
        "sample_token": ref("sample"),
        "ego_pose_token": ref("ego_pose"),
        "calibrated_sensor_token": ref("calibrated_sensor"),
        "timestamp": INT,
        "fileformat": STR,
        "is_key_frame": BOOL,
        "height": INT,
        "width": INT,
        "filename": STR,
        "prev": optional_ref("sample_data"),
        "next": optional_ref("sample_data"),
    },
    "sample_annotation": {
        "token": TOKEN,
        "sample_token": ref("sample"),
        "instance_token": ref("instance"),
        "visibility_token": optional_ref("visibility"),
        "attribute_tokens": ref_list("attribute"),
        "translation": vector(3),
        "size": vector(3),
        "rotation": vector(4),
        "prev": optional_ref("sample_annotation"),
        "next": optional_ref("sample_annotation"),
        "num_lidar_pts": INT,
        "num_radar_pts": INT,
    },
    "map": {"category": STR, "token": TOKEN, "filename": STR, "log_tokens": ref_list("log")},
}
"""Table name -> field name -> kind, fields in the order real table files write them."""

_INT64_MIN = -(2**63)
_INT64_MAX = 2**63 - 1


def _describe(value: object) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


NUL = "\x00"
"""No string of a table may hold it: numpy's string arrays, which hold every column, drop trailing
NULs, so "a\x00" would be read as "a" (another record's token, or a scene name no split lists)."""


def _expectation(field: Field) -> str:
    return {
        "token": "a non-empty string without NUL",
        "str": "a string without NUL",
        "int": "an integer",
        "bool": "true or false",
        "vector": f"a list of {field.length} finite numbers",
        "intrinsic": "[] or a 3x3 pinhole matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] of finite numbers, "
                     "fx and fy > 0",
        "ref": f"a {field.table} token",
        "optional_ref": f'a {field.table} token or ""',
        "ref_list": f"a list of {field.table} tokens",
    }[field.kind]


def _is_text(value: object) -> bool:
    return isinstance(value, str) and NUL not in value


def _is_valid(field: Field, value: object) -> bool:
    kind = field.kind
    if kind in ("token", "ref"):
        return _is_text(value) and value != ""
    if kind in ("str", "optional_ref"):
        return _is_text(value)
    if kind == "int":
        return type(value) is int and _INT64_MIN <= value <= _INT64_MAX
    if kind == "bool":
        return type(value) is bool
    if kind == "vector":
        return (
            type(value) is list
            and len(value) == field.length
            and all(is_finite_number(v) for v in value)
        )
    if kind == "intrinsic":
        return type(value) is list and (
            value == []
            or (
                len(value) == 3
                and all(type(row) is list and len(row) == 3 for row in value)
                and all(is_finite_number(v) for row in value for v in row)
                and _is_pinhole(value)
            )
        )
    assert kind == "ref_list", kind
    return type(value) is list and all(_is_text(v) and v != "" for v in value)


def _is_pinhole(matrix: list[list[float]]) -> bool:
    """[[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0: a camera matrix rays can be cast from."""
    (fx, _, _), (below_fx, fy, _), last = matrix
    return fx > 0 and fy > 0 and below_fx == 0 and last == [0, 0, 1]


def check_value(field: Field, value: object) -> str | None:
    """What is wrong with ``value`` as a value of ``field``, or None when it is valid.

    Values are as JSON decodes them: lists (not tuples), Python ints, floats, bools and strings.
    Whether a token exists in its table is not checked here. Example of a problem:
    ``"expected an integer, got '40' (str)"``.
    """
    if _is_valid(field, value):
        return None
    return f"expected {_expectation(field)}, got {_describe(value)}"


class Category(NamedTuple):
    name: str
    description: str


class Attribute(NamedTuple):
    name: str
    description: str


class Visibility(NamedTuple):
    token: str
    level: str
    description: str


class Sensor(NamedTuple):
    channel: str
    token: str
    modality: str


CATEGORIES: tuple[Category, ...] = (
    Category("animal", "All animals, e.g. cats, dogs, deer, birds."),
    Category("human.pedestrian.adult", "Adult pedestrian."),
    Category("human.pedestrian.child", "Child pedestrian."),
    Category("human.pedestrian.construction_worker", "Person working at a construction site."),
    Category(
        "human.pedestrian.personal_mobility",
        "Person riding a small personal vehicle: skateboard, segway, scooter; box includes both.",
    ),
    Category("human.pedestrian.police_officer", "Police officer on foot."),
    Category("human.pedestrian.stroller", "Stroller, including a person in it."),
    Category("human.pedestrian.wheelchair", "Wheelchair, including a person in it."),
    Category("movable_object.barrier", "Temporary road barrier redirecting traffic; no fences."),
    Category("movable_object.debris", "Object on the road too large to drive over safely."),
    Category(
        "movable_object.pushable_pullable",
        "Object a pedestrian pushes or pulls: dolly, wheelbarrow, garbage bin, shopping cart.",
    ),
    Category("movable_object.trafficcone", "Traffic cone of any type."),
    Category("static_object.bicycle_rack", "Area or device for parking bicycles, bikes included."),
    Category("vehicle.bicycle", "Human or electric powered two-wheeler for low speeds."),
    Category("vehicle.bus.bendy", "Articulated bus; each section annotated separately."),
    Category("vehicle.bus.rigid", "Rigid bus."),
    Category("vehicle.car", "Vehicle for personal use: sedan, hatchback, wagon, van, SUV, jeep."),
    Category("vehicle.construction", "Vehicle built for construction work, slow or stationary."),
    Category("vehicle.emergency.ambulance", "Ambulance."),
    Category("vehicle.emergency.police", "Police vehicle, police bicycles and motorcycles too."),
    Category("vehicle.motorcycle", "Motor-powered two-wheeler at car speeds, vespas included."),
    Category("vehicle.trailer", "Trailer hauled by a truck, car or bike."),
    Category("vehicle.truck", "Vehicle built to haul cargo: pick-up, lorry, truck, semi-tractor."),
)
"""The 23 general object categories of nuScenes v1.0, with short descriptions."""

ATTRIBUTES: tuple[Attribute, ...] = (
    Attribute("vehicle.moving", "Vehicle is moving."),
    Attribute("vehicle.stopped", "Vehicle with a driver is stationary but about to move."),
    Attribute("vehicle.parked", "Vehicle is stationary with no intent to move."),
    Attribute("cycle.with_rider", "A rider is on the bicycle or motorcycle."),
    Attribute("cycle.without_rider", "No rider is on the bicycle or motorcycle."),
    Attribute("pedestrian.moving", "The person is moving."),
    Attribute("pedestrian.standing", "The person is standing."),
    Attribute("pedestrian.sitting_lying_down", "The person is sitting or lying down."),
)
"""The 8 annotation attributes of nuScenes v1.0."""

VISIBILITIES: tuple[Visibility, ...] = (
    Visibility("1", "v0-40", "visibility of whole object is between 0 and 40%"),
    Visibility("2", "v40-60", "visibility of whole object is between 40 and 60%"),
    Visibility("3", "v60-80", "visibility of whole object is between 60 and 80%"),
    Visibility("4", "v80-100", "visibility of whole object is between 80 and 100%"),
)
"""The 4 visibility records with their real tokens: the visible fraction of the object over
the panorama of all 6 cameras."""

SENSORS: tuple[Sensor, ...] = (
    Sensor("CAM_FRONT", "725903f5b62f56118f4094b46a4470d8", "camera"),
    Sensor("CAM_FRONT_RIGHT", "2f7ad058f1ac5557bf321c7543758f43", "camera"),
    Sensor("CAM_BACK_RIGHT", "ca7dba2ec9f95951bbe67246f7f2c3f7", "camera"),
    Sensor("CAM_BACK", "ce89d4f3050b5892b33b3d328c5e82a3", "camera"),
    Sensor("CAM_BACK_LEFT", "a89643a5de885c6486df2232dc954da2", "camera"),
    Sensor("CAM_FRONT_LEFT", "ec4b5d41840a509984f7ec36419d4c09", "camera"),
    Sensor("LIDAR_TOP", "dc8b396651c05aedbb9cdaae573bb567", "lidar"),
    # Real radar tokens are not on record; these are md5(channel name), stable across runs.
    Sensor("RADAR_FRONT", "23d7d7ba7ca5a892c5b0ce9a5aef5062", "radar"),
    Sensor("RADAR_FRONT_LEFT", "c9debb4659e6a2dac806721e6ee4e7dc", "radar"),
    Sensor("RADAR_FRONT_RIGHT", "3cba7cc775dc72d34e41c8266ecbe784", "radar"),
    Sensor("RADAR_BACK_LEFT", "92d0d30823ae46d768176000302bd3aa", "radar"),
    Sensor("RADAR_BACK_RIGHT", "28f501033369d8cebe09f7af64d24328", "radar"),
)
"""The 12 sensors of the nuScenes rig: channel, token (the real global token for cameras and
LIDAR_TOP), modality."""

CAMERA_CHANNELS: tuple[str, ...] = tuple(s.channel for s in SENSORS if s.modality == "camera")
"""The 6 camera channels in ring order, clockwise from CAM_FRONT as seen from above."""
