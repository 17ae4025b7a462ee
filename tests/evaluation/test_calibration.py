"""`sianms eval --thresholds-from`: every threshold chosen on a calibration split, never on the evaluated one.

The world is the shared 3-scene mini: the calibration split is mini_val (one scene), the
evaluated split mini_train (two scenes), both prepared without filled-in ground truth; the
siamese run is validated on the calibration cache, so its own dis_thr is the calibration's.
"""

from __future__ import annotations

import json
import shutil

import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.evaluation.calibration import THRESHOLDS_FILE, check_calibration, choose_dis_thr, read_calibration
from sianms_cli.evaluation.job import EvalConfig, run
from sianms_cli.evaluation.methods import split_name
from sianms_cli.training.run import load_checkpoint

SWEEP = "0.05,0.1,0.2,0.5,0.7"
METHODS = "vanilla,axis-nms,sianms,hybrid"
runner = CliRunner()


@pytest.fixture(scope="module")
def world(synthetic_dataroot, eval_inputs, tmp_path_factory):
    """The caches, a siamese run validated on the calibration cache, and the calibration's evaluation."""
    from types import SimpleNamespace

    from sianms_cli.prepare.config import PrepareConfig
    from sianms_cli.prepare.job import run as prepare
    from sianms_cli.training.siamese import SiameseConfig
    from sianms_cli.training.siamese import run as train_siamese

    data = synthetic_dataroot(scenes=3)
    folder = tmp_path_factory.mktemp("calibration")
    caches = {split: prepare(PrepareConfig(dataroot=str(data), version="v1.0-mini", split=split, fill_missed=False),
                             folder / f"cache-{split}").out for split in ("mini_val", "mini_train")}
    train_siamese(SiameseConfig(cache=str(eval_inputs.cache), val_cache=str(caches["mini_val"]), epochs=1, seed=1),
                  folder / "siamese")
    world = SimpleNamespace(data=data, caches=caches, siamese=folder / "siamese", fpointnet=eval_inputs.fpointnet,
                            folder=folder)
    run(config_of(world, "mini_val", nms_sweep=SWEEP), folder / "calib")
    world.calib = folder / "calib"
    return world


def config_of(world, split, **fields):
    return EvalConfig(**{"dataroot": str(world.data), "version": "v1.0-mini", "split": split,
                                "cache": str(world.caches[split]), "siamese": str(world.siamese),
                                "fpointnet": str(world.fpointnet), "methods": METHODS, "pictures": 0, **fields})


def thresholds(folder):
    return json.loads((folder / THRESHOLDS_FILE).read_text())


def edited_calibration(world, tmp_path, change):
    """A copy of the calibration evaluation whose thresholds.json ``change`` edited."""
    copy = shutil.copytree(world.calib, tmp_path / "calib-edited")
    record = thresholds(copy)
    change(record)
    (copy / THRESHOLDS_FILE).write_text(json.dumps(record))
    return copy


@pytest.fixture(scope="module")
def calibrated(world, tmp_path_factory):
    """mini_train evaluated with every threshold from the calibration."""
    out = tmp_path_factory.mktemp("calibrated") / "eval"
    return out, run(config_of(world, "mini_train", thresholds_from=str(world.calib)), out)


def test_the_calibration_split_chooses_dis_thr_as_the_siamese_training_does(world):
    record = thresholds(world.calib)
    trained = load_checkpoint(world.siamese / "checkpoint.pt").extra["dis_thr"]
    assert record["dis_thr"]["value"] == trained  # the training validated on this very cache
    assert record["dis_thr"]["pairs_true"] > 0 and 0 < record["dis_thr"]["f1"] <= 1
    table = json.loads((world.calib / "table.json").read_text())
    assert {family: choice["method"] for family, choice in record["nms"].items()} == table["best_nms"]
    assert record["chosen_on"]["split"] == "mini_val" and record["chosen_on"]["nms_sweep"] == SWEEP
    assert table["thresholds"]["nms"]["axis-nms"]["source"] == "this split"
    assert table["thresholds"]["calibration"] is None


