"""`sianms eval` end to end on a generated mini: every method's results, metrics and table; resume; refusals."""

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from cache_records import record_again

from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.metrics.algo import calc_ap
from sianms_cli.metrics.evaluate import read_details
from sianms_cli.metrics.results import read_results
from sianms_cli.evaluation.job import EvalConfig, claim_output, run
from sianms_cli.evaluation.methods import METHODS
from sianms_cli.progress import SILENT
from sianms_cli.reporting.eval_table import format_cell
from sianms_cli.reporting.report import SCHEMA as REPORT_SCHEMA, ReportConfig, run as run_report
from sianms_cli.training.run import load_checkpoint, save_checkpoint


def config_of(inputs, **fields):
    values = dict(dataroot=str(inputs.dataroot), version="v1.0-mini", split=inputs.split, cache=str(inputs.cache),
                  siamese=str(inputs.siamese), fpointnet=str(inputs.fpointnet))
    return EvalConfig(**{**values, **fields})


@pytest.fixture(scope="module")
def evaluated(eval_inputs, tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "out"
    return out, run(config_of(eval_inputs, nms_sweep="0.1"), out)


def test_every_method_writes_valid_results_metrics_and_the_table(evaluated):
    out, result = evaluated
    marker = json.loads((out / "eval.json").read_text())
    assert marker["complete"] and marker["missing_scenes"] == [] and marker["scenes_expected"] == 2
    assert sorted(marker["pictures"]) == sorted(path.name for path in (out / "pictures").iterdir())
    assert marker["pictures"]
    names = list(METHODS) + ["axis-nms@0.1", "rotated-nms@0.1"]
    assert sorted(result.table["methods"]) == sorted(names)
    samples = None
    for name in names:
        results = read_results(out / f"results_{name}.json")
        samples = samples or set(results.sample_tokens)
        assert set(results.sample_tokens) == samples  # every sample listed, [] where nothing
        assert np.all(results.boxes["size"] > 0)
        metrics = json.loads((out / f"metrics_{name}.json").read_text())
        assert "all" in metrics["regions"] and "overlap" in metrics["regions"]
        curves = read_details(out / f"metrics_details_{name}.json")
        assert list(curves) == ["all", "overlap"] and len(curves["all"]) == 3 * 4  # paper classes x thresholds
        aps = [calc_ap(curves["all"][f"car:{th}"], 0.1, 0.1) for th in ("0.5", "1.0", "2.0", "4.0")]
        assert 100 * np.mean(aps) == pytest.approx(result.table["regions"]["all"][name]["car"]["AP"], abs=1e-9)
    assert not (out / "curves.json").exists() and (out / "pr_curves.png").is_file()
    counts = result.table["boxes"]
    assert counts["vanilla"] >= max(counts[name] for name in names)
    assert counts["hybrid"] <= counts["sianms"]
    assert "| Areas |" in (out / "table.md").read_text()


def test_the_report_of_a_real_evaluation_shows_its_table(evaluated, tmp_path):
    out, result = evaluated
    report = run_report(ReportConfig(eval=str(out)), tmp_path / "report")
    rows = [line.strip("| ").split(" | ") for line in report.markdown.splitlines()
            if line.startswith(("| All |", "| Overlap |"))]
    shown = {(row[0], row[1].removesuffix(" (best)")): row[2:6] + row[10:] for row in rows}
    for region, label in (("all", "All"), ("overlap", "Overlap")):
        for method in result.table["methods"]:
            figures = result.table["regions"][region][method]["car"]
            assert shown[(label, method)] == [*(format_cell(figures[c], c) for c in ("AP", "ATE", "ASE", "AOE")),
                                              str(figures["gt"]), str(figures["pred"])]
    assert {path.name for path in report.out.iterdir()} >= {"pr_curves.png", "tp_curves.png", "report.html"}
    same = run_report(ReportConfig(eval=str(out), baseline=str(out)), tmp_path / "gate")
    assert same.regressions == [] and len(same.content["comparison"]["cells"]) == 2 * 4 * len(result.table["methods"])


def test_the_oracle_matches_only_one_instance_and_sianms_is_scored_against_it(evaluated):
    out, result = evaluated
    tables = [pq.read_table(path).to_pylist() for path in sorted((out / "scenes").glob("*.parquet"))]
    rows = [row for table in tables for row in table]
    oracle = [row for row in rows if row["kind"] == "oracle"]
    assert oracle and all(row["correct"] for row in oracle)
    reid = result.table["reidentification"]
    assert reid["oracle"]["precision"] == 1.0 and reid["sianms"]["pairs_true"] == len(oracle)
    sianms, gated = reid["sianms"], reid["gated-sianms"]
    for matcher in (sianms, gated):
        assert (matcher["wrong_without_partner"] + matcher["wrong_partner_passed_over"]
                == matcher["pairs_matched"] - matcher["pairs_correct"])
    assert gated["pairs_matched"] + gated["gate_refused"] == sianms["pairs_matched"]
    assert gated["pairs_correct"] + gated["gate_refused_right"] == sianms["pairs_correct"]
    assert result.table["boxes"]["gated-sianms"] == result.table["boxes"]["sianms"] + gated["gate_refused"]
    single = [row for row in rows if row["kind"] == "single"]
    assert all(row["detection_b"] is None and row["translation"] is not None for row in single)


def test_a_rerun_resumes_and_an_interrupted_run_resumes_to_the_same_bytes(eval_inputs, evaluated, tmp_path):
    out, _ = evaluated
    again = run(config_of(eval_inputs, nms_sweep="0.1"), out)
    assert again.scenes_run == [] and len(again.scenes_skipped) == 2

    class Stop(SILENT.__class__):
        def advance(self, amount=1):
            raise KeyboardInterrupt

    stopped = tmp_path / "stopped"
    with pytest.raises(KeyboardInterrupt):
        run(config_of(eval_inputs, nms_sweep="0.1"), stopped, progress=Stop())
    marker = json.loads((stopped / "eval.json").read_text())
    assert not marker["complete"] and marker["scenes_finished"] == 1 and not (stopped / "table.json").exists()
    resumed = run(config_of(eval_inputs, nms_sweep="0.1"), stopped)
    assert len(resumed.scenes_run) == 1
    for path in sorted(out.glob("results_*.json")):
        assert (stopped / path.name).read_bytes() == path.read_bytes(), path.name
    for path in sorted((out / "scenes").glob("*.parquet")):  # equal but for the timings in the metadata
        assert pq.read_table(stopped / "scenes" / path.name).replace_schema_metadata(None).equals(
            pq.read_table(path).replace_schema_metadata(None)), path.name



def test_the_same_inputs_moved_elsewhere_resume_the_evaluation(eval_inputs, evaluated, tmp_path):
    """The cache prepared from a dataroot at another path and the runs trained on caches at
    other paths are the same inputs: eval.json's config (their fingerprints) is unchanged, so
    the finished evaluation is kept rather than refused as another one."""
    moved = tmp_path / "moved"
    shutil.copytree(eval_inputs.cache, moved / "cache")
    manifest_path = moved / "cache" / "manifest.json"
    manifest_path.write_text(json.dumps({**json.loads(manifest_path.read_text()), "dataroot": "/elsewhere/data"}))
    for name in ("siamese", "fpointnet"):
        shutil.copytree(getattr(eval_inputs, name), moved / name)
        checkpoint = load_checkpoint(moved / name / "checkpoint.pt")
        save_checkpoint(moved / name / "checkpoint.pt",
                        replace(checkpoint, config={**checkpoint.config, "cache": str(moved / "cache")}))
    out = tmp_path / "out"
    shutil.copytree(evaluated[0], out)
    run(config_of(eval_inputs, cache=str(moved / "cache"), siamese=str(moved / "siamese"),
                  fpointnet=str(moved / "fpointnet"), nms_sweep="0.1"), out)
    assert json.loads((out / "eval.json").read_text())["config"] == json.loads(
        (evaluated[0] / "eval.json").read_text())["config"]


def test_refusals_name_the_problem(eval_inputs, evaluated, tmp_path):
    out, _ = evaluated
    with pytest.raises(OutputExistsError, match=r"differs in: seed\)"):
        run(config_of(eval_inputs, seed=5, nms_sweep="0.1"), out)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "keep.txt").write_text("mine")
    with pytest.raises(OutputExistsError, match="not a sianms evaluation"):
        run(config_of(eval_inputs), foreign, overwrite=True)
    assert [path.name for path in foreign.iterdir()] == ["keep.txt"]  # no lock file left in it either
    with pytest.raises(DataFormatError, match="mini_val"):
        run(config_of(eval_inputs, split="mini_val"), tmp_path / "other")


