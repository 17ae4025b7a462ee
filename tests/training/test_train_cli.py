"""`sianms train siamese` through the CLI: files, --json, refusing, resuming, errors as one line."""

import json

from typer.testing import CliRunner

from sianms_cli.cli import app

SMALL = ["--dim", "8", "--conv-channels", "8,8", "--hidden", "16", "--lr", "1e-3", "--batch-size", "4",
         "--device", "cpu"]


def invoke(*arguments):
    return CliRunner().invoke(app, ["train", "siamese", *arguments])


def test_train_writes_the_run_and_prints_json(tiny_caches, tmp_path):
    train, val = tiny_caches
    out = tmp_path / "run"
    done = invoke("--cache", str(train), "--val-cache", str(val), "--out", str(out), "--epochs", "2", "--quiet",
                  "--json", *SMALL)
    assert done.exit_code == 0, done.output
    result = json.loads(done.stdout)
    assert result["epochs_run"] == [1, 2] and result["metrics"]["epoch"] == 2
    assert result["dis_thr"] == result["metrics"]["val_dis_thr"]
    assert {"val_auc", "baseline_auc", "val_f1", "baseline_f1"} <= set(result["metrics"])
    assert {p.name for p in out.iterdir() if not p.name.startswith(".")} == {
        "checkpoint.pt", "config.json", "metrics.csv", "curves.png"}
    config = json.loads((out / "config.json").read_text())
    assert config["kind"] == "siamese" and config["dim"] == 8 and config["conv_channels"] == [8, 8]

    again = invoke("--cache", str(train), "--out", str(out), "--quiet", *SMALL)
    assert again.exit_code == 2 and again.stderr.startswith("error: ") and "--resume" in again.stderr

    resumed = invoke("--cache", str(train), "--val-cache", str(val), "--out", str(out), "--epochs", "3", "--quiet",
                     "--resume", *SMALL)
    assert resumed.exit_code == 0, resumed.output
    assert "trained epochs 3-3" in resumed.stdout and "baseline (mean-pooled ROI" in resumed.stdout


def test_user_errors_are_one_line(tmp_path):
    done = invoke("--cache", str(tmp_path / "missing"), "--out", str(tmp_path / "run"), "--quiet")
    assert done.exit_code == 2
    assert done.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'missing' / 'manifest.json'}: not found: not a `sianms prepare` cache "
        "(run `sianms prepare` first)"]
    bad = invoke("--cache", str(tmp_path), "--out", str(tmp_path / "run"), "--conv-channels", "8,x")
    assert bad.exit_code == 2 and "--conv-channels must be comma-separated integers" in bad.stderr


def test_sweep_over_d_tabulates_each_size(tiny_caches, tmp_path):
    train, val = tiny_caches
    done = invoke("--cache", str(train), "--val-cache", str(val), "--out", str(tmp_path / "sweep"), "--epochs", "1",
                  "--sweep-dims", "2,4", "--quiet", "--json", *SMALL)
    assert done.exit_code == 0, done.output
    rows = json.loads(done.stdout)["rows"]
    assert [row["dim"] for row in rows] == [2, 4] and rows[0]["parameters"] < rows[1]["parameters"]
    assert json.loads((tmp_path / "sweep" / "sweep.json").read_text())["rows"] == rows
    table = (tmp_path / "sweep" / "sweep.md").read_text().splitlines()
    assert table[0].startswith("| dim | parameters | val_auc") and len(table) == 4
    assert (tmp_path / "sweep" / "d4" / "checkpoint.pt").is_file()
    bad = invoke("--cache", str(train), "--out", str(tmp_path / "x"), "--sweep-dims", "4,4")
    assert bad.exit_code == 2 and "--sweep-dims must list distinct positive sizes" in bad.stderr
    again = invoke("--cache", str(train), "--val-cache", str(val), "--out", str(tmp_path / "sweep"), "--epochs", "1",
                   "--sweep-dims", "2,4", "--quiet", *SMALL)
    assert again.exit_code == 2 and again.stderr == (f"error: {tmp_path / 'sweep'} holds a sweep; pass --resume to "
                                                     "continue it or --overwrite to replace it\n")


def test_a_sweep_never_writes_over_what_it_did_not_write(tiny_caches, tmp_path):
    """sweep.md of the user's own was rewritten without --overwrite; now a folder holding anything
    a sweep does not write, or tables without a sweep's sweep.json, is refused, --overwrite or not."""
    train, val = tiny_caches
    for name, content in (("sweep.md", "my notes"), ("data.csv", "mine"), ("sweep.json", '{"mine": 1}')):
        out = tmp_path / name
        out.mkdir()
        (out / name).write_text(content)
        for flag in ("--resume", "--overwrite"):
            done = invoke("--cache", str(train), "--val-cache", str(val), "--out", str(out), "--epochs", "1",
                          "--sweep-dims", "2", "--quiet", flag, *SMALL)
            assert done.exit_code == 2 and done.stderr.startswith("error: ") and done.stderr.count("\n") == 1
            assert sorted(p.name for p in out.iterdir()) == [name] and (out / name).read_text() == content
