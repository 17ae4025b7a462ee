"""The image-box rule against the devkit's own ``export_2d_annotations_as_json.get_2d_boxes``.

The devkit pins numpy<2, so it runs in its own virtual environment (``scripts/devkit_venv.sh``)
as a subprocess that prints, for every camera key frame, the annotations it yields a 2-D box
for (all visibility levels, as the script's default). Its canvas is fixed at 1600 x 900; the
subprocess gives it each key frame's own size, as our rule does. A degenerate intersection (a
point or a segment, on which the script itself fails) is counted apart and must not occur.
Skipped when the devkit interpreter is absent.
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
from devkit_venv import DEVKIT_MARKS, DEVKIT_PYTHON

from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.reporting.image_boxes import annotation_image_boxes

pytestmark = DEVKIT_MARKS

DUMP = """
import json, sys
from nuscenes.nuscenes import NuScenes
from nuscenes.scripts import export_2d_annotations_as_json as export

export.nusc = nusc = NuScenes(version=sys.argv[2], dataroot=sys.argv[1], verbose=False)
original = export.post_process_coords
degenerate = 0
pairs = []
for sd in nusc.sample_data:
    if sd["sensor_modality"] != "camera" or not sd["is_key_frame"]:
        continue
    def post_process(coords, imsize=(sd["width"], sd["height"])):
        global degenerate
        try:
            return original(coords, imsize)
        except AttributeError:  # a Point or LineString has no exterior
            degenerate += 1
            return None
    export.post_process_coords = post_process
    channel = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])["sensor_token"]
    channel = nusc.get("sensor", channel)["channel"]
    visibilities = ["", "1", "2", "3", "4"]
    pairs += [[record["sample_annotation_token"], channel] for record in export.get_2d_boxes(sd["token"], visibilities)]
print(json.dumps({"pairs": pairs, "degenerate": degenerate}))
"""


def test_image_boxes_match_the_devkit_export(tiny_dataroot):
    dataroot = tiny_dataroot
    done = subprocess.run([str(DEVKIT_PYTHON), "-c", DUMP, str(dataroot), "v1.0-mini"], capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    devkit = json.loads(done.stdout.strip().splitlines()[-1])
    db = NuScenesDB(dataroot, "v1.0-mini")
    ours = annotation_image_boxes(db)
    rows = db.table("sample_annotation").indices([token for token, _ in devkit["pairs"]])
    columns = np.array([ours.channels.index(channel) for _, channel in devkit["pairs"]], dtype=np.int64)
    expected = np.zeros_like(ours.imaged)
    expected[rows, columns] = True
    assert devkit["degenerate"] == 0
    assert len(devkit["pairs"]) == int(expected.sum()) > 0
    assert np.array_equal(ours.imaged, expected)
