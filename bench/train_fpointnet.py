"""Benchmark of Frustum PointNets v1 training steps on this machine's CPU, path against path.

A path is ``kernels:precision[:flags]``: the kernels the arithmetic libraries run (``avx2``:
what every command but the trainings asks for, so bytes agree across CPUs; ``native``: the
CPU's own, what ``sianms train`` runs, :mod:`sianms_cli.kernels`), the precision of the forward
pass (:mod:`sianms_cli.training.precision`), and flags: ``compiled`` (``torch.compile``,
minutes of compiling first; needs a C++ compiler), ``original`` (the network's operations
as they were when the 4x goal of docs/performance.md was set: ReLU at every point before an
``amax`` pool, torch's own dropout draws, the linear maps' biases added before batch norm,
Adam's loop over the parameters) and ``per-point`` (every max-pooled layer through its
per-point outputs, none through its input's covariance). Kernels are chosen when the
libraries load, so every path is measured in a process of its own; all of them run in this
one invocation, and each one's frustums per second is printed as a ratio against the
reference path, ``avx2:fp32:original`` (the trainings' default path then), at the same points
and threads; ``--rounds`` measures them in turn several times.

A step is forward + loss + backward + Adam, batch 32, on random tensors of the real shapes,
with half as many object points as frustum points (the demo's 128 of 256, the original's 512
of 1,024; ``--object-points`` sets them): reading the cache costs well under 1 % of a step.
On a GPU (``--device cuda``) the precisions are compared on the device instead.

Usage: python bench/train_fpointnet.py [--points 256,1024] [--object-points N] [--threads 1,2] [--steps 6] [--rounds 1]
                                       [--paths avx2:fp32,native:fp32,native:bf16,native:bf16:compiled]
                                       [--device cuda]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

REFERENCE = "avx2:fp32:original"
DEFAULT_PATHS = "avx2:fp32,avx2:bf16,native:fp32,native:bf16:per-point,native:bf16"
FLAGS = ("compiled", "original", "per-point")


def use_original_operations() -> None:
    """The network's operations as they were when the 4x goal was set (module docstring)."""
    import torch

    from sianms_cli.models import fpointnet, point_layers

    def original_dropout(x, p, share, training):
        if not training or p == 0:
            return x
        shape = x.shape if share is None else (share.size, *x.shape[1:])
        noise = torch.empty(shape, dtype=x.dtype, device=x.device).bernoulli_(1 - p)
        if share is not None:
            noise = noise[share.start:share.stop]
        return x * noise.div_(1 - p)

    def original_pool(layer, x):
        return torch.relu(point_layers.PointLinear.forward(layer, x)).amax(dim=1)

    point_layers.PooledPointLinear.forward = original_pool
    point_layers.PointLinear.leaves_out_bias = lambda layer: False
    fpointnet.dropout = original_dropout


def use_per_point_pools() -> None:
    """Every max-pooled layer through its per-point outputs (module docstring)."""
    from sianms_cli.models import point_layers

    point_layers.COVARIANCE_MIN_WIDENING = 10**9


def measure(points: int, object_points: int, size: int, steps: int, precision: str, flags: list[str],
            device_name: str) -> float:
    """Training frustums per second over ``steps`` steps after two warm-up steps (compiling, if asked)."""
    import torch

    from sianms_cli.models.fpointnet import FPointNetV1
    from sianms_cli.models.fpointnet_losses import fpointnet_loss
    from sianms_cli.training.precision import MixedPrecision, float32_outputs

    device = torch.device(device_name)
    mean_sizes = torch.tensor([[4.61, 1.95, 1.72], [0.73, 0.66, 1.76], [1.68, 0.60, 1.27]])
    torch.manual_seed(0)
    generator = torch.Generator().manual_seed(0)
    classes = torch.randint(0, 3, (size,), generator=generator)
    targets = {"seg": torch.randint(0, 2, (size, points), generator=generator),
               "center": torch.randn(size, 3, generator=generator) + torch.tensor([0.0, 1.0, 20.0]),
               "heading": torch.rand(size, generator=generator) * 6.28 - 3.14,
               "lwh": mean_sizes[classes] * 1.05, "size_class": classes}
    targets = {key: value.to(device) for key, value in targets.items()}
    x = torch.randn(size, points, 4, generator=generator).to(device)
    one_hot = torch.eye(3)[classes].to(device)
    model = FPointNetV1(mean_sizes, num_object_points=object_points).to(device)
    forward = torch.compile(model) if "compiled" in flags else model
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3, fused="original" not in flags)  # fused: sianms train's
    mixed = MixedPrecision(precision, device)

    def step() -> None:
        with mixed.autocast():
            outputs = forward(x, one_hot)
        losses = fpointnet_loss(float32_outputs(outputs), targets, model.mean_sizes)
        optimizer.zero_grad()
        mixed.backward_step(losses["total"], optimizer)
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    step()
    step()
    start = time.perf_counter()
    for _ in range(steps):
        step()
    return steps * size / (time.perf_counter() - start)


