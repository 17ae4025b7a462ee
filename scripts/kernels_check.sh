#!/usr/bin/env bash
# Does this machine draw the CI gate's quick-demo dataset (v1.0-mini, 2 scenes, image scale 0.25,
# seed 1) as the baselines do? Writes it twice, with the machine's native kernels
# (SIANMS_NATIVE_KERNELS=1) and with the AVX2 kernels sianms asks for on every AVX2 CPU
# (sianms_cli/kernels.py), names the CI baseline whose dataset_sha256 each fingerprint equals and
# lists the tables and sensor folders the two differ in. On an AVX2-only machine both runs are
# one; on an AVX-512 one the second should name the AuthenticAMD.AVX2 baseline's dataset
# (README, "The CI gate"). About a minute a run on 2 cores; needs the venv with sianms installed active.
set -euo pipefail
cd "$(dirname "$0")/.."
scratch="$(mktemp -d)"
trap 'rm -rf "$scratch"' EXIT
echo "$(SIANMS_NATIVE_KERNELS=1 .ci/platform) natively, $(.ci/platform) as sianms runs"
SIANMS_NATIVE_KERNELS=1 sianms synth --version v1.0-mini --scenes 2 --image-scale 0.25 --seed 1 --workers 2 \
    --quiet --out "$scratch/native"
sianms synth --version v1.0-mini --scenes 2 --image-scale 0.25 --seed 1 --workers 2 --quiet --out "$scratch/avx2"
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
runs = {"native": "native kernels", "avx2": "AVX2 kernels"}
for folder, label in runs.items():
    fingerprint = dataset_fingerprint(Path(sys.argv[1]) / folder / "v1.0-mini")
    print(f"{label}: {fingerprint[:12]}, the dataset of {', '.join(known.get(fingerprint, ['no baseline']))}")
native, avx2 = (part_digests(Path(sys.argv[1]) / folder) for folder in runs)
differing = [part for part in native if native[part] != avx2.get(part)]
print(f"parts that differ between the two: {', '.join(differing) or 'none'}")
PY
