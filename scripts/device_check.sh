#!/usr/bin/env bash
# The GPU checks in one call, well inside 10 minutes on one H200: the opt-in CUDA tests
# (both trainings in mixed precision, an fp16 resume with its loss scale); training throughput
# per precision (network steps alone, then whole siamese epochs); both trainings under a
# one-rank torchrun on NCCL beside the same run in one process; whole F-PointNets epochs at the
# original's 1,024 points and batch 32; and the evaluation's networks on the GPU.
#
# Usage: scripts/device_check.sh [LOG_FOLDER [CHECK ...]]   (from anywhere; LOG_FOLDER defaults to
# $OUT, else a temporary folder; CHECK names the checks to run, all by default: nccl-* and
# fpointnet-epochs train on the cache siamese-epochs makes). The python3 on PATH must hold torch
# with CUDA and sianms's dependencies; the repository goes on PYTHONPATH, so nothing is built or
# installed. Each check has its own
# time limit and a failed one does not stop the rest; the exit code counts the failures.
# NCCL across ranks needs two GPUs (two ranks may not share one): one rank checks NCCL's set-up,
# the DDP wrapper and the all-reduced batch norm on the GPU, not the traffic between GPUs.
set -uo pipefail
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
logs="${1:-${OUT:-$(mktemp -d)}}"
wanted=" ${*:2} "
export work="$(mktemp -d)"
mkdir -p "$logs"
failures=0

check() {  # check NAME SECONDS COMMAND...: run one check, its output to the screen and LOGS/NAME.log
    local name="$1" seconds="$2" started=$SECONDS
    shift 2
    [ "$wanted" = "  " ] || [[ "$wanted" == *" $name "* ]] || return 0
    echo "== $name"
    timeout "$seconds" "$@" 2>&1 | tee "$logs/$name.log"
    local code=${PIPESTATUS[0]}
    echo "== $name: exit $code, $((SECONDS - started)) s"
    [ "$code" -eq 0 ] || failures=$((failures + 1))
}

sianms() { python3 -m sianms_cli "$@"; }

nccl_pair() {  # one training in one process, then the same under a one-rank torchrun (NCCL)
    local model="$1"
    shift
    sianms train "$model" --cache "$work/train/cache" --out "$work/$model-1p" --device cuda --quiet "$@" &&
        python3 -m torch.distributed.run --standalone --nproc-per-node 1 -m sianms_cli train "$model" \
            --cache "$work/train/cache" --out "$work/$model-nccl" --device cuda --quiet "$@" &&
        python3 - "$work/$model-1p/metrics.csv" "$work/$model-nccl/metrics.csv" <<'EOF'
import csv, sys
rows = [list(csv.DictReader(open(path))) for path in sys.argv[1:]]
loss = "train_loss" if "train_loss" in rows[0][0] else "train_total"
for epoch, (one, ranked) in enumerate(zip(*rows), 1):
    print(f"epoch {epoch}: {loss} one process {float(one[loss]):.5f}, torchrun/NCCL {float(ranked[loss]):.5f}")
EOF
}

fpointnet_epochs() {  # whole epochs at the original's settings, per precision; frustums/s after epoch 1
    for precision in fp32 bf16; do
        sianms train fpointnet --cache "$work/train/cache" --out "$work/fpn-$precision" --device cuda \
            --precision "$precision" --epochs 3 --min-box-height 0 --quiet --json > /dev/null || return 1
        python3 - "$work/fpn-$precision/metrics.csv" "$precision" <<'EOF'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))[1:]
count = sum(int(row["train_count"]) for row in rows)
seconds = sum(float(row["train_seconds"]) for row in rows)
print(f"{sys.argv[2]}: {count / seconds:.1f} training frustums/s over epochs 2-3 "
      f"(1,024 points, batch 32; {count} frustums in {seconds:.1f} s)")
EOF
    done
}

check facts 60 bash -c 'nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader &&
    python3 -c "import torch; print(\"torch\", torch.__version__, \"bf16\", torch.cuda.is_bf16_supported())"'
check cuda-tests 180 env PYTEST_DISABLE_PLUGIN_AUTOLOAD=1 python3 -m pytest -q -p no:cacheprovider -m cuda tests/training/test_cuda.py
check fpointnet-steps 120 python3 bench/train_fpointnet.py --device cuda --points 1024,256 \
    --paths native:fp32,native:bf16,native:fp16 --steps 50
check fpointnet-batches 120 bash -c 'for batch in 256 1024; do
    python3 bench/train_fpointnet.py --device cuda --points 1024 --batch $batch --paths native:fp32,native:bf16 --steps 20; done'
check siamese-epochs 240 python3 bench/train.py --device cuda --precisions fp32,bf16 --scenes 2 --epochs 3 \
    --keep "$work/train"
export -f sianms nccl_pair fpointnet_epochs  # timeout runs commands, not functions: bash -c runs them
check nccl-siamese 120 bash -c 'nccl_pair siamese --epochs 2'
check nccl-fpointnet 120 bash -c 'nccl_pair fpointnet --epochs 2 --num-points 256 --num-object-points 128 --min-box-height 0'
check fpointnet-epochs 180 bash -c fpointnet_epochs
check eval-networks 240 python3 bench/eval.py --device cuda --scenes 2
echo "device checks: $failures failed; logs in $logs"
rm -rf "$work"
exit "$failures"
