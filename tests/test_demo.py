"""`sianms demo`: the stages end to end on a tiny profile, resume after an interrupt, the folder rules."""

import json
import os
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest
from typer.testing import CliRunner

import sianms_cli.demo as demo
from sianms_cli.cli import app
from sianms_cli.demo import DemoConfig, run
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.io import FolderBusyError, exclusive_lock

runner = CliRunner()
TINY = replace(demo.QUICK, scene_seconds=1.0, siamese_epochs=1, fpointnet_epochs=1, num_points=64,
               num_object_points=32, nms_sweep="0.1")
REAL_FPOINTNET = demo.RUNNERS["fpointnet"]


@pytest.fixture(scope="module")
def interrupted_then_resumed(tmp_path_factory):
    """A demo on the quick profile cut to two 2-key-frame scenes (seconds), interrupted in
    its F-PointNets stage, then rerun: (stage events of the first run, its record, the rerun's result)."""
    out = tmp_path_factory.mktemp("demo") / "demo"
    events = []

    def interrupted(*args):
        raise KeyboardInterrupt

    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(demo.PROFILES, "quick", TINY)
        patch.setitem(demo.RUNNERS, "fpointnet", interrupted)
        with pytest.raises(KeyboardInterrupt):
            run(DemoConfig(quick=True, seed=3, train_fpointnet=True), out,
                on_stage=lambda stage, event, seconds: events.append((stage, event)))
        record = json.loads((out / "demo.json").read_text())
        patch.setitem(demo.RUNNERS, "fpointnet", REAL_FPOINTNET)
        result = run(DemoConfig(quick=True, seed=3, train_fpointnet=True), out)
    return events, record, result


def test_an_interrupted_demo_resumes_at_the_stage_it_was_in(interrupted_then_resumed):
    events, record, result = interrupted_then_resumed
    assert not record["complete"] and events[-1] == ("fpointnet", "start")
    assert sorted(record["stages"]) == sorted(["synth", "prepare-train", "prepare-val", "siamese"])
    assert result.stages_skipped == ["synth", "prepare-train", "prepare-val", "siamese"]
    assert result.stages_run == ["fpointnet", "eval", "report"]
    assert (result.out / "eval" / "report" / "report.html").is_file()
    assert result.manifest["complete"] and result.table["table_class"] == "car"
    assert "rotated-nms@0.1" in result.table["methods"] and "sianms" in result.table["methods"]
    assert json.loads((result.out / "data" / "sianms-synth.json").read_text())["config"]["seed"] == 3
    assert json.loads((result.out / "eval" / "eval.json").read_text())["config"]["seed"] == 3
    shares = demo.stage_shares(result.manifest)
    assert list(shares) == list(demo.STAGES) and sum(shares.values()) == pytest.approx(1.0)


def test_the_cli_on_a_finished_demo_skips_every_stage_and_prints_the_table(interrupted_then_resumed, monkeypatch):
    monkeypatch.setitem(demo.PROFILES, "quick", TINY)
    out = str(interrupted_then_resumed[2].out)
    result = runner.invoke(app, ["demo", "--quick", "--out", out, "--seed", "3", "--train-fpointnet"])
    assert result.exit_code == 0, result.output
    assert "| Areas |" in result.stdout and "wall time by stage: synth" in result.stdout
    assert f"report: {out}/eval/report/report.html" in result.stdout
    assert "[1/7] synth: done earlier" in result.stderr
    result = runner.invoke(app, ["demo", "--quick", "--out", out, "--seed", "3", "--train-fpointnet", "--json",
                                 "--quiet"])
    report = json.loads(result.stdout)
    assert report["config"]["profile"] == "quick" and set(report["stages"]) == set(demo.STAGES)
    assert report["table"] == interrupted_then_resumed[2].table
    result = runner.invoke(app, ["demo", "--quick", "--out", out, "--train-fpointnet", "--json"])
    assert result.exit_code == 2 and result.stderr.startswith("error:") and "differs in: seed" in result.stderr


