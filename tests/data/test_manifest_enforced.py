"""A cache is read as its manifest lists it: a shard file copied in, missing, cut short, altered or with
an id twice is refused with one line naming the file, and train and eval refuse the same things."""

import json
import os
import re
import shutil

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from cache_records import record_again
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.data import cache as cache_module
from sianms_cli.data.cache import PREPARE_AGAIN, checked_files, trust_checked_files, verified_shards, verify_cache
from sianms_cli.errors import DataFormatError

runner = CliRunner()


@pytest.fixture
def cache(eval_inputs, tmp_path):
    """A copy of the session's prepared cache (two shards), this test's to damage."""
    return shutil.copytree(eval_inputs.cache, tmp_path / "cache")


def first(cache, dataset):
    return sorted((cache / dataset).glob("*.parquet"))[0]


def rewrite(path, edit):
    table = pq.read_table(path)
    pq.write_table(edit(table), path)


def duplicate_first_id(table):
    ids = table["detection_id"].to_pylist()
    ids[1] = ids[0]
    return table.set_column(table.schema.get_field_index("detection_id"), "detection_id", pa.array(ids))


def refusal(cache):
    with pytest.raises(DataFormatError) as raised:
        verify_cache(cache)
    return str(raised.value)


def test_a_shard_copied_in_is_refused(cache):
    stray = cache / "frustums" / "scene-9999.parquet"
    shutil.copyfile(first(cache, "frustums"), stray)
    assert refusal(cache) == (f"{stray}: not listed in manifest.json: the cache holds a file prepare did not write "
                              f"there (copied in?); remove it, or {PREPARE_AGAIN}")
    stray.rename(cache / "frustums" / ".scene-9999.parquet.123.abcdef01.partial")  # a killed write's: not read
    assert len(verified_shards(cache, "frustums")) == 2


def test_a_missing_shard_is_refused(cache):
    path = first(cache, "pairs")
    path.unlink()
    assert refusal(cache) == f"{path}: missing: manifest.json lists it; {PREPARE_AGAIN}"


def test_a_shard_cut_short_is_refused(cache):
    path = first(cache, "detections")
    size = path.stat().st_size
    with open(path, "r+b") as handle:
        handle.truncate(size - 10)
    assert refusal(cache) == (f"{path}: {size - 10:,} bytes where manifest.json records {size:,} (cut short or "
                              f"altered); {PREPARE_AGAIN}")


def test_a_shard_altered_in_place_is_refused(cache):
    path = first(cache, "frustums")
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF  # the same size: only the digest tells
    path.write_bytes(bytes(data))
    assert refusal(cache) == (f"{path}: its content is not what manifest.json records (another SHA-256: altered or "
                              f"replaced); {PREPARE_AGAIN}")


def test_a_shard_with_rows_missing_is_refused_even_when_its_digest_is_recorded(cache):
    path = first(cache, "frustums")
    rows = pq.read_metadata(path).num_rows
    rewrite(path, lambda table: table.slice(0, rows - 1))
    record_again(cache)
    manifest = json.loads((cache / "manifest.json").read_text())
    manifest["files"][f"frustums/{path.name}"]["rows"] = rows  # the manifest's count, the file's digest
    (cache / "manifest.json").write_text(json.dumps(manifest))
    assert refusal(cache) == f"{path}: {rows - 1:,} rows where manifest.json records {rows:,}; {PREPARE_AGAIN}"


@pytest.mark.parametrize("dataset", ["detections", "frustums"])
def test_an_id_twice_in_a_shard_is_refused(cache, dataset):
    path = first(cache, dataset)
    table = pq.read_table(path)
    rewrite(path, duplicate_first_id)
    record_again(cache)  # recorded as if prepare had written it: the ids are checked all the same
    assert refusal(cache) == (f"{path}: record {table['detection_id'][0]}: field 'detection_id': appears 2 times; "
                              f"an id is unique in a shard; {PREPARE_AGAIN}")


def test_a_shard_that_is_not_a_regular_file_is_refused(cache):
    path = first(cache, "pairs")
    path.unlink()
    os.mkfifo(path)  # would never end if read
    assert refusal(cache) == f"{path}: not a regular file; {PREPARE_AGAIN}"


