"""A damaged cache: truncated shard files fail with one DataFormatError naming them, a shard whose
file changed size is not finished (a rerun rebuilds it), and readers refuse an incomplete cache."""

import json
import re

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from cache_records import record_again

from sianms_cli.data.cache import (
    PREPARE_AGAIN, ShardWriter, cache_fingerprint, complete_manifest, read_dataset, read_shard_table, roi_feature_shape,
    shard_done, write_manifest,
)
from sianms_cli.data.frustum_dataset import FrustumSelection, read_shard
from sianms_cli.data.index import build_pair_index
from sianms_cli.data.schemas import cache_schemas
from sianms_cli.data.siamese import iter_scenes
from sianms_cli.errors import DataFormatError
from sianms_cli.evaluation.scene import SceneEvaluator

UNREADABLE = "not a readable Parquet file; rerun `sianms prepare` on the cache to rebuild it"


def write_shard(root, shard="s"):
    """A finished shard of one detection (its frustums and pairs files empty); its completion record."""
    schemas = cache_schemas((1, 2, 2), "tiny")
    row = {name: None for name in schemas["detections"].names}
    row.update(detection_id="d", scene_token="scene", sample_token="sample", camera="CAM_FRONT", x1=1.0, y1=1.0,
               x2=5.0, y2=5.0, score=0.5, overlap_pairs=[], detection_index=0,
               roi_feature=np.zeros((1, 2, 2), dtype="<f2").tobytes())
    with ShardWriter(root, shard, schemas) as writer:
        writer.write("detections", pa.Table.from_pylist([row], schema=schemas["detections"]))
        return writer.commit({"samples": 1})


def write_cache(root, shard="s"):
    """A complete cache of one :func:`write_shard` shard (its manifest written)."""
    write_shard(root, shard)
    write_manifest(root, {"seed": 0}, [shard], root)


def truncate(path, size=100):
    with open(path, "r+b") as handle:
        handle.truncate(size)


def test_the_completion_record_holds_each_file_size(tmp_path):
    record = write_shard(tmp_path)
    for name in ("detections", "frustums", "pairs"):
        info = record["files"][f"{name}/s.parquet"]
        assert info["bytes"] == (tmp_path / name / "s.parquet").stat().st_size
    manifest = write_manifest(tmp_path, {"seed": 0}, ["s"], tmp_path)
    assert manifest["files"]["detections/s.parquet"]["bytes"] == record["files"]["detections/s.parquet"]["bytes"]


@pytest.mark.parametrize("name", ["detections", "frustums", "pairs"])
def test_a_shard_whose_file_changed_size_is_not_finished(tmp_path, name):
    write_shard(tmp_path)
    assert shard_done(tmp_path, "s")
    truncate(tmp_path / name / "s.parquet")
    assert not shard_done(tmp_path, "s")
    manifest = write_manifest(tmp_path, {"seed": 0}, ["s"], tmp_path)
    assert manifest["complete"] is False and manifest["missing_shards"] == ["s"]


def test_a_record_without_sizes_is_checked_for_a_parquet_footer(tmp_path):
    """Caches written before sizes were recorded stay readable; a truncated file is still caught."""
    record = write_shard(tmp_path)
    for info in record["files"].values():
        del info["bytes"]
    (tmp_path / "_shards" / "s.json").write_text(json.dumps(record))
    assert shard_done(tmp_path, "s")
    truncate(tmp_path / "pairs" / "s.parquet")
    assert not shard_done(tmp_path, "s")


def test_an_unreadable_completion_record_is_not_finished(tmp_path):
    write_shard(tmp_path)
    (tmp_path / "_shards" / "s.json").write_text("{\"files\": ")
    assert not shard_done(tmp_path, "s")


@pytest.mark.parametrize("edit", [
    lambda record: record.update(samples="x"),
    lambda record: record.update(samples=-1),
    lambda record: record["files"]["detections/s.parquet"].update(rows="x"),
    lambda record: record["files"]["pairs/s.parquet"].update(bytes=True),
    lambda record: record["files"].update({"../../etc/passwd": {"rows": 1}}),
    lambda record: record["files"].pop("frustums/s.parquet"),
])
def test_a_completion_record_of_another_form_is_not_finished(tmp_path, edit):
    """A record edited by hand ended the next prepare in a TypeError or KeyError traceback as the
    manifest summed it; now the shard is redone."""
    record = write_shard(tmp_path)
    edit(record)
    (tmp_path / "_shards" / "s.json").write_text(json.dumps(record))
    assert not shard_done(tmp_path, "s")
    assert write_manifest(tmp_path, {"seed": 0}, ["s"], tmp_path)["missing_shards"] == ["s"]


