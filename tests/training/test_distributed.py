"""Two processes under torchrun (gloo, CPU), each reading its own stream of shards, train what one
process with the same two streams trains."""

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from sianms_cli.cli._app import INTERRUPTED
from sianms_cli.kernels import AVX2_SETTINGS, NATIVE_SWITCH, has_native_bf16
from sianms_cli.training.run import load_checkpoint

SIAMESE = ["--epochs", "2", "--dim", "8", "--conv-channels", "8,8", "--hidden", "16", "--lr", "1e-3",
           "--batch-size", "4", "--device", "cpu", "--quiet"]
# One batch per epoch (each stream holds fewer than 256 frustums): epoch 1 is the initial weights' loss.
FPOINTNET = ["--epochs", "2", "--num-points", "64", "--num-object-points", "32", "--batch-size", "512",
             "--min-box-height", "0", "--device", "cpu", "--quiet"]


def native_environment():
    """This environment with the CPU's own kernels: the suite runs AVX2 ones, whose settings the commands it
    starts would inherit and keep (a user's own), and under which bfloat16 is emulated and refused."""
    environment = {key: value for key, value in os.environ.items() if key not in AVX2_SETTINGS}
    return {**environment, NATIVE_SWITCH: "1"}


def torchrun_two(tmp_path, *arguments, environment=None):
    """Two local processes of one thread under torchrun, its logs under tmp_path (left to itself, torchrun
    leaves a torchelastic_* folder in /tmp on every launch)."""
    return subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
                           "--log-dir", str(tmp_path / "torchrun-logs"), *arguments],
                          env={**(environment or os.environ), "OMP_NUM_THREADS": "1"}, capture_output=True, text=True)


def train_twice(command, tmp_path, environment=None):
    """(checkpoint of 2 gloo processes, checkpoint of 1 process with --streams 2) of a `sianms train` command."""
    environment = {**(environment or os.environ), "OMP_NUM_THREADS": "1"}
    done = torchrun_two(tmp_path, "-m", "sianms_cli", *command, "--out", str(tmp_path / "ddp"),
                        environment=environment)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("trained epochs 1-2 into") == 1, "rank 0 alone reports"
    subprocess.run([sys.executable, "-m", "sianms_cli", *command, "--streams", "2", "--out", str(tmp_path / "one")],
                   check=True, env=environment, capture_output=True)
    assert json.loads((tmp_path / "ddp" / "config.json").read_text())["streams"] == 2  # one per process
    return load_checkpoint(tmp_path / "ddp" / "checkpoint.pt"), load_checkpoint(tmp_path / "one" / "checkpoint.pt")


def weight_differences(two, one):
    """|two - one| of every floating-point entry of the state dicts, flattened."""
    return torch.cat([(two.model[key].double() - value.double()).abs().flatten()
                      for key, value in one.model.items() if value.is_floating_point()])


def test_siamese_two_gloo_processes_equal_one(two_shard_cache, tiny_caches, tmp_path):
    train, val = two_shard_cache, tiny_caches[1]
    two, one = train_twice(["train", "siamese", "--cache", str(train), "--val-cache", str(val), *SIAMESE], tmp_path)
    # The gradient sums differ in rounding only, but Adam divides by sqrt(v): where a gradient
    # is ~0 (a dead ReLU unit) rounding can flip a step of size ~lr (1e-3). So: no weight
    # differs by more than lr per optimizer step taken, and the median one by under 10 % of lr.
    steps = sum(math.ceil(row["train_references"] / 4) for row in one.history)
    differences = weight_differences(two, one)
    assert differences.max().item() <= 1e-3 * steps
    assert differences.median().item() < 1e-4
    for a, b in zip(two.history, one.history):
        assert a["train_references"] == b["train_references"]
        assert a["train_loss"] == pytest.approx(b["train_loss"], rel=1e-3)


