"""Benchmark of Frustum PointNets v1 training and inference steps on this machine's CPU.

Prints frustums per second for training (forward + loss + backward + Adam step) and
inference (eval mode, no grad) with 1 and 2 torch threads, at the given point counts, and
the 2-thread / 1-thread ratio measured in the same run (models.md §8 measured 17 frustums/s
at 1,024 points on 2 threads, 10 on 1; 1.7-1.8x). Then, with 2 threads, training against
the original's formulation of the segmentation head (the global feature tiled to every
point, then one linear map), which the model replaces by applying the global part once per
frustum. With several ``--precisions``, each one's frustums per second against fp32's on 2
threads, as the training runs them (:mod:`sianms_cli.training.precision`: autocast forward,
float32 loss, loss-scaled backward in fp16). Batches are random tensors of the real shapes:
the cache's reading costs well under 1 % of a step (one shard in memory at a time).

On a GPU (``--device cuda``) the same tables have one column, the device's, and the
thread comparison is left out.

Usage: python bench/train_fpointnet.py [--points 1024,512] [--batch 32] [--steps 5] [--precisions fp32,bf16]
                                       [--device cpu|cuda|cuda:N]
"""

from __future__ import annotations

import argparse
import time

import torch

from sianms_cli.models.fpointnet import FPointNetV1
from sianms_cli.models.fpointnet_losses import fpointnet_loss
from sianms_cli.training.precision import MixedPrecision, float32_outputs

MEAN_SIZES = torch.tensor([[4.61, 1.95, 1.72], [0.73, 0.66, 1.76], [1.68, 0.60, 1.27]])


def batch(size: int, points: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Random points, one-hot vectors and targets of a batch."""
    classes = torch.randint(0, 3, (size,), generator=generator)
    targets = {"seg": torch.randint(0, 2, (size, points), generator=generator),
               "center": torch.randn(size, 3, generator=generator) + torch.tensor([0.0, 1.0, 20.0]),
               "heading": torch.rand(size, generator=generator) * 6.28 - 3.14,
               "lwh": MEAN_SIZES[classes] * 1.05, "size_class": classes}
    return torch.randn(size, points, 4, generator=generator), torch.eye(3)[classes], targets


class ConcatenatedHead(FPointNetV1):
    """The original's segmentation head: [point feature, tiled global feature] through one per-point map."""

    def _seg_head_first_layer(self, point_feature: torch.Tensor, global_feature: torch.Tensor) -> torch.Tensor:
        tiled = global_feature[:, None, :].expand(-1, point_feature.shape[1], -1)
        return self.seg_head[0][0](torch.cat([point_feature, tiled], dim=2))


def frustums_per_second(points: int, size: int, steps: int, train: bool, precision: str = "fp32",
                        network: type[FPointNetV1] = FPointNetV1, device: torch.device = torch.device("cpu")) -> float:
    """Frustums per second over ``steps`` steps after one warm-up step."""
    torch.manual_seed(0)
    generator = torch.Generator().manual_seed(0)
    model = network(MEAN_SIZES).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    model.train(train)
    x, one_hot, targets = batch(size, points, generator)
    x, one_hot = x.to(device), one_hot.to(device)
    targets = {key: value.to(device) for key, value in targets.items()}
    mixed = MixedPrecision(precision, device)

    def finished() -> float:  # CUDA runs asynchronously: wait for the queued steps before reading the clock
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return time.perf_counter()

    def step() -> None:
        if not train:
            with torch.no_grad(), mixed.autocast():
                model(x, one_hot)
            return
        with mixed.autocast():
            outputs = model(x, one_hot)
        losses = fpointnet_loss(float32_outputs(outputs), targets, model.mean_sizes)
        optimizer.zero_grad()
        mixed.backward_step(losses["total"], optimizer)

    step()
    start = finished()
    for _ in range(steps):
        step()
    return steps * size / (finished() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", default="1024,512")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--precisions", default="fp32",
                        help="comma-separated: fp32, bf16 (AVX512-BF16 / AMX CPUs), fp16 (loss-scaled)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    args = parser.parse_args()
    device = torch.device(args.device)
    on_cpu = device.type == "cpu"
    point_counts = [int(p) for p in args.points.split(",")]
    precisions = args.precisions.split(",")
    print(f"F-PointNets v1, batch {args.batch}, {args.steps} timed steps, "
          f"{'CPU' if on_cpu else torch.cuda.get_device_name(device)}")
    print("precision | points | mode      | " + ("1 thread | 2 threads | ratio" if on_cpu else "frustums/s"))
    fastest = {}  # (precision, points, mode) -> frustums/s on 2 threads or the GPU
    for precision in precisions:
        for points in point_counts:
            for train in (True, False):
                rates = []
                for threads in ((1, 2) if on_cpu else (None,)):
                    if threads is not None:
                        torch.set_num_threads(threads)
                    rates.append(frustums_per_second(points, args.batch, args.steps, train, precision, device=device))
                mode = "train" if train else "inference"
                fastest[precision, points, mode] = rates[-1]
                columns = (f"{rates[0]:8.1f} | {rates[1]:9.1f} | {rates[1] / rates[0]:.2f}" if on_cpu
                           else f"{rates[0]:10.1f}")
                print(f"{precision:9s} | {points:6d} | {mode:9s} | {columns}")
    if len(precisions) > 1 and "fp32" in precisions:
        print(f"{'2 threads' if on_cpu else args.device}, each precision / fp32")
        for precision in (name for name in precisions if name != "fp32"):
            for key in (key for key in fastest if key[0] == precision):
                print(f"{precision:9s} | {key[1]:6d} | {key[2]:9s} | {fastest[key] / fastest[('fp32', *key[1:])]:.2f}")
    print(f"training in {precisions[0]}{', 2 threads' if on_cpu else ''}: segmentation head as the model applies "
          "it / as the original concatenates")
    print("points | per frustum | concatenated | ratio")
    if on_cpu:
        torch.set_num_threads(2)
    for points in point_counts:
        ours = frustums_per_second(points, args.batch, args.steps, True, precisions[0], device=device)
        original = frustums_per_second(points, args.batch, args.steps, True, precisions[0], ConcatenatedHead, device)
        print(f"{points:6d} | {ours:11.1f} | {original:12.1f} | {ours / original:.2f}")


if __name__ == "__main__":
    main()