def test_overwrite_with_other_methods_keeps_the_scenes(eval_inputs, evaluated, tmp_path):
    out, _ = evaluated
    copy = tmp_path / "copy"
    shutil.copytree(out, copy)
    scenes = {path.name: path.stat().st_mtime_ns for path in (copy / "scenes").glob("*.parquet")}
    result = run(config_of(eval_inputs, methods="vanilla,sianms"), copy, overwrite=True)
    assert result.scenes_run == [] and result.table["methods"] == ["vanilla", "sianms"]
    assert {path.name: path.stat().st_mtime_ns for path in (copy / "scenes").glob("*.parquet")} == scenes
    assert not (copy / "results_axis-nms.json").exists()
    assert (copy / "results_sianms.json").read_bytes() == (out / "results_sianms.json").read_bytes()


STALE_CONFIG = {"seed": 0, "split_scenes": ["scene-0001"]}
NEW_CONFIG = {"seed": 1, "split_scenes": ["scene-0001"]}  # another seed: the scenes are redone too


def stale_evaluation(out):
    """A hand-made evaluation folder of :data:`STALE_CONFIG` holding what `sianms eval` and
    `sianms report EVAL` write there (as a real one, tests/evaluation' ``evaluated``, shows)."""
    (out / "scenes").mkdir(parents=True)
    (out / "eval.json").write_text(json.dumps({"kind": "sianms-eval", "config": STALE_CONFIG, "complete": True,
                                               "pictures": ["0123abcd.png"]}))
    (out / ".eval.lock").write_text("1\n")
    for name in ("results_vanilla.json", "metrics_sianms.json", "metrics_details_gated-sianms.json",
                 "results_axis-nms@0.05.json", "metrics_details_rotated-nms@0.1.json", "table.json", "table.md",
                 "pr_curves.png", ".results_oracle.json.4242.0123abcd.partial",  # a killed run's temporary file
                 "scenes/scene-0001.parquet", "scenes/scene-0001.lock", "pictures/0123abcd.png"):
        (out / name).parent.mkdir(exist_ok=True)
        (out / name).write_text("stale")
    (out / "report").mkdir()
    (out / "report" / "report.json").write_text(json.dumps({"schema": REPORT_SCHEMA}))
    (out / "report" / "report.html").write_text("<html></html>")
    return out


