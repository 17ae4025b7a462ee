"""Every command's config refuses a flag value that would fail deep in the run, naming the flag."""

import math
import subprocess
import sys

import pytest

from sianms_cli.demo import DemoConfig
from sianms_cli.errors import SEED_LIMIT, SianmsError
from sianms_cli.evaluation.job import EvalConfig
from sianms_cli.prepare.config import MAX_ROI_SIZE, PrepareConfig
from sianms_cli.synth.generate import SynthConfig
from sianms_cli.training.fpointnet import FPointNetConfig
from sianms_cli.training.siamese import SiameseConfig

CONFIGS = {
    "synth": lambda **flags: SynthConfig(scenes=1, **flags),
    "demo": lambda **flags: DemoConfig(**flags),
    "prepare": lambda **flags: PrepareConfig(dataroot="d", version="v1.0-mini", split="mini_train", **flags),
    "siamese": lambda **flags: SiameseConfig(cache="c", **flags),
    "fpointnet": lambda **flags: FPointNetConfig(cache="c", **flags),
    "eval": lambda **flags: EvalConfig(dataroot="d", version="v1.0-mini", split="mini_val", cache="c",
                                       siamese="s", fpointnet="f", **flags),
}


@pytest.mark.parametrize("command", sorted(CONFIGS))
@pytest.mark.parametrize("seed", [-1, SEED_LIMIT])
def test_every_command_takes_the_same_seeds(command, seed):
    with pytest.raises(SianmsError, match=rf"^--seed must be between 0 and 2\*\*63 - 1, got {seed}$"):
        CONFIGS[command](seed=seed)
    assert CONFIGS[command](seed=SEED_LIMIT - 1).seed == SEED_LIMIT - 1


@pytest.mark.parametrize("flags, message", [
    (dict(lr=math.inf), "--lr must be positive, got inf"),
    (dict(lr=math.nan), "--lr must be positive, got nan"),
    (dict(decay_rate=0.0), r"--decay-rate must be in \(0, 1\], got 0.0"),
    (dict(min_box_height=-1.0), "--min-box-height must be >= 0, got -1.0"),
    (dict(box_weight=-1.0), "--box-weight must be a finite number >= 0, got -1.0"),
    (dict(corner_weight=math.nan), "--corner-weight must be a finite number >= 0, got nan"),
    (dict(heading_class_weight=-0.5), "--heading-class-weight must be a finite number >= 0, got -0.5"),
])
def test_fpointnet_names_the_flag_it_refuses(flags, message):
    with pytest.raises(SianmsError, match=f"^{message}$"):
        CONFIGS["fpointnet"](**flags)


@pytest.mark.parametrize("command", ["siamese", "fpointnet"])
def test_trainings_refuse_zero_streams_rather_than_taking_it_for_the_default(command):
    with pytest.raises(SianmsError, match="^--streams must be at least 1, got 0$"):
        CONFIGS[command](streams=0)


@pytest.mark.parametrize("flags, message", [
    (dict(dim=100_000_000_000), r"--dim must be in \[1, 65536\], got 100000000000"),
    (dict(conv_channels=(128, 70_000)), r"--conv-channels must be two widths in \[1, 65536\]"),
    (dict(hidden=(0,)), r"--hidden widths must be in \[1, 65536\], got \(0,\)"),
    # each width allowed, their products not: the OOM killer had ended the run without a word
    (dict(hidden=(65536,) * 4, dim=65536), r"^--hidden 65536,65536,65536,65536 and --dim 65536 make "
                                           r"17,179,869,184 weights between the layers; at most 1,000,000,000$"),
    (dict(alpha=0.0, beta=1e300), r"^--alpha and --beta need 0 <= alpha < beta <= 1e\+06, got 0.0, 1e\+300$"),
])
def test_siamese_bounds_its_layer_widths(flags, message):
    with pytest.raises(SianmsError, match=message):
        CONFIGS["siamese"](**flags)


