import numpy as np
import pytest
import torch

from sianms_cli.detection2d.backbones import ResNet50C4, TinyBackbone, build_backbone, resize_and_pad
from sianms_cli.errors import DataFormatError, SianmsError


def test_resize_rule_of_torchvision():
    batch, (sx, sy) = resize_and_pad(np.zeros((900, 1600, 3), dtype=np.uint8))
    assert batch.shape == (1, 3, 768, 1344)  # 1333 x 749 padded to multiples of 32
    assert (sx, sy) == pytest.approx((1333 / 1600, 749 / 900))
    # Normalisation: black pixels become -mean/std, padding stays 0.
    assert batch[0, 0, 0, 0].item() == pytest.approx(-0.485 / 0.229, rel=1e-5)
    assert batch[0, :, 760, :].abs().sum() == 0


def test_tiny_is_seeded_and_stride_16():
    image = np.random.default_rng(0).integers(0, 255, (90, 160, 3), dtype=np.uint8)
    a, ratios = TinyBackbone(3).features(image)
    b, _ = TinyBackbone(3).features(image)
    assert a.shape == (1, 64, 6, 10) and ratios == (1.0, 1.0) and torch.equal(a, b)
    assert not torch.equal(a, TinyBackbone(4).features(image)[0])


def test_resnet50_c4_key_layout_and_checkpoint_round_trip(tmp_path):
    model = ResNet50C4()
    state = model.state_dict()
    assert len(state) == 215
    assert tuple(state["layer3.0.conv2.weight"].shape) == (256, 256, 3, 3)
    assert tuple(state["layer3.0.downsample.0.weight"].shape) == (1024, 512, 1, 1)
    assert model.layer3[0].conv2.stride == (2, 2) and model.layer3[0].conv1.stride == (1, 1)
    generator = torch.Generator().manual_seed(0)
    checkpoint = {f"backbone.body.{k}": torch.randn(v.shape, generator=generator) * 0.01 for k, v in state.items()}
    for key in checkpoint:
        if key.endswith("running_var"):
            checkpoint[key] = checkpoint[key].abs() + 1.0
    checkpoint["backbone.body.layer4.0.conv1.weight"] = torch.zeros(512, 1024, 1, 1)  # ignored
    checkpoint["rpn.head.conv.0.0.weight"] = torch.zeros(1)  # ignored
    path = tmp_path / "detector.pth"
    torch.save(checkpoint, path)
    loaded = ResNet50C4.from_checkpoint(path, min_size=64, max_size=128)
    assert torch.equal(loaded.state_dict()["layer2.3.bn3.running_mean"],
                       checkpoint["backbone.body.layer2.3.bn3.running_mean"])
    features, _ = loaded.features(np.zeros((45, 80, 3), dtype=np.uint8))
    assert features.shape == (1, 1024, 4, 8)  # 128 x 72 padded to 128 x 96, / 16


def test_bad_checkpoints_fail_clearly(tmp_path):
    state = ResNet50C4().state_dict()
    missing = dict(state)
    del missing["layer1.0.conv1.weight"]
    torch.save(missing, tmp_path / "missing.pth")
    with pytest.raises(DataFormatError, match="layer1.0.conv1.weight.*missing"):
        ResNet50C4.from_checkpoint(tmp_path / "missing.pth")
    wrong = dict(state)
    wrong["conv1.weight"] = torch.zeros(64, 3, 3, 3)
    torch.save(wrong, tmp_path / "wrong.pth")
    with pytest.raises(DataFormatError, match=r"conv1.weight.*\(64, 3, 3, 3\), expected \(64, 3, 7, 7\)"):
        ResNet50C4.from_checkpoint(tmp_path / "wrong.pth")
    poisoned = dict(state)
    poisoned["layer2.0.bn1.running_var"] = torch.full((128,), float("nan"))  # had loaded: NaN ROI features
    torch.save(poisoned, tmp_path / "nan.pth")
    with pytest.raises(DataFormatError, match=r"nan.pth: field 'layer2.0.bn1.running_var': holds a NaN"):
        ResNet50C4.from_checkpoint(tmp_path / "nan.pth")
    torch.save({0: torch.zeros(1)}, tmp_path / "int-keys.pth")  # had ended in an AttributeError traceback
    with pytest.raises(DataFormatError, match=r"int-keys.pth: expected a flat state dict \(name -> tensor\)"):
        ResNet50C4.from_checkpoint(tmp_path / "int-keys.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    with pytest.raises(DataFormatError, match="junk.pth"):
        ResNet50C4.from_checkpoint(tmp_path / "junk.pth")
    with pytest.raises(SianmsError, match="needs --weights"):
        build_backbone("resnet50-c4")
    with pytest.raises(SianmsError, match="unknown backbone"):
        build_backbone("vgg")
