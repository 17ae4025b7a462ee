#!/usr/bin/env bash
# One world of the zoo study (docs/results/zoo_study_protocol.md): synth, carve the calibration split,
# prepare three caches, train the siamese network, evaluate calib then val with calib's thresholds.
# Every command resumes what an interrupted run left, so rerunning this script continues a world.
# With --prune, the world's dataset and caches are deleted once its val evaluation is complete
# (about 30 GB per world; the report needs only the evaluation folders).
#
# Usage: scripts/zoo_study_world.sh SEED STUDY_FOLDER [--prune]
set -euo pipefail
S=${1:?seed}; W=${2:?study folder}/s$S; PRUNE=${3:-}
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mkdir -p "$W"
done_eval() { [ -f "$1/eval.json" ] && python -c "import json,sys; sys.exit(0 if json.load(open('$1/eval.json')).get('complete') else 1)"; }
if done_eval "$W/eval-val"; then echo "s$S: done"; exit 0; fi
[ -f "$W/data/sianms-synth.json" ] || \
  sianms synth --out "$W/data" --version v1.0-trainval --scenes 120 --image-scale 0.25 --seed "$S" --workers 2 --quiet
python "$ROOT/scripts/carve_calibration.py" --dataroot "$W/data" --version v1.0-trainval --split train --every 4
for SPLIT in train_fit calib val; do
  sianms prepare --dataroot "$W/data" --version v1.0-trainval --split $SPLIT --seed "$S" --workers 2 \
    --out "$W/cache-$SPLIT" --quiet
done
sianms train siamese --cache "$W/cache-train_fit" --val-cache "$W/cache-calib" --lr 1e-3 --epochs 12 \
  --precision fp32 --seed "$S" --device cpu --out "$W/siamese" --quiet --resume 2>/dev/null || \
  sianms train siamese --cache "$W/cache-train_fit" --val-cache "$W/cache-calib" --lr 1e-3 --epochs 12 \
  --precision fp32 --seed "$S" --device cpu --out "$W/siamese" --quiet
sianms eval --dataroot "$W/data" --version v1.0-trainval --split calib --cache "$W/cache-calib" \
  --siamese "$W/siamese" --fpointnet zoo:fpointnet-single --nms-sweep 0.05,0.1,0.2,0.5 \
  --seed "$S" --device cpu --workers 2 --out "$W/eval-calib" --quiet
sianms eval --dataroot "$W/data" --version v1.0-trainval --split val --cache "$W/cache-val" \
  --siamese "$W/siamese" --fpointnet zoo:fpointnet-single --thresholds-from "$W/eval-calib" \
  --seed "$S" --device cpu --workers 2 --out "$W/eval-val" --quiet
if [ "$PRUNE" = "--prune" ]; then rm -rf "$W/data" "$W"/cache-*; fi
echo "s$S: done"
