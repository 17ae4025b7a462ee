import json

from typer.testing import CliRunner

from sianms_cli.cli import app

runner = CliRunner()


def arguments(inputs, out, *extra):
    return ["eval", "--dataroot", str(inputs.dataroot), "--split", inputs.split, "--cache", str(inputs.cache),
            "--siamese", str(inputs.siamese), "--fpointnet", str(inputs.fpointnet), "--out", str(out), "--quiet",
            *extra]


def test_eval_cli_prints_the_table_and_reports_bad_inputs_in_one_line(eval_inputs, tmp_path):
    out = tmp_path / "eval"
    result = runner.invoke(app, arguments(eval_inputs, out, "--methods", "vanilla,sianms", "--pictures", "1"))
    assert result.exit_code == 0, result.output
    assert "| Areas |" in result.output and "vanilla" in result.output
    assert len(list((out / "pictures").glob("*.png"))) <= 1
    assert (out / "metrics_details_sianms.json").is_file() and not (out / "curves.json").exists()
    report = runner.invoke(app, ["report", str(out), "--quiet"])
    assert report.exit_code == 0, report.output
    assert f"wrote {out / 'report' / 'report.html'}" in report.output
    result = runner.invoke(app, arguments(eval_inputs, out, "--methods", "vanilla,sianms", "--pictures", "1",
                                          "--json"))
    assert result.exit_code == 0 and json.loads(result.output)["complete"]

    for extra, message in ((["--methods", "nms"], "unknown method nms"),
                           (["--nms-sweep", "0.1,2"], "--nms-sweep"),
                           (["--axis-mode", "tilted"], "--axis-mode"),
                           (["--seed", "3"], "--overwrite")):
        result = runner.invoke(app, arguments(eval_inputs, out, *extra))
        assert result.exit_code == 2, (extra, result.output)
        assert result.output.startswith("error:") and message in result.output and "Traceback" not in result.output
    result = runner.invoke(app, arguments(eval_inputs, tmp_path / "other", "--split", "mini_val"))
    assert result.exit_code == 2 and "manifest.json" in result.output and "mini_val" in result.output
    (tmp_path / "bad.pt").write_bytes(b"junk")
    result = runner.invoke(app, arguments(eval_inputs, tmp_path / "other", "--siamese", str(tmp_path / "bad.pt")))
    assert result.exit_code == 2 and "bad.pt" in result.output and "Traceback" not in result.output


def test_overwrite_refuses_a_folder_holding_the_users_files_and_deletes_nothing(eval_inputs, tmp_path):
    out = tmp_path / "mine"
    (out / "photos").mkdir(parents=True)
    marker = json.dumps({"kind": "sianms-eval", "config": {"seed": 99}, "complete": True})
    (out / "eval.json").write_text(marker)  # another evaluation's, so --overwrite would replace it
    (out / "results_vanilla.json").write_text("stale")
    (out / "notes.txt").write_text("precious")
    (out / "photos" / "a.jpg").write_text("x")
    result = runner.invoke(app, arguments(eval_inputs, out, "--methods", "vanilla", "--overwrite"))
    assert result.exit_code == 2, result.output
    assert result.output == (f"error: {out}: not replaced: 'notes.txt' is not something sianms eval writes; "
                             "remove it yourself or choose another --out\n")
    assert (out / "notes.txt").read_text() == "precious" and (out / "photos" / "a.jpg").read_text() == "x"
    assert (out / "eval.json").read_text() == marker and (out / "results_vanilla.json").read_text() == "stale"
