"""Error lines quote at most 200 characters of an offending value, then say how long it was, and no line
is longer than LINE_LIMIT: a results field holding a 50 MB string had been echoed whole into a 52 MB line."""

import json
import re
import shutil

from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.cli._app import command
from sianms_cli.errors import LINE_LIMIT, DataFormatError, SianmsError, bounded_line, quote, shorten

runner = CliRunner()
HUGE = "x" * 1_000_000


def test_a_value_is_quoted_whole_up_to_200_characters_then_cut_and_counted():
    assert quote("car") == "'car'" and quote(3.5) == "3.5" and quote([1, 2]) == "[1, 2]"
    assert quote("y" * 200) == f"'{'y' * 200}'"
    assert quote("y" * 201) == f"'{'y' * 200}...' (201 characters in all)"
    assert quote(list(range(1000))).endswith("...' (4,890 characters in all)")
    assert shorten(HUGE) == f"{'x' * 200}... (1,000,000 characters in all)"


def test_a_records_token_and_field_are_bounded_as_values():
    error = DataFormatError("f.json", "bad", token=HUGE, field=HUGE)
    assert len(str(error)) < 600 and str(error).count("(1,000,000 characters in all)") == 2


def test_a_line_past_the_limit_keeps_its_start_and_its_end():
    line = "error: f.json: " + HUGE + "; rerun it"
    bounded = bounded_line(line)
    assert len(bounded) < LINE_LIMIT + 60
    assert bounded.startswith("error: f.json: xxx") and bounded.endswith("xxx; rerun it")
    assert f"... ({len(line) - LINE_LIMIT // 2 - LINE_LIMIT // 4:,} characters left out) ..." in bounded
    assert bounded_line("short") == "short"


def test_the_command_line_bounds_any_error_line(monkeypatch):
    """A message no reader quoted (a library's, echoing its input) is bounded where every error line goes out."""
    import typer

    probe = typer.Typer()

    @command("fail", probe)
    def fail() -> None:
        raise SianmsError("a library said: " + HUGE)

    @probe.command("other")
    def other() -> None:  # two commands, so that typer keeps "fail" a subcommand
        pass

    monkeypatch.delenv("RANK", raising=False)
    done = runner.invoke(probe, ["fail"])
    assert done.exit_code == 2 and done.output.count("\n") == 1 and len(done.output) < LINE_LIMIT + 60


def test_metrics_quotes_a_huge_config_value_in_a_short_line(tiny_dataroot, tmp_path):
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"dist_fcn": HUGE}))
    done = runner.invoke(app, ["metrics", "--dataroot", str(tiny_dataroot), "--split", "mini_train", "--results",
                               str(tmp_path / "results.json"), "--config", str(config)])
    assert done.exit_code == 2 and done.stderr.count("\n") == 1 and len(done.stderr) < 600, done.stderr[:300]
    assert f"'{'x' * 200}...' (1,000,000 characters in all)" in done.stderr


def test_train_quotes_a_huge_shard_name_of_a_manifest_in_a_short_line(eval_inputs, tmp_path):
    cache = shutil.copytree(eval_inputs.cache, tmp_path / "cache")
    manifest = json.loads((cache / "manifest.json").read_text())
    manifest["files"]["detections/" + HUGE] = {"rows": 1, "bytes": 1, "sha256": "0" * 64}
    (cache / "manifest.json").write_text(json.dumps(manifest))
    done = runner.invoke(app, ["train", "siamese", "--cache", str(cache), "--out", str(tmp_path / "run"), "--quiet"])
    assert done.exit_code == 2 and done.stderr.count("\n") == 1 and len(done.stderr) < 600, done.stderr[:300]
    assert re.search(r"'detections/x{189}\.\.\.' \(1,000,011 characters in all\) is not a shard file", done.stderr)