def test_a_siamese_sweep_under_torchrun_is_tabulated_by_rank_0(two_shard_cache, tiny_caches, tmp_path):
    """The other rank trains each d too but does not validate: its rows must not reach the table."""
    command = ["train", "siamese", "--cache", str(two_shard_cache), "--val-cache", str(tiny_caches[1]),
               "--sweep-dims", "2,4", "--epochs", "1", "--conv-channels", "8,8", "--hidden", "16", "--batch-size", "4",
               "--device", "cpu", "--quiet", "--out", str(tmp_path / "sweep")]
    done = torchrun_two(tmp_path, "-m", "sianms_cli", *command)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("sweep of d = 2,4") == 1
    rows = json.loads((tmp_path / "sweep" / "sweep.json").read_text())["rows"]
    assert [row["dim"] for row in rows] == [2, 4] and all(row["val_auc"] is not None for row in rows)


def test_fpointnet_steps_on_two_gloo_processes_equal_one_in_float64(tmp_path):
    """Batch norm over both ranks, the global batch's random draws, the loss weights: in float64
    three steps on shares of 3 and 4 frustums end where one process ends, to rounding."""
    script = str(Path(__file__).with_name("fpointnet_ddp_steps.py"))
    environment = {**os.environ, "OMP_NUM_THREADS": "1"}
    subprocess.run([sys.executable, script, str(tmp_path / "one.pt")], check=True, env=environment)
    done = torchrun_two(tmp_path, script, str(tmp_path / "two.pt"))
    assert done.returncode == 0, done.stderr[-3000:]
    one, two = torch.load(tmp_path / "one.pt"), torch.load(tmp_path / "two.pt")
    assert two["losses"] == pytest.approx(one["losses"], rel=1e-8)
    for key, value in one["state"].items():
        torch.testing.assert_close(two["state"][key], value, rtol=0, atol=1e-7, msg=key)


def test_fpointnet_two_gloo_processes_train_as_one(two_shard_cache, two_shard_dataroot, tiny_caches, tmp_path):
    """The command under torchrun: the same frustums and union frustums (built once, by rank 0),
    rank 0 validating and writing. In float32 the runs agree to rounding until the first Adam
    step, which turns rounding of near-zero gradients (and the odd point whose mask flips) into
    steps of ±lr: measured on about 1 % of the weights after one step, so the later losses
    part by a few per cent and only the weights' bounds are checked after it."""
    train, val = two_shard_cache, tiny_caches[1]
    two, one = train_twice(["train", "fpointnet", "--cache", str(train), "--val-cache", str(val), "--multiview",
                            "--dataroot", str(two_shard_dataroot), *FPOINTNET], tmp_path)
    first = one.history[0]
    assert first["train_count"] > 0 and first["train_union_count"] > 0
    for a, b in zip(two.history, one.history):
        assert (a["train_count"], a["train_union_count"]) == (b["train_count"], b["train_union_count"])
        assert a["val_count"] == b["val_count"] > 0
    # Epoch 1 is one batch: the loss of the same initial weights on the same frustums. The per-point
    # segmentation loss agrees to rounding; the terms after the masking agree unless a point whose
    # logits tie to rounding flips its mask (measured: 1 of 13,248 points, margin 1e-5, moved the
    # centre loss by 5e-4); the split batch's exact equality is the float64 test's above.
    assert two.history[0]["train_mask"] == pytest.approx(first["train_mask"], rel=1e-5)
    for term in ("total", "center", "corner", "heading_class", "size_residual"):
        assert two.history[0][f"train_{term}"] == pytest.approx(first[f"train_{term}"], rel=1e-2)
    parameters = torch.cat([(two.model[key] - value).abs().flatten() for key, value in one.model.items()
                            if value.is_floating_point() and "running" not in key])
    assert parameters.max().item() <= 2 * 1e-3 * len(one.history) and parameters.median().item() < 1e-4