def test_overwrite_replaces_a_stale_evaluation_and_its_report(tmp_path):
    out = stale_evaluation(tmp_path / "eval")
    assert claim_output(out, NEW_CONFIG, overwrite=True) is False
    assert sorted(path.name for path in out.iterdir()) == [".eval.lock", "eval.json", "scenes"]
    assert list((out / "scenes").iterdir()) == []
    marker = json.loads((out / "eval.json").read_text())
    assert marker["config"] == NEW_CONFIG and not marker["complete"]


@pytest.mark.parametrize("foreign", ["notes.txt", "photos/a.jpg", "results_final.json", "metrics_vanilla.json.bak",
                                     "report/", "report/notes.txt", "pictures/mine.jpg", "pictures/mine.png",
                                     "scenes/notes.txt",
                                     "scenes/my-notes.parquet", "scenes/scene-0002.parquet"])
def test_overwrite_refuses_a_folder_holding_what_eval_does_not_write(tmp_path, foreign):
    out = stale_evaluation(tmp_path / "eval")
    if foreign == "report/":  # a folder named report that is not a sianms report
        (out / "report" / "report.json").write_text(json.dumps({"schema": "my-own"}))
    else:
        (out / foreign).parent.mkdir(exist_ok=True)
        (out / foreign).write_text("precious")
    before = {path: path.read_bytes() for path in sorted(out.rglob("*")) if path.is_file()}
    with pytest.raises(OutputExistsError) as refused:
        claim_output(out, NEW_CONFIG, overwrite=True)
    shown = foreign.split("/")[0] if foreign.startswith(("photos", "report")) else foreign
    assert str(refused.value) == (f"{out}: not replaced: '{shown}' is not something sianms eval writes; "
                                  "remove it yourself or choose another --out")
    assert {path: path.read_bytes() for path in sorted(out.rglob("*")) if path.is_file()} == before


