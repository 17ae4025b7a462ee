"""sianms_cli/zoo: an entry made from a run loads back to the run's weights (float16 storage, float32
in use), fine-tunes with --init, and is refused in one line when unknown, damaged, of another
architecture or pickled code; `sianms zoo` lists the shipped entries without torch."""

import json
import pickle
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from sianms_cli import zoo
from sianms_cli.cli import app
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.training.fpointnet import FPointNetConfig
from sianms_cli.training.fpointnet import run as train_fpointnet
from sianms_cli.training.run import checkpoint_file, load_checkpoint
from sianms_cli.zoo.export import export_entry

HELD_OUT_SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "zoo_held_out.py"

TINY = {"num_points": 32, "num_object_points": 16, "batch_size": 8, "min_box_height": 0, "flip": False,
        "shift": False, "jitter": False, "device": "cpu", "seed": 2, "precision": "fp32"}
HELD_OUT = {"description": "tiny", "figures": {"car": {"AOE": 1.0}}}


@pytest.fixture(scope="module")
def tiny_run(tiny_caches, tmp_path_factory):
    out = tmp_path_factory.mktemp("zoo-run") / "run"
    train_fpointnet(FPointNetConfig(cache=str(tiny_caches[0]), val_cache=str(tiny_caches[1]), epochs=2, **TINY), out)
    return out


@pytest.fixture
def folder(tiny_run, tmp_path, monkeypatch):
    """A zoo folder holding one entry, ``tiny``, made from :func:`tiny_run`."""
    monkeypatch.setattr(zoo, "FOLDER", tmp_path)
    export_entry(tiny_run, "tiny", summary="a tiny test entry", commands=["sianms train fpointnet ..."],
                 commit="0" * 40, held_out=HELD_OUT, machine="test", folder=tmp_path)
    return tmp_path


def test_an_entry_loads_back_to_the_runs_weights_in_float16_storage(tiny_run, folder):
    run = load_checkpoint(tiny_run / "checkpoint.pt", "fpointnet")
    entry = load_checkpoint(checkpoint_file("zoo:tiny"), "fpointnet")
    assert entry.optimizer == {} and entry.extra == run.extra and entry.config == run.config
    for key, value in run.model.items():
        if key.endswith((".weight", ".bias")):
            assert entry.model[key].dtype == torch.float16
            assert torch.allclose(entry.model[key].float(), value, rtol=1e-3, atol=1e-4), key
        else:  # batch-norm statistics and the size clusters, exactly
            assert torch.equal(entry.model[key], value), key
    card = zoo.card("tiny")
    assert card["bytes"] == (folder / "tiny.pt").stat().st_size
    assert card["training"]["epochs"] == 2 and len(card["training"]["curve"]) == 2
    assert card["dataset"]["split"] == "mini_train"


def test_init_fine_tunes_from_an_entry_keeping_its_size_clusters(tiny_caches, folder, tmp_path):
    result = train_fpointnet(FPointNetConfig(cache=str(tiny_caches[0]), epochs=1, init="zoo:tiny", **TINY),
                             tmp_path / "tuned")
    entry = load_checkpoint(checkpoint_file("zoo:tiny"))
    assert torch.equal(torch.as_tensor(result.mean_sizes, dtype=torch.float32), entry.model["mean_sizes"])
    assert result.history[0]["train_total"] < 10 * entry.history[-1]["train_total"]


def test_a_fine_tuned_entrys_card_accounts_for_the_training_it_started_from(tiny_caches, tiny_run, folder, tmp_path):
    """From a run folder: that run's epochs and curve; from a zoo entry: the entry's card's training."""
    for init, name in ((str(tiny_run), "from-run"), ("zoo:tiny", "from-entry")):
        tuned = tmp_path / name
        train_fpointnet(FPointNetConfig(cache=str(tiny_caches[0]), epochs=1, init=init, **TINY), tuned)
        export_entry(tuned, name, summary="tuned", commands=["sianms train fpointnet --init ..."], commit="0" * 40,
                     held_out=HELD_OUT, machine="test", folder=folder)
        training = zoo.card(name)["training"]
        assert training["epochs"] == 1 and len(training["curve"]) == 1
        started = training["started_from"]
        assert started["init"] == init and started["epochs"] == 2 and len(started["curve"]) == 2
        assert started["curve"] == zoo.card("tiny")["training"]["curve"]
    assert "started_from" not in zoo.card("tiny")["training"]


def test_an_unknown_name_lists_the_shipped_entries(folder):
    with pytest.raises(SianmsError, match=r"zoo:nope: no such zoo entry \(shipped: zoo:tiny; `sianms zoo`"):
        checkpoint_file("zoo:nope")
    with pytest.raises(SianmsError, match="no such zoo entry"):
        checkpoint_file("zoo:../tiny")


