#!/usr/bin/env bash
# The zoo study (docs/results/zoo_study_protocol.md) on a Slurm cluster: one array task per world
# (seeds 101-107), each running scripts/zoo_study_world.sh with --prune (synth, the calibration
# split, three caches, the siamese training, the calibration and validation evaluations; each
# stage's wall time and disk in $WORK/s<SEED>/costs.jsonl), then, once every world is done, the
# report and the results page.
#
# Usage, from a shell where `sianms` is installed (the jobs inherit its environment):
#
#   WORK=/scratch/$USER/zoo-study bash examples/slurm_zoo_study.sh
#
# Settings (environment variables):
#   WORK          where the worlds, their evaluations, the report and the logs go (required; about
#                 30 GB per world while it runs, a few hundred MB once pruned)
#   SBATCH_EXTRA  flags added to every sbatch call, e.g. "--partition=cpu --time=04:00:00"
#
# A task can be resubmitted as it is: every stage of a world resumes what an interrupted one left.
# Each world runs on 2 cores, as the protocol's costs are stated; the worlds are independent.
set -euo pipefail

STAGE="${1:-submit}"
WORK="${WORK:?set WORK to a folder for the worlds, the report and the logs}"
SEEDS=(101 102 103 104 105 106 107)
SELF="$(realpath "${BASH_SOURCE[0]}")"
# Slurm runs a copy of this file from its spool folder: the repository is found from where it was submitted.
export ZOO_STUDY_ROOT="${ZOO_STUDY_ROOT:-$(cd "$(dirname "$SELF")/.." && pwd)}"

submit() {  # sbatch [flags...] STAGE: prints the job id
    # shellcheck disable=SC2086  # SBATCH_EXTRA is a list of flags
    sbatch --parsable --export=ALL --output="$WORK/logs/%x-%A_%a.out" ${SBATCH_EXTRA:-} "$@"
}

case "$STAGE" in
    submit)
        mkdir -p "$WORK/logs"
        worlds=$(submit --cpus-per-task=2 --mem=24G --job-name=zoo-study-world --array="0-$((${#SEEDS[@]} - 1))" \
            "$SELF" world)
        report=$(submit --cpus-per-task=1 --mem=8G --job-name=zoo-study-report --dependency="afterok:$worlds" \
            "$SELF" report)
        echo "submitted: worlds $worlds, report $report (logs in $WORK/logs)"
        ;;
    world)
        "$ZOO_STUDY_ROOT/scripts/zoo_study_world.sh" "${SEEDS[$SLURM_ARRAY_TASK_ID]}" "$WORK" --prune
        ;;
    report)
        runs=()
        for S in "${SEEDS[@]}"; do runs+=("$WORK/s$S/eval-val"); done
        sianms report "${runs[@]}" --out "$WORK/report" --page "$ZOO_STUDY_ROOT/docs/results/zoo_study.md"
        ;;
    *)
        echo "error: $STAGE: unknown stage (submit, world or report)" >&2
        exit 2
        ;;
esac
