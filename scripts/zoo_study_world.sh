#!/usr/bin/env bash
# One world of the zoo study (docs/results/zoo_study_protocol.md): synth, carve the calibration split,
# prepare three caches, train the siamese network, evaluate calib then val with calib's thresholds.
# Every command resumes what an interrupted run left, so rerunning this script continues a world.
# Each stage's wall time and the disk its output takes are appended to STUDY_FOLDER/s<SEED>/costs.jsonl
# (one line per stage run: a rerun after an interruption adds a line for each stage it runs again).
# With --prune, the world's dataset and caches are deleted once its val evaluation is complete
# (about 30 GB per world; the report needs only the evaluation folders).
#
# With --arm ENTRY, a further arm on a world whose first arm (zoo:fpointnet-single) is done
# (docs/results/zoo_study_multiview_protocol.md): the same dataset (made again from the seed if it was
# pruned), calibration and validation caches and siamese run, with zoo:ENTRY as the detector, into
# eval-calib-ENTRY and eval-val-ENTRY; costs go to costs-ENTRY.jsonl. Before it, the first arm's val is
# evaluated again (eval-val-again, with the first arm's calibration: eval refuses it unless the dataset,
# cache and networks are the first arm's) and must give byte-identical results files (the boxes every
# metric is computed from), so both arms are evaluated by the same code on the same inputs.
#
# Usage: scripts/zoo_study_world.sh SEED STUDY_FOLDER [--prune] [--arm ENTRY]
set -euo pipefail
S=${1:?seed}; W=${2:?study folder}/s$S; shift 2
PRUNE=; ARM=
while [ $# -gt 0 ]; do
  case "$1" in
    --prune) PRUNE=1; shift ;;
    --arm) ARM=${2:?--arm needs a zoo entry name}; shift 2 ;;
    *) echo "error: $1: unknown option (--prune, --arm ENTRY)" >&2; exit 2 ;;
  esac
done
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
COSTS="$W/costs${ARM:+-$ARM}.jsonl"
mkdir -p "$W"
done_eval() { [ -f "$1/eval.json" ] && python -c "import json,sys; sys.exit(0 if json.load(open('$1/eval.json')).get('complete') else 1)"; }
# timed STAGE OUTPUT COMMAND...: run COMMAND, then record its seconds and OUTPUT's bytes.
timed() {
  local stage=$1 output=$2 start=$SECONDS; shift 2
  "$@"
  printf '{"seed": %s, "stage": "%s", "seconds": %d, "bytes": %s, "finished": "%s"}\n' "$S" "$stage" \
    $((SECONDS - start)) "$(du -sb "$output" | cut -f1)" "$(date -u +%FT%TZ)" >> "$COSTS"
}
prune() { if [ -n "$PRUNE" ]; then rm -rf "$W/data" "$W"/cache-*; fi; echo "s$S${ARM:+ ($ARM)}: done"; }
# evaluate SPLIT OUTPUT ENTRY [FLAGS...]: one evaluation of the world's SPLIT cache with zoo:ENTRY.
evaluate() {
  local split=$1 output=$2 entry=$3; shift 3
  timed "$(basename "$output")" "$output" sianms eval --dataroot "$W/data" --version v1.0-trainval --split "$split" \
    --cache "$W/cache-$split" --siamese "$W/siamese" --fpointnet "zoo:$entry" --seed "$S" --device cpu \
    --workers 2 --out "$output" --quiet "$@"
}
LAST="$W/eval-val${ARM:+-$ARM}"
if done_eval "$LAST"; then prune; exit 0; fi
if [ -n "$ARM" ] && ! done_eval "$W/eval-val"; then
  echo "error: $W/eval-val: the first arm of world $S is not done; run it before --arm" >&2; exit 2
fi
[ -f "$W/data/sianms-synth.json" ] || \
  timed synth "$W/data" sianms synth --out "$W/data" --version v1.0-trainval --scenes 120 --image-scale 0.25 \
    --seed "$S" --workers 2 --quiet
python "$ROOT/scripts/carve_calibration.py" --dataroot "$W/data" --version v1.0-trainval --split train --every 4
# A further arm reuses the siamese run, so it needs no fitting cache.
SPLITS=(train_fit calib val)
[ -z "$ARM" ] || SPLITS=(calib val)
for SPLIT in "${SPLITS[@]}"; do
  timed "prepare-$SPLIT" "$W/cache-$SPLIT" sianms prepare --dataroot "$W/data" --version v1.0-trainval \
    --split "$SPLIT" --seed "$S" --workers 2 --out "$W/cache-$SPLIT" --quiet
done
if [ -z "$ARM" ]; then
  SIAMESE=(--cache "$W/cache-train_fit" --val-cache "$W/cache-calib" --lr 1e-3 --epochs 12 --precision fp32
           --seed "$S" --device cpu --out "$W/siamese" --quiet)
  if [ -f "$W/siamese/checkpoint.pt" ]; then
    timed siamese "$W/siamese" sianms train siamese "${SIAMESE[@]}" --resume
  else
    timed siamese "$W/siamese" sianms train siamese "${SIAMESE[@]}"
  fi
  evaluate calib "$W/eval-calib" fpointnet-single --nms-sweep 0.05,0.1,0.2,0.5
  evaluate val "$W/eval-val" fpointnet-single --thresholds-from "$W/eval-calib"
else
  done_eval "$W/eval-val-again" || evaluate val "$W/eval-val-again" fpointnet-single --thresholds-from "$W/eval-calib"
  for FILE in "$W"/eval-val/results_*.json; do
    cmp -s "$FILE" "$W/eval-val-again/$(basename "$FILE")" || {
      echo "error: $W/eval-val-again: $(basename "$FILE") differs from the first arm's; the arms would not be" \
           "evaluated alike" >&2; exit 1; }
  done
  evaluate calib "$W/eval-calib-$ARM" "$ARM" --nms-sweep 0.05,0.1,0.2,0.5
  evaluate val "$LAST" "$ARM" --thresholds-from "$W/eval-calib-$ARM"
fi
prune