def test_a_damaged_file_is_refused_naming_it(folder):
    data = bytearray((folder / "tiny.pt").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (folder / "tiny.pt").write_bytes(bytes(data))
    with pytest.raises(DataFormatError, match=r"tiny\.pt: damaged: .* the model card says"):
        checkpoint_file("zoo:tiny")


def test_another_architecture_is_refused_by_kind_and_by_shape(folder, tiny_caches, tmp_path):
    with pytest.raises(DataFormatError, match="a 'fpointnet' checkpoint, expected 'siamese'"):
        load_checkpoint(checkpoint_file("zoo:tiny"), "siamese")
    with pytest.raises(DataFormatError, match=r"tiny\.pt: field 'model\.seg_point\.0\.linear\.weight': shape"):
        train_fpointnet(FPointNetConfig(cache=str(tiny_caches[0]), epochs=1, init="zoo:tiny", intensity=False,
                                        **TINY), tmp_path / "other")
    with pytest.raises(DataFormatError, match="trained on classes"):
        train_fpointnet(FPointNetConfig(cache=str(tiny_caches[0]), epochs=1, init="zoo:tiny", classes=("car",),
                                        **TINY), tmp_path / "cars")


class Payload:
    def __reduce__(self):
        return (print, ("pickled code ran",))


def test_pickled_code_in_an_entry_is_refused(folder):
    data = pickle.dumps({"format": "sianms-checkpoint-1", "model": Payload()})
    (folder / "tiny.pt").write_bytes(data)
    card = json.loads((folder / "tiny.json").read_text())
    card.update(bytes=len(data), sha256=__import__("hashlib").sha256(data).hexdigest())
    (folder / "tiny.json").write_text(json.dumps(card))
    with pytest.raises(DataFormatError, match="weights-only load refused it"):
        load_checkpoint(checkpoint_file("zoo:tiny"))


def test_a_card_of_the_wrong_shape_is_refused_by_field(folder):
    card = json.loads((folder / "tiny.json").read_text())
    (folder / "tiny.json").write_text(json.dumps({**card, "bytes": "many"}))
    with pytest.raises(DataFormatError, match=r"tiny\.json: field 'bytes': expected int, got str"):
        zoo.card("tiny")


def test_the_cli_lists_entries_and_refuses_unknown_names_in_one_line(folder, tiny_caches, tmp_path):
    listed = CliRunner().invoke(app, ["zoo"])
    assert listed.exit_code == 0 and "zoo:tiny  (fpointnet" in listed.stdout and "car: AOE 1.0" in listed.stdout
    assert json.loads(CliRunner().invoke(app, ["zoo", "--json"]).stdout)[0]["name"] == "tiny"
    refused = CliRunner().invoke(app, ["train", "fpointnet", "--cache", str(tiny_caches[0]), "--out",
                                       str(tmp_path / "r"), "--init", "zoo:missing", "--epochs", "1", "--quiet"])
    assert refused.exit_code == 2 and refused.stderr.count("\n") == 1
    assert refused.stderr.startswith("error: zoo:missing: no such zoo entry")


def test_listing_the_zoo_imports_no_torch():
    probe = "import sys; sys.argv = ['sianms', 'zoo']\nfrom sianms_cli.entry import main\ntry:\n    main()\n" \
            "except SystemExit:\n    pass\nassert 'torch' not in sys.modules, 'torch imported'\n"
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr


def test_the_shipped_entries_load_as_their_cards_say_within_the_packages_budget():
    for name in zoo.names():
        checkpoint = load_checkpoint(checkpoint_file(f"{zoo.PREFIX}{name}"), zoo.card(name)["model"])
        assert checkpoint.optimizer == {}
    assert {"fpointnet-single", "fpointnet-multiview", "siamese"} <= set(zoo.names())
    assert sum(zoo.card(name)["bytes"] for name in zoo.names()) <= 10_000_000  # the zoo's share of the package


def test_the_held_out_script_splits_each_class_heading_errors_and_reads_the_devkits_figures(tiny_run, tiny_caches,
                                                                                          tmp_path):
    """Right + flipped + off the axis = 1 for each class seen, besides the validation's own figures;
    the devkit's AP and true-positive errors in the card's units."""
    labels = ("car", "pedestrian", "bicycle")
    evaluation = {"mean_dist_aps": dict.fromkeys(labels, 0.4331), "gt_boxes_per_class": dict.fromkeys(labels, 7),
                  "label_tp_errors": dict.fromkeys(labels, {"trans_err": 0.2973, "scale_err": 0.19418,
                                                            "orient_err": 0.99956})}
    (tmp_path / "devkit.json").write_text(json.dumps({"evaluation": evaluation}))
    out = tmp_path / "figures.json"
    result = subprocess.run([sys.executable, str(HELD_OUT_SCRIPT), "--fpointnet", str(tiny_run), "--cache",
                             str(tiny_caches[1]), "--out", str(out), "--devkit", str(tmp_path / "devkit.json")],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    figures = json.loads(out.read_text())["figures"]
    seen = [group for group, values in figures.items()
            if ", frustums" in group and group != "all, frustums" and values.get("count")]
    assert "car, frustums" in seen
    bands = [group for group in seen if group.startswith("car, frustums at ")]
    assert bands and sum(figures[group]["count"] for group in bands) == figures["car, frustums"]["count"]
    for values in (figures[group] for group in seen):
        shares = values["heading_right"] + values["heading_flipped"] + values["heading_off_axis"]
        assert shares == pytest.approx(1, abs=2e-4)  # each share rounded to 4 places
    assert figures["car, devkit"] == {"AP": 43.3, "ATE": 0.297, "ASE": 0.194, "AOE": 1.0, "ground_truth": 7}