def test_every_reader_names_the_truncated_shard(tmp_path):
    """A file reader names the damaged file; a cache reader refuses it sooner, by its manifest size."""
    write_cache(tmp_path)
    detections, frustums, pairs = (tmp_path / name / "s.parquet" for name in ("detections", "frustums", "pairs"))
    size = pairs.stat().st_size
    truncate(pairs)
    with pytest.raises(DataFormatError) as error:
        list(iter_scenes(tmp_path))
    assert str(error.value) == (f"{pairs}: 100 bytes where manifest.json records {size:,} (cut short or altered); "
                                f"{PREPARE_AGAIN}")
    truncate(frustums)
    with pytest.raises(DataFormatError) as error:
        read_shard(frustums, FrustumSelection())
    assert str(error.value) == f"{frustums}: {UNREADABLE}"
    truncate(detections)
    for read in (lambda: read_shard_table(detections), lambda: roi_feature_shape(detections),
                 lambda: SceneEvaluator(None, None, None, None).scene(detections, frustums, "scene")):
        with pytest.raises(DataFormatError) as error:
            read()
        assert str(error.value) == f"{detections}: {UNREADABLE}"
    for read in (lambda: read_dataset(tmp_path, "detections"), lambda: build_pair_index(tmp_path)):
        with pytest.raises(DataFormatError, match="^" + re.escape(f"{detections}: 100 bytes where manifest.json")):
            read()


def edit_roi_feature_shape(path, shape):
    """Rewrite a detections file with ``shape`` as its schema's ``sianms.roi_feature_shape``."""
    table = pq.read_table(path)
    metadata = {**table.schema.metadata, b"sianms.roi_feature_shape": shape}
    pq.write_table(table.replace_schema_metadata(metadata), path)


@pytest.mark.parametrize("shape", [b"1,x,2", b"1,2", b"1,2,2,2", b"0,2,2", b"-1,2,2", b"1,2,99999999", b""])
def test_an_edited_roi_feature_shape_is_named(tmp_path, shape):
    write_cache(tmp_path)
    detections = tmp_path / "detections" / "s.parquet"
    edit_roi_feature_shape(detections, shape)
    record_again(tmp_path)
    for read in (lambda: roi_feature_shape(detections), lambda: list(iter_scenes(tmp_path))):
        with pytest.raises(DataFormatError) as error:
            read()
        assert str(error.value) == (f"{detections}: sianms.roi_feature_shape must be 'C,PH,PW', three whole numbers "
                                    f"in [1, 65,536], got '{shape.decode()}'; {PREPARE_AGAIN}")


def test_features_of_another_size_than_the_schema_says_are_named(tmp_path):
    write_cache(tmp_path)
    detections = tmp_path / "detections" / "s.parquet"
    edit_roi_feature_shape(detections, b"2,2,2")
    record_again(tmp_path)
    with pytest.raises(DataFormatError) as error:
        list(iter_scenes(tmp_path))
    assert str(error.value) == (f"{detections}: field 'roi_feature': row 0: a feature of 8 bytes where the shape "
                                f"2,2,2 in float16 takes 16 bytes; {PREPARE_AGAIN}")


def test_a_missing_shard_file_is_left_to_the_os_error_line(tmp_path):
    with pytest.raises(FileNotFoundError):
        read_shard_table(tmp_path / "detections" / "s.parquet")


def test_readers_refuse_a_folder_without_manifest_or_an_incomplete_cache(tmp_path):
    with pytest.raises(DataFormatError) as error:
        complete_manifest(tmp_path)
    assert str(error.value) == (f"{tmp_path / 'manifest.json'}: not found: not a `sianms prepare` cache "
                                "(run `sianms prepare` first)")
    (tmp_path / "a-file").write_text("x")
    with pytest.raises(DataFormatError) as error:
        complete_manifest(tmp_path / "a-file")
    assert str(error.value) == f"{tmp_path / 'a-file'}: is a file: a cache is the folder `sianms prepare` wrote"
    write_shard(tmp_path)
    write_manifest(tmp_path, {"seed": 0}, ["s", "t", "u"], tmp_path)
    with pytest.raises(DataFormatError) as error:
        complete_manifest(tmp_path)
    assert str(error.value) == (f"{tmp_path / 'manifest.json'}: field 'complete': the cache is not complete "
                                "(2 of 3 shards missing); rerun `sianms prepare` with the same flags to finish it")
    written = write_manifest(tmp_path, {"seed": 0}, ["s"], tmp_path)
    assert complete_manifest(tmp_path) == written
    for edited in ("yes", 1, None):  # "yes" had been read as "0 of 1 shards missing", 1 as complete
        (tmp_path / "manifest.json").write_text(json.dumps({**written, "complete": edited}))
        with pytest.raises(DataFormatError) as error:
            complete_manifest(tmp_path)
        assert str(error.value) == (f"{tmp_path / 'manifest.json'}: field 'complete': must be true or false, got "
                                    f"{json.dumps(edited)}; rerun `sianms prepare` with the same flags to rewrite it")