def test_streams_the_processes_cannot_share_are_one_error_line(tiny_caches, tmp_path):
    train, _ = tiny_caches
    done = torchrun_two(tmp_path, "-m", "sianms_cli", "train", "fpointnet", "--cache", str(train),
                        "--out", str(tmp_path / "run"), "--streams", "3", "--device", "cpu")
    assert done.returncode != 0
    assert ("error: --streams 3 is not a multiple of the 2 processes: each runs the same number of streams\n"
            in done.stderr)
    assert not (tmp_path / "run").exists()


@pytest.mark.skipif(not has_native_bf16(), reason="bfloat16 is refused where the CPU would emulate it")
def test_fpointnet_in_bf16_on_two_gloo_processes_takes_the_first_step_as_one(two_shard_cache, tmp_path):
    """Autocast under DDP: batch norm's all-reduced statistics are summed in float32, so the two
    processes' first epoch (one batch of the same initial weights) gives one process's total and
    per-point segmentation loss within 1 %. Summed in bfloat16, as a CPU's autocast sums, the total
    loss came out 104.8 against 101.7 (3 %). The terms after the masking move with the points whose
    bfloat16 logits tie and flip (the size residual by 1.8 % in this batch): within 5 %."""
    command = ["train", "fpointnet", "--cache", str(two_shard_cache), "--precision", "bf16", *FPOINTNET]
    two, one = train_twice(command, tmp_path, native_environment())
    assert two.extra["precision"] == one.extra["precision"] == "bf16"
    for term, within in [("total", 1e-2), ("mask", 1e-2), ("center", 5e-2), ("corner", 5e-2),
                         ("heading_class", 5e-2), ("size_residual", 5e-2)]:
        assert two.history[0][f"train_{term}"] == pytest.approx(one.history[0][f"train_{term}"], rel=within), term


def _rank_process(parent: int, rank: int) -> int | None:
    """The pid of the torchrun worker of ``rank`` under the launcher ``parent``, once it runs."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) != parent:
                continue
            if f"RANK={rank}".encode() in (stat.parent / "environ").read_bytes().split(b"\0"):
                return int(stat.parent.name)
        except (OSError, ValueError, IndexError):
            continue
    return None


def test_a_rank_killed_mid_run_leaves_the_other_one_error_line_and_a_loadable_checkpoint(two_shard_cache, tmp_path):
    """Rank 1 killed (the OOM killer, a scheduler) after the first checkpoint: rank 0's collective
    fails, and it says so in one line, with no traceback of its own, then exits when torchrun
    stops it; the last checkpoint is whole, so --resume can go on from it."""
    out = tmp_path / "run"
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
               "--log-dir", str(tmp_path / "torchrun-logs"), "-m", "sianms_cli", "train", "fpointnet",
               "--cache", str(two_shard_cache), *FPOINTNET, "--epochs", "500", "--out", str(out)]
    launcher = subprocess.Popen(command, env={**os.environ, "OMP_NUM_THREADS": "1"}, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while not (out / "checkpoint.pt").is_file() and time.monotonic() < deadline and launcher.poll() is None:
            time.sleep(0.2)
        victim = _rank_process(launcher.pid, 1)
        assert victim is not None and (out / "checkpoint.pt").is_file(), "the run never reached its first checkpoint"
        os.kill(victim, signal.SIGKILL)
        _, stderr = launcher.communicate(timeout=120)
    finally:
        if launcher.poll() is None:
            os.killpg(launcher.pid, signal.SIGKILL)
            launcher.communicate()
    assert launcher.returncode != 0
    own = [line for line in stderr.splitlines()
           if line.startswith(("error:", "interrupted", "[rank0]", "Exception ignored"))]
    # Rank 0 meets the lost peer in its next collective, unless torchrun, which watches its ranks,
    # sends it SIGTERM first (rank 0 validating alone, on a loaded machine): one line either way.
    assert own in (["error: another process of this torchrun run stopped; its own lines or torchrun's failure "
                    "summary say why"], [f"interrupted (SIGTERM); {INTERRUPTED}"])
    assert load_checkpoint(out / "checkpoint.pt").epoch >= 1
