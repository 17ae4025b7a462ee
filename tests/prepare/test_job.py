"""`sianms prepare` as a job: the cache folder, its manifest, faults, interrupts, concurrent runs."""

import errno
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import sys
import threading
import time

import pytest
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.io import OutputError
from sianms_cli.prepare import job
from sianms_cli.prepare.config import PrepareConfig
from sianms_cli.prepare.sample import Preparer



@pytest.fixture(scope="module")
def dataroot(synthetic_dataroot):
    """Three scenes: mini_train holds two of them (scene-0061, scene-0553), so two shards."""
    return synthetic_dataroot(scenes=3)


@pytest.fixture(scope="module")
def config(dataroot):
    return PrepareConfig(str(dataroot), "v1.0-mini", "mini_train", seed=5)


@pytest.fixture(scope="module")
def finished(config, tmp_path_factory):
    """A complete cache of ``config``."""
    out = tmp_path_factory.mktemp("cache") / "finished"
    job.run(config, out)
    return out


def manifest_of(out):
    return json.loads((out / "manifest.json").read_text())


def parquet_bytes(root):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*.parquet"))}


def modes(root):
    return {stat.S_IMODE(p.stat().st_mode) for p in [root, *root.rglob("*")] if not p.name.endswith(".lock")}


def test_a_finished_cache_is_complete_and_checksummed(finished):
    manifest = manifest_of(finished)
    assert manifest["complete"] and manifest["shards_expected"] == manifest["shards_finished"] > 0
    assert manifest["missing_shards"] == []
    assert set(manifest["files"]) == {str(p.relative_to(finished)) for p in finished.rglob("*.parquet")}
    assert "dataroot" not in manifest["config"] and len(manifest["config"]["dataset_sha256"]) == 64


@pytest.mark.parametrize("mask, files, folders", [(0o022, 0o644, 0o755), (0o077, 0o600, 0o700)])
def test_cache_permissions_follow_the_umask(config, tmp_path, umask, mask, files, folders):
    umask(mask)
    out = tmp_path / "cache"
    job.run(config, out)
    assert modes(out) == {files, folders}


def test_an_interrupted_run_leaves_an_incomplete_manifest_and_a_rerun_finishes(config, finished, tmp_path,
                                                                                monkeypatch):
    out = tmp_path / "killed"
    original = Preparer.sample
    calls = []

    def interrupted_on_the_second_sample(self, *args):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return original(self, *args)

    monkeypatch.setattr(Preparer, "sample", interrupted_on_the_second_sample)
    with pytest.raises(KeyboardInterrupt):
        job.run(config, out)
    manifest = manifest_of(out)
    assert manifest["complete"] is False
    assert manifest["shards_expected"] == manifest_of(finished)["shards_expected"]
    assert manifest["shards_finished"] == 0 and not list(out.rglob("*.parquet")) and not list(out.rglob("*.partial"))
    monkeypatch.setattr(Preparer, "sample", original)
    job.run(config, out)
    assert manifest_of(out)["complete"] and parquet_bytes(out) == parquet_bytes(finished)


def test_sigint_stops_the_workers_and_leaves_an_incomplete_cache(dataroot, tmp_path, process_tree):
    out = tmp_path / "cache"
    command = [sys.executable, "-m", "sianms_cli", "prepare", "--dataroot", str(dataroot), "--split", "mini_train",
               "--out", str(out), "--workers", "2", "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               preexec_fn=process_tree.default_sigint)
    deadline = time.monotonic() + 60
    workers = []
    while len(workers) < 2 and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.05)
        workers = process_tree.workers(process.pid)
    assert len(workers) == 2, process.communicate()
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 130, stderr
    assert stderr.decode().startswith("interrupted (SIGINT)")
    time.sleep(0.5)
    assert not [pid for pid in workers if process_tree.alive(pid)]
    assert manifest_of(out)["complete"] is False
    assert not list(out.rglob("*.partial"))


def test_a_full_disk_at_the_lock_leaves_no_output_folder(config, tmp_path, monkeypatch):
    def full(*_):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", full)
    out = tmp_path / "cache"
    with pytest.raises(OutputError, match=f"cannot write {out}/.*lock: No space left on device"):
        job.run(config, out)
    assert not out.exists()


def test_disk_full_is_one_error_and_leaves_no_partial_file(config, full_disk):
    out = full_disk / "cache"
    with pytest.raises(OutputError, match=f"cannot write {out}/.*: No space left on device"):
        job.run(config, out)
    assert not list(out.rglob("*.partial")) and not list(out.rglob("*.parquet"))
    assert manifest_of(out)["complete"] is False


def test_read_only_output_is_one_error_line(config, read_only_folder):
    result = CliRunner().invoke(app, ["prepare", "--dataroot", config.dataroot, "--split", "mini_train",
                                      "--out", str(read_only_folder / "cache"), "--quiet"])
    assert result.exit_code == 2
    assert result.output == f"error: cannot write {read_only_folder / 'cache'}: Read-only file system\n"