def test_thresholds_come_from_the_calibration_even_where_the_evaluated_split_would_choose_otherwise(world, calibrated):
    out, result = calibrated
    chosen = thresholds(world.calib)["dis_thr"]["value"]
    own = thresholds(out)["dis_thr"]["value"]  # what mini_train's own labels choose, written for later use only
    assert own is not None and own != chosen
    marker = json.loads((out / "eval.json").read_text())
    assert marker["config"]["dis_thr"] == chosen
    calibration = read_calibration(world.calib)
    assert marker["config"]["thresholds_from"] == {"split": "mini_val", "sha256": calibration.sha256}
    assert marker["config"]["nms_sweep"] == SWEEP  # the calibration's sweep, --nms-sweep being left out
    used = result.table["thresholds"]
    assert used["dis_thr"] == {"value": chosen, "source": "calibration"}
    assert used["calibration"] == {"path": str(world.calib), "split": "mini_val",
                                   "split_scenes": thresholds(world.calib)["chosen_on"]["split_scenes"],
                                   "sha256": calibration.sha256}
    assert json.loads((out / "table.json").read_text())["thresholds"] == used
    assert "*best* = best car AP of its family on the calibration split mini_val" in (out / "table.md").read_text()
    rows = [row for path in sorted((out / "scenes").glob("*.parquet")) for row in pq.read_table(path).to_pylist()]
    distances = [row["distance"] for row in rows if row["kind"] == "sianms"]
    assert distances and max(distances) <= chosen  # the scenes matched at the calibration's dis_thr


def test_each_nms_family_is_reported_at_the_calibrations_choice_not_at_the_evaluated_splits(world, calibrated,
                                                                                              tmp_path):
    out, result = calibrated
    own_best = thresholds(out)["nms"]["axis-nms"]["method"]  # mini_train's own choice
    aps = result.table["regions"]["all"]
    worse = [method for method in result.table["methods"]
             if method.startswith("axis-nms") and aps[method]["car"]["AP"] < aps[own_best]["car"]["AP"]]
    assert worse  # variants mini_train's own labels would never pick
    other = worse[-1]

    def choose_other(record):
        record["nms"]["axis-nms"]["method"] = other
    calibration = edited_calibration(world, tmp_path, choose_other)
    again = shutil.copytree(out, tmp_path / "again")
    scenes = {path.name: path.stat().st_mtime_ns for path in (again / "scenes").iterdir()}
    rerun = run(config_of(world, "mini_train", thresholds_from=str(calibration)), again, overwrite=True)
    assert rerun.table["best_nms"]["axis-nms"] == other
    assert rerun.table["thresholds"]["nms"]["axis-nms"] == {"method": other, "iou": split_name(other)[1],
                                                            "source": "calibration"}
    assert {path.name: path.stat().st_mtime_ns for path in (again / "scenes").iterdir()} == scenes  # finish only
    assert thresholds(again) == thresholds(out)  # the split's own choices do not depend on the calibration


def _cli(world, out, split, *extra):
    return runner.invoke(app, ["eval", "--dataroot", str(world.data), "--split", split,
                               "--cache", str(world.caches[split]), "--siamese", str(world.siamese),
                               "--fpointnet", str(world.fpointnet), "--methods", METHODS, "--pictures", "0",
                               "--out", str(out), "--quiet", *extra])


def _other_dataset(record):
    record["chosen_on"]["dataset_sha256"] = "0" * 64


def _other_roi_size(record):
    record["chosen_on"]["prepare"]["roi_size"] = 14


def _picks_0_7(record):
    record["nms"]["axis-nms"]["method"] = "axis-nms@0.7"


def _no_dis_thr(record):
    record["dis_thr"] = {"value": None, "why": "no ground-truth pair among the overlap candidates"}


