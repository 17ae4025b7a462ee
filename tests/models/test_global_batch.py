"""A rank's share of a global batch draws what one process draws for those rows."""

import pytest
import torch

from sianms_cli.models.global_batch import BatchShare, batch_norm, dropout, keep_mask, uniform


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


@pytest.mark.parametrize("p", [0.25, 0.5])  # uniform floats; random bits
def test_dropout_keeps_a_bernoulli_share_scaled_up_and_a_share_masks_its_rows_of_the_global_mask(p):
    x = torch.rand(60, 10, 8) + 1
    torch.manual_seed(4)
    dropped = dropout(x, p, None, training=True)
    kept = dropped != 0
    assert kept.float().mean().item() == pytest.approx(1 - p, abs=0.025)  # 4,800 draws: sd 0.007
    torch.testing.assert_close(dropped[kept], x[kept] / (1 - p))
    torch.manual_seed(4)
    assert torch.equal(dropout(x, p, None, training=True), dropped)  # torch's global generator
    share = BatchShare.of_counts([30, 30], 1)
    torch.manual_seed(4)
    assert torch.equal(dropout(x[share.start:share.stop], p, share, training=True), dropped[30:])
    assert dropout(x, p, None, training=False) is x


def test_half_masks_are_fair_independent_bits_of_any_shape():
    torch.manual_seed(5)
    mask = keep_mask((200, 313), 0.5, torch.device("cpu"))  # 62,600 bits: not a multiple of 31
    assert mask.shape == (200, 313) and mask.dtype == torch.bool
    assert mask.float().mean().item() == pytest.approx(0.5, abs=0.01)  # sd 0.002
    flat = mask.reshape(-1).float()
    neighbours = (flat[1:] == flat[:-1]).float().mean().item()  # bits of one draw side by side
    strided = (flat[31:] == flat[:-31]).float().mean().item()  # the same bit of successive draws
    assert neighbours == pytest.approx(0.5, abs=0.01) and strided == pytest.approx(0.5, abs=0.01)


def test_batch_norm_without_a_process_group_is_the_module_itself():
    norm = torch.nn.BatchNorm1d(4).train()
    twin = torch.nn.BatchNorm1d(4).train()
    x = torch.randn(9, 4)
    assert torch.equal(batch_norm(norm, x), twin(x))
    assert torch.equal(norm.running_var, twin.running_var)
