"""training/precision.py and --precision in both trainings: what each mode resolves to, float32
unchanged, bfloat16 trainings that learn and resume exactly, the fp16 loss scaler skipping an
overflowed step and coming back with a resumed run, and one error line for a mode the device lacks."""

import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.errors import SianmsError
from sianms_cli.training import fpointnet as fpointnet_training
from sianms_cli.training import precision as precision_module
from sianms_cli.training.fpointnet import LOSS_TERMS, FPointNetConfig
from sianms_cli.training.fpointnet import run as train_fpointnet
from sianms_cli.training.precision import MixedPrecision, float32_outputs, resolve_precision
from sianms_cli.training.run import load_checkpoint
from sianms_cli.training.siamese import SiameseConfig
from sianms_cli.training.siamese import run as train_siamese

CPU = torch.device("cpu")
# 32 points (16 masked): on a CPU without native bfloat16 its matrix products are emulated, 7x slower
# than float32's (an AVX2 EPYC: 0.70 s against 0.10 s for a step of 8 frustums of 64 points).
TINY_FPOINTNET = dict(num_points=32, num_object_points=16, batch_size=8, min_box_height=0, flip=False, shift=False,
                      jitter=False, device="cpu", seed=1)
TINY_SIAMESE = dict(dim=8, conv_channels=(8, 8), hidden=(16,), lr=1e-3, batch_size=4, device="cpu", seed=0)


# --------------------------------------------------------------------------- resolving --precision


@pytest.fixture
def native_bf16(monkeypatch):
    """bfloat16 taken as native: the suite runs AVX2 kernels, under which it is emulated (slowly, same results)."""
    monkeypatch.setattr(precision_module, "cpu_bf16_is_native", lambda: True)


def test_auto_on_a_cpu_is_bf16_where_native_and_bf16_is_taken_as_asked(native_bf16):
    assert resolve_precision("auto", CPU) == "bf16"
    assert resolve_precision("fp32", CPU) == "fp32"
    assert resolve_precision("bf16", CPU) == "bf16"


def test_auto_on_a_cpu_is_float32_where_bf16_would_be_emulated_and_bf16_is_refused(monkeypatch):
    monkeypatch.setattr(precision_module, "cpu_bf16_is_native", lambda: False)
    assert resolve_precision("auto", CPU) == "fp32"
    with pytest.raises(SianmsError, match="--precision bf16: this CPU would emulate bfloat16"):
        resolve_precision("bf16", CPU)


@pytest.mark.parametrize("environment, capability, expected", [
    ({}, "AVX512", True), ({"ONEDNN_MAX_CPU_ISA": "AVX2"}, "AVX512", False), ({}, "AVX2", False),
    ({"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_AMX"}, "AVX512", True)])
def test_bf16_is_native_only_under_the_cpus_own_kernels(monkeypatch, environment, capability, expected):
    monkeypatch.delenv("ONEDNN_MAX_CPU_ISA", raising=False)
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    monkeypatch.setattr(precision_module, "has_native_bf16", lambda: True)
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: capability)
    assert precision_module.cpu_bf16_is_native() is expected
    monkeypatch.setattr(precision_module, "has_native_bf16", lambda: False)
    assert precision_module.cpu_bf16_is_native() is False


def test_fp16_on_a_cpu_and_unknown_modes_are_refused():
    with pytest.raises(SianmsError, match="--precision fp16 runs on CUDA only"):
        resolve_precision("fp16", CPU)
    with pytest.raises(SianmsError, match="--precision must be one of auto, fp32, bf16, fp16, got 'half'"):
        resolve_precision("half", CPU)
    with pytest.raises(SianmsError, match="--precision must be one of"):
        SiameseConfig(cache="c", precision="fp64")
    with pytest.raises(SianmsError, match="--precision must be one of"):
        FPointNetConfig(cache="c", precision="tf32")


@pytest.mark.parametrize("has_bf16, expected", [(True, "bf16"), (False, "fp16")])
def test_auto_on_cuda_takes_bf16_where_the_gpu_has_it(monkeypatch, has_bf16, expected):
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: has_bf16)
    assert resolve_precision("auto", torch.device("cuda", 0)) == expected
    assert resolve_precision("fp16", torch.device("cuda", 0)) == "fp16"