@pytest.mark.parametrize(("split", "change", "extra", "message"), [
    ("mini_val", None, [], ("--thresholds-from: {calib} was evaluated on split 'mini_val', which shares 1 scene(s) "
                           "with --split mini_val")),
    ("mini_train", _other_dataset, [], ("--thresholds-from: {calib} was made on another dataset, cache settings or "
                                       "networks (differs in: dataset_sha256)")),
    ("mini_train", _other_roi_size, [], "(differs in: prepare roi_size)"),
    ("mini_train", _no_dis_thr, [], "chose no dis_thr (no ground-truth pair among the overlap candidates)"),
    ("mini_train", _picks_0_7, ["--nms-sweep", "0.1"], ("--nms-sweep: the calibration chose axis-nms@0.7, which "
                                                       "this evaluation does not run")),
    ("mini_train", None, ["--dis-thr", "0.5"], "--dis-thr: --thresholds-from sets dis_thr"),
])
def test_a_calibration_that_may_not_set_the_thresholds_is_one_error_line(world, tmp_path, split, change, extra,
                                                                         message):
    calibration = world.calib if change is None else edited_calibration(world, tmp_path, change)
    out = tmp_path / "out"
    result = _cli(world, out, split, "--thresholds-from", str(calibration), *extra)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message.format(calib=calibration) in lines[0]
    assert not out.exists()


def test_a_calibration_that_is_not_a_finished_evaluation_is_named(world, tmp_path):
    with pytest.raises(DataFormatError, match="not a folder"):
        read_calibration(tmp_path / "missing")
    old = shutil.copytree(world.calib, tmp_path / "old")
    (old / THRESHOLDS_FILE).unlink()
    with pytest.raises(DataFormatError, match="predates thresholds.json; rerun it with --overwrite"):
        read_calibration(old)
    unfinished = shutil.copytree(world.calib, tmp_path / "unfinished")
    marker = json.loads((unfinished / "eval.json").read_text())
    (unfinished / "eval.json").write_text(json.dumps({**marker, "complete": False}))
    with pytest.raises(DataFormatError, match="field 'complete': the calibration evaluation is not complete"):
        read_calibration(unfinished)


@pytest.mark.parametrize(("change", "field"), [
    (lambda r: r.update(kind="other"), "kind"),
    (lambda r: r["dis_thr"].update(value=-1), "dis_thr.value"),
    (lambda r: r["nms"]["axis-nms"].update(method="rotated-nms@0.1"), "nms.axis-nms.method"),
    (lambda r: r["nms"]["axis-nms"].update(method="axis-nms@x"), "nms.axis-nms.method"),
    (lambda r: r["chosen_on"].update(split_scenes=[]), "chosen_on.split_scenes"),
    (lambda r: r["chosen_on"].pop("dataset_sha256"), "chosen_on.dataset_sha256"),
])
def test_an_edited_thresholds_file_is_named_by_field(world, tmp_path, change, field):
    with pytest.raises(DataFormatError, match=f"field '{field}'"):
        read_calibration(edited_calibration(world, tmp_path, change))


def test_a_family_the_calibration_did_not_evaluate_is_refused(world, tmp_path):
    def without_rotated(record):
        record["nms"].pop("rotated-nms", None)
    calibration = read_calibration(edited_calibration(world, tmp_path, without_rotated))
    resolved = {**calibration.chosen_on, "split": "mini_train", "split_scenes": ["elsewhere"],
                "methods": ["rotated-nms", "rotated-nms@0.1"]}
    with pytest.raises(SianmsError, match="did not evaluate rotated-nms"):
        check_calibration(calibration, resolved, calibration.chosen_on["prepare"], matchers_evaluated=False)


def test_no_dis_thr_is_chosen_on_a_cache_filled_with_ground_truth(eval_inputs):
    choice = choose_dis_thr(eval_inputs.cache, {"fill_missed": True}, encoder=None, default=1.0)
    assert choice["value"] is None and "--no-fill-missed" in choice["why"]
