#!/usr/bin/env bash
# One world of the zoo study (docs/results/zoo_study_protocol.md): synth, carve the calibration split,
# prepare three caches, train the siamese network, evaluate calib then val with calib's thresholds.
# Every command resumes what an interrupted run left, so rerunning this script continues a world.
# Each stage's wall time and the disk its output takes are appended to STUDY_FOLDER/s<SEED>/costs.jsonl
# (one line per stage run: a rerun after an interruption adds a line for each stage it runs again).
# With --prune, the world's dataset and caches are deleted once its val evaluation is complete
# (about 30 GB per world; the report needs only the evaluation folders).
#
# Usage: scripts/zoo_study_world.sh SEED STUDY_FOLDER [--prune]
set -euo pipefail
S=${1:?seed}; W=${2:?study folder}/s$S; PRUNE=${3:-}
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mkdir -p "$W"
done_eval() { [ -f "$1/eval.json" ] && python -c "import json,sys; sys.exit(0 if json.load(open('$1/eval.json')).get('complete') else 1)"; }
# timed STAGE OUTPUT COMMAND...: run COMMAND, then record its seconds and OUTPUT's bytes.
timed() {
  local stage=$1 output=$2 start=$SECONDS; shift 2
  "$@"
  printf '{"seed": %s, "stage": "%s", "seconds": %d, "bytes": %s, "finished": "%s"}\n' "$S" "$stage" \
    $((SECONDS - start)) "$(du -sb "$output" | cut -f1)" "$(date -u +%FT%TZ)" >> "$W/costs.jsonl"
}
if done_eval "$W/eval-val"; then
  if [ "$PRUNE" = "--prune" ]; then rm -rf "$W/data" "$W"/cache-*; fi
  echo "s$S: done"; exit 0
fi
[ -f "$W/data/sianms-synth.json" ] || \
  timed synth "$W/data" sianms synth --out "$W/data" --version v1.0-trainval --scenes 120 --image-scale 0.25 \
    --seed "$S" --workers 2 --quiet
python "$ROOT/scripts/carve_calibration.py" --dataroot "$W/data" --version v1.0-trainval --split train --every 4
for SPLIT in train_fit calib val; do
  timed "prepare-$SPLIT" "$W/cache-$SPLIT" sianms prepare --dataroot "$W/data" --version v1.0-trainval \
    --split $SPLIT --seed "$S" --workers 2 --out "$W/cache-$SPLIT" --quiet
done
SIAMESE=(--cache "$W/cache-train_fit" --val-cache "$W/cache-calib" --lr 1e-3 --epochs 12 --precision fp32 --seed "$S"
         --device cpu --out "$W/siamese" --quiet)
if [ -f "$W/siamese/checkpoint.pt" ]; then
  timed siamese "$W/siamese" sianms train siamese "${SIAMESE[@]}" --resume
else
  timed siamese "$W/siamese" sianms train siamese "${SIAMESE[@]}"
fi
timed eval-calib "$W/eval-calib" sianms eval --dataroot "$W/data" --version v1.0-trainval --split calib \
  --cache "$W/cache-calib" --siamese "$W/siamese" --fpointnet zoo:fpointnet-single --nms-sweep 0.05,0.1,0.2,0.5 \
  --seed "$S" --device cpu --workers 2 --out "$W/eval-calib" --quiet
timed eval-val "$W/eval-val" sianms eval --dataroot "$W/data" --version v1.0-trainval --split val \
  --cache "$W/cache-val" --siamese "$W/siamese" --fpointnet zoo:fpointnet-single --thresholds-from "$W/eval-calib" \
  --seed "$S" --device cpu --workers 2 --out "$W/eval-val" --quiet
if [ "$PRUNE" = "--prune" ]; then rm -rf "$W/data" "$W"/cache-*; fi
echo "s$S: done"
