"""Carve a calibration split out of a dataset's training scenes, as two custom splits in its splits.json.

    python scripts/carve_calibration.py --dataroot DATA --version v1.0-trainval --split train --every 4

Of the scenes of ``--split`` that the dataset holds, in the order of its scene table, every
``--every``-th one starting with the first goes to the calibration split (``--calibration``,
default ``calib``) and the others to the fitting split (``--rest``, default ``train_fit``); both are
added to ``DATA/VERSION/splits.json``, the file every sianms command reads custom splits from
(splits.json is not part of the dataset's fingerprint, so caches of the other splits stay
valid). Then train on ``train_fit``, choose thresholds on ``calib`` (`sianms eval --split calib`) and
report on the validation split with ``sianms eval --thresholds-from`` that evaluation.

The same dataset and arguments give the same splits. Splits the file already holds are kept; a
name already there with other scenes is refused (exit 2), so a study's splits never change
under it. The names follow ``sianms prepare``'s rule, which fills in missed objects from the ground
truth for a split whose name contains "train": the fitting split's should (as the training split's
does), the calibration split's must not (a threshold is chosen on what the detector gave).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import describe_os_error, read_json, write_json
from sianms_cli.nuscenes.splits import load_split_file, split_scene_names


def dataset_scene_names(table_root: Path) -> list[str]:
    """The scene names of ``table_root/scene.json``, in the table's order."""
    path = table_root / "scene.json"
    records = read_json(path)
    if not isinstance(records, list):
        raise DataFormatError(path, "must be a list of scene records")
    names = []
    for index, record in enumerate(records):
        if not (isinstance(record, dict) and isinstance(record.get("name"), str)):
            raise DataFormatError(path, f"record {index}: must hold a scene name", field="name")
        names.append(record["name"])
    return names


def carve(scenes: list[str], every: int) -> tuple[list[str], list[str]]:
    """(calibration, rest): every ``every``-th scene from the first, and the others, each in the given order."""
    return scenes[::every], [scene for i, scene in enumerate(scenes) if i % every]


def carve_splits(dataroot: Path, version: str, split: str, every: int, calibration: str, rest: str
                 ) -> dict[str, list[str]]:
    """Add the two splits to ``dataroot/version/splits.json`` (module docstring) and return them."""
    if every < 2:
        raise SianmsError(f"--every must be at least 2 (one scene in N to calibration), got {every}")
    if "train" in calibration:
        raise SianmsError(f"--calibration: '{calibration}' contains 'train', for which `sianms prepare` fills in "
                          "missed objects from the ground truth; name it otherwise")
    if calibration == rest:
        raise SianmsError(f"--calibration and --rest must differ, both are '{calibration}'")
    table_root = dataroot / version
    wanted = set(split_scene_names(split, version, dataroot))
    scenes = [name for name in dataset_scene_names(table_root) if name in wanted]
    if len(scenes) < every:
        raise SianmsError(f"split '{split}' holds {len(scenes)} scene(s) of {table_root}: too few to carve one in "
                          f"{every} out and keep the rest")
    carved = dict(zip((calibration, rest), carve(scenes, every)))
    path = table_root / "splits.json"
    existing = load_split_file(path) if path.exists() else {}
    for name, names in carved.items():
        if name in existing and existing[name] != names:
            raise DataFormatError(path, f"already defines '{name}' with other scenes; choose another name or remove "
                                        "it yourself", field=name)
    write_json(path, {**existing, **carved})
    return carved


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataroot", type=Path, required=True, help="the dataset's dataroot")
    parser.add_argument("--version", required=True, help="its version folder, e.g. v1.0-trainval")
    parser.add_argument("--split", default="train", help="the split to carve from (default: train)")
    parser.add_argument("--every", type=int, default=4, help="one scene in this many goes to calibration (4)")
    parser.add_argument("--calibration", default="calib", help="the calibration split's name (calib)")
    parser.add_argument("--rest", default="train_fit", help="the name of the split of the other scenes (train_fit)")
    arguments = parser.parse_args()
    try:
        carved = carve_splits(arguments.dataroot, arguments.version, arguments.split, arguments.every,
                              arguments.calibration, arguments.rest)
    except (SianmsError, OSError) as error:
        print(f"error: {describe_os_error(error) if isinstance(error, OSError) else error}", file=sys.stderr)
        raise SystemExit(2) from None
    print(", ".join(f"{name}: {len(names)} scenes" for name, names in carved.items())
          + f" (of {arguments.split}) in {arguments.dataroot / arguments.version / 'splits.json'}")


if __name__ == "__main__":
    main()
