"""A rerun of `sianms prepare` rebuilds a finished shard whose file was truncated since."""

import json

from sianms_cli.prepare import job
from sianms_cli.prepare.config import PrepareConfig


def test_a_rerun_rebuilds_a_truncated_shard_and_only_then_says_complete(tiny_dataroot, tmp_path):
    out = tmp_path / "cache"
    config = PrepareConfig(str(tiny_dataroot), "v1.0-mini", "mini_train")
    first = job.run(config, out)
    (shard,) = first.shards_run
    files = {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*.parquet"))}
    sizes = {path: info["bytes"] for path, info in first.manifest["files"].items()}
    assert sizes == {str(path): len(data) for path, data in files.items()}

    with open(out / "frustums" / f"{shard}.parquet", "r+b") as handle:
        handle.truncate(2000)
    again = job.run(config, out)
    assert (again.shards_run, again.shards_skipped) == ([shard], [])
    assert {p.relative_to(out): p.read_bytes() for p in sorted(out.rglob("*.parquet"))} == files
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] is True and manifest == first.manifest

    third = job.run(config, out)
    assert (third.shards_run, third.shards_skipped) == ([], [shard])