def test_an_evaluation_stopped_before_it_listed_its_pictures_may_have_any_png_replaced(tmp_path):
    out = stale_evaluation(tmp_path / "eval")
    (out / "eval.json").write_text(json.dumps({"kind": "sianms-eval", "config": STALE_CONFIG, "complete": False}))
    (out / "pictures" / "fedcba98.png").write_text("drawn before the run stopped")
    assert claim_output(out, NEW_CONFIG, overwrite=True) is False
    assert not (out / "pictures").exists()


def test_overwrite_refuses_a_link_even_to_what_eval_writes(tmp_path):
    out = stale_evaluation(tmp_path / "eval")
    mine = tmp_path / "mine"
    (out / "report").rename(mine)  # a sianms report, but not in the evaluation's folder
    (out / "report").symlink_to(mine)
    with pytest.raises(OutputExistsError, match="'report' is not something sianms eval writes"):
        claim_output(out, NEW_CONFIG, overwrite=True)
    assert (mine / "report.json").is_file() and (out / "results_vanilla.json").is_file()


def test_each_checkpoint_is_read_once(eval_inputs, evaluated, monkeypatch):
    """One read serves both the model and eval.json's fingerprint of it."""
    import torch

    reads = []
    load = torch.load
    monkeypatch.setattr(torch, "load", lambda path, *args, **kwargs: reads.append(Path(path)) or load(path, *args,
                                                                                                      **kwargs))
    run(config_of(eval_inputs, nms_sweep="0.1"), evaluated[0])
    assert sorted(reads) == sorted(Path(getattr(eval_inputs, name)) / "checkpoint.pt"
                                   for name in ("siamese", "fpointnet"))


def test_scenes_run_on_one_torch_thread_in_this_process_too(eval_inputs, tmp_path, monkeypatch):
    """Workers run scenes on one torch thread; so must a run without them, or the scenes' bytes
    would depend on --workers wherever a kernel sums in another order on more threads."""
    import torch

    from sianms_cli import processes
    from sianms_cli.evaluation import job

    seen = []
    write_scene = job.write_scene
    monkeypatch.setattr(job, "write_scene", lambda *args: seen.append(torch.get_num_threads()) or write_scene(*args))
    torch.set_num_threads(2)
    run(config_of(eval_inputs, methods="vanilla", pictures=0), tmp_path / "one", workers=1)
    assert seen and set(seen) == {processes.TASK_TORCH_THREADS}
    assert torch.get_num_threads() == 2


