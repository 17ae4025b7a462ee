"""Both trainings on a CUDA device in mixed precision (opt-in: `-m cuda`; skipped without a GPU,
so CI, which has none, never runs them; `scripts/device_check.sh` runs them on a lent GPU)."""

import math

import pytest
import torch

from sianms_cli.training.fpointnet import FPointNetConfig
from sianms_cli.training.fpointnet import run as train_fpointnet
from sianms_cli.training.run import load_checkpoint
from sianms_cli.training.siamese import SiameseConfig, embed, load_encoder
from sianms_cli.training.siamese import run as train_siamese

pytestmark = [pytest.mark.cuda, pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")]

FPOINTNET = dict(num_points=64, num_object_points=32, batch_size=8, min_box_height=0, device="cuda", seed=1)
SIAMESE = dict(dim=8, conv_channels=(8, 8), hidden=(16,), lr=1e-3, batch_size=4, device="cuda", seed=0)


def test_auto_trains_both_networks_in_mixed_precision_and_the_weights_load_on_a_cpu(tiny_caches, tmp_path):
    train, val = tiny_caches
    expected = "bf16" if torch.cuda.is_bf16_supported() else "fp16"
    siamese = train_siamese(SiameseConfig(cache=str(train), val_cache=str(val), epochs=3, **SIAMESE),
                            tmp_path / "siamese")
    assert siamese.precision == expected
    assert siamese.history[-1]["train_loss"] < siamese.history[0]["train_loss"]
    encoder, _ = load_encoder(tmp_path / "siamese", "cpu")
    assert embed(encoder, torch.zeros(2, *encoder.feature_shape).numpy()).shape == (2, 8)
    fpointnet = train_fpointnet(FPointNetConfig(cache=str(train), val_cache=str(val), epochs=3, **FPOINTNET),
                                tmp_path / "fpointnet")
    assert fpointnet.precision == expected
    assert all(math.isfinite(row["train_total"]) for row in fpointnet.history)
    assert 0 <= fpointnet.history[-1]["val_iou_0.5"] <= 1


def test_an_fp16_run_resumes_with_its_loss_scale(tiny_caches, tmp_path):
    train, _ = tiny_caches
    train_fpointnet(FPointNetConfig(cache=str(train), epochs=1, precision="fp16", **FPOINTNET), tmp_path / "run")
    first = load_checkpoint(tmp_path / "run" / "checkpoint.pt").extra["grad_scaler"]
    resumed = train_fpointnet(FPointNetConfig(cache=str(train), epochs=2, precision="fp16", **FPOINTNET),
                              tmp_path / "run", resume=True)
    assert first["scale"] > 0 and resumed.resumed_from == 1 and len(resumed.history) == 2
    assert load_checkpoint(tmp_path / "run" / "checkpoint.pt").extra["precision"] == "fp16"
