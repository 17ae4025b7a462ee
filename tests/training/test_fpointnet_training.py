"""training/fpointnet.py: a tiny training on a generated mini lowers every loss; resume equality;
the run folder; the box score; the same with --multiview's union frustums."""

import math
import shutil
from dataclasses import replace

import numpy as np
import pyarrow.parquet as pq
import pytest
import torch

from sianms_cli.errors import SianmsError
from sianms_cli.training.fpointnet import LOSS_TERMS, FPointNetConfig, box_scores, run, schedule
from sianms_cli.training.run import load_checkpoint

# Small and fast: few points, few masked points, no augmentation (so the losses fall smoothly).
TINY = dict(num_points=64, num_object_points=32, batch_size=8, min_box_height=0, flip=False, shift=False,
            jitter=False, device="cpu", seed=1)


@pytest.fixture(scope="module")
def trained(tiny_caches, tmp_path_factory):
    config = FPointNetConfig(cache=str(tiny_caches[0]), val_cache=str(tiny_caches[1]), epochs=12, lr=3e-4, **TINY)
    out = tmp_path_factory.mktemp("fpointnet") / "run"
    return config, run(config, out)


def test_a_tiny_training_lowers_every_loss_but_the_centre_terms(trained):
    """Every term's mean over the last three epochs is below its mean over the first three,
    except the two centre terms, which only must not grow by half.

    On the 2-scene mini (about 40 frustums, a few steps an epoch) the centre terms stay flat:
    a few far frustums with metres of error sit on Huber's linear part and dominate them. A
    centre that learns needs a larger training set (README, "Not done yet").
    """
    _, result = trained
    first, last = result.history[:3], result.history[-3:]
    for term in LOSS_TERMS:
        before = np.mean([row[f"train_{term}"] for row in first])
        after = np.mean([row[f"train_{term}"] for row in last])
        assert after < (1.5 * before if term in ("center", "stage1_center") else before), term


def test_the_run_folder_holds_checkpoint_metrics_and_curves(trained):
    config, result = trained
    assert {p.name for p in result.out.iterdir()} >= {"checkpoint.pt", "config.json", "metrics.csv", "curves.png"}
    checkpoint = load_checkpoint(result.out / "checkpoint.pt", "fpointnet")
    assert checkpoint.epoch == 12 and checkpoint.extra["classes"] == list(config.classes)
    assert np.allclose(checkpoint.extra["mean_sizes"], result.mean_sizes)
    header = (result.out / "metrics.csv").read_text().splitlines()[0].split(",")
    for column in ("val_iou_0.5", "val_iou_0.7", "val_center_error", "val_heading_error", "val_seg_accuracy",
                   "val_car_iou_0.5", "val_pedestrian_center_error"):
        assert column in header, column
    assert 0 <= result.history[-1]["val_iou_0.5"] <= 1


def test_size_clusters_are_the_training_means_in_lwh_order(trained):
    _, result = trained
    car = result.mean_sizes[0]
    assert car[0] > car[1]  # length before width: the (w, l, h) order was converted


class Stopped(Exception):
    """Stands for a kill between two epochs."""


def stop_in_epoch_two(row):
    if row["epoch"] == 2:  # before epoch 2's checkpoint is written
        raise Stopped


def stop_in_epoch_three(row):
    if row["epoch"] == 3:
        raise Stopped


@pytest.mark.parametrize("streams", [1, 2])
def test_resume_ends_where_an_uninterrupted_run_ends(streams, two_shard_cache, tmp_path):
    full = FPointNetConfig(cache=str(two_shard_cache), epochs=2, streams=streams, **TINY)
    run(full, tmp_path / "straight")
    with pytest.raises(Stopped):
        run(full, tmp_path / "stopped", on_epoch=stop_in_epoch_two)
    resumed = run(full, tmp_path / "stopped", resume=True)
    assert len(resumed.history) == 2 and resumed.resumed_from == 1
    a = load_checkpoint(tmp_path / "straight" / "checkpoint.pt").model
    b = load_checkpoint(tmp_path / "stopped" / "checkpoint.pt").model
    assert all(torch.equal(a[key], b[key]) for key in a)


def test_schedule_original_is_the_originals_staircase_whatever_the_runs_length():
    config = FPointNetConfig(cache="unused", schedule="original")
    for total in (1_000, 10**8):
        assert schedule(config, 0, total) == (1e-3, 0.5)
        assert schedule(config, 799_999, total) == (1e-3, 0.5)
        assert schedule(config, 800_000, total) == (5e-4, 0.25)
        assert schedule(config, 10 * 800_000, total)[1] == 0.01  # BN decay capped at 0.99