def test_two_workers_write_the_same_scenes_as_one(eval_inputs, evaluated, tmp_path):
    out, _ = evaluated
    result = run(config_of(eval_inputs, methods="vanilla", pictures=0), tmp_path / "two", workers=2)
    assert sorted(result.scenes_run) == sorted(path.stem for path in (out / "scenes").glob("*.parquet"))
    for path in sorted((out / "scenes").glob("*.parquet")):
        assert pq.read_table(tmp_path / "two" / "scenes" / path.name).replace_schema_metadata(None).equals(
            pq.read_table(path).replace_schema_metadata(None)), path.name


def test_a_nan_in_the_cache_is_blamed_on_the_cache_file(eval_inputs, tmp_path):
    cache = tmp_path / "cache"
    shutil.copytree(eval_inputs.cache, cache)
    path = sorted((cache / "frustums").glob("*.parquet"))[0]
    table = pq.read_table(path)
    rot_angle = table["rot_angle"].to_numpy().copy()
    rot_angle[3] = np.nan
    table = table.set_column(table.schema.get_field_index("rot_angle"), "rot_angle",
                             pa.array(rot_angle, table.schema.field("rot_angle").type))
    pq.write_table(table, path)
    record_again(cache)  # as if prepare had written it: the values are checked all the same
    record = table["detection_id"][3]
    with pytest.raises(DataFormatError, match=rf"^{path}: record {record}: field 'rot_angle': not a finite number"):
        run(config_of(eval_inputs, cache=str(cache), methods="vanilla"), tmp_path / "out")


def test_a_folder_claimed_by_a_run_killed_at_once_is_still_the_evaluations(tmp_path, monkeypatch):
    """eval.json is written before the scenes' folder: a kill between the two had left a folder
    that no later run, --overwrite or not, would take as an evaluation's."""
    from sianms_cli.evaluation import job

    def interrupted(path):
        raise KeyboardInterrupt

    out = tmp_path / "eval"
    out.mkdir()
    with monkeypatch.context() as patch:
        patch.setattr(job, "make_folder", interrupted)
        with pytest.raises(KeyboardInterrupt):
            claim_output(out, NEW_CONFIG, overwrite=False)
    assert claim_output(out, NEW_CONFIG, overwrite=False) is False
    assert (out / "scenes").is_dir()


@pytest.mark.parametrize("edited", ["yes", 1])
def test_an_eval_json_saying_complete_other_than_true_is_resumed_not_taken_as_finished(tmp_path, edited):
    out = tmp_path / "eval"
    out.mkdir()
    (out / "eval.json").write_text(json.dumps({"kind": "sianms-eval", "config": NEW_CONFIG, "complete": edited}))
    assert claim_output(out, NEW_CONFIG, overwrite=False) is False
    assert json.loads((out / "eval.json").read_text())["complete"] is False
    assert claim_output(out, NEW_CONFIG, overwrite=False) is False
    (out / "eval.json").write_text(json.dumps({"kind": "sianms-eval", "config": NEW_CONFIG, "complete": True}))
    assert claim_output(out, NEW_CONFIG, overwrite=False) is True


@pytest.mark.parametrize("flag, value, message", [
    ("dis_thr", float("inf"), "--dis-thr must be a finite number > 0, got inf"),
    ("max_distance", float("inf"), "--max-distance must be a finite number > 0, got inf"),
    ("max_distance", float("nan"), "--max-distance must be a finite number > 0, got nan"),
])
def test_a_flag_json_cannot_hold_is_refused(eval_inputs, flag, value, message):
    """--dis-thr inf ran and wrote "dis_thr": Infinity into eval.json, which strict JSON readers refuse."""
    with pytest.raises(SianmsError, match=message):
        config_of(eval_inputs, **{flag: value})


def test_an_eval_json_whose_config_is_not_an_object_is_named(tmp_path):
    out = tmp_path / "eval"
    out.mkdir()
    (out / "eval.json").write_text(json.dumps({"kind": "sianms-eval", "config": 5, "complete": "yes"}))
    with pytest.raises(DataFormatError, match=r"eval.json: field 'config': must be an object, got int"):
        claim_output(out, NEW_CONFIG, overwrite=True)