def test_more_epochs_with_overwrite_redo_only_fpointnet_eval_and_report(interrupted_then_resumed, monkeypatch,
                                                                        tmp_path):
    monkeypatch.setitem(demo.PROFILES, "quick", TINY)
    out = tmp_path / "demo"
    shutil.copytree(interrupted_then_resumed[2].out, out)
    result = runner.invoke(app, ["demo", "--quick", "--out", str(out), "--seed", "3", "--train-fpointnet",
                                 "--fpointnet-epochs", "2", "--overwrite"])
    assert result.exit_code == 0, result.output
    assert "[4/7] siamese: done earlier" in result.stderr and "[5/7] fpointnet: done in" in result.stderr
    assert len((out / "fpointnet" / "metrics.csv").read_text().splitlines()) == 1 + 2  # header, 2 epochs


def test_an_earlier_demo_of_another_config_is_replaced_only_when_asked_and_only_if_all_its_own(tmp_path):
    out = tmp_path / "demo"
    demo.claim_output(out, DemoConfig(seed=1).resolved(), overwrite=False)
    (out / "data").mkdir()
    with pytest.raises(OutputExistsError, match="differs in: seed"):
        demo.claim_output(out, DemoConfig(seed=2).resolved(), overwrite=False)
    (out / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="notes.txt"):
        demo.claim_output(out, DemoConfig(seed=2).resolved(), overwrite=True)
    (out / "notes.txt").unlink()
    record = demo.claim_output(out, DemoConfig(seed=2).resolved(), overwrite=True)
    assert record["config"]["seed"] == 2 and sorted(p.name for p in out.iterdir()) == ["demo.json"]


def test_a_folder_that_is_not_a_demo_is_never_touched(tmp_path):
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(OutputExistsError, match="not a sianms demo"):
        demo.claim_output(tmp_path, DemoConfig().resolved(), overwrite=True)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputExistsError, match="not a folder"):
        demo.claim_output(tmp_path / "file", DemoConfig().resolved(), overwrite=True)


def test_a_demo_folder_in_use_is_refused_and_a_refused_folder_gets_no_lock_file(tmp_path):
    """Two demos into one folder had run side by side, each rewriting the other's stages and demo.json."""
    out = tmp_path / "demo"
    with exclusive_lock(out / demo.LOCK, what=str(out)):
        with pytest.raises(FolderBusyError) as busy:
            run(DemoConfig(quick=True), out)
    assert str(busy.value) == f"{out} is in use by another sianms process (pid {os.getpid()})"
    assert sorted(path.name for path in out.iterdir()) == [demo.LOCK]
    record = demo.claim_output(out, DemoConfig().resolved(), overwrite=False)  # the lock alone is no foreign file
    assert record["complete"] is False
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "keep.txt").write_text("x")
    with pytest.raises(OutputExistsError, match="not a sianms demo"):
        run(DemoConfig(quick=True), mine)
    assert sorted(path.name for path in mine.iterdir()) == ["keep.txt"]


@pytest.mark.parametrize(("stages", "message"), [
    ("x", "field 'stages': must be an object, got str"),
    ({"eval": None}, "field 'stages.eval': must be an object with a true or false 'done'"),
    ({"eval": {"done": True, "seconds": "abc"}}, "field 'stages.eval.seconds': must be a number of seconds >= 0, "
                                                 "got 'abc'"),
    ({"eval": {"done": True, "seconds": float("nan")}}, "field 'stages.eval.seconds': must be a number"),
])
def test_a_damaged_demo_record_is_named_with_its_field(tmp_path, stages, message):
    out = tmp_path / "demo"
    record = demo.claim_output(out, DemoConfig().resolved(), overwrite=False)
    (out / "demo.json").write_text(json.dumps({**record, "stages": stages}))
    with pytest.raises(DataFormatError, match=f"demo.json: {message}"):
        demo.claim_output(out, DemoConfig().resolved(), overwrite=False)


