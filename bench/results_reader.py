"""Benchmark ``read_results`` against the reader of an earlier commit, in the same run.

Writes (with ``write_results``, into a temporary folder unless ``--workdir``) a results file
of ``--boxes`` boxes, 200 per sample (20 per class, as bench/metrics.py; 1,203,800 boxes
are its 6,019 validation samples, ~0.5 GB), with float64 values printed by Python's repr as
our writer prints them. Then reads it in a fresh process per reader, ``--repeat`` times each:

- the reference: ``sianms_cli/metrics/results.py`` at ``--reference`` (git show, loaded as
  a module of its own; it uses the current sianms_cli for everything else);
- ours: the working tree's ``read_results``.

Prints each reader's best wall time, the ratio, the peak RSS of each reading process, and
whether both gave the same tokens and the same table to the bit (exit 1 if not). The
reference commit 58db60f is the reader before the collector was paused during decoding
(the target: 3x on 1.2 M boxes). Files of at least ``SCAN_MIN_BYTES`` (64 MiB) go
through the compiled scanner (:mod:`sianms_cli.metrics.results_scan`), whose first read
after an install compiles it (about 6 s, cached): ``--repeat 2`` or more keeps the best.

    python bench/results_reader.py                   # 1.2 M boxes
    python bench/results_reader.py --boxes 300000
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import multiprocessing
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

from sianms_cli.metrics.boxes import ATTRIBUTE_NAMES, DETECTION_NAMES, empty_boxes
from sianms_cli.metrics.results import results_from_boxes, write_results
from sianms_cli.geometry.quaternion import yaw_to_quat

REPO = Path(__file__).resolve().parents[1]
PER_CLASS = 20  # boxes per class and sample, as bench/metrics.py's predictions


def write_workload(path: Path, boxes: int, seed: int) -> None:
    """A results file of ``boxes`` plausible boxes (global frame, metres), deterministic."""
    rng = np.random.default_rng(seed)
    per_sample = PER_CLASS * len(DETECTION_NAMES)
    table = empty_boxes(boxes)
    table["sample"] = np.arange(boxes) // per_sample
    table["label"] = (np.arange(boxes) % per_sample) // PER_CLASS
    table["translation"] = rng.normal(0, 1, (boxes, 3)) * [600, 600, 1] + [1000, 1000, 1]
    table["size"] = rng.uniform(0.4, 10, (boxes, 3))
    table["rotation"] = yaw_to_quat(rng.uniform(-np.pi, np.pi, boxes))
    table["velocity"] = rng.normal(0, 2, (boxes, 2))
    table["score"] = np.round(rng.random(boxes), 3)
    table["attribute"] = rng.integers(-1, len(ATTRIBUTE_NAMES), boxes)
    tokens = [hashlib.md5(f"sample {i}".encode()).hexdigest() for i in range(int(table["sample"][-1]) + 1)]
    write_results(path, results_from_boxes(tokens, table), overwrite=True)


def reference_module(commit: str, folder: Path):
    """results.py at ``commit``, loaded as the module ``reference_results``."""
    source = subprocess.run(["git", "-C", str(REPO), "show", f"{commit}:sianms_cli/metrics/results.py"],
                            capture_output=True, text=True, check=True).stdout
    path = folder / "reference_results.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("reference_results", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _peak_rss_mib() -> float:
    """This process's peak resident set (Linux VmHWM: ru_maxrss would include the parent's
    peak before the exec that started this process)."""
    with open("/proc/self/status") as status:
        line = next(line for line in status if line.startswith("VmHWM:"))
    return int(line.split()[1]) / 1024


def _read_child(results_path: str, reference: str | None, folder: str, queue) -> None:
    try:
        if reference is None:
            from sianms_cli.metrics.results import read_results
        else:
            read_results = reference_module(reference, Path(folder)).read_results
        started = time.perf_counter()
        results = read_results(results_path)
        seconds = time.perf_counter() - started
        digest = hashlib.sha256("\n".join(results.sample_tokens).encode())
        digest.update(results.boxes.tobytes())
        queue.put({"seconds": seconds, "peak_mib": _peak_rss_mib(), "digest": digest.hexdigest(),
                   "boxes": len(results.boxes)})
    except BaseException:
        queue.put({"error": traceback.format_exc()})  # the parent waits on the queue
        raise


def read_in_child(results_path: Path, reference: str | None, folder: Path) -> dict:
    """One read in a fresh process: seconds, peak RSS (MiB), digest of tokens and table."""
    context = multiprocessing.get_context("spawn")
    queue = context.Queue()
    process = context.Process(target=_read_child, args=(str(results_path), reference, str(folder), queue))
    process.start()
    outcome = queue.get()
    process.join()
    if "error" in outcome:
        raise RuntimeError(f"the reading process failed:\n{outcome['error']}")
    return outcome


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--boxes", type=int, default=1_203_800, help="boxes in the results file")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--reference", default="58db60f", help="commit whose reader is the reference")
    parser.add_argument("--repeat", type=int, default=1, help="reads per reader (best time kept)")
    parser.add_argument("--workdir", default=None,
                        help="where the file is written and reused (default: a temporary folder)")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory() as temporary:
        folder = Path(args.workdir or temporary)
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"results-{args.boxes}-seed{args.seed}.json"
        if not path.is_file():
            started = time.perf_counter()
            write_workload(path, args.boxes, args.seed)
            print(f"wrote {path} in {time.perf_counter() - started:.0f} s", flush=True)
        print(f"{args.boxes} boxes, {path.stat().st_size / 2**20:.0f} MiB")
        runs = {name: [read_in_child(path, reference, folder) for _ in range(args.repeat)]
                for name, reference in (("reference", args.reference), ("ours", None))}
    best = {name: min(outcomes, key=lambda outcome: outcome["seconds"]) for name, outcomes in runs.items()}
    for name, outcome in best.items():
        print(f"{name:9s}: read_results {outcome['seconds']:.2f} s ({outcome['seconds'] / args.boxes * 1e6:.2f} us "
              f"per box), peak RSS {outcome['peak_mib']:.0f} MiB")
    print(f"ratio reference / ours: {best['reference']['seconds'] / best['ours']['seconds']:.2f}x")
    same = len({outcome["digest"] for outcomes in runs.values() for outcome in outcomes}) == 1
    print("tokens and table: " + ("identical to the bit" if same else "DIFFER"))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
