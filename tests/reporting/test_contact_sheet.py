"""The contact sheet on a hand-made dataset: one key frame per scene, six cameras, flat-colour images.

Each camera image is one flat colour that encodes its scene and camera, so the sheet's tiles can
be checked in place: which key frame each row shows and the cameras' order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.nuscenes.tables import SENSORS
from sianms_cli.nuscenes.writer import DatasetWriter, make_token
from sianms_cli.reporting.contact_sheet import GAP, LABEL_HEIGHT, MISSING_TILE, RIG_ORDER, write_contact_sheet

VERSION = "v1.0-mini"
WIDTH, HEIGHT = 64, 36
SENSOR_TOKEN = {sensor.channel: sensor.token for sensor in SENSORS}


def colour(scene: int, camera: int) -> tuple[int, int, int]:
    """The flat colour of camera ``camera`` (index in RIG_ORDER) of scene ``scene``."""
    return (40 * scene + 20, 40 * camera + 10, 200)


def write_dataset(root: Path, descriptions: list[str], missing: tuple[int, str] | None = None) -> list[str]:
    """One scene per description, each of one sample with a key frame of every camera.

    ``missing`` (scene, channel): that key frame is not in the tables. Returns the sample tokens.
    """
    log = make_token("log", 0)
    samples = []
    with DatasetWriter(root, VERSION) as writer:
        writer.add_static_tables()
        writer.add("log", {"token": log, "logfile": "handmade", "vehicle": "n0", "date_captured": "2018-07-24",
                           "location": "boston-seaport"})
        writer.add_map(make_token("map", 0), [log])
        for c, channel in enumerate(RIG_ORDER):
            writer.add("calibrated_sensor", {
                "token": make_token("calibrated_sensor", channel), "sensor_token": SENSOR_TOKEN[channel],
                "translation": [1.5, 0.0, 1.5], "rotation": [0.5, -0.5, 0.5, -0.5],
                "camera_intrinsic": [[50.0, 0, WIDTH / 2], [0, 50.0, HEIGHT / 2], [0, 0, 1]]})
        for s, description in enumerate(descriptions):
            scene, sample, time = make_token("scene", s), make_token("sample", s), 1_000_000 * (s + 1)
            samples.append(sample)
            writer.add("scene", {"token": scene, "log_token": log, "nbr_samples": 1, "first_sample_token": sample,
                                 "last_sample_token": sample, "name": f"scene-{s:04d}", "description": description})
            writer.add("sample", {"token": sample, "timestamp": time, "prev": "", "next": "", "scene_token": scene})
            for c, channel in enumerate(RIG_ORDER):
                if missing == (s, channel):
                    continue
                token = make_token("sample_data", s, channel)
                filename = f"samples/{channel}/handmade__{channel}__{time}.jpg"
                writer.add("ego_pose", {"token": token, "timestamp": time, "rotation": [1.0, 0, 0, 0],
                                        "translation": [0.0, 0.0, 0.0]})
                writer.add("sample_data", {
                    "token": token, "sample_token": sample, "ego_pose_token": token,
                    "calibrated_sensor_token": make_token("calibrated_sensor", channel), "timestamp": time,
                    "fileformat": "jpg", "is_key_frame": True, "height": HEIGHT, "width": WIDTH,
                    "filename": filename, "prev": "", "next": ""})
                (root / filename).parent.mkdir(parents=True, exist_ok=True)
                Image.new("RGB", (WIDTH, HEIGHT), colour(s, c)).save(root / filename, quality=95)
    return samples


def tile_centre(sheet: np.ndarray, row: int, camera: int, tile_width: int) -> np.ndarray:
    """The pixel at the centre-bottom of a tile (below the camera's label), (3,) int."""
    tile_height = round(HEIGHT * tile_width / WIDTH)
    top = row * (LABEL_HEIGHT + tile_height + GAP) + LABEL_HEIGHT
    return sheet[top + tile_height - 3, camera * (tile_width + GAP) + tile_width // 2].astype(int)


def test_rows_are_the_first_day_night_and_rain_scenes_in_rig_order(tmp_path):
    descriptions = ["Rain, peds, parking lot", "Big street, bus stop", "Night, big street", "Night, rain, turns",
                    "Parking lot again"]
    samples = write_dataset(tmp_path / "data", descriptions)
    out = tmp_path / "sheet.png"
    rows = write_contact_sheet(tmp_path / "data", VERSION, out, tile_width=32)
    assert [(row.condition, row.scene_name, row.sample_token) for row in rows] == [
        ("day", "scene-0001", samples[1]), ("night", "scene-0002", samples[2]), ("rain", "scene-0000", samples[0])]
    sheet = np.asarray(Image.open(out).convert("RGB"))
    assert sheet.shape == (3 * (LABEL_HEIGHT + 18) + 2 * GAP, 6 * 32 + 5 * GAP, 3)
    for row, scene in enumerate((1, 2, 0)):
        for camera in range(len(RIG_ORDER)):
            np.testing.assert_allclose(tile_centre(sheet, row, camera, 32), colour(scene, camera), atol=4)
    assert not list(tmp_path.glob(".*"))  # no temporary file left


def test_a_missing_condition_has_no_row_and_words_must_start_with_it(tmp_path):
    write_dataset(tmp_path / "data", ["Train station, drain works", "Rainy, nightfall"])
    rows = write_contact_sheet(tmp_path / "data", VERSION, tmp_path / "sheet.jpg")
    assert [(row.condition, row.scene_name) for row in rows] == [
        ("day", "scene-0000"), ("night", "scene-0001"), ("rain", "scene-0001")]
    write_dataset(tmp_path / "day-only", ["Day, quiet street"])
    rows = write_contact_sheet(tmp_path / "day-only", VERSION, tmp_path / "day.png", tile_width=16)
    assert [row.condition for row in rows] == ["day"]
    assert Image.open(tmp_path / "day.png").size == (6 * 16 + 5 * GAP, LABEL_HEIGHT + 9)


def test_a_camera_without_a_key_frame_is_a_grey_tile(tmp_path):
    write_dataset(tmp_path / "data", ["Day"], missing=(0, "CAM_BACK"))
    write_contact_sheet(tmp_path / "data", VERSION, tmp_path / "sheet.png", tile_width=32)
    sheet = np.asarray(Image.open(tmp_path / "sheet.png").convert("RGB"))
    back = RIG_ORDER.index("CAM_BACK")
    np.testing.assert_array_equal(tile_centre(sheet, 0, back, 32), MISSING_TILE)
    np.testing.assert_allclose(tile_centre(sheet, 0, back - 1, 32), colour(0, back - 1), atol=4)


def test_bad_input_is_one_clear_error_and_writes_nothing(tmp_path):
    write_dataset(tmp_path / "data", ["Day"])
    out = tmp_path / "sheet.png"
    with pytest.raises(SianmsError, match="sheet.gif"):
        write_contact_sheet(tmp_path / "data", VERSION, tmp_path / "sheet.gif")
    with pytest.raises(SianmsError, match="tile width"):
        write_contact_sheet(tmp_path / "data", VERSION, out, tile_width=0)
    image = next((tmp_path / "data" / "samples" / "CAM_FRONT").glob("*.jpg"))
    image.unlink()
    with pytest.raises(DataFormatError, match="image file not found") as caught:
        write_contact_sheet(tmp_path / "data", VERSION, out)
    assert image.name in str(caught.value) and make_token("sample_data", 0, "CAM_FRONT") in str(caught.value)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["data"]
    out.write_bytes(b"finished")
    with pytest.raises(OutputExistsError):
        write_contact_sheet(tmp_path / "data", VERSION, out)
    with pytest.raises(DataFormatError, match="version folder not found"):
        write_contact_sheet(tmp_path / "nowhere", VERSION, tmp_path / "other.png")
