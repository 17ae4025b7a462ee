import json

from typer.testing import CliRunner

from sianms_cli.cli import app

runner = CliRunner()


def test_prepare_cli_writes_a_cache_resumes_and_reports_errors(synthetic_dataroot, tmp_path):
    data = synthetic_dataroot()
    out = tmp_path / "cache"
    args = ["prepare", "--dataroot", str(data), "--version", "v1.0-mini", "--split", "mini_train", "--out", str(out),
            "--quiet"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "prepared 1 shard(s)" in result.output
    assert (out / "detections" / "scene-0061.parquet").is_file() and (out / "manifest.json").is_file()
    result = runner.invoke(app, args + ["--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["already_finished"] == ["scene-0061"] and report["complete"]

    result = runner.invoke(app, args + ["--detector", "rcnn"])
    assert result.exit_code == 2 and "unknown detector 'rcnn'" in result.output
    assert "Traceback" not in result.output
    result = runner.invoke(app, args + ["--seed", "1"])
    assert result.exit_code == 2 and "--overwrite" in result.output
    (tmp_path / "w.pth").write_bytes(b"junk")
    result = runner.invoke(app, args + ["--backbone", "resnet50-c4", "--weights", str(tmp_path / "w.pth"),
                                        "--overwrite"])
    assert result.exit_code == 2 and "w.pth" in result.output
    assert (out / "detections" / "scene-0061.parquet").is_file()  # a failed run deletes nothing
