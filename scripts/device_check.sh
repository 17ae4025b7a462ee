#!/usr/bin/env bash
# Issue 9's GPU checks, for a session lent a device machine (the `run` tool runs this from the
# repository root): the CUDA tests (both trainings in mixed precision, an fp16 resume with its
# loss scale), then training and inference throughput per precision on the GPU. One call, well
# under its 10 minutes on one H200. It fetches nothing: the machine's python3 holds torch,
# pyarrow, scipy, typer and matplotlib, so the project goes in without its dependencies.
# NCCL DDP needs two GPUs (two ranks may not share one): a one-GPU machine cannot check it.
set -euo pipefail
cd "$(dirname "$0")/.."
python3 -m pip install --quiet --no-deps --no-build-isolation -e .
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import torch; print('torch', torch.__version__, 'bf16', torch.cuda.is_bf16_supported())"
python3 -m pytest -q -p no:cacheprovider -m cuda tests/training/test_cuda.py
python3 bench/train_fpointnet.py --device cuda --points 1024,256 --precisions fp32,bf16,fp16 --steps 20
python3 bench/train.py --device cuda --precisions fp32,bf16 --scenes 2 --epochs 3
