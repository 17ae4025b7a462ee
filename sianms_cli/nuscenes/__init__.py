"""The nuScenes v1.0 on-disk format: schema, indexed loader, writer, splits, sensor files.

Knows nothing of torch. Points are row-major (N, 3+) arrays, not the devkit's 3xN; frames and
units follow nuScenes (metres, radians, quaternions w, x, y, z; global -> ego -> sensor).
"""

from sianms_cli.nuscenes.loader import NuScenesDB, Table
from sianms_cli.nuscenes.splits import (
    PREDEFINED_SPLITS,
    load_split_file,
    split_sample_tokens,
    split_scene_names,
    splits_for_version,
)
from sianms_cli.nuscenes.tables import SCHEMAS, TABLE_NAMES
from sianms_cli.nuscenes.writer import DatasetWriter, make_token

__all__ = [
    "PREDEFINED_SPLITS",
    "SCHEMAS",
    "TABLE_NAMES",
    "DatasetWriter",
    "NuScenesDB",
    "Table",
    "load_split_file",
    "make_token",
    "split_sample_tokens",
    "split_scene_names",
    "splits_for_version",
]
