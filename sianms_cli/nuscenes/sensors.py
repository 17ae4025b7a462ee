"""Sensor files of a nuScenes dataroot: where they are, and LIDAR ``.pcd.bin`` / camera JPEG I/O.

A LIDAR_TOP sweep is a headerless little-endian float32 file of 5 values per point, row-major:
x, y, z (metres, LIDAR_TOP sensor frame), intensity, ring index. Camera images are JPEG, RGB.
Every writer here goes through :func:`sianms_cli.io.write_bytes` (atomic, umask permissions).
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
from PIL import Image

from sianms_cli.errors import DataFormatError
from sianms_cli.io import write_bytes

PCD_BIN_VALUES_PER_POINT = 5
_PCD_BIN_POINT_BYTES = 4 * PCD_BIN_VALUES_PER_POINT


def resolve_data_path(
    dataroot: str | Path,
    filename: str,
    *,
    table_path: str | Path | None = None,
    token: str | None = None,
) -> Path:
    """The path of a record's ``filename`` (relative to ``dataroot``) inside the dataroot.

    The check is lexical: ``filename`` must be relative and, once ``.`` and ``..`` components
    are collapsed, stay inside ``dataroot`` (symbolic links are not followed). Otherwise a
    :class:`DataFormatError` names ``table_path`` (or the dataroot when not given), the record
    ``token`` and the field ``filename``. The file itself need not exist.
    """
    root = Path(os.path.normpath(dataroot))
    where = table_path if table_path is not None else root
    if Path(filename).is_absolute():
        raise DataFormatError(
            where, f"'{filename}' is absolute; it must be relative to the dataroot",
            token=token, field="filename",
        )
    resolved = Path(os.path.normpath(root / filename))
    if resolved == root:
        raise DataFormatError(
            where, f"'{filename}' names the dataroot itself, not a file in it",
            token=token, field="filename",
        )
    if root not in resolved.parents:
        raise DataFormatError(
            where, f"'{filename}' resolves outside the dataroot {root}",
            token=token, field="filename",
        )
    return resolved


def read_pcd_bin(path: str | Path, token: str | None = None) -> np.ndarray:
    """Read a LIDAR ``.pcd.bin`` sweep as an (N, 5) float32 array, sensor frame.

    Columns: x, y, z (m), intensity, ring index. A missing file, an empty one, or a size that is
    not a whole number of 20-byte points (a truncated file), raises :class:`DataFormatError`
    naming the file and the sample_data ``token`` when given. nuScenes stores every beam of
    every column, invalid returns at the origin (nuscenes-devkit #117, #845), so no sweep is
    empty: an empty file is a download that stopped.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DataFormatError(path, "lidar file not found", token=token) from None
    except OSError as exc:
        raise DataFormatError(
            path, f"cannot read lidar file: {exc.strerror}", token=token
        ) from None
    if not raw:
        raise DataFormatError(path, "empty lidar file (0 bytes): a download that stopped?", token=token)
    if len(raw) % _PCD_BIN_POINT_BYTES:
        raise DataFormatError(
            path,
            f"truncated lidar file: {len(raw)} bytes is not a whole number of "
            f"{_PCD_BIN_POINT_BYTES}-byte points (5 float32 each)",
            token=token,
        )
    points = np.frombuffer(raw, dtype="<f4").reshape(-1, PCD_BIN_VALUES_PER_POINT)
    return points.astype(np.float32)


def write_pcd_bin(path: str | Path, points: np.ndarray) -> None:
    """Write an (N, 5) array (x, y, z, intensity, ring; sensor frame) as little-endian float32.

    Values are cast to float32. Raises ValueError for any other shape or a non-numeric dtype.
    Creates parent folders; writes through a temporary file and a rename.
    """
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != PCD_BIN_VALUES_PER_POINT:
        raise ValueError(f"lidar points must have shape (N, 5), got {points.shape}")
    if not (np.issubdtype(points.dtype, np.floating) or np.issubdtype(points.dtype, np.integer)):
        raise ValueError(f"lidar points must be numeric, got dtype {points.dtype}")
    write_bytes(path, np.ascontiguousarray(points, dtype="<f4").tobytes())


def read_image(path: str | Path, token: str | None = None) -> np.ndarray:
    """Read a camera image as an (H, W, 3) uint8 RGB array (rows top to bottom).

    The image is fully decoded here, so a truncated or undecodable file raises
    :class:`DataFormatError` (naming the file and the sample_data ``token`` when given) instead
    of failing later. Relies on Pillow's default of refusing truncated images
    (``ImageFile.LOAD_TRUNCATED_IMAGES`` left False). Grey or RGBA images are converted to RGB.
    """
    path = Path(path)
    try:
        with Image.open(path) as image:
            image.load()
            rgb = image.convert("RGB") if image.mode != "RGB" else image
            pixels = np.array(rgb, dtype=np.uint8)
    except FileNotFoundError:
        raise DataFormatError(path, "image file not found", token=token) from None
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as exc:
        raise DataFormatError(path, f"cannot decode image: {exc}", token=token) from None
    return pixels


def write_jpeg(path: str | Path, image: np.ndarray, quality: int = 90) -> None:
    """Write an (H, W, 3) uint8 RGB array as a baseline JPEG.

    The same array and quality always give byte-identical files (no timestamps or metadata are
    embedded). Raises ValueError for another shape or dtype, or a quality outside 1..95.
    Creates parent folders; writes through a temporary file and a rename.
    """
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be an (H, W, 3) uint8 array, got {image.shape} {image.dtype}")
    if not 1 <= quality <= 95:
        raise ValueError(f"JPEG quality must be in 1..95, got {quality}")
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image)).save(buffer, format="JPEG", quality=quality)
    write_bytes(path, buffer.getvalue())