def test_prepare_bounds_the_roi_size():
    with pytest.raises(SianmsError, match=f"--roi-size must be between 1 and {MAX_ROI_SIZE}, got 100000"):
        CONFIGS["prepare"](roi_size=100_000)


def test_eval_refuses_a_class_siamese_matching_cannot_have():
    with pytest.raises(SianmsError, match="--sianms-classes: unknown detection class 'tank'"):
        CONFIGS["eval"](sianms_classes=("tank",))


def test_eval_checks_the_device_before_loading_anything():
    from sianms_cli.evaluation.job import load_models

    with pytest.raises(SianmsError, match="--device must be auto, cpu, cuda or cuda:N, got 'tpu'"):
        load_models(CONFIGS["eval"](device="tpu"))


def test_demo_checks_its_worker_count_before_writing(tmp_path):
    from sianms_cli.demo import run

    with pytest.raises(SianmsError, match="--workers must be at least 1, got 0"):
        run(DemoConfig(quick=True), tmp_path / "demo", workers=0)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("cpus, workers, allowed", [(2, 8, True), (2, 9, False), (1, 4, True), (64, 257, False)])
def test_workers_are_bounded_by_the_usable_cpus(monkeypatch, cpus, workers, allowed):
    from sianms_cli import errors

    monkeypatch.setattr(errors, "usable_cpus", lambda: cpus)
    if allowed:
        errors.check_workers(workers)
    else:
        with pytest.raises(SianmsError, match=f"--workers must be at most {4 * cpus} .*, got {workers}$"):
            errors.check_workers(workers)


def test_a_worker_count_past_the_bound_is_one_error_line_before_anything_is_written(tmp_path):
    from sianms_cli import errors

    result = subprocess.run([sys.executable, "-m", "sianms_cli", "synth", "--out", str(tmp_path / "out"),
                             "--workers", str(errors.PER_CPU_LIMIT * errors.usable_cpus() + 1)],
                            capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.startswith("error: --workers must be at most ") and result.stderr.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flag", ["siamese_epochs", "fpointnet_epochs"])
@pytest.mark.parametrize("epochs", [0, 20_000])
def test_demo_bounds_each_trainings_epochs_by_its_own_flag_before_any_stage(tmp_path, flag, epochs):
    # 20,000 had passed the demo's check, and the demo ran synth and both prepares (or, with
    # --overwrite, deleted the finished training stages) before the training refused "--epochs".
    from sianms_cli.demo import run

    name = flag.replace("_", "-")
    with pytest.raises(SianmsError, match=f"^--{name} must be in \\[1, 10,000\\], got {epochs}$"):
        run(DemoConfig(quick=True, **{flag: epochs}), tmp_path / "demo")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["demo", "--quick"], ["train", "siamese", "--cache", "c"],
                                     ["train", "fpointnet", "--cache", "c"]])
def test_threads_past_the_bound_are_one_error_line_before_torch_or_anything_else(tmp_path, command):
    # 10,000,000,000 had been an OverflowError traceback inside torch; 100,000 crashed OpenBLAS.
    result = subprocess.run([sys.executable, "-m", "sianms_cli", *command, "--out", str(tmp_path / "out"),
                             "--threads", "10000000000"], capture_output=True, text=True)
    assert result.returncode == 2
    assert result.stderr.startswith("error: --threads must be at most ") and result.stderr.count("\n") == 1
    assert result.stderr.endswith("got 10000000000\n")
    assert list(tmp_path.iterdir()) == []


def test_an_nms_sweep_threshold_given_twice_is_one_method():
    # "0.1,0.10" had made axis-nms@0.1 and rotated-nms@0.1 twice each, scored and shown twice.
    methods = CONFIGS["eval"](methods="vanilla,axis-nms,rotated-nms", nms_sweep="0.1,0.10,0.30,0.05").method_names
    assert methods == ("vanilla", "axis-nms", "axis-nms@0.1", "axis-nms@0.05",
                       "rotated-nms", "rotated-nms@0.1", "rotated-nms@0.05")