def test_a_caches_fingerprint_is_its_content_not_the_dataroot_it_came_from():
    manifest = {"schema_version": 1, "config": {"dataset_sha256": "d" * 64, "split": "mini_train"},
                "dataroot": "/home/a/data", "complete": True, "counts": {"samples": 2},
                "files": {"frustums/scene-1.parquet": {"rows": 3, "bytes": 10, "sha256": "a" * 64}}}
    fingerprint = cache_fingerprint(manifest)
    assert cache_fingerprint({**manifest, "dataroot": "/scratch/b/data"}) == fingerprint
    assert cache_fingerprint(dict(reversed(list(manifest.items())))) == fingerprint
    other_file = {"frustums/scene-1.parquet": {"rows": 3, "bytes": 10, "sha256": "b" * 64}}
    assert cache_fingerprint({**manifest, "files": other_file}) != fingerprint
    assert cache_fingerprint({**manifest, "config": {**manifest["config"], "dataset_sha256": "e" * 64}}) != fingerprint


def test_a_shard_arrow_cannot_open_is_named_in_the_os_error_line(tmp_path):
    """Arrow's PermissionError names no file: a shard the user may not read gave 'error: Permission
    denied' alone."""
    from sianms_cli.data.cache import reading_shard
    from sianms_cli.io import describe_os_error

    shard = tmp_path / "pairs" / "scene-0061.parquet"
    with pytest.raises(PermissionError) as raised:
        with reading_shard(shard):
            raise PermissionError("Permission denied")
    assert describe_os_error(raised.value) == f"{shard}: Permission denied"


def test_a_damaged_scene_table_of_an_evaluation_is_named_with_what_to_do(tmp_path):
    from sianms_cli.evaluation.finish import read_boxes

    table = tmp_path / "scene-0103.parquet"
    table.write_bytes(b"PAR1 not a whole file")
    with pytest.raises(DataFormatError) as raised:
        read_boxes([table], ["token"])
    assert str(raised.value) == (f"{table}: not a readable Parquet file; delete it and rerun the same `sianms eval`, "
                                 "which evaluates its scene again")


def _rewrite(path, edit):
    table = pq.read_table(path)
    pq.write_table(edit(table), path)


@pytest.mark.parametrize("dataset, edit, field, problem", [
    ("detections", lambda t: t.set_column(t.schema.get_field_index("overlap_pairs"), "overlap_pairs",
                                          pa.array(["CAM_FRONT|CAM_FRONT_RIGHT"] * len(t))), "overlap_pairs",
     "string where prepare writes list<item: string>"),
    ("detections", lambda t: t.drop_columns(["camera"]), "camera", "no such column"),
    ("detections", lambda t: t.set_column(t.schema.get_field_index("roi_feature"), "roi_feature",
                                          pa.array([np.full((1, 2, 2), np.nan, dtype="<f2").tobytes()] * len(t),
                                                   pa.binary(8))),
     "roi_feature", "row 0: a feature holding NaN or infinity"),
])
def test_an_edited_siamese_column_is_named_by_file_and_field(tmp_path, dataset, edit, field, problem):
    """A string overlap_pairs had been an ArrowNotImplementedError traceback, a NaN feature a
    ValueError in the validation's ROC or a "lower --lr" (training diverged)."""
    write_cache(tmp_path)
    path = tmp_path / dataset / "s.parquet"
    _rewrite(path, edit)
    record_again(tmp_path)
    with pytest.raises(DataFormatError) as error:
        list(iter_scenes(tmp_path))
    assert str(error.value) == f"{path}: field '{field}': {problem}; {PREPARE_AGAIN}"


def test_a_pairs_row_without_its_pair_is_named(tmp_path):
    """A null pair had ended in a TypeError while sorting the pair names."""
    write_cache(tmp_path)
    path = tmp_path / "pairs" / "s.parquet"
    row = {name: None for name in cache_schemas((1, 2, 2), "tiny")["pairs"].names}
    row.update(scene_token="scene", sample_token="sample", reference_detection_id="d", positive_detection_id="d")
    pq.write_table(pa.Table.from_pylist([row], schema=cache_schemas((1, 2, 2), "tiny")["pairs"]), path)
    record_again(tmp_path)
    with pytest.raises(DataFormatError, match=f"^{path}: field 'pair': a pairs row without its camera pair$"):
        list(iter_scenes(tmp_path))
