#!/usr/bin/env bash
# Which world does this machine draw from a seed, and does turning numpy's AVX-512 paths off make
# it draw the AVX2 machines' one? Writes the CI gate's quick-demo dataset (v1.0-mini, 2 scenes,
# image scale 0.25, seed 1) twice, with numpy as it is and with X86_V4 AVX512_ICL AVX512_SPR
# disabled (numpy 2.4 needs all three names), and names the CI baseline whose dataset_sha256 each
# fingerprint equals. On an AVX-512 machine the second line answering `AuthenticAMD.AVX2` would
# confirm numpy's AVX-512 (SVML) paths as the cause of README "The CI gate"'s AVX2 finding; the
# tables and sensor folders whose bytes the two runs differ in are listed, to show where.
# About a minute a run on 2 cores; needs the venv with sianms installed active.
set -euo pipefail
cd "$(dirname "$0")/.."
scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT
.ci/platform
NPY_DISABLE_CPU_FEATURES="" sianms synth --version v1.0-mini --scenes 2 --image-scale 0.25 --seed 1 --workers 2 \
    --quiet --out "$scratch/as-is"
NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" sianms synth --version v1.0-mini --scenes 2 \
    --image-scale 0.25 --seed 1 --workers 2 --quiet --out "$scratch/avx512-off"
python - "$scratch" <<'PY'
import hashlib, json, sys
from pathlib import Path
from sianms_cli.nuscenes.fingerprint import TABLE_NAMES, dataset_fingerprint

def part_digests(dataroot: Path) -> dict[str, str]:
    """SHA-256 of each table and of each sensor folder's files (names and bytes, in name order)."""
    digests = {table: hashlib.sha256((dataroot / "v1.0-mini" / f"{table}.json").read_bytes()).hexdigest()
               for table in TABLE_NAMES}
    for folder in sorted(dataroot.glob("s*/*")):
        digest = hashlib.sha256()
        for path in sorted(folder.iterdir()):
            digest.update(path.name.encode() + b"\0" + path.read_bytes())
        digests[f"{folder.parent.name}/{folder.name}"] = digest.hexdigest()
    return digests

known = {}
for path in sorted(Path(".ci").glob("demo-quick-report.*.json")):
    platform = path.name.removeprefix("demo-quick-report.").removesuffix(".json")
    known.setdefault(json.loads(path.read_text())["config"]["dataset_sha256"], []).append(platform)
runs = {"as-is": "numpy as it is", "avx512-off": "numpy's AVX-512 paths off"}
for folder, label in runs.items():
    fingerprint = dataset_fingerprint(Path(sys.argv[1]) / folder / "v1.0-mini")
    print(f"{label}: {fingerprint[:12]}, the dataset of {', '.join(known.get(fingerprint, ['no baseline']))}")
as_is, off = (part_digests(Path(sys.argv[1]) / folder) for folder in runs)
differing = [part for part in as_is if as_is[part] != off.get(part)]
print(f"parts that differ between the two: {', '.join(differing) or 'none'}")
PY