def test_schedule_cosine_warms_up_then_decays_both_over_the_run():
    config = FPointNetConfig(cache="unused", epochs=100, lr=1e-3, bn_momentum=0.5, bn_momentum_min=0.01)
    total = 100_000  # 1,000 samples an epoch: the warm-up is min(3 % of the run, one epoch) = 1,000 samples
    warmup = 1_000
    assert schedule(config, 0, total) == pytest.approx((1e-3 / (warmup + 1), 0.5))
    assert schedule(config, warmup // 2, total)[0] == pytest.approx(1e-3 * (warmup // 2 + 1) / (warmup + 1))
    lr, momentum = schedule(config, warmup, total)
    assert lr == pytest.approx(1e-3) and momentum == pytest.approx(0.01 + 0.49 * 0.5 * (1 + math.cos(math.pi * 0.01)))
    middle = warmup + (total - warmup) // 2
    assert schedule(config, middle, total)[0] == pytest.approx(1e-3 * (0.01 + 0.99 * 0.5), rel=1e-4)
    assert schedule(config, total // 2, total)[1] == pytest.approx(0.01 + 0.49 * 0.5)
    assert schedule(config, total, total) == pytest.approx((1e-5, 0.01))
    assert schedule(config, 2 * total, total) == pytest.approx((1e-5, 0.01))  # past the end: the floor
    short = replace(config, epochs=10)  # three percent of the run is shorter than an epoch here
    assert schedule(short, 300, 10_000)[0] == pytest.approx(1e-3)


def test_a_short_training_learns_heading_beyond_a_uniform_guess(trained):
    """The heading-bin loss of the last epoch is below ln 12, a uniform guess over the 12 bins's,
    and the validation figures of both heading errors are logged (modulo π no larger than the AOE's)."""
    _, result = trained
    assert result.history[-1]["train_heading_class"] < math.log(12)
    assert result.history[0]["train_heading_class"] > result.history[-1]["train_heading_class"]
    last = result.history[-1]
    assert 0 <= last["val_heading_error_mod_pi"] <= min(last["val_heading_error"], math.pi / 2)
    assert 0 <= last["val_heading_bin_accuracy"] <= 1


def test_box_score_hand_computed():
    seg_logits = torch.tensor([[[0.0, math.log(3.0)], [0.0, math.log(1 / 3)], [0.0, 0.0]]])  # p = .75, .25, .5
    outputs = {"seg_logits": seg_logits, "mask": seg_logits[..., 1] > seg_logits[..., 0],
               "heading_scores": torch.log(torch.tensor([[0.5, 0.25, 0.25]])),
               "size_scores": torch.log(torch.tensor([[0.2, 0.8]]))}
    expected = math.log(0.75) + math.log(0.5) + math.log(0.8)
    assert box_scores(outputs).item() == pytest.approx(expected)


def test_bad_options_are_user_errors():
    with pytest.raises(SianmsError, match="batch-size"):
        FPointNetConfig(cache="c", batch_size=1)
    with pytest.raises(SianmsError, match="distinct"):
        FPointNetConfig(cache="c", classes=("car", "car"))
    with pytest.raises(SianmsError, match="--schedule must be one of cosine, original, got 'step'"):
        FPointNetConfig(cache="c", schedule="step")


# --multiview: the union frustums of the cache's camera pairs join the training set.

@pytest.fixture(scope="module")
def multiview(tiny_caches, synthetic_dataroot, tmp_path_factory):
    config = FPointNetConfig(cache=str(tiny_caches[0]), epochs=3, multiview=True, dataroot=str(synthetic_dataroot()),
                             **{**TINY, "num_points": 32, "num_object_points": 16, "seed": 2})
    return config, run(config, tmp_path_factory.mktemp("fpointnet-multiview") / "run")


def test_a_tiny_multiview_training_lowers_the_loss_and_counts_its_union_frustums(multiview):
    config, result = multiview
    unions = pq.read_table(result.out / "multiview").num_rows  # every union frustum of the cache
    assert unions > 0
    total = sum(load_checkpoint(result.out / "checkpoint.pt").extra["train_counts"]) + unions
    lone = int(total % config.batch_size == 1)  # a last batch of one frustum is dropped (batch norm)
    for row in result.history:
        assert row["train_count"] == total - lone and unions - lone <= row["train_union_count"] <= unions
    assert result.history[-1]["train_total"] < result.history[0]["train_total"]
    assert result.history[-1]["train_mask"] < result.history[0]["train_mask"]
    header = (result.out / "metrics.csv").read_text().splitlines()[0].split(",")
    assert "train_union_count" in header


def test_multiview_resume_ends_where_an_uninterrupted_run_ends(multiview, tmp_path):
    """The union frustums are recomputed here (the folder is removed) and give the same bytes."""
    config, result = multiview
    with pytest.raises(Stopped):
        run(config, tmp_path / "stopped", on_epoch=stop_in_epoch_three)
    shutil.rmtree(tmp_path / "stopped" / "multiview")
    resumed = run(config, tmp_path / "stopped", resume=True)
    timings = ("seconds", "train_seconds")
    assert resumed.resumed_from == 2
    assert ({k: v for k, v in resumed.history[-1].items() if k not in timings}
            == {k: v for k, v in result.history[-1].items() if k not in timings})
    assert all(resumed.history[-1][key] > 0 for key in timings)
    a = load_checkpoint(result.out / "checkpoint.pt").model
    b = load_checkpoint(tmp_path / "stopped" / "checkpoint.pt").model
    assert all(torch.equal(a[key], b[key]) for key in a)


def test_multiview_without_a_dataroot_is_one_clear_error():
    with pytest.raises(SianmsError, match="--multiview needs --dataroot"):
        FPointNetConfig(cache="c", multiview=True)
    with pytest.raises(SianmsError, match="--max-distance"):
        FPointNetConfig(cache="c", multiview=True, dataroot="d", max_distance=0)
