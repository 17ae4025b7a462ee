"""A rank's share of a global batch draws what one process draws for those rows."""

import pytest
import torch

from sianms_cli.models.global_batch import BatchShare, batch_norm, dropout, uniform


def test_shares_cover_the_batch_in_order_and_weigh_the_loss_to_its_mean():
    shares = [BatchShare.of_counts([2, 0, 5], rank) for rank in range(3)]
    assert [(s.start, s.stop, s.size) for s in shares] == [(0, 2, 7), (2, 2, 7), (2, 7, 7)]
    assert sum(s.loss_weight(3) for s in shares) / 3 == 1.0  # DDP averages the ranks' gradients
    assert BatchShare.of_counts([5], 0).loss_weight(1) == 1.0


def test_a_shares_uniform_draws_are_its_rows_of_the_global_draw():
    whole = uniform(7, 5, None, generator=torch.Generator().manual_seed(1))
    share = BatchShare.of_counts([3, 4], 1)
    part = uniform(len(share), 5, share, generator=torch.Generator().manual_seed(1))
    assert torch.equal(part, whole[share.start:share.stop])


def test_dropout_keeps_a_bernoulli_share_scaled_up_and_a_share_masks_its_rows_of_the_global_mask():
    x = torch.rand(60, 10, 8) + 1
    torch.manual_seed(4)
    dropped = dropout(x, 0.25, None, training=True)
    kept = dropped != 0
    assert kept.float().mean().item() == pytest.approx(0.75, abs=0.01)  # 4,800 draws: sd 0.006
    torch.testing.assert_close(dropped[kept], x[kept] / 0.75)
    torch.manual_seed(4)
    assert torch.equal(dropout(x, 0.25, None, training=True), dropped)  # torch's global generator
    share = BatchShare.of_counts([30, 30], 1)
    torch.manual_seed(4)
    assert torch.equal(dropout(x[share.start:share.stop], 0.25, share, training=True), dropped[30:])
    assert dropout(x, 0.25, None, training=False) is x


def test_batch_norm_without_a_process_group_is_the_module_itself():
    norm = torch.nn.BatchNorm1d(4).train()
    twin = torch.nn.BatchNorm1d(4).train()
    x = torch.randn(9, 4)
    assert torch.equal(batch_norm(norm, x), twin(x))
    assert torch.equal(norm.running_var, twin.running_var)
