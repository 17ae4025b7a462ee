"""Benchmark the nuScenes table loader against the official devkit on the same dataroot.

Loads ``DATAROOT/VERSION`` with :class:`NuScenesDB` in a fresh child process (so that its
peak memory is the load's own) and, when the devkit venv exists (``scripts/devkit_venv.sh``),
with ``nuscenes.NuScenes`` in a child process of that venv, and prints both times, their
ratio and our peak memory. Our load is timed ``--repeat`` times and the fastest counts; its
CPU time, printed beside the wall time, varies less on a busy machine.

    python bench/loader.py data/synth-mini v1.0-mini
    python bench/loader.py data/synth-mini v1.0-mini --repeat 3
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import resource
import subprocess
import sys
import time
from pathlib import Path
from queue import Empty

from sianms_cli.errors import SianmsError
from sianms_cli.nuscenes.loader import NuScenesDB

REPO = Path(__file__).resolve().parents[1]
DEVKIT_PYTHON = Path(os.environ.get("SIANMS_DEVKIT_PYTHON", REPO / ".devkit-venv" / "bin" / "python"))
DEVKIT_LOAD = """
import sys, time
from nuscenes.nuscenes import NuScenes
start = time.perf_counter()
NuScenes(version=sys.argv[2], dataroot=sys.argv[1], verbose=False)
print(time.perf_counter() - start)
"""


def _load_child(dataroot: str, version: str, queue) -> None:
    start, start_cpu = time.perf_counter(), time.process_time()
    try:
        db = NuScenesDB(dataroot, version)
    except SianmsError as error:  # the parent says it: one line, exit 2
        queue.put(str(error))
        return
    seconds, cpu = time.perf_counter() - start, time.process_time() - start_cpu
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    sizes = ", ".join(f"{name} {len(db.table(name))}" for name in ("sample", "sample_data", "sample_annotation"))
    queue.put((seconds, cpu, peak, sizes))


def measure_load(dataroot: Path, version: str) -> tuple[float, float, float, str]:
    """(wall seconds, CPU seconds, peak RSS in MiB, table sizes) of one load in a fresh process."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_load_child, args=(str(dataroot), version, queue))
    process.start()
    while True:  # a child that dies without a word (killed, out of memory) must not leave us waiting
        try:
            result = queue.get(timeout=1.0)
            break
        except Empty:
            if not process.is_alive():
                raise SystemExit(f"error: the loading process died (exit code {process.exitcode})") from None
    process.join()
    if isinstance(result, str):
        print(f"error: {result}", file=sys.stderr)
        raise SystemExit(2)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataroot", type=Path)
    parser.add_argument("version")
    parser.add_argument("--repeat", type=int, default=1, help="loads to time; the fastest counts")
    args = parser.parse_args()

    ours, cpu, peak, sizes = min(measure_load(args.dataroot, args.version) for _ in range(args.repeat))
    print(f"{args.dataroot}/{args.version}: {sizes}")
    print(f"  sianms NuScenesDB: {ours:.2f} s ({cpu:.2f} s CPU), peak RSS {peak:.0f} MiB")
    if not DEVKIT_PYTHON.exists():
        print(f"  devkit: not measured ({DEVKIT_PYTHON} absent; run scripts/devkit_venv.sh)")
        return
    result = subprocess.run([str(DEVKIT_PYTHON), "-c", DEVKIT_LOAD, str(args.dataroot), args.version],
                            capture_output=True, text=True, check=True)
    devkit = float(result.stdout.strip().splitlines()[-1])
    print(f"  nuscenes-devkit NuScenes(): {devkit:.2f} s -> devkit / sianms = {devkit / ours:.1f}x")


if __name__ == "__main__":
    sys.exit(main())