def test_profiles_and_overrides():
    assert DemoConfig().settings == demo.DEFAULT and DemoConfig(quick=True).settings == demo.QUICK
    custom = DemoConfig(scenes=4, siamese_epochs=2, fpointnet_epochs=5, train_fpointnet=True).settings
    assert (custom.scenes, custom.siamese_epochs, custom.fpointnet_epochs) == (4, 2, 5)
    assert demo.DEFAULT.min_box_height == pytest.approx(25.0 * demo.DEFAULT.image_scale)
    seeds = DemoConfig().run_seed, DemoConfig(quick=True).run_seed, DemoConfig(quick=True, seed=0).run_seed
    assert seeds == (0, 1, 0)
    resolved = DemoConfig(quick=True, seed=4).resolved()
    assert resolved["profile"] == "quick" and resolved["seed"] == 4 and resolved["scenes"] == demo.QUICK.scenes
    assert resolved["version"] == "v1.0-mini" and DemoConfig().splits == ("mini_train", "mini_val")
    larger = DemoConfig(version="v1.0-trainval", scenes=40)
    assert larger.splits == ("train", "val") and larger.settings.scenes == 40
    for kwargs, flag in (({"seed": -1}, "--seed"), ({"scenes": 1}, "--scenes"), ({"scenes": 11}, "--scenes"),
                         ({"version": "v1.0-trainval", "scenes": 851}, "--scenes"),
                         ({"version": "v1.0-test"}, "--version"),
                         ({"fpointnet_epochs": 0, "train_fpointnet": True}, "--fpointnet-epochs"),
                         ({"fpointnet_epochs": 3}, "--fpointnet-epochs needs --train-fpointnet"),
                         ({"precision": "fp16"}, "--precision must be fp32 or bf16")):
        with pytest.raises(SianmsError, match=flag):
            DemoConfig(**kwargs)


def test_overwrite_keeps_the_stages_before_the_first_one_the_change_affects(tmp_path):
    out = tmp_path / "demo"
    record = demo.claim_output(out, DemoConfig(train_fpointnet=True).resolved(), overwrite=False)
    for stage in demo.STAGES:  # empty folders: what is in each is its command's to recognise (test below)
        if stage != "report":  # inside eval's: that would not be empty
            (out / demo.FOLDERS[stage]).mkdir(parents=True, exist_ok=True)
        record["stages"][stage] = {"done": True, "seconds": 1.0}
    (out / "demo.json").write_text(json.dumps(record))
    more_epochs = DemoConfig(fpointnet_epochs=demo.DEFAULT.fpointnet_epochs + 2, train_fpointnet=True).resolved()
    with pytest.raises(OutputExistsError, match="differs in: fpointnet_epochs"):
        demo.claim_output(out, more_epochs, overwrite=False)
    record = demo.claim_output(out, more_epochs, overwrite=True)
    kept = ["synth", "prepare-train", "prepare-val", "siamese"]
    assert list(record["stages"]) == kept and record["config"] == more_epochs and not record["complete"]
    assert sorted(p.name for p in out.iterdir()) == sorted(["demo.json", *(demo.FOLDERS[s] for s in kept)])
    assert demo.first_changed_stage(more_epochs, DemoConfig(seed=1).resolved()) == 0
    assert demo.first_changed_stage(more_epochs, more_epochs) == len(demo.STAGES)
    bf16 = DemoConfig(precision="bf16").resolved()
    assert demo.first_changed_stage(DemoConfig().resolved(), bf16) == demo.STAGES.index("siamese")
    trained = DemoConfig(train_fpointnet=True).resolved()
    assert demo.first_changed_stage(DemoConfig().resolved(), trained) == demo.STAGES.index("fpointnet")
    assert DemoConfig().stages == tuple(stage for stage in demo.STAGES if stage != "fpointnet")


def test_the_quick_demo_evaluates_the_zoo_detector_and_tells_the_methods_apart(tmp_path):
    """The quick demo as typed: no F-PointNets stage, the zoo's detector in eval; car AP above zero
    in both regions, duplicates in the overlap that vanilla keeps and NMS removes."""
    result = runner.invoke(app, ["demo", "--quick", "--out", str(tmp_path / "demo"), "--threads", "2"])
    assert result.exit_code == 0, result.output
    assert "fpointnet" not in result.stderr and "[6/6] report: done in" in result.stderr
    table = json.loads((tmp_path / "demo" / "eval" / "table.json").read_text())
    assert json.loads((tmp_path / "demo" / "demo.json").read_text())["config"]["fpointnet"] == demo.ZOO_FPOINTNET
    assert not (tmp_path / "demo" / "fpointnet").exists()
    for region in ("all", "overlap"):
        assert table["regions"][region]["vanilla"]["car"]["AP"] > 0, region
    duplicates = table["duplicates"]
    assert duplicates["vanilla"]["overlap"]["car"] > duplicates["axis-nms"]["overlap"]["car"]


