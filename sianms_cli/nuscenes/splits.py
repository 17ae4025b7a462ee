"""Dataset splits: which scenes, by name, belong to train, val, test and custom splits.

The predefined scene lists in ``data/splits.json`` are those of nuscenes-devkit 1.2.0, read
from the literals of ``nuscenes/utils/splits.py`` in its wheel (``pip download
nuscenes-devkit==1.2.0``): ``train_detect`` and ``train_track`` (350 scenes each), ``train``
(their union, 700, sorted), ``val`` (150), ``test`` (150), ``mini_train`` (8), ``mini_val``
(2). train, val and test are disjoint and cover 1000 scenes; ``mini_train`` holds two val
scenes, as in the devkit.

The devkit's rules apply: a predefined split needs a matching version suffix (train, val,
train_detect, train_track: ``trainval``; mini_train, mini_val: ``mini``; test: ``test``), and
any other split name is a custom split read from ``<dataroot>/<version>/splits.json``
({split name: [scene names]}, nuscenes-devkit >= 1.2.0).
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import read_json

if TYPE_CHECKING:
    from sianms_cli.nuscenes.loader import NuScenesDB

_VERSION_SUFFIX = {
    "train": "trainval",
    "val": "trainval",
    "test": "test",
    "mini_train": "mini",
    "mini_val": "mini",
    "train_detect": "trainval",
    "train_track": "trainval",
}

PREDEFINED_SPLITS: tuple[str, ...] = tuple(_VERSION_SUFFIX)
"""Names of the devkit's predefined splits."""


@cache
def _predefined() -> dict[str, tuple[str, ...]]:
    text = resources.files("sianms_cli.nuscenes").joinpath("data/splits.json").read_text("utf-8")
    splits = {name: tuple(scenes) for name, scenes in json.loads(text).items()}
    assert set(splits) == set(PREDEFINED_SPLITS), sorted(splits)
    return splits


def splits_for_version(version: str) -> dict[str, list[str]]:
    """The predefined splits that apply to ``version`` (by its suffix): name -> scene names.

    E.g. ``v1.0-mini`` -> mini_train, mini_val; ``v1.0-trainval`` -> train, val, train_detect,
    train_track; ``v1.0-test`` -> test; any other version -> {}.
    """
    return {
        name: list(scenes)
        for name, scenes in _predefined().items()
        if version.endswith(_VERSION_SUFFIX[name])
    }


def load_split_file(path: str | Path) -> dict[str, list[str]]:
    """Read a split file: a JSON object mapping split names to lists of scene names.

    Raises DataFormatError naming the file (and the split name as the field) for a missing
    file, invalid JSON, a top level that is not an object, a value that is not a list of
    strings, or a scene listed twice in one split.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "split file not found")
    splits = read_json(path)
    if not isinstance(splits, dict):
        raise DataFormatError(
            path, "top level must be an object mapping split names to lists of scene names, "
            f"got {type(splits).__name__}"
        )
    for name, scenes in splits.items():
        if not isinstance(scenes, list) or not all(isinstance(scene, str) for scene in scenes):
            raise DataFormatError(path, "expected a list of scene names", field=name)
        seen: set[str] = set()
        for scene in scenes:
            if scene in seen:
                raise DataFormatError(path, f"scene '{scene}' is listed twice", field=name)
            seen.add(scene)
    return {name: list(scenes) for name, scenes in splits.items()}


def split_scene_names(split: str, version: str, dataroot: str | Path | None = None) -> list[str]:
    """The scene names of ``split`` for a dataset of ``version``.

    A predefined split whose version suffix does not match raises SianmsError. Any other
    name is looked up in ``<dataroot>/<version>/splits.json``: SianmsError without a dataroot,
    DataFormatError if that file is missing or malformed, SianmsError listing the available
    names if the split is not in it.
    """
    if split in _VERSION_SUFFIX:
        suffix = _VERSION_SUFFIX[split]
        if not version.endswith(suffix):
            raise SianmsError(
                f"split '{split}' needs a dataset version ending in '{suffix}', got '{version}'"
            )
        return list(_predefined()[split])
    predefined = ", ".join(splits_for_version(version)) or "none"
    if dataroot is None:
        raise SianmsError(
            f"split '{split}' is not predefined (for {version}: {predefined}); custom splits "
            "are read from <dataroot>/<version>/splits.json, which needs a dataroot"
        )
    path = Path(dataroot) / version / "splits.json"
    if not path.is_file():
        raise DataFormatError(
            path, f"not found; split '{split}' is not predefined (for {version}: {predefined}), "
            "so it must be defined in this file"
        )
    custom = load_split_file(path)
    if split not in custom:
        raise SianmsError(
            f"{path}: no split '{split}'; available: {', '.join(custom) or 'none'} "
            f"(predefined for {version}: {predefined})"
        )
    return custom[split]


def split_sample_tokens(db: NuScenesDB, split: str) -> list[str]:
    """Tokens of the samples of ``split`` in ``db``: scenes in scene-table order, each in time
    order. Scenes of the split that the dataset does not hold are skipped, as in the devkit."""
    names = set(split_scene_names(split, db.version, db.dataroot))
    scenes = db.table("scene")
    tokens: list[str] = []
    for token, name in zip(scenes.tokens.tolist(), scenes.column("name").tolist()):
        if name in names:
            tokens.extend(db.sample_tokens_of_scene(token))
    return tokens
