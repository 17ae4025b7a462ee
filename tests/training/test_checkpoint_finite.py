"""A checkpoint whose weights hold NaN or infinity is refused when loaded, naming it and the tensor, and
an evaluation whose network gives boxes that are not finite names the checkpoint: it had blamed its own
scene file, whose deletion its message advised and which the next run wrote again."""

import re

import pytest
import torch
from typer.testing import CliRunner

from sianms_cli.cli import app
from sianms_cli.errors import DataFormatError
from sianms_cli.training.run import CHECKPOINT, load_checkpoint

runner = CliRunner()


def edited_checkpoint(source, target, edit):
    """``source``'s checkpoint with ``edit(data)`` applied, saved at ``target``; the first float weight's name."""
    data = torch.load(source / CHECKPOINT, weights_only=True)
    name = next(name for name, value in data["model"].items() if value.is_floating_point())
    edit(data, name)
    torch.save(data, target)
    return name


@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_a_weight_that_is_not_finite_is_refused_naming_the_tensor(eval_inputs, tmp_path, value):
    path = tmp_path / "bad.pt"
    name = edited_checkpoint(eval_inputs.fpointnet, path, lambda data, name: data["model"][name].view(-1)[:2]
                             .fill_(value))
    with pytest.raises(DataFormatError) as raised:
        load_checkpoint(path, "fpointnet")
    assert str(raised.value) == (f"{path}: field 'model.{name}': 2 of its {torch.load(path)['model'][name].numel():,} "
                                 "values are NaN or infinite (a training that diverged, or an altered file): not a "
                                 "usable checkpoint; take an earlier one or train again")


def test_an_optimizer_state_that_is_not_finite_is_refused(eval_inputs, tmp_path):
    """A resumed run would go on from it."""
    path = tmp_path / "bad.pt"
    data = torch.load(eval_inputs.siamese / CHECKPOINT, weights_only=True)
    key = sorted(data["optimizer"]["state"])[0]
    state = data["optimizer"]["state"][key]
    moment = next(entry for entry, value in state.items() if value.is_floating_point() and value.numel() > 1)
    state[moment].view(-1)[0] = float("nan")
    torch.save(data, path)
    where = re.escape(f"optimizer.state.{key}.{moment}")
    with pytest.raises(DataFormatError, match=rf"^{re.escape(str(path))}: field '{where}': 1 of its"):
        load_checkpoint(path, "siamese")


def eval_arguments(inputs, fpointnet, out):
    return ["eval", "--dataroot", str(inputs.dataroot), "--split", inputs.split, "--cache", str(inputs.cache),
            "--siamese", str(inputs.siamese), "--fpointnet", str(fpointnet), "--out", str(out),
            "--methods", "vanilla", "--pictures", "0", "--quiet"]


def test_eval_names_the_checkpoint_with_nan_weights_and_writes_nothing(eval_inputs, tmp_path):
    path = tmp_path / "nan.pt"
    name = edited_checkpoint(eval_inputs.fpointnet, path, lambda data, name: data["model"][name].fill_(float("nan")))
    done = runner.invoke(app, eval_arguments(eval_inputs, path, tmp_path / "eval"))
    assert done.exit_code == 2
    assert done.stderr.startswith(f"error: {path}: field 'model.{name}': ") and done.stderr.count("\n") == 1
    assert not (tmp_path / "eval").exists()


def test_eval_blames_the_checkpoint_whose_boxes_overflow_not_the_scene_file(eval_inputs, tmp_path):
    """Weights finite but beyond what float32 boxes hold: the network's boxes are infinite."""
    path = tmp_path / "huge.pt"

    def enlarge(data, name):
        for key, value in data["model"].items():
            if key.startswith("box_head") and value.is_floating_point():
                value.mul_(1e30)

    edited_checkpoint(eval_inputs.fpointnet, path, enlarge)
    out = tmp_path / "eval"
    done = runner.invoke(app, eval_arguments(eval_inputs, path, out))
    assert done.exit_code == 2, done.output
    last = done.stderr.splitlines()[-1]
    assert re.fullmatch(rf"error: {re.escape(str(path))}: the network gave scene \S+ a box whose \w+ is not .+ "
                        r"\(row \d+\): the checkpoint is not usable; take another one or train again", last), last
    assert not list((out / "scenes").glob("*.parquet"))  # no scene table to blame
