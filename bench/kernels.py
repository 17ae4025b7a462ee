"""What asking for AVX2 kernels costs (sianms_cli/kernels.py): the two stages that dominate the
demo, timed in fresh processes with the machine's native kernels and with the AVX2 ones.

Frustum PointNets training (75 % of the demo: frustums per second at 1,024 points, batch 32,
512 object points, 2 torch threads, float32: :func:`train_fpointnet.measure`) and ``sianms synth`` of one
5-second mini scene at image scale 0.25 (15 %: samples per second). Prints both rates under
both settings and AVX2 / native; on an AVX2-only machine the two settings run the same kernels
and the ratios measure the noise.

Usage: python bench/kernels.py [--steps 5] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def measure(steps: int) -> dict[str, float]:
    """Frustums per second training, samples per second synthesising, in this process."""
    import torch

    from sianms_cli.synth.generate import SynthConfig, run
    from train_fpointnet import measure as training_rate

    torch.set_num_threads(2)
    training = training_rate(1024, 512, 32, steps, "fp32", False, "cpu")
    config = SynthConfig(version="v1.0-mini", scenes=1, image_scale=0.25, scene_seconds=5.0, seed=1)
    with tempfile.TemporaryDirectory() as scratch:
        start = time.perf_counter()
        written = run(config, Path(scratch) / "data")
        synth = written.samples / (time.perf_counter() - start)
    return {"train": training, "synth": synth}


def in_fresh_process(native: bool, steps: int) -> dict[str, float]:
    """:func:`measure` in a new process that loads numpy and torch with the chosen kernels."""
    from sianms_cli.kernels import AVX2_SETTINGS, NATIVE_SWITCH, use_avx2_kernels

    environment = {name: value for name, value in os.environ.items() if name not in AVX2_SETTINGS}
    environment.pop(NATIVE_SWITCH, None)
    if native:
        environment[NATIVE_SWITCH] = "1"
    use_avx2_kernels(environment)
    done = subprocess.run([sys.executable, __file__, "--child", "--steps", str(steps)], env=environment,
                          capture_output=True, text=True, check=True)
    return json.loads(done.stdout)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=3, help="fresh processes per setting; the best is kept")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(measure(args.steps)))
        return
    from sianms_cli.kernels import cpu_facts

    vendor, width = cpu_facts()
    best = {}
    for _ in range(args.repeats):  # alternated, so a slower minute of the machine hits both
        for native in (True, False):
            rates = in_fresh_process(native, args.steps)
            for stage, rate in rates.items():
                best[native, stage] = max(best.get((native, stage), 0.0), rate)
    print(f"{vendor}, {width} CPU; best of {args.repeats} fresh processes each")
    print("stage                         | native | AVX2   | AVX2 / native")
    for stage, label in (("train", "F-PointNets train, frustums/s"), ("synth", "synth, samples/s")):
        native, avx2 = best[True, stage], best[False, stage]
        print(f"{label:29s} | {native:6.1f} | {avx2:6.1f} | {avx2 / native:.2f}")


if __name__ == "__main__":
    main()
