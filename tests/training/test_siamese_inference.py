"""The inference API eval calls: `load_encoder` (checkpoint -> encoder, dis_thr) and `embed`
(ROI features -> embeddings)."""

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from sianms_cli.cli import app

from sianms_cli.data.siamese import feature_statistics, iter_scenes
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.models.siamese import SiameseEncoder
from sianms_cli.training.run import CHECKPOINT, Checkpoint, load_checkpoint, save_checkpoint
from sianms_cli.training.siamese import SiameseConfig, embed, load_encoder, run

SMALL = dict(dim=8, conv_channels=(8, 8), hidden=(16,), lr=1e-3, batch_size=4, epochs=1, device="cpu")


@pytest.fixture(scope="module")
def tiny_run(tiny_caches, tmp_path_factory):
    """A one-epoch run on the session's mini caches (validated, so dis_thr is the tuned one)."""
    train, val = tiny_caches
    out = tmp_path_factory.mktemp("siamese-inference") / "run"
    result = run(SiameseConfig(cache=str(train), val_cache=str(val), **SMALL), out)
    return out, result


def first_scene_features(cache):
    return next(iter(iter_scenes(cache))).features  # (N, C, PH, PW) float16


def test_round_trip_embeds_deterministically(tiny_run, tiny_caches):
    out, result = tiny_run
    model, dis_thr = load_encoder(out)
    assert isinstance(model, SiameseEncoder) and not model.training
    assert dis_thr == result.dis_thr == load_checkpoint(out / CHECKPOINT).extra["dis_thr"]
    features = first_scene_features(tiny_caches[1])
    first = embed(model, features)
    assert first.dtype == np.float32 and first.shape == (len(features), 8)
    np.testing.assert_array_equal(first, embed(model, features))
    again, _ = load_encoder(out / CHECKPOINT)  # the checkpoint file itself works too
    np.testing.assert_array_equal(first, embed(again, features))
    # rows are independent: chunking and float32 input change nothing beyond rounding
    np.testing.assert_allclose(embed(model, features.astype(np.float32), batch=3), first, rtol=1e-5, atol=1e-5)
    assert embed(model, features[:0]).shape == (0, 8)


def test_without_standardize_the_statistics_are_the_identity(tiny_run):
    model, _ = load_encoder(tiny_run[0])
    assert torch.equal(model.input_mean, torch.zeros(model.feature_shape[0]))
    assert torch.equal(model.input_std, torch.ones(model.feature_shape[0]))


def test_a_checkpoint_without_the_statistics_buffers_loads_as_raw_features(tiny_run, tiny_caches, tmp_path):
    out, _ = tiny_run
    good = load_checkpoint(out / CHECKPOINT)
    older = {key: value for key, value in good.model.items() if not key.startswith("input_")}
    save_checkpoint(tmp_path / "older.pt", Checkpoint(kind="siamese", config={
        key: value for key, value in good.config.items() if key != "standardize"}, epoch=1, model=older,
        extra=good.extra))
    features = first_scene_features(tiny_caches[1])
    np.testing.assert_array_equal(embed(load_encoder(tmp_path / "older.pt")[0], features),
                                  embed(load_encoder(out)[0], features))


def test_embed_refuses_features_of_another_shape(tiny_run):
    model, _ = load_encoder(tiny_run[0])
    with pytest.raises(SianmsError, match="do not fit this encoder"):
        embed(model, np.zeros((2, 3, 7, 7), dtype=np.float32))


def test_a_wrong_file_is_one_clear_error(tiny_run, tmp_path):
    out, _ = tiny_run
    good = load_checkpoint(out / CHECKPOINT)
    cases = {
        "missing.pt": None,
        "fpointnet.pt": Checkpoint(kind="fpointnet", config=good.config, epoch=1, model=good.model, extra=good.extra),
        "no-threshold.pt": Checkpoint(kind="siamese", config=good.config, epoch=1, model=good.model,
                                      extra={"feature_shape": good.extra["feature_shape"]}),
        "other-dim.pt": Checkpoint(kind="siamese", config={**good.config, "dim": 9}, epoch=1, model=good.model,
                                   extra=good.extra),
        "negative-threshold.pt": Checkpoint(kind="siamese", config=good.config, epoch=1, model=good.model,
                                            extra={**good.extra, "dis_thr": -1.0}),
        "negative-width.pt": Checkpoint(kind="siamese", config={**good.config, "hidden": [-1]}, epoch=1,
                                        model=good.model, extra=good.extra),
    }
    for name, checkpoint in cases.items():
        if checkpoint is not None:
            save_checkpoint(tmp_path / name, checkpoint)
    torch.save({"format": "sianms-checkpoint-1", "kind": "siamese", "surprise": 1}, tmp_path / "foreign.pt")
    torch.save(SiameseConfig(cache="c"), tmp_path / "pickled.pt")
    expected = {"missing.pt": "file not found", "fpointnet.pt": "a 'fpointnet' checkpoint, expected 'siamese'",
                "no-threshold.pt": "extra.dis_thr", "other-dim.pt": "model.head",
                "negative-threshold.pt": r"field 'extra.dis_thr': no finite matching threshold > 0 \(got -1.0\)",
                "negative-width.pt": "field 'config': the stored config does not describe an encoder",
                "foreign.pt": "unexpected keys \\['surprise'\\]", "pickled.pt": "weights-only load refused"}
    for name, message in expected.items():
        with pytest.raises(DataFormatError, match=message) as caught:
            load_encoder(tmp_path / name)
        assert name in str(caught.value)


def test_standardize_flag_puts_the_training_caches_statistics_in_the_checkpoint(tiny_caches, tmp_path):
    train, _ = tiny_caches
    done = CliRunner().invoke(app, ["train", "siamese", "--cache", str(train), "--out", str(tmp_path / "run"),
                                    "--standardize", "--epochs", "1", "--dim", "8", "--conv-channels", "8,8",
                                    "--hidden", "16", "--device", "cpu", "--quiet"])
    assert done.exit_code == 0, done.output
    assert json.loads((tmp_path / "run" / "config.json").read_text())["standardize"] is True
    model, dis_thr = load_encoder(tmp_path / "run")
    assert dis_thr == 2.0  # no validation cache: the margins' midpoint
    mean, std, _ = feature_statistics(train)
    np.testing.assert_allclose(model.input_mean.numpy(), mean, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(model.input_std.numpy(), np.maximum(std, 1e-6), rtol=1e-6, atol=1e-6)
    assert {"input_mean", "input_std"} <= set(load_checkpoint(tmp_path / "run" / CHECKPOINT).model)
