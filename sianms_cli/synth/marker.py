"""The provenance marker at the top of a dataroot `sianms synth` wrote: what wrote it, with which
config, on which numeric platform. Written and read here, apart from the generator, so that
readers (`sianms info`) need not import the world."""

from __future__ import annotations

from pathlib import Path

from sianms_cli import __version__, io
from sianms_cli.errors import DataFormatError
from sianms_cli.provenance import numeric_platform

MARKER_NAME = "sianms-synth.json"
MARKER_KIND = "sianms synth dataroot"


def make_marker(config: dict) -> dict:
    """The marker of a dataroot written here, now, with the resolved ``config``."""
    return {"kind": MARKER_KIND, "sianms_version": __version__, "config": config, "platform": numeric_platform()}


def read_marker(dataroot: str | Path) -> dict | None:
    """The marker of ``dataroot``; None when it has no valid one (a real dataset, a damaged file)."""
    path = Path(dataroot) / MARKER_NAME
    if path.is_symlink() or not path.is_file():
        return None
    try:
        marker = io.read_json(path)
    except DataFormatError:
        return None
    return marker if isinstance(marker, dict) and marker.get("kind") == MARKER_KIND else None
