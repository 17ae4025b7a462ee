#!/usr/bin/env bash
# The zoo study's seven worlds one after another (docs/results/zoo_study_protocol.md), each pruned of
# its dataset and caches once evaluated; rerun to continue (finished worlds are skipped, an interrupted
# one resumes). On a cluster, run scripts/zoo_study_world.sh once per seed instead (an array job).
#
# Usage: scripts/zoo_study.sh STUDY_FOLDER
set -euo pipefail
FOLDER=${1:?study folder}
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
for S in 101 102 103 104 105 106 107; do
  "$ROOT/scripts/zoo_study_world.sh" "$S" "$FOLDER" --prune
done
