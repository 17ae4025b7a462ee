"""Benchmark of the parts of a Frustum PointNets training step that sianms computes its own way,
each against the way it replaced, in the same run (docs/performance.md#training-sianms-train).

- the max-pooled layers, forward + backward of one batch under bfloat16 autocast: through the
  layer input's covariance (:class:`~sianms_cli.models.point_layers.PooledPointLinear`) against
  per point, for the network's three pooled layers at the demo's sizes (batch 32, 256 points,
  128 object points);
- Adam over the network's 1.6 M parameters: the fused kernel against the loop over parameters;
- dropout's mask for the segmentation head (32 x 256 x 128): random bits against a uniform float
  each and torch's Bernoulli draws.

Native kernels (what ``sianms train`` runs), the median of ``--repeats`` timings of ``--calls``
calls each, after two warm-up calls.

Usage: python bench/train_step_parts.py [--threads 2] [--calls 20] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Callable


def median_ms(work: Callable[[], object], calls: int, repeats: int) -> float:
    """Median over ``repeats`` of the mean milliseconds per call of ``work`` over ``calls`` calls."""
    work()
    work()
    timings = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            work()
        timings.append((time.perf_counter() - start) / calls * 1e3)
    return statistics.median(timings)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--calls", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    from sianms_cli.kernels import use_avx2_kernels

    use_avx2_kernels(native_default=True)
    import torch

    from sianms_cli.models.fpointnet import FPointNetV1
    from sianms_cli.models.global_batch import keep_mask
    from sianms_cli.models.point_layers import PooledPointLinear

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)

    def time_it(work: Callable[[], object]) -> float:
        return median_ms(work, args.calls, args.repeats)

    print(f"parts of a Frustum PointNets training step, {args.threads} threads, ms per call (median of {args.repeats})")
    print(f"{'part (our way / the way it replaced)':58s} |     ours | replaced | ratio")

    def report(part: str, ours: float, theirs: float) -> None:
        print(f"{part:58s} | {ours:8.2f} | {theirs:8.2f} | {theirs / ours:.2f}", flush=True)

    for name, (batch, points, inputs, outputs) in {
            "pooled 128 -> 1,024, segmentation": (32, 256, 128, 1024),
            "pooled 256 -> 512, box": (32, 128, 256, 512),
            "pooled 128 -> 256, T-Net": (32, 128, 128, 256)}.items():
        layer = PooledPointLinear(inputs, outputs).train()
        x = torch.relu(torch.randn(batch, points, inputs)).bfloat16().requires_grad_(True)

        def pooled_step(by_covariance: bool) -> None:
            layer.by_covariance = by_covariance
            with torch.autocast("cpu", dtype=torch.bfloat16):
                pooled = layer(x)
            pooled.float().sum().backward()

        report(name + " (covariance / per point)", time_it(lambda: pooled_step(True)),
               time_it(lambda: pooled_step(False)))

    network = FPointNetV1(torch.ones(3, 3))
    for parameter in network.parameters():
        parameter.grad = torch.randn_like(parameter)
    fused = torch.optim.Adam(network.parameters(), lr=1e-3, fused=True)
    loop = torch.optim.Adam(network.parameters(), lr=1e-3, foreach=False)
    report("Adam step (fused / loop)", time_it(fused.step), time_it(loop.step))

    shape = (32, 256, 128)
    cpu = torch.device("cpu")
    bits = time_it(lambda: keep_mask(shape, 0.5, cpu))
    report("dropout mask (bits / uniform floats)", bits, time_it(lambda: torch.rand(shape) < 0.5))
    report("dropout mask (bits / torch's Bernoulli)", bits,
           time_it(lambda: torch.empty(shape, dtype=torch.bool).bernoulli_(0.5)))


if __name__ == "__main__":
    main()