def child(args: argparse.Namespace) -> None:
    """One path in this process: set the kernels before torch loads, then print the rate as JSON."""
    from sianms_cli.kernels import use_avx2_kernels

    use_avx2_kernels(native_default=args.kernels == "native")
    import torch

    if args.device == "cpu":
        torch.set_num_threads(int(args.threads))
    flags = args.flags.split(",")
    if "original" in flags:
        use_original_operations()
    if "per-point" in flags:
        use_per_point_pools()
    rate = measure(int(args.points), object_points(args), args.batch, args.steps, args.precision, flags, args.device)
    print(json.dumps({"frustums_per_second": rate, "capability": torch.backends.cpu.get_cpu_capability()}))


def object_points(args: argparse.Namespace) -> int:
    """The object points of a step: ``--object-points``, or half the frustum's points."""
    return args.object_points or int(args.points) // 2


def run_path(path: str, points: int, threads: int, args: argparse.Namespace) -> float:
    kernels, precision, *flags = path.split(":")
    unknown = set(flags) - set(FLAGS)
    if unknown:
        raise SystemExit(f"path {path}: unknown flag {sorted(unknown)[0]} (flags: {', '.join(FLAGS)})")
    command = [sys.executable, __file__, "--child", "--kernels", kernels, "--precision", precision,
               "--points", str(points), "--threads", str(threads), "--batch", str(args.batch),
               "--steps", str(args.steps), "--device", args.device, "--flags", ",".join(flags),
               *(["--object-points", str(args.object_points)] if args.object_points else [])]
    environment = {key: value for key, value in os.environ.items() if key != "SIANMS_NATIVE_KERNELS"}
    done = subprocess.run(command, capture_output=True, text=True, env=environment, check=False)
    if done.returncode != 0:
        raise SystemExit(f"path {path} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])["frustums_per_second"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", default="256,1024")
    parser.add_argument("--threads", default="1,2")
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--steps", type=int, default=6)
    parser.add_argument("--rounds", type=int, default=1,
                        help="measure every path this many times, in turn; print the medians and the ratios' range")
    parser.add_argument("--object-points", type=int, default=0, help="object points (default: half the points)")
    parser.add_argument("--paths", default=DEFAULT_PATHS, help=f"comma list of kernels:precision[:flags] "
                                                               f"(reference {REFERENCE} is always measured)")
    parser.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N (precisions compared on the device)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--kernels", default="avx2", help=argparse.SUPPRESS)
    parser.add_argument("--precision", default="fp32", help=argparse.SUPPRESS)
    parser.add_argument("--flags", default="", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args)
        return
    if args.device != "cpu":
        args.points = args.points.split(",")[0]
        args.threads = "1"
    paths = [REFERENCE] + [path for path in args.paths.split(",") if path != REFERENCE]
    with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as cpuinfo:
        model = next((line.split(":", 1)[1].strip() for line in cpuinfo if line.startswith("model name")), "unknown")
    print(f"F-PointNets v1 training steps, batch {args.batch}, {args.steps} timed steps, {model}, {args.device}")
    print(f"object points: {args.object_points or 'half the points'}")
    print("path                     | points | threads | frustums/s | / " + REFERENCE)
    for points in (int(value) for value in args.points.split(",")):
        for threads in (int(value) for value in args.threads.split(",")):
            rates: dict[str, list[float]] = {path: [] for path in paths}
            for _ in range(args.rounds):  # in turn, so a slow spell of a shared machine slows every path
                for path in paths:
                    rates[path].append(run_path(path, points, threads, args))
            for path in paths:
                ratios = [rate / reference for rate, reference in zip(rates[path], rates[REFERENCE])]
                spread = f" ({min(ratios):.2f}-{max(ratios):.2f})" if args.rounds > 1 else ""
                print(f"{path:24s} | {points:6d} | {threads:7d} | {statistics.median(rates[path]):10.1f} | "
                      f"{statistics.median(ratios):.2f}{spread}", flush=True)


if __name__ == "__main__":
    main()
