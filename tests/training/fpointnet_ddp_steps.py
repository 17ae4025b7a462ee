"""Three Adam steps of Frustum PointNets in float64 on a fixed batch of 7, in one process or,
under torchrun, split over the ranks as ``train fpointnet`` splits it; rank 0 saves the
losses and weights to ``sys.argv[1]`` (run by test_distributed.py)."""

import sys

import torch
import torch.distributed as dist

from sianms_cli.data.streams import stream_batch_size
from sianms_cli.models.fpointnet import FPointNetV1
from sianms_cli.models.fpointnet_losses import fpointnet_loss
from sianms_cli.models.global_batch import BatchShare
from sianms_cli.training.run import init_distributed

BATCH, POINTS = 7, 64


def main(out: str) -> None:
    # The commands' own join, whose exit handler frees the DDP wrapper before destroying the group.
    rank, world, _ = init_distributed(torch.device("cpu"))
    torch.manual_seed(0)
    network = FPointNetV1(torch.tensor([[4.0, 1.8, 1.6], [0.8, 0.7, 1.7], [1.7, 0.6, 1.2]]),
                          num_object_points=32).double()
    model = torch.nn.parallel.DistributedDataParallel(network) if world > 1 else network
    optimizer = torch.optim.Adam(network.parameters(), lr=1e-3)
    data = torch.Generator().manual_seed(3)
    classes = torch.tensor([0, 1, 2, 0, 1, 2, 0])
    batch = {"points": torch.randn(BATCH, POINTS, 4, generator=data, dtype=torch.float64),
             "one_hot": torch.eye(3, dtype=torch.float64)[classes], "size_class": classes,
             "seg": (torch.rand(BATCH, POINTS, generator=data) > 0.5).long(),
             "center": torch.randn(BATCH, 3, generator=data, dtype=torch.float64) + torch.tensor([0.0, 0.0, 10.0]),
             "heading": torch.rand(BATCH, generator=data, dtype=torch.float64) * 6,
             "lwh": network.mean_sizes.double()[classes]}
    share = BatchShare.of_counts([stream_batch_size(BATCH, r, world) for r in range(world)], rank)
    mine = {key: value[share.start:share.stop] for key, value in batch.items()}
    network.train()
    losses = []
    for step in range(3):
        network.set_bn_momentum(0.5)
        torch.manual_seed(5 + step)  # dropout
        outputs = model(mine["points"], mine["one_hot"], generator=torch.Generator().manual_seed(7 + step),
                        share=share)
        loss = fpointnet_loss(outputs, mine, network.mean_sizes.double())["total"]
        optimizer.zero_grad()
        (loss * share.loss_weight(world)).backward()
        optimizer.step()
        total = torch.tensor([loss.item() * len(share)], dtype=torch.float64)
        if world > 1:
            dist.all_reduce(total)
        losses.append(total.item() / BATCH)
    if rank == 0:
        torch.save({"losses": losses, "state": network.state_dict()}, out)
    if world > 1:
        dist.barrier()


if __name__ == "__main__":
    main(sys.argv[1])