def test_a_trainval_demo_synthesises_trainval_names_and_prepares_its_train_and_val_splits(tmp_path, monkeypatch):
    def stop(*args):
        raise KeyboardInterrupt

    monkeypatch.setitem(demo.PROFILES, "quick", TINY)
    monkeypatch.setitem(demo.RUNNERS, "siamese", stop)
    out = tmp_path / "demo"
    with pytest.raises(KeyboardInterrupt):
        run(DemoConfig(quick=True, version="v1.0-trainval", scenes=3), out)
    assert (out / "data" / "v1.0-trainval").is_dir()
    train = json.loads((out / "cache-train" / "manifest.json").read_text())["config"]
    val = json.loads((out / "cache-val" / "manifest.json").read_text())["config"]
    assert (train["version"], train["split"], val["version"], val["split"]) == ("v1.0-trainval", "train",
                                                                                 "v1.0-trainval", "val")
    assert (len(train["split_scenes"]), len(val["split_scenes"])) == (2, 1)  # round(3 x 150 / 850) = 1
    record = json.loads((out / "demo.json").read_text())
    assert record["config"]["version"] == "v1.0-trainval" and not record["complete"]


def test_match_geometry_reads_a_finished_demo(interrupted_then_resumed):
    out, table = interrupted_then_resumed[2].out, interrupted_then_resumed[2].table
    script = Path(__file__).resolve().parents[1] / "scripts" / "match_geometry.py"
    result = subprocess.run([sys.executable, str(script), str(out)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    counts = {line.split()[2]: int(line.split()[1]) for line in result.stdout.splitlines()}
    reid = table["reidentification"]["sianms"]
    assert counts.get("right", 0) == reid["pairs_correct"]
    assert counts.get("wrong", 0) == reid["pairs_matched"] - reid["pairs_correct"]


def test_overwrite_deletes_no_file_in_a_stage_folder_that_its_command_did_not_write(interrupted_then_resumed,
                                                                                  tmp_path, monkeypatch):
    """Each stage's folder is checked by its own command's rule before any is deleted (a note in
    siamese/ and a folder of plots in eval/ had been deleted with them), and demo.json says the
    replaced stages are to do before the first is deleted (a kill while deleting had left it
    saying 'complete' over a half-deleted dataset)."""
    out = tmp_path / "demo"
    shutil.copytree(interrupted_then_resumed[2].out, out)
    before = (out / "demo.json").read_bytes()
    other = {**json.loads(before)["config"], "seed": 99}
    for mine, named in (("siamese/notes.txt", "siamese/notes.txt"), ("eval/my-plots/fig.txt", "eval/my-plots"),
                        ("cache-val/frustums/mine.parquet", "cache-val/frustums/mine.parquet"),
                        ("data/maps/mine.png", "data/maps/mine.png"), ("eval/report/notes.md", "eval/report")):
        (out / mine).parent.mkdir(exist_ok=True)
        (out / mine).write_text("mine")
        with pytest.raises(OutputExistsError, match=f"it holds {named}, which the demo did not write"):
            demo.claim_output(out, other, overwrite=True)
        assert (out / mine).read_text() == "mine" and (out / "demo.json").read_bytes() == before
        (out / mine).unlink()
        if "my-plots" in mine:
            (out / mine).parent.rmdir()

    def interrupted(path, *args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setattr(demo.shutil, "rmtree", interrupted)
        with pytest.raises(KeyboardInterrupt):
            demo.claim_output(out, other, overwrite=True)
    record = json.loads((out / "demo.json").read_text())
    assert record["config"] == other and not record["complete"] and record["stages"] == {}
    assert record["replacing"] == list(demo.STAGES)
    finished = demo.claim_output(out, other, overwrite=False)  # the rerun, as typed: it finishes the deletion
    assert finished == {key: value for key, value in record.items() if key != "replacing"}
    assert sorted(p.name for p in out.iterdir()) == [".demo.lock", "demo.json"]  # the lock: the demo ran here
    assert "replacing" not in json.loads((out / "demo.json").read_text())
