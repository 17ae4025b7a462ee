import io
import re

import numpy as np
import pytest
from PIL import Image

from sianms_cli.errors import DataFormatError
from sianms_cli.nuscenes.sensors import (
    read_image,
    read_pcd_bin,
    resolve_data_path,
    write_jpeg,
    write_pcd_bin,
)


def test_resolve_data_path_joins_inside_the_dataroot(tmp_path):
    assert resolve_data_path(tmp_path, "samples/CAM_FRONT/a.jpg") == tmp_path / "samples/CAM_FRONT/a.jpg"
    assert resolve_data_path(tmp_path, "samples/./x/../a.jpg") == tmp_path / "samples/a.jpg"


@pytest.mark.parametrize("filename, problem", [
    ("/etc/passwd", "'/etc/passwd' is absolute; it must be relative to the dataroot"),
    ("../secret.jpg", "'../secret.jpg' resolves outside the dataroot"),
    ("samples/../../secret.jpg", "'samples/../../secret.jpg' resolves outside the dataroot"),
    ("samples/..", "'samples/..' names the dataroot itself, not a file in it"),
])
def test_resolve_data_path_refuses_escapes(tmp_path, filename, problem):
    table = tmp_path / "v1.0-mini" / "sample_data.json"
    with pytest.raises(DataFormatError) as caught:
        resolve_data_path(tmp_path / "root", filename, table_path=table, token="sd1")
    message = str(caught.value)
    assert message.startswith(f"{table}: record sd1: field 'filename': {problem}")
    assert caught.value.field == "filename" and caught.value.token == "sd1"


def test_pcd_bin_round_trip_is_exact_little_endian_float32(tmp_path):
    points = np.array([[1.5, -2.25, 0.125, 7.0, 31.0], [0.1, 0.2, 0.3, 0.0, 0.0]])
    path = tmp_path / "samples" / "LIDAR_TOP" / "x.pcd.bin"
    write_pcd_bin(path, points)
    assert path.read_bytes() == points.astype("<f4").tobytes()
    assert path.stat().st_size == 40
    loaded = read_pcd_bin(path)
    assert loaded.dtype == np.float32 and loaded.shape == (2, 5)
    np.testing.assert_array_equal(loaded, points.astype(np.float32))
    assert [p.name for p in path.parent.iterdir()] == ["x.pcd.bin"]


def test_an_empty_pcd_bin_is_a_data_format_error(tmp_path):
    """A partial download's 0-byte file had been read as a sweep without points: info averaged it in."""
    path = tmp_path / "empty.pcd.bin"
    path.write_bytes(b"")
    with pytest.raises(DataFormatError) as caught:
        read_pcd_bin(path, token="sd9")
    assert str(caught.value) == f"{path}: record sd9: empty lidar file (0 bytes): a download that stopped?"


def test_truncated_pcd_bin_is_a_data_format_error(tmp_path):
    path = tmp_path / "cut.pcd.bin"
    path.write_bytes(np.zeros((3, 5), "<f4").tobytes()[:-4])
    with pytest.raises(DataFormatError) as caught:
        read_pcd_bin(path, token="sd9")
    assert str(caught.value) == (
        f"{path}: record sd9: truncated lidar file: 56 bytes is not a whole number of "
        "20-byte points (5 float32 each)"
    )


def test_missing_pcd_bin_is_a_data_format_error(tmp_path):
    with pytest.raises(DataFormatError, match=re.escape(f"{tmp_path / 'no.pcd.bin'}: lidar file not found")):
        read_pcd_bin(tmp_path / "no.pcd.bin")


@pytest.mark.parametrize("points", [np.zeros((4, 4)), np.zeros(5), np.array([["a"] * 5])])
def test_write_pcd_bin_refuses_bad_arrays(tmp_path, points):
    with pytest.raises(ValueError):
        write_pcd_bin(tmp_path / "x.pcd.bin", points)
    assert list(tmp_path.iterdir()) == []


def _gradient_image(height=24, width=40):
    rows, cols = np.mgrid[0:height, 0:width]
    return np.stack([rows * 10, cols * 6, (rows + cols) * 3], axis=-1).astype(np.uint8)


def test_jpeg_write_is_byte_identical_and_reads_back_rgb(tmp_path):
    image = _gradient_image()
    write_jpeg(tmp_path / "a.jpg", image)
    write_jpeg(tmp_path / "b.jpg", image)
    assert (tmp_path / "a.jpg").read_bytes() == (tmp_path / "b.jpg").read_bytes()
    loaded = read_image(tmp_path / "a.jpg")
    assert loaded.dtype == np.uint8 and loaded.shape == (24, 40, 3)
    # JPEG is lossy; a smooth gradient at quality 90 comes back within a few levels.
    assert np.abs(loaded.astype(int) - image).max() <= 8


def test_jpeg_quality_changes_the_bytes(tmp_path):
    image = _gradient_image()
    write_jpeg(tmp_path / "q90.jpg", image)
    write_jpeg(tmp_path / "q50.jpg", image, quality=50)
    assert (tmp_path / "q90.jpg").read_bytes() != (tmp_path / "q50.jpg").read_bytes()


def test_read_image_converts_grey_to_rgb(tmp_path):
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4) * 20
    buffer = io.BytesIO()
    Image.fromarray(grey).save(buffer, format="PNG")
    (tmp_path / "g.png").write_bytes(buffer.getvalue())
    loaded = read_image(tmp_path / "g.png")
    assert loaded.shape == (3, 4, 3)
    np.testing.assert_array_equal(loaded[..., 1], grey)


def test_truncated_jpeg_is_a_data_format_error(tmp_path):
    write_jpeg(tmp_path / "full.jpg", _gradient_image(64, 64))
    data = (tmp_path / "full.jpg").read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(DataFormatError) as caught:
        read_image(tmp_path / "cut.jpg", token="cam1")
    assert str(caught.value).startswith(f"{tmp_path / 'cut.jpg'}: record cam1: cannot decode image:")


def test_undecodable_and_missing_images_are_data_format_errors(tmp_path):
    (tmp_path / "junk.jpg").write_bytes(b"not an image at all")
    with pytest.raises(DataFormatError, match="cannot decode image"):
        read_image(tmp_path / "junk.jpg")
    with pytest.raises(DataFormatError, match="image file not found"):
        read_image(tmp_path / "none.jpg")


@pytest.mark.parametrize("image, quality", [
    (np.zeros((4, 4), np.uint8), 90), (np.zeros((4, 4, 3), np.float32), 90),
    (np.zeros((4, 4, 4), np.uint8), 90), (np.zeros((4, 4, 3), np.uint8), 0),
])
def test_write_jpeg_refuses_bad_input(tmp_path, image, quality):
    with pytest.raises(ValueError):
        write_jpeg(tmp_path / "x.jpg", image, quality=quality)
    assert list(tmp_path.iterdir()) == []