def test_out_naming_a_file_is_refused(config, tmp_path):
    (tmp_path / "file").write_text("mine")
    with pytest.raises(OutputExistsError, match="exists and is not a folder"):
        job.run(config, tmp_path / "file")


def test_a_cache_killed_as_it_wrote_its_first_manifest_is_started_again(config, tmp_path):
    """A kill while the first manifest was written leaves the lock and the manifest's temporary
    file: the folder is still the cache's, not someone else's (it had been refused for good)."""
    out = tmp_path / "cache"
    out.mkdir()
    (out / ".sianms.lock").write_text("")
    (out / ".manifest.json.4242.0123abcd.partial").write_text("")
    assert job.run(config, out).manifest["complete"]


def test_a_folder_that_is_not_a_cache_is_never_deleted(config, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    for overwrite in (False, True):
        with pytest.raises(OutputExistsError, match="is not a sianms cache"):
            job.run(config, out, overwrite=overwrite)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_overwrite_interrupted_after_deleting_still_leaves_a_cache(config, finished, tmp_path, monkeypatch):
    out = tmp_path / "cache"
    shutil.copytree(finished, out)
    other = PrepareConfig(config.dataroot, config.version, config.split, seed=6)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(job, "write_scene_shard", interrupted)
    with pytest.raises(KeyboardInterrupt):
        job.run(other, out, overwrite=True)
    monkeypatch.undo()
    assert manifest_of(out)["config"]["seed"] == 6 and not list(out.rglob("*.parquet"))
    job.run(config, out, overwrite=True)
    assert parquet_bytes(out) == parquet_bytes(finished)


def test_overwrite_deletes_the_shards_files_and_keeps_yours_among_them(config, finished, tmp_path):
    out = tmp_path / "cache"
    shutil.copytree(finished, out)
    (out / "detections" / "mine").mkdir()
    (out / "detections" / "mine" / "notes.txt").write_text("x")
    (out / "frustums" / "README.txt").write_text("y")
    job.run(PrepareConfig(config.dataroot, config.version, config.split, seed=6), out, overwrite=True)
    assert (out / "detections" / "mine" / "notes.txt").read_text() == "x"
    assert (out / "frustums" / "README.txt").read_text() == "y"
    assert manifest_of(out)["complete"] and manifest_of(out)["config"]["seed"] == 6


def test_a_moved_dataset_keeps_its_cache_and_a_changed_one_does_not(config, finished, dataroot, tmp_path):
    copied_dataroot = shutil.copytree(dataroot, tmp_path / "moved")
    out = tmp_path / "cache"
    shutil.copytree(finished, out)
    moved = PrepareConfig(str(copied_dataroot), config.version, config.split, seed=5)
    result = job.run(moved, out)
    assert result.shards_run == [] and manifest_of(out)["complete"]
    scene_table = copied_dataroot / "v1.0-mini" / "scene.json"
    scene_table.write_text(scene_table.read_text().replace("Two lanes", "2 lanes").replace("One lane", "1 lane"))
    with pytest.raises(OutputExistsError, match=r"differs in: dataset_sha256"):
        job.run(moved, out)


def test_a_tables_only_dataset_is_refused_before_anything_is_written(synthetic_dataroot, tmp_path):
    tables_only = synthetic_dataroot(sensors="none")
    with pytest.raises(DataFormatError, match=r"sensor file not found \(a dataset written with `sianms synth "
                                              r"--sensors none` has tables only"):
        job.run(PrepareConfig(str(tables_only), "v1.0-mini", "mini_train"), tmp_path / "cache")
    assert not (tmp_path / "cache").exists()


@pytest.mark.parametrize("table, change, message", [
    ("sample_data", lambda records, camera: records[camera].update(height=0),
     "field 'height': a camera key frame needs a positive image height, got 0"),
    ("calibrated_sensor", lambda records, camera: [record.update(camera_intrinsic=[[0, 0, 0], [0, 0, 0], [0, 0, 1]])
                                                   for record in records if record["camera_intrinsic"]],
     "field 'camera_intrinsic': expected [] or a 3x3 pinhole matrix"),
])
def test_a_damaged_table_is_refused_before_anything_is_written(config, dataroot, tmp_path, table, change, message):
    """Found when the scene was reached, it would leave a cache whose manifest blocks the rerun
    on the mended dataset (another dataset_sha256)."""
    copied = tmp_path / "data"
    shutil.copytree(dataroot / "v1.0-mini", copied / "v1.0-mini")
    for name in ("samples", "sweeps", "maps"):
        if (dataroot / name).exists():
            (copied / name).symlink_to(dataroot / name)
    records = json.loads((copied / "v1.0-mini" / "sample_data.json").read_text())
    last_camera = max(i for i, record in enumerate(records) if record["is_key_frame"] and "/CAM_" in record["filename"])
    path = copied / "v1.0-mini" / f"{table}.json"
    table_records = json.loads(path.read_text())
    change(table_records, last_camera)
    path.write_text(json.dumps(table_records))
    with pytest.raises(DataFormatError, match=re.escape(message)):
        job.run(PrepareConfig(str(copied), config.version, config.split, seed=5), tmp_path / "cache")
    assert not (tmp_path / "cache").exists()


def test_sweeps_need_lidar_sweeps_between_key_frames(synthetic_dataroot, tmp_path):
    # Scenes of one key frame have sensor files but no sweep between key frames.
    one_keyframe = synthetic_dataroot(scenes=3, scene_seconds=0.5)
    with_sweeps = PrepareConfig(str(one_keyframe), "v1.0-mini", "mini_train", sweeps=5)
    with pytest.raises(SianmsError, match="--sweeps 5: .* has no LiDAR sweeps between key frames"):
        job.run(with_sweeps, tmp_path / "cache")
    assert not (tmp_path / "cache").exists()


@pytest.mark.parametrize("fields, message", [
    (dict(min_depth=10.0, max_depth=5.0), r"--max-depth must be a finite number greater than --min-depth \(10.0\)"),
    (dict(max_depth=float("inf")), r"--max-depth must be a finite number .* got inf \(leave it out for no limit\)"),
    (dict(min_depth=-1.0), "--min-depth must be a finite number >= 0"),
    (dict(sampling_ratio=200), r"--sampling-ratio must be at most 16 \(<= 0: adaptive\), got 200"),
    (dict(version="../escape"), "--version"),
    (dict(sweeps=10**9), r"^--sweeps must be in \[0, 100\], got 1000000000$"),  # had run out of memory
    (dict(sweeps=-1), r"^--sweeps must be in \[0, 100\], got -1$"),
])
def test_config_validation(config, fields, message):
    with pytest.raises(SianmsError, match=message):
        PrepareConfig(**{"dataroot": config.dataroot, "version": config.version, "split": config.split, **fields})


def test_concurrent_runs_share_the_work_shard_by_shard(config, finished, tmp_path, monkeypatch):
    """Two runs into one folder: each shard is written once, by whichever run locks it first."""
    out = tmp_path / "cache"
    started = threading.Barrier(2)
    original = job._write_shard

    def both_runs_in_flight(*args, **kwargs):
        started.wait(timeout=30)  # the first shard of each run starts only once both runs hold one
        monkeypatch.setattr(job, "_write_shard", original)
        return original(*args, **kwargs)

    monkeypatch.setattr(job, "_write_shard", both_runs_in_flight)
    results = [None, None]

    def prepare_into_out(i):
        results[i] = job.run(config, out)

    second = threading.Thread(target=prepare_into_out, args=(1,))
    second.start()
    prepare_into_out(0)
    second.join()
    assert results[0].shards_run and results[1].shards_run  # both runs did work
    assert sorted(results[0].shards_run + results[1].shards_run) == ["scene-0061", "scene-0553"]
    assert manifest_of(out)["complete"] and parquet_bytes(out) == parquet_bytes(finished)


def test_cli_prints_what_it_did_as_json(config, finished, tmp_path):
    out = tmp_path / "cache"
    shutil.copytree(finished, out)
    result = CliRunner().invoke(app, ["prepare", "--dataroot", config.dataroot, "--split", "mini_train",
                                      "--seed", "5", "--out", str(out), "--json"])
    assert result.exit_code == 0, result.output
    printed = json.loads(result.stdout)  # the progress bar goes to stderr
    assert printed["written"] == [] and printed["complete"] and printed["busy"] == []
    assert sorted(printed["already_finished"]) == sorted(p.stem for p in (finished / "_shards").glob("*.json"))
    assert os.path.samefile(printed["out"], out)



@pytest.mark.parametrize("name", ["../outside", "a/b", "*", ".hidden", "-rf"])
def test_a_scene_name_that_is_no_plain_file_name_is_refused_before_anything_is_written(synthetic_dataroot, tmp_path,
                                                                                         name):
    """Scene names name a cache's and an evaluation's files: '../outside' had written and deleted
    beside the cache, '*' had matched other scenes' temporaries."""
    dataroot = shutil.copytree(synthetic_dataroot(sensors="none"), tmp_path / "data")
    tables = dataroot / "v1.0-mini"
    scenes = json.loads((tables / "scene.json").read_text())
    scenes[0]["name"] = name
    (tables / "scene.json").write_text(json.dumps(scenes))
    (tables / "splits.json").write_text(json.dumps({"odd": [name]}))
    (tmp_path / "outside.parquet").write_text("mine")
    result = CliRunner().invoke(app, ["prepare", "--dataroot", str(dataroot), "--split", "odd", "--out",
                                      str(tmp_path / "cache" / "run"), "--quiet"])
    assert result.exit_code == 2, result.output
    assert result.output.startswith(f"error: {tables / 'scene.json'}: record {scenes[0]['token']}: field 'name': ")
    assert "cannot name the scene's files" in result.output and result.output.count("\n") == 1
    assert not (tmp_path / "cache").exists() and (tmp_path / "outside.parquet").read_text() == "mine"