def test_a_cache_the_encoder_cannot_take_is_refused_before_anything_is_written(eval_inputs, tmp_path):
    """ROI features of another --roi-size were refused only in the first scene, after eval.json and
    scenes/ were written: the rerun with the right cache then met 'another config'."""
    from sianms_cli.data.siamese import cache_feature_shape
    from sianms_cli.evaluation.job import check_feature_shape

    check_feature_shape(Path(eval_inputs.cache), cache_feature_shape(eval_inputs.cache), str(eval_inputs.siamese))
    with pytest.raises(DataFormatError, match=r"manifest.json: field 'config.roi_size': ROI features of shape "
                                              r"\(\d+, \d+, \d+\), but the siamese encoder of .*checkpoint.pt takes "
                                              r"\(64, 5, 5\)"):
        check_feature_shape(Path(eval_inputs.cache), (64, 5, 5), str(eval_inputs.siamese))


@pytest.mark.parametrize("edit, field", [
    (lambda c: c.extra.update(mean_sizes="x"), "extra.mean_sizes"),
    (lambda c: c.extra.update(mean_sizes=[[4.0, 1.8, float("nan")]] * len(c.extra["classes"])), "extra.mean_sizes"),
    (lambda c: c.extra.update(classes=5), "extra.classes"),
    (lambda c: c.extra.update(classes=["car"]), "extra.mean_sizes"),  # one class, three size clusters
    (lambda c: c.config.update(num_points="x"), "config.num_points"),
    (lambda c: c.config.update(num_points=0), "config.num_points"),
    (lambda c: c.config.update(num_object_points=-5), "config.num_object_points"),
])
def test_a_hand_edited_fpointnet_checkpoint_is_named_with_its_field(eval_inputs, edit, field):
    """Each of these had ended eval in a traceback (ValueError, TypeError, IndexError, or a matrix
    product of mismatched shapes)."""
    from sianms_cli.evaluation.inference import FPointNetPredictor
    from sianms_cli.training.run import checkpoint_file, load_checkpoint

    path = checkpoint_file(eval_inputs.fpointnet)
    checkpoint = load_checkpoint(path, "fpointnet")
    FPointNetPredictor(checkpoint, path)
    edit(checkpoint)
    with pytest.raises(DataFormatError, match=f"checkpoint.pt: field '{field}': must be"):
        FPointNetPredictor(checkpoint, path)


def test_a_kill_while_overwrite_deletes_leaves_an_evaluation_to_resume_not_a_complete_one(tmp_path, monkeypatch):
    """The deletions had run under the old eval.json saying "complete": killed among them, the
    folder said complete over deleted files, and a rerun of the old config took it as finished."""
    from sianms_cli.evaluation import job

    out = stale_evaluation(tmp_path / "eval")
    deleted = []

    def killed_after_one(path, *args, **kwargs):
        if deleted:
            raise KeyboardInterrupt
        deleted.append(path)
        Path(path).unlink()

    with monkeypatch.context() as patch:
        patch.setattr(job.Path, "unlink", killed_after_one)
        with pytest.raises(KeyboardInterrupt):
            claim_output(out, NEW_CONFIG, overwrite=True)
    assert deleted and json.loads((out / "eval.json").read_text())["complete"] is False
    assert claim_output(out, STALE_CONFIG, overwrite=False) is False  # resumed, not taken as finished


def test_overwrite_redoes_a_complete_evaluation_of_the_same_config_keeping_its_scenes(tmp_path):
    out = stale_evaluation(tmp_path / "eval")
    assert claim_output(out, STALE_CONFIG, overwrite=False) is True
    assert claim_output(out, STALE_CONFIG, overwrite=True) is False
    assert sorted(path.name for path in out.iterdir()) == [".eval.lock", "eval.json", "scenes"]
    assert (out / "scenes" / "scene-0001.parquet").is_file()