def test_bf16_on_a_gpu_without_it_is_refused_naming_the_gpu(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_bf16_supported", lambda *a, **k: False)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda *a, **k: "Tesla V100")
    with pytest.raises(SianmsError, match="--precision bf16: Tesla V100 has no bfloat16; use fp16"):
        resolve_precision("bf16", torch.device("cuda", 0))


# --------------------------------------------------------------------------- the steps


def _model_and_optimizer(seed=0):
    torch.manual_seed(seed)
    model = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.ReLU(), torch.nn.Linear(8, 1))
    return model, torch.optim.Adam(model.parameters(), lr=1e-2)


def test_fp32_computes_exactly_the_plain_backward_and_step():
    x = torch.randn(16, 4, generator=torch.Generator().manual_seed(3))
    plain, plain_optimizer = _model_and_optimizer()
    mixed, mixed_optimizer = _model_and_optimizer()
    precision = MixedPrecision("fp32", CPU)
    for _ in range(5):
        plain_optimizer.zero_grad()
        plain(x).square().mean().backward()
        plain_optimizer.step()
        mixed_optimizer.zero_grad()
        with precision.autocast():
            loss = mixed(x).square().mean()
        precision.backward_step(loss, mixed_optimizer)
    for a, b in zip(plain.parameters(), mixed.parameters()):
        assert torch.equal(a, b)
    assert precision.state_dict() == {}


def test_bf16_computes_the_products_in_bfloat16_and_float32_outputs_casts_back():
    model, _ = _model_and_optimizer()
    with MixedPrecision("bf16", CPU).autocast():
        outputs = {"y": model(torch.randn(2, 4)), "mask": torch.ones(2, dtype=torch.bool)}
    assert outputs["y"].dtype == torch.bfloat16
    cast = float32_outputs(outputs)
    assert cast["y"].dtype == torch.float32 and cast["mask"].dtype == torch.bool


def test_the_fp16_scaler_skips_an_overflowed_step_and_its_state_comes_back():
    """A loss whose scaled gradients overflow float16 leaves the weights as they were and halves
    the scale (GradScaler's dynamic loss scaling); a new MixedPrecision loaded with the state has
    the lowered scale, an fp32 one ignores it."""
    model, optimizer = _model_and_optimizer()
    before = [p.detach().clone() for p in model.parameters()]
    precision = MixedPrecision("fp16", CPU)
    assert precision.state_dict()["scale"] == 65536.0
    with precision.autocast():
        loss = model(torch.full((4, 4), 1e4)).float().square().mean()  # gradients ~1e8 x 65536: inf
    precision.backward_step(loss, optimizer)
    assert all(torch.equal(a, b) for a, b in zip(before, model.parameters()))
    state = precision.state_dict()
    assert state["scale"] == 32768.0
    restored = MixedPrecision("fp16", CPU)
    restored.load_state_dict(state)
    assert restored.state_dict() == state
    unscaled = MixedPrecision("fp32", CPU)
    unscaled.load_state_dict(state)
    assert unscaled.state_dict() == {}


# --------------------------------------------------------------------------- the trainings


def test_a_bf16_siamese_training_learns_records_its_precision_and_resumes_exactly(tiny_caches, tmp_path,
                                                                                   native_bf16):
    train, _ = tiny_caches
    config = SiameseConfig(cache=str(train), epochs=4, precision="bf16", **TINY_SIAMESE)
    straight = train_siamese(config, tmp_path / "straight")
    assert straight.precision == "bf16"
    losses = [row["train_loss"] for row in straight.history]
    assert losses[-1] < losses[0]
    train_siamese(SiameseConfig(cache=str(train), epochs=2, precision="bf16", **TINY_SIAMESE), tmp_path / "resumed")
    train_siamese(config, tmp_path / "resumed", resume=True)
    a = load_checkpoint(tmp_path / "straight" / "checkpoint.pt")
    b = load_checkpoint(tmp_path / "resumed" / "checkpoint.pt")
    assert a.extra["precision"] == "bf16" and a.extra["grad_scaler"] == {}
    assert all(torch.equal(value, b.model[key]) for key, value in a.model.items())
    float32 = train_siamese(SiameseConfig(cache=str(train), epochs=1, precision="fp32", **TINY_SIAMESE),
                            tmp_path / "fp32")
    assert float32.history[0]["train_loss"] != straight.history[0]["train_loss"]  # bf16 did compute otherwise