def test_a_manifest_entry_without_its_digest_is_refused(cache):
    manifest = json.loads((cache / "manifest.json").read_text())
    name = sorted(manifest["files"])[0]
    del manifest["files"][name]["sha256"]
    (cache / "manifest.json").write_text(json.dumps(manifest))
    assert refusal(cache) == (f"{cache / 'manifest.json'}: field 'files.{name}': expected rows, bytes and sha256 "
                              f"of the file; {PREPARE_AGAIN}")


def test_a_cache_is_hashed_once_per_process_and_a_worker_starts_from_what_was_checked(cache, monkeypatch):
    hashed = []
    real = cache_module.sha256_of
    monkeypatch.setattr(cache_module, "sha256_of", lambda path: hashed.append(path) or real(path))
    monkeypatch.setattr(cache_module, "_CHECKED_CACHES", {})
    monkeypatch.setattr(cache_module, "_CHECKED_FILES", set())
    for dataset in ("detections", "frustums", "pairs", "detections"):
        verified_shards(cache, dataset)
    assert len(hashed) == 6  # each of the 2 shards' 3 files once
    checked = checked_files()
    monkeypatch.setattr(cache_module, "_CHECKED_CACHES", {})  # a fresh worker process
    monkeypatch.setattr(cache_module, "_CHECKED_FILES", set())
    trust_checked_files(checked)
    verified_shards(cache, "frustums")
    assert len(hashed) == 6
    path = first(cache, "pairs")
    path.write_bytes(path.read_bytes())  # rewritten since: another identity, checked again
    monkeypatch.setattr(cache_module, "_CHECKED_CACHES", {})
    verified_shards(cache, "pairs")
    assert hashed[6:] == [path]


def train_arguments(kind, cache, out):
    flags = (["--dim", "8", "--conv-channels", "8,8", "--hidden", "16", "--batch-size", "4"] if kind == "siamese"
             else ["--num-points", "32", "--num-object-points", "16", "--batch-size", "8", "--min-box-height", "0"])
    return ["train", kind, "--cache", str(cache), "--out", str(out), "--epochs", "1", "--device", "cpu", "--quiet",
            *flags]


def eval_arguments(inputs, cache, out):
    return ["eval", "--dataroot", str(inputs.dataroot), "--split", inputs.split, "--cache", str(cache),
            "--siamese", str(inputs.siamese), "--fpointnet", str(inputs.fpointnet), "--out", str(out),
            "--methods", "vanilla", "--pictures", "0", "--quiet"]


def test_train_and_eval_refuse_the_same_stray_shard_before_writing(eval_inputs, cache, tmp_path):
    """A stray shard had been trained on silently, and scored by eval with exit 0."""
    stray = cache / "detections" / "scene-9999.parquet"
    shutil.copyfile(first(cache, "detections"), stray)
    expected = [f"error: {stray}: not listed in manifest.json: the cache holds a file prepare did not write there "
                f"(copied in?); remove it, or {PREPARE_AGAIN}"]
    for arguments in (train_arguments("siamese", cache, tmp_path / "s"),
                      train_arguments("fpointnet", cache, tmp_path / "f"),
                      eval_arguments(eval_inputs, cache, tmp_path / "e")):
        done = runner.invoke(app, arguments)
        assert (done.exit_code, done.stderr.splitlines()) == (2, expected), arguments[:2]
    assert not any((tmp_path / name).exists() for name in ("s", "f", "e"))


def test_eval_refuses_point_lists_out_of_step_as_train_does(eval_inputs, cache, tmp_path):
    """A frustum's y list one value short had been a numpy traceback in eval (train named it)."""
    path = first(cache, "frustums")

    def shorten_y(table):
        y = table["y"].to_pylist()
        row = next(i for i, values in enumerate(y) if values)
        y[row] = y[row][:-1]
        return table.set_column(table.schema.get_field_index("y"), table.schema.field("y"),
                                pa.array(y, table.schema.field("y").type))

    rewrite(path, shorten_y)
    record_again(cache)
    lines = []
    for arguments in (train_arguments("fpointnet", cache, tmp_path / "f"),
                      eval_arguments(eval_inputs, cache, tmp_path / "e")):
        done = runner.invoke(app, arguments)
        assert done.exit_code == 2 and len(done.stderr.splitlines()) == 1, done.output
        lines.append(done.stderr)
    assert lines[0] == lines[1]
    assert re.fullmatch(rf"error: {re.escape(str(path))}: record \S+: field 'y': not one value per point of x; "
                        rf"{re.escape(PREPARE_AGAIN)}\n", lines[1])