@pytest.mark.parametrize("damage, problem", [
    ("table.json", "invalid JSON at line 1, column 1: Expecting value"),  # truncated to nothing
    ("table.md", "missing from a complete evaluation"),
])
def test_a_damaged_table_of_a_complete_evaluation_is_named_with_what_to_do(eval_inputs, evaluated, tmp_path,
                                                                           damage, problem):
    out = tmp_path / "copy"
    shutil.copytree(evaluated[0], out)
    if damage == "table.md":
        (out / damage).unlink()
    else:
        (out / damage).write_text("")
    with pytest.raises(DataFormatError) as raised:
        run(config_of(eval_inputs, nms_sweep="0.1"), out)
    assert str(raised.value) == (f"{out / damage}: {problem}; rerun with --overwrite, which redoes the finish stage "
                                 "and keeps the scenes")
    again = run(config_of(eval_inputs, nms_sweep="0.1"), out, overwrite=True)
    assert again.scenes_run == [] and again.manifest["complete"]
    assert (out / "table.json").read_bytes() == (evaluated[0] / "table.json").read_bytes()


def _edited_scene_table(evaluated, tmp_path, edit):
    path = sorted((evaluated[0] / "scenes").glob("*.parquet"))[0]
    table = edit(pq.read_table(path))
    edited = tmp_path / path.name
    pq.write_table(table, edited)
    return edited, table


def _with_value(name, row, value, kind=None):
    def edit(table):
        values = table[name].to_pylist()
        values[row] = value
        return table.set_column(table.schema.get_field_index(name), name,
                                pa.array(values, kind or table.schema.field(name).type))
    return edit


def _first_box(evaluated):
    path = sorted((evaluated[0] / "scenes").glob("*.parquet"))[0]
    dismissed = pq.read_table(path)["dismissed"].to_pylist()
    return dismissed.index(False)


@pytest.mark.parametrize("edit, field, problem", [
    (lambda table: table.drop_columns(["kind"]), "kind", "no such column"),
    (lambda table: table.set_column(table.schema.get_field_index("yaw"), "yaw", pa.array(
        [str(value) for value in table["yaw"].to_pylist()])), "yaw", "string where eval writes double"),
])
def test_a_scene_table_missing_a_column_is_named_not_read_as_nulls(evaluated, tmp_path, edit, field, problem):
    """A dropped column had been read as all nulls: eval finished "complete" with no box."""
    from sianms_cli.evaluation.finish import read_boxes

    edited, _ = _edited_scene_table(evaluated, tmp_path, edit)
    with pytest.raises(DataFormatError) as raised:
        read_boxes([edited], [])
    assert str(raised.value) == (f"{edited}: field '{field}': {problem}; delete it and rerun the same `sianms eval`, "
                                 "which evaluates its scene again")


@pytest.mark.parametrize("field, value, expected", [
    ("class", "tank", "a detection class"),  # had been a KeyError traceback
    ("kind", "twice", "single or sianms or oracle"),
    ("score", float("nan"), "a score in [0, 1]"),  # had been blamed on results_<method>.json, not yet written
    ("score", None, "a score in [0, 1]"),
    ("translation", None, "3 finite numbers for a box"),
    ("translation", [1.0, float("inf"), 2.0], "3 finite numbers for a box"),
    ("size", [-1.0, -1.0, -1.0], "3 positive numbers for a box"),
    ("yaw", float("nan"), "a finite number for a box"),
])
def test_a_bad_value_in_a_scene_table_is_named_by_file_row_and_field(evaluated, tmp_path, field, value, expected):
    from sianms_cli.evaluation.finish import read_boxes

    row = _first_box(evaluated)
    edited, table = _edited_scene_table(evaluated, tmp_path, _with_value(field, row, value))
    with pytest.raises(DataFormatError) as raised:
        read_boxes([edited], table["sample_token"].to_pylist())
    assert str(raised.value) == (f"{edited}: field '{field}': row {row}: expected {expected}; delete it and rerun "
                                 "the same `sianms eval`, which evaluates its scene again")
