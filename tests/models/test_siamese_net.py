"""The embedding net of Fig. 4: output shapes for any ROI shape and d, shared weights."""

import pytest
import torch

from sianms_cli.models.siamese import SiameseEncoder, parameter_count


@pytest.mark.parametrize("shape", [(64, 7, 7), (32, 14, 14), (8, 1, 1), (16, 3, 5)])
@pytest.mark.parametrize("dim", [5, 100, 1000])
def test_output_shape(shape, dim):
    torch.manual_seed(0)
    net = SiameseEncoder(shape, dim=dim, conv_channels=(8, 8), hidden=(16,))
    assert net(torch.randn(3, *shape)).shape == (3, dim)


def test_branches_share_weights():
    """One module embeds both branches: the same input gives the same embedding wherever it sits."""
    torch.manual_seed(0)
    net = SiameseEncoder((4, 7, 7), dim=10, conv_channels=(8, 8), hidden=(16,)).eval()
    x = torch.randn(5, 4, 7, 7)
    both = net(torch.cat([x, x.flip(0)]))
    torch.testing.assert_close(both[:5], both[5:].flip(0))


def test_parameter_count_by_hand():
    net = SiameseEncoder((2, 2, 2), dim=3, conv_channels=(4, 5), hidden=(6,))
    # conv 2->4: 4*2*9+4; conv 4->5: 5*4*9+5; pools 2->1->1: fc 5->6, 6->3
    assert parameter_count(net) == (72 + 4) + (180 + 5) + (30 + 6) + (18 + 3)


def test_input_standardisation_is_per_channel_and_in_the_state_dict():
    torch.manual_seed(0)
    net = SiameseEncoder((3, 7, 7), dim=4, conv_channels=(8, 8), hidden=(16,)).eval()
    x = torch.randn(5, 3, 7, 7) * torch.tensor([1.0, 10.0, 100.0])[:, None, None] + 5
    plain = net(x)  # statistics default to the identity
    mean, std = torch.tensor([5.0, -1.0, 2.0]), torch.tensor([1.0, 10.0, 0.0])
    net.set_input_statistics(mean.numpy(), std.numpy())
    std_used = torch.tensor([1.0, 10.0, 1e-6])  # a constant channel is not divided by zero
    reference = SiameseEncoder((3, 7, 7), dim=4, conv_channels=(8, 8), hidden=(16,)).eval()
    reference.load_state_dict({**net.state_dict(), "input_mean": torch.zeros(3), "input_std": torch.ones(3)})
    torch.testing.assert_close(net(x), reference((x - mean[:, None, None]) / std_used[:, None, None]))
    assert not torch.equal(net(x), plain)
    assert torch.equal(net.state_dict()["input_std"], std_used)
    assert parameter_count(net) == parameter_count(reference)  # buffers, not parameters
