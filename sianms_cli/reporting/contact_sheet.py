"""A contact sheet of a dataset: the six cameras of one day, one night and one rain key frame.

One picture that shows what a dataroot looks like (synthetic or real): a row per condition,
each the first key frame (the scene's ``first_sample_token``) of the first scene, in table
order, of that condition, read from the scene ``description`` as nuScenes writes it
("Night, big street, ...", "Rain, peds, parking lot"):

- **night**: a word starting with "night", any case; **rain**: a word starting with "rain"
  ("rainy" counts, "train" and "drain" do not), the rule `sianms info` counts conditions by;
- **day**: neither.

A scene both at night and in rain may give both rows. A condition the dataset lacks has no
row; :func:`write_contact_sheet` returns the rows it drew. Each row is a label band (scene
name and condition, Pillow's default font) over the six cameras in :data:`RIG_ORDER`, each
scaled to ``tile_width`` pixels wide (height by its aspect); a camera without a key frame in
the sample is a grey tile saying so.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.io import check_writable_output, write_bytes
from sianms_cli.nuscenes.keyframes import keyframe_rows
from sianms_cli.nuscenes.loader import NuScenesDB
from sianms_cli.reporting.dataset_summary import night_and_rain

RIG_ORDER = ("CAM_FRONT_LEFT", "CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_LEFT", "CAM_BACK", "CAM_BACK_RIGHT")
CONDITIONS = ("day", "night", "rain")
TILE_WIDTH = 320  # px per camera: six cameras make a 1920 px wide sheet, a screen's width
LABEL_HEIGHT = 16  # px, the band above each row (Pillow's default font is about 11 px tall)
GAP = 2  # px between tiles and rows
BACKGROUND = (255, 255, 255)
MISSING_TILE = (96, 96, 96)
FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}


@dataclass(frozen=True)
class SheetRow:
    """One row of a contact sheet: which key frame shows a condition."""

    condition: str  # one of CONDITIONS
    scene_name: str
    scene_token: str
    sample_token: str


def scene_conditions(descriptions: np.ndarray) -> dict[str, np.ndarray]:
    """{condition: (N,) bool} of scene descriptions, for each of :data:`CONDITIONS`."""
    night, rain = night_and_rain(descriptions)
    return {"day": ~night & ~rain, "night": night, "rain": rain}


def pick_rows(db: NuScenesDB) -> list[SheetRow]:
    """The first key frame of the first scene of each condition present, in :data:`CONDITIONS` order."""
    scenes = db.table("scene")
    conditions = scene_conditions(scenes.column("description"))
    samples = db.table("sample").tokens[scenes.rows("first_sample_token")]
    rows = []
    for condition in CONDITIONS:
        found = np.flatnonzero(conditions[condition])
        if len(found):
            first = int(found[0])
            rows.append(SheetRow(condition, str(scenes.column("name")[first]), str(scenes.tokens[first]),
                                 str(samples[first])))
    return rows


def _tile(db: NuScenesDB, sample_data_row: int, width: int) -> Image.Image:
    """One camera key frame scaled to ``width`` px wide (aspect kept, at least 1 px tall)."""
    token = str(db.table("sample_data").tokens[sample_data_row])
    image = Image.fromarray(db.read_image(token))
    height = max(1, round(image.height * width / image.width))
    return image.resize((width, height), Image.Resampling.BILINEAR, reducing_gap=2.0)


def _missing_tile(channel: str, width: int, height: int, font) -> Image.Image:
    tile = Image.new("RGB", (width, height), MISSING_TILE)
    ImageDraw.Draw(tile).text((4, 4), f"{channel}: no key frame", fill=(255, 255, 255), font=font)
    return tile


def _row_image(db: NuScenesDB, row: SheetRow, frames: np.ndarray, width: int, font) -> Image.Image:
    """A label band over the six cameras of one key frame; ``frames`` (6,) sample_data rows, -1 for none."""
    tiles = {c: _tile(db, int(frames[c]), width) for c in range(len(RIG_ORDER)) if frames[c] >= 0}
    height = max((tile.height for tile in tiles.values()), default=round(width * 9 / 16))
    canvas = Image.new("RGB", (len(RIG_ORDER) * (width + GAP) - GAP, LABEL_HEIGHT + height), BACKGROUND)
    draw = ImageDraw.Draw(canvas)
    draw.text((2, 2), f"{row.scene_name}, {row.condition}", fill=(0, 0, 0), font=font)
    for c, channel in enumerate(RIG_ORDER):
        tile = tiles[c] if c in tiles else _missing_tile(channel, width, height, font)
        left = c * (width + GAP)
        canvas.paste(tile, (left, LABEL_HEIGHT))
        # The channel on a dark box, readable on any picture.
        box = draw.textbbox((left + 3, LABEL_HEIGHT + 2), channel, font=font)
        draw.rectangle((box[0] - 2, box[1] - 1, box[2] + 2, box[3] + 1), fill=(0, 0, 0))
        draw.text((left + 3, LABEL_HEIGHT + 2), channel, fill=(255, 255, 255), font=font)
    return canvas


def render_contact_sheet(db: NuScenesDB, rows: list[SheetRow], tile_width: int = TILE_WIDTH) -> Image.Image:
    """The sheet of ``rows`` (from :func:`pick_rows`) as one RGB image, rows stacked top to bottom."""
    if not isinstance(tile_width, int) or tile_width < 1:
        raise SianmsError(f"the contact sheet's tile width must be a whole number of pixels >= 1, got {tile_width!r}")
    if not rows:
        raise DataFormatError(db.table("scene").path, "no scene to show (the table has no record)")
    samples = db.table("sample").indices([row.sample_token for row in rows])
    frames = keyframe_rows(db, samples, RIG_ORDER)  # (rows, 6)
    font = ImageFont.load_default()
    images = [_row_image(db, row, frames[k], tile_width, font) for k, row in enumerate(rows)]
    sheet = Image.new("RGB", (max(image.width for image in images),
                              sum(image.height for image in images) + GAP * (len(images) - 1)), BACKGROUND)
    top = 0
    for image in images:
        sheet.paste(image, (0, top))
        top += image.height + GAP
    return sheet


def sheet_format(out_path: str | Path) -> str:
    """Pillow's format for a contact sheet file name; SianmsError for another suffix."""
    image_format = FORMATS.get(Path(out_path).suffix.lower())
    if image_format is None:
        raise SianmsError(f"cannot write a contact sheet to {out_path}: use a {', '.join(FORMATS)} file name")
    return image_format