def test_a_bf16_fpointnet_training_lowers_its_losses(tiny_caches, tmp_path, native_bf16):
    config = FPointNetConfig(cache=str(tiny_caches[0]), val_cache=str(tiny_caches[1]), epochs=8, lr=3e-4,
                             precision="bf16", **TINY_FPOINTNET)
    result = train_fpointnet(config, tmp_path / "run")
    assert result.precision == "bf16"
    total = [row["train_total"] for row in result.history]
    assert np.mean(total[-3:]) < np.mean(total[:3])
    assert all(math.isfinite(row[f"train_{term}"]) for row in result.history for term in LOSS_TERMS)
    assert 0 <= result.history[-1]["val_iou_0.5"] <= 1  # validated in float32


def test_a_bf16_fpointnet_run_on_the_cosine_schedule_resumes_where_an_uninterrupted_one_ends(tiny_caches, tmp_path,
                                                                                                native_bf16):
    """The trainings' default path on CPUs with native bfloat16: killed between two epochs, resumed, the
    weights are the uninterrupted run's to the bit (the schedule is a function of the samples seen)."""
    full = FPointNetConfig(cache=str(tiny_caches[0]), epochs=2, precision="bf16", **TINY_FPOINTNET)
    train_fpointnet(full, tmp_path / "straight")

    def stop_in_epoch_two(row):
        if row["epoch"] == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_fpointnet(full, tmp_path / "stopped", on_epoch=stop_in_epoch_two)
    resumed = train_fpointnet(full, tmp_path / "stopped", resume=True)
    assert resumed.resumed_from == 1 and resumed.precision == "bf16"
    a = load_checkpoint(tmp_path / "straight" / "checkpoint.pt").model
    b = load_checkpoint(tmp_path / "stopped" / "checkpoint.pt").model
    assert all(torch.equal(value, b[key]) for key, value in a.items())


def test_an_fp16_fpointnet_run_keeps_its_loss_scale_across_a_resume(tiny_caches, tmp_path, monkeypatch):
    """fp16 runs on CUDA only; here its arithmetic runs on the CPU (slowly, tiny) so the loss
    scaler's state is checked to travel in the checkpoint: the scale moved in the first epoch
    and the resumed run ends on the uninterrupted run's weights."""
    monkeypatch.setattr(fpointnet_training, "resolve_precision", lambda name, device: "fp16")
    tiny = {**TINY_FPOINTNET, "cache": str(tiny_caches[0]), "precision": "fp16"}
    full = FPointNetConfig(epochs=2, **tiny)
    train_fpointnet(full, tmp_path / "straight")

    def stop_in_epoch_two(row):
        if row["epoch"] == 2:  # before epoch 2's checkpoint: a kill between the epochs
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train_fpointnet(full, tmp_path / "stopped", on_epoch=stop_in_epoch_two)
    first = load_checkpoint(tmp_path / "stopped" / "checkpoint.pt")
    assert first.extra["precision"] == "fp16" and first.extra["grad_scaler"]["scale"] != 65536.0
    train_fpointnet(full, tmp_path / "stopped", resume=True)
    a = load_checkpoint(tmp_path / "straight" / "checkpoint.pt")
    b = load_checkpoint(tmp_path / "stopped" / "checkpoint.pt")
    assert a.extra["grad_scaler"] == b.extra["grad_scaler"]
    assert all(torch.equal(value, b.model[key]) for key, value in a.model.items())


def test_the_cli_says_the_precision_and_refuses_fp16_on_a_cpu_in_one_line(tiny_caches, tmp_path, native_bf16):
    train, _ = tiny_caches
    small = ["--num-points", "32", "--num-object-points", "16", "--batch-size", "8", "--min-box-height", "0",
             "--device", "cpu", "--epochs", "1", "--quiet"]
    done = CliRunner().invoke(app, ["train", "fpointnet", "--cache", str(train), "--out", str(tmp_path / "bf16"),
                                    "--precision", "bf16", *small])
    assert done.exit_code == 0, done.output
    assert "parameters, bf16)" in done.stdout
    refused = CliRunner().invoke(app, ["train", "fpointnet", "--cache", str(train), "--out", str(tmp_path / "fp16"),
                                       "--precision", "fp16", *small])
    assert refused.exit_code == 2
    assert refused.stderr.strip().splitlines() == [
        "error: --precision fp16 runs on CUDA only (float16 on a CPU is several times slower than float32); "
        "on a CPU use bf16 or fp32"]
    assert not (tmp_path / "fp16").exists()
