"""What a training does with bad input: an incomplete or damaged cache is refused before the run
folder exists, and a run that fails before its first checkpoint leaves nothing that blocks the next."""

import json
import shutil

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.data.cache import write_manifest
from sianms_cli.errors import SianmsError
from sianms_cli.training import siamese
from sianms_cli.training.run import CHECKPOINT, CONFIG, FOLDER_LOCK_NAME, Checkpoint, RunFolder

SIAMESE = ["--dim", "8", "--conv-channels", "8,8", "--hidden", "16", "--batch-size", "4", "--device", "cpu",
           "--epochs", "1", "--quiet"]
FPOINTNET = ["--num-points", "32", "--num-object-points", "16", "--batch-size", "8", "--min-box-height", "0",
             "--device", "cpu", "--epochs", "1", "--quiet"]


def invoke(*arguments):
    return CliRunner().invoke(app, ["train", *arguments])


def save_epoch(run):
    run.save(Checkpoint(kind="siamese", config=run.config, epoch=1, model={}), curves=False)


def entries(path):
    return sorted(p.name for p in path.iterdir())


# --------------------------------------------------------------------------- the run folder


def test_a_run_failing_before_its_first_checkpoint_removes_the_folder_it_made(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(SianmsError, match="bad data"):
        with RunFolder.open(out, kind="siamese", config={"cache": "a"}):
            (out / "multiview").mkdir()
            (out / "multiview" / "s.parquet").write_bytes(b"x")
            raise SianmsError("bad data")
    assert not out.exists()


def test_in_a_folder_it_did_not_make_it_removes_only_its_own_entries(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    with pytest.raises(SianmsError):
        with RunFolder.open(out, kind="siamese", config={"cache": "a"}):
            assert entries(out) == [FOLDER_LOCK_NAME, CONFIG]
            raise SianmsError("bad data")
    assert entries(out) == []
    (out / FOLDER_LOCK_NAME).touch()  # left by an earlier run: not this run's to delete
    with pytest.raises(SianmsError):
        with RunFolder.open(out, kind="siamese", config={"cache": "a"}):
            raise SianmsError("bad data")
    assert entries(out) == [FOLDER_LOCK_NAME]


def test_a_run_failing_after_a_checkpoint_or_interrupted_keeps_its_folder(tmp_path):
    with pytest.raises(SianmsError):
        with RunFolder.open(tmp_path / "saved", kind="siamese", config={"cache": "a"}) as run:
            save_epoch(run)
            raise SianmsError("later epoch")
    assert {CONFIG, CHECKPOINT} <= set(entries(tmp_path / "saved"))
    with pytest.raises(KeyboardInterrupt):
        with RunFolder.open(tmp_path / "stopped", kind="siamese", config={"cache": "a"}):
            raise KeyboardInterrupt
    assert entries(tmp_path / "stopped") == [FOLDER_LOCK_NAME, CONFIG]


def test_resuming_a_run_without_checkpoint_compares_its_config_json(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        with RunFolder.open(out, kind="siamese", config={"cache": "a", "epochs": 2, "lr": 0.1}):
            raise KeyboardInterrupt  # stopped in its first epoch: config.json, no checkpoint
    with pytest.raises(SianmsError) as error:
        RunFolder.open(out, kind="siamese", config={"cache": "a", "epochs": 2, "lr": 0.2}, resume=True)
    assert str(error.value) == (f"cannot resume {out}: the config differs in lr (pass the same options, "
                                "or --overwrite to start afresh)")
    with pytest.raises(SianmsError, match="differs in kind"):
        RunFolder.open(out, kind="fpointnet", config={"cache": "a", "epochs": 2, "lr": 0.1}, resume=True)
    # The cache spelled otherwise ("./a", or moved): its content, not its path, is the run's input.
    resumed = RunFolder.open(out, kind="siamese", config={"cache": "./a", "epochs": 5, "lr": 0.1}, resume=True,
                             may_differ=("epochs",))
    assert resumed.resumed is None  # nothing to resume: starts afresh, in the same run
    with pytest.raises(SianmsError):
        with resumed:
            raise SianmsError("bad data")
    assert json.loads((out / CONFIG).read_text()) == {"kind": "siamese", "cache": "./a", "epochs": 5, "lr": 0.1}


def test_a_run_made_before_a_setting_existed_resumes_with_the_value_it_had(tmp_path):
    out = tmp_path / "run"
    with pytest.raises(KeyboardInterrupt):
        with RunFolder.open(out, kind="fpointnet", config={"cache": "a", "lr": 0.1}):
            raise KeyboardInterrupt
    RunFolder.open(out, kind="fpointnet", config={"cache": "a", "lr": 0.1, "weight": 1.0}, resume=True,
                   added={"weight": 1.0})
    with pytest.raises(SianmsError, match="the config differs in weight"):
        RunFolder.open(out, kind="fpointnet", config={"cache": "a", "lr": 0.1, "weight": 3.0}, resume=True,
                       added={"weight": 1.0})


# --------------------------------------------------------------------------- the commands


@pytest.fixture
def incomplete_cache(tiny_caches, tmp_path):
    """A copy of the tiny training cache whose manifest expects one more shard than it holds."""
    cache = shutil.copytree(tiny_caches[0], tmp_path / "incomplete")
    manifest = json.loads((cache / "manifest.json").read_text())
    write_manifest(cache, manifest["config"], [*manifest["config"]["split_scenes"], "scene-9999"],
                   manifest["dataroot"])
    return cache


@pytest.mark.parametrize("kind, flags", [("siamese", SIAMESE), ("fpointnet", FPOINTNET)])
def test_an_incomplete_cache_is_refused_before_the_run_folder_exists(incomplete_cache, tiny_caches, tmp_path,
                                                                     kind, flags):
    out = tmp_path / "run"
    expected = (f"error: {incomplete_cache / 'manifest.json'}: field 'complete': the cache is not complete "
                "(1 of 2 shards missing); rerun `sianms prepare` with the same flags to finish it")
    for caches in (["--cache", str(incomplete_cache)],
                   ["--cache", str(tiny_caches[0]), "--val-cache", str(incomplete_cache)]):
        done = invoke(kind, *caches, "--out", str(out), *flags)
        assert done.exit_code == 2 and done.stderr.strip().splitlines() == [expected]
        assert not out.exists()


@pytest.mark.parametrize("kind, flags", [("siamese", SIAMESE), ("fpointnet", FPOINTNET)])
def test_a_folder_without_manifest_is_not_a_cache(tiny_caches, tmp_path, kind, flags):
    cache = shutil.copytree(tiny_caches[0], tmp_path / "copy", ignore=shutil.ignore_patterns("manifest.json"))
    done = invoke(kind, "--cache", str(cache), "--out", str(tmp_path / "run"), *flags)
    assert done.exit_code == 2 and done.stderr.strip().splitlines() == [
        f"error: {cache / 'manifest.json'}: not found: not a `sianms prepare` cache (run `sianms prepare` first)"]
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("kind, flags, name", [("siamese", SIAMESE, "detections"),
                                               ("fpointnet", FPOINTNET, "frustums")])
def test_a_truncated_shard_is_one_error_line(tiny_caches, tmp_path, kind, flags, name):
    cache = shutil.copytree(tiny_caches[0], tmp_path / "cache")
    (shard,) = sorted((cache / name).glob("*.parquet"))
    size = shard.stat().st_size
    with open(shard, "r+b") as handle:
        handle.truncate(2000)
    done = invoke(kind, "--cache", str(cache), "--out", str(tmp_path / "run"), *flags)
    assert done.exit_code == 2 and done.stderr.strip().splitlines() == [
        f"error: {shard}: 2,000 bytes where manifest.json records {size:,} (cut short or altered); rerun `sianms "
        "prepare` on the cache to rebuild it"]
    assert not (tmp_path / "run").exists()


def test_data_found_unusable_mid_run_does_not_block_the_next_run(tiny_caches, tmp_path, monkeypatch):
    out = tmp_path / "run"

    def no_pairs(*args, **kwargs):
        raise SianmsError("cache: no reference instance with a positive and a negative")

    original = siamese.train_epoch
    monkeypatch.setattr(siamese, "train_epoch", no_pairs)
    done = invoke("siamese", "--cache", str(tiny_caches[0]), "--out", str(out), *SIAMESE)
    assert done.exit_code == 2 and done.stderr == "error: cache: no reference instance with a positive and a negative\n"
    assert not out.exists()
    monkeypatch.setattr(siamese, "train_epoch", original)
    done = invoke("siamese", "--cache", str(tiny_caches[0]), "--out", str(out), *SIAMESE)
    assert done.exit_code == 0, done.output
    assert (out / CHECKPOINT).is_file()


def test_a_wrong_multiview_dataroot_leaves_no_run_folder(tiny_caches, tmp_path):
    out = tmp_path / "run"
    done = invoke("fpointnet", "--cache", str(tiny_caches[0]), "--out", str(out), "--multiview", "--dataroot",
                  str(tmp_path / "nope"), *FPOINTNET)
    assert done.exit_code == 2 and done.stderr.strip().splitlines() == [
        f"error: {tmp_path / 'nope' / 'v1.0-mini'}: version folder not found (expected <dataroot>/<version>/)"]
    assert not out.exists()


def test_a_run_resumes_on_its_cache_spelled_otherwise_but_not_on_other_content(tiny_caches, tmp_path, monkeypatch):
    """`train fpointnet` recorded --cache as typed: the same cache as a relative and an absolute path
    had been "the config differs in cache"."""
    shutil.copytree(tiny_caches[0], tmp_path / "cache")
    monkeypatch.chdir(tmp_path)
    first = invoke("fpointnet", "--cache", "cache", "--out", "run", *FPOINTNET)
    assert first.exit_code == 0, first.output
    again = invoke("fpointnet", "--cache", str(tmp_path / "cache"), "--out", "run", "--resume",
                   *FPOINTNET[:-3], "--epochs", "2", "--quiet")
    assert again.exit_code == 0, again.output
    shutil.rmtree(tmp_path / "cache")
    shutil.copytree(tiny_caches[1], tmp_path / "cache")  # other content at the same path
    other = invoke("fpointnet", "--cache", "cache", "--out", "run", "--resume", *FPOINTNET[:-3], "--epochs", "3",
                   "--quiet")
    assert other.exit_code == 2 and "the content of --cache changed since the run began" in other.output