def sheet_bytes(sheet: Image.Image, out_path: str | Path) -> bytes:
    """A drawn sheet encoded for ``out_path``'s suffix (.png, or .jpg/.jpeg at quality 90).

    Encoded in memory, then written whole: Pillow's JPEG encoder writes to a file's descriptor
    and takes a short write on a full disk for success (a cut-off picture, exit 0)."""
    image_format = sheet_format(out_path)
    encoded = io.BytesIO()
    sheet.save(encoded, format=image_format, **({"quality": 90} if image_format == "JPEG" else {}))
    return encoded.getvalue()


def write_contact_sheet(dataroot: str | Path, version: str, out_path: str | Path, *, tile_width: int = TILE_WIDTH,
                        overwrite: bool = False, db: NuScenesDB | None = None) -> list[SheetRow]:
    """Write the contact sheet of a dataset to ``out_path`` (.png, or .jpg/.jpeg at quality 90).

    Args:
        dataroot, version: the dataset (``<dataroot>/<version>/*.json``).
        out_path: the picture; written under a temporary name and renamed when complete.
        tile_width: width of each camera's tile, pixels.
        overwrite: replace an existing file (else OutputExistsError).
        db: the dataset already loaded from ``dataroot``/``version`` (skips loading it again).

    Returns:
        The rows drawn, top to bottom: day, night, rain, each when the dataset has it.

    Raises:
        SianmsError for an unknown output suffix, a bad tile width or a dataset without scenes;
        DataFormatError (naming the file, record and field) for a bad table or a missing or
        undecodable image; OutputExistsError / OutputError for the output.
    """
    sheet_format(out_path)
    check_writable_output(Path(out_path), overwrite=overwrite)
    db = NuScenesDB(dataroot, version) if db is None else db
    rows = pick_rows(db)
    write_bytes(Path(out_path), sheet_bytes(render_contact_sheet(db, rows, tile_width), out_path))
    return rows
