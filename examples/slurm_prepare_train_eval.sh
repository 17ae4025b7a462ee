#!/usr/bin/env bash
# The whole study on a Slurm cluster: prepare and eval as array jobs (sianms --shard K/N), both
# trainings under torchrun on GPU nodes, then the report, each stage waiting for the one before.
#
# Usage, from a shell where `sianms` is installed (the jobs inherit its environment):
#
#   DATAROOT=/data/nuscenes WORK=/scratch/$USER/sianms bash examples/slurm_prepare_train_eval.sh
#
# Settings (environment variables):
#   DATAROOT   the nuScenes dataroot (required)
#   WORK       where the caches, runs, evaluation and logs go (required)
#   VERSION    v1.0-trainval (default) or v1.0-mini
#   TRAIN_SPLIT, VAL_SPLIT   train and val (default); mini_train and mini_val for the mini
#   SHARDS     array tasks for prepare and eval (default 16); each does the scenes at positions
#              K mod SHARDS, and runs into one folder share the work scene by scene
#   DETECTOR   simulated (default) or file:PATH, an external detections file (docs/nuscenes.md)
#   WEIGHTS    a local torchvision COCO checkpoint: ROI features from ResNet-50 res4
#              (--backbone resnet50-c4); empty, the default: the tiny backbone
#   GPUS       GPUs (torchrun processes) per training job (default 1)
#   SBATCH_EXTRA  flags added to every sbatch call, e.g. "--partition=gpu --time=24:00:00"
#
# Every job can be resubmitted as it is: prepare and eval resume scene by scene, the trainings
# from their last epoch (--resume).
set -euo pipefail

STAGE="${1:-submit}"
DATAROOT="${DATAROOT:?set DATAROOT to the nuScenes dataroot}"
WORK="${WORK:?set WORK to a folder for the caches, runs and logs}"
VERSION="${VERSION:-v1.0-trainval}"
TRAIN_SPLIT="${TRAIN_SPLIT:-train}"
VAL_SPLIT="${VAL_SPLIT:-val}"
SHARDS="${SHARDS:-16}"
DETECTOR="${DETECTOR:-simulated}"
WEIGHTS="${WEIGHTS:-}"
GPUS="${GPUS:-1}"
SELF="$(realpath "${BASH_SOURCE[0]}")"

# The ROI features' backbone: ResNet-50 res4 from the given checkpoint, else the tiny one.
backbone=(--backbone tiny)
if [ -n "$WEIGHTS" ]; then
    backbone=(--backbone resnet50-c4 --weights "$WEIGHTS")
fi

submit() {  # sbatch [flags...] STAGE [args...]: prints the job id
    # shellcheck disable=SC2086  # SBATCH_EXTRA is a list of flags
    sbatch --parsable --export=ALL --output="$WORK/logs/%x-%A_%a.out" ${SBATCH_EXTRA:-} "$@"
}

case "$STAGE" in
    submit)
        mkdir -p "$WORK/logs"
        last=$((SHARDS - 1))
        cpu=(--cpus-per-task=4 --mem=32G)
        gpu=(--cpus-per-task=$((4 * GPUS)) --mem=64G --gres="gpu:$GPUS")
        prep_train=$(submit "${cpu[@]}" --job-name=prepare-train --array="0-$last" "$SELF" prepare "$TRAIN_SPLIT" cache-train)
        prep_val=$(submit "${cpu[@]}" --job-name=prepare-val --array="0-$last" "$SELF" prepare "$VAL_SPLIT" cache-val)
        after_prepare="afterok:$prep_train:$prep_val"
        siamese=$(submit "${gpu[@]}" --job-name=train-siamese --dependency="$after_prepare" "$SELF" train siamese)
        fpointnet=$(submit "${gpu[@]}" --job-name=train-fpointnet --dependency="$after_prepare" "$SELF" train fpointnet)
        evaluation=$(submit "${cpu[@]}" --job-name=eval --array="0-$last" --dependency="afterok:$siamese:$fpointnet" \
            "$SELF" eval)
        report=$(submit --cpus-per-task=1 --mem=8G --job-name=report --dependency="afterok:$evaluation" "$SELF" report)
        echo "submitted: prepare $prep_train $prep_val, train $siamese $fpointnet, eval $evaluation, report $report"
        ;;
    prepare)  # one array task: the scenes at positions K mod N of the split
        sianms prepare --dataroot "$DATAROOT" --version "$VERSION" --split "$2" --out "$WORK/$3" \
            --detector "$DETECTOR" "${backbone[@]}" --workers "${SLURM_CPUS_PER_TASK:-1}" \
            --shard "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT" --quiet
        ;;
    train)  # one training on GPUS processes; --resume continues a requeued or resubmitted run
        torchrun --standalone --nproc-per-node "$GPUS" --log-dir "$WORK/logs/torchrun-$2" \
            -m sianms_cli train "$2" --cache "$WORK/cache-train" --val-cache "$WORK/cache-val" \
            --out "$WORK/$2" --device cuda --resume --quiet
        ;;
    eval)  # one array task; whichever task finds every scene done writes the results
        sianms eval --dataroot "$DATAROOT" --version "$VERSION" --split "$VAL_SPLIT" --cache "$WORK/cache-val" \
            --siamese "$WORK/siamese" --fpointnet "$WORK/fpointnet" --out "$WORK/eval" \
            --shard "$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT" --quiet
        ;;
    report)
        sianms report "$WORK/eval" --quiet
        echo "report: $WORK/eval/report/report.html"
        ;;
    *)
        echo "error: $STAGE: unknown stage (submit, prepare, train, eval, report)" >&2
        exit 2
        ;;
esac
