"""A path that is not valid UTF-8 is refused at the flag that names it, by every command, before anything
is written: `prepare --out $'x\\xff'` had written a cache that train and eval then failed to read with a
UnicodeEncodeError traceback."""

import os

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app

runner = CliRunner()
BAD = os.fsdecode(b"x\xff")  # as Python hands an argument holding the byte 0xff to the program


@pytest.mark.parametrize("arguments, flag, where", [
    (["synth", "--out", "{bad}", "--scenes", "1"], "--out", "out/"),
    (["prepare", "--dataroot", "data", "--split", "mini_train", "--out", "{bad}"], "--out", "out/"),
    (["prepare", "--dataroot", "data", "--split", "mini_train", "--out", "{ok}", "--detector", "file:{bad}.json"],
     "--detector", "file:out/"),
    (["train", "siamese", "--cache", "{bad}", "--out", "{ok}"], "--cache", "out/"),
    (["train", "fpointnet", "--cache", "cache", "--out", "{bad}"], "--out", "out/"),
    (["eval", "--dataroot", "d", "--split", "s", "--cache", "c", "--siamese", "s", "--fpointnet", "f",
      "--out", "{bad}"], "--out", "out/"),
    (["report", "{bad}"], "EVAL", "out/"),
    (["report", "e", "--baseline", "{bad}", "--out", "{ok}"], "--baseline", "out/"),
    (["metrics", "--dataroot", "d", "--split", "s", "--results", "r.json", "--out", "{bad}"], "--out", "out/"),
    (["info", "--dataroot", "{bad}"], "--dataroot", "out/"),
    (["demo", "--out", "{bad}"], "--out", "out/"),
])
def test_a_path_that_is_not_utf8_is_refused_at_its_flag(tmp_path, monkeypatch, arguments, flag, where):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out").mkdir()
    values = [argument.format(bad=f"out/{BAD}", ok="out/fine") for argument in arguments]
    done = runner.invoke(app, values)
    assert done.exit_code == 2, done.output
    assert done.stderr == (f"error: {flag}: {where}x\\xff{'.json' if flag == '--detector' else ''} is not valid "
                           f"UTF-8 (byte 0xff at {len(where) + 1}); sianms records its paths as text: rename it or "
                           "choose another path\n")
    assert list((tmp_path / "out").iterdir()) == []  # nothing written
