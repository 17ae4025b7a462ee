"""The shared run folder: checkpoints (weights-only, clear errors), refusing, resuming, metrics, seeds."""

import pickle
from dataclasses import replace

import numpy as np
import pytest
import torch

from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError
from sianms_cli.io import OutputError
from sianms_cli.training.run import (
    CHECKPOINT, CONFIG, CURVES, METRICS, Checkpoint, RunFolder, check_losses_finite, checkpoint_fingerprint,
    choose_device, epoch_generator, load_checkpoint, load_state, metrics_csv, save_checkpoint, step_decay,
)


def small_checkpoint(kind="siamese", epoch=2):
    torch.manual_seed(0)
    net = torch.nn.Linear(3, 2)
    optimizer = torch.optim.Adam(net.parameters())
    net(torch.ones(1, 3)).sum().backward()
    optimizer.step()
    return net, Checkpoint(kind=kind, config={"dim": 2, "widths": [1, 2], "cache": None}, epoch=epoch,
                           model=net.state_dict(), optimizer=optimizer.state_dict(),
                           history=[{"epoch": done, "loss": 0.5} for done in range(1, epoch + 1)],
                           extra={"dis_thr": 1.25})



def test_a_checkpoints_fingerprint_is_its_weights_and_settings_not_where_its_inputs_lay(tmp_path):
    _, checkpoint = small_checkpoint()
    fingerprint = checkpoint_fingerprint(checkpoint)
    save_checkpoint(tmp_path / CHECKPOINT, checkpoint)
    assert checkpoint_fingerprint(load_checkpoint(tmp_path / CHECKPOINT)) == fingerprint
    moved = {**checkpoint.config, "cache": "/elsewhere/cache", "val_cache": "/elsewhere/val", "dataroot": "/data"}
    assert checkpoint_fingerprint(replace(checkpoint, config=moved, optimizer={}, history=[])) == fingerprint
    weights = {key: value.clone() for key, value in checkpoint.model.items()}
    weights["bias"][0] = torch.nextafter(weights["bias"][0], torch.tensor(1.0))
    as_bf16 = {key: value.to(torch.bfloat16) for key, value in checkpoint.model.items()}
    for changed in (replace(checkpoint, model=weights), replace(checkpoint, model=as_bf16),
                    replace(checkpoint, config={**checkpoint.config, "dim": 3}), replace(checkpoint, epoch=3),
                    replace(checkpoint, extra={"dis_thr": 1.5}), replace(checkpoint, kind="fpointnet")):
        assert checkpoint_fingerprint(changed) != fingerprint


def test_checkpoint_round_trip(tmp_path):
    net, checkpoint = small_checkpoint()
    save_checkpoint(tmp_path / CHECKPOINT, checkpoint)
    loaded = load_checkpoint(tmp_path / CHECKPOINT, "siamese")
    assert (loaded.kind, loaded.config, loaded.epoch, loaded.history, loaded.extra) == (
        "siamese", checkpoint.config, 2, checkpoint.history, {"dis_thr": 1.25})
    other = torch.nn.Linear(3, 2)
    load_state(other, loaded.model, tmp_path / CHECKPOINT)
    for key, value in net.state_dict().items():
        assert torch.equal(other.state_dict()[key], value)
    assert loaded.optimizer["state"][0]["exp_avg"].shape == (2, 3)


def test_a_pickled_object_is_refused(tmp_path):
    path = tmp_path / "evil.pt"
    torch.save({"format": "sianms-checkpoint-1", "model": {}, "payload": ValueError("x")}, path)
    with pytest.raises(DataFormatError,
                       match="evil.pt: not a sianms checkpoint .weights-only load refused it") as error:
        load_checkpoint(path)
    assert "Unsupported global" in str(error.value) and "weights_only" not in str(error.value)  # no advice to unpickle
    good = save_checkpoint(tmp_path / CHECKPOINT, small_checkpoint()[1]).read_bytes()
    # the last two: torch's zip reader raises OSError(EINVAL), its unpickler IndexError
    for content in (pickle.dumps({"a": 1}) + b"junk", b"junk", b"", b"PK\x03\x04 a broken zip",
                    good[:len(good) // 2], b"\x80\x02q\x00."):
        path.write_bytes(content)
        with pytest.raises(DataFormatError, match="evil.pt: not a sianms checkpoint"):
            load_checkpoint(path)


def test_foreign_keys_and_kinds_are_refused(tmp_path):
    _, checkpoint = small_checkpoint()
    path = save_checkpoint(tmp_path / CHECKPOINT, checkpoint)
    data = torch.load(path, weights_only=True)
    torch.save({**data, "surprise": 1}, tmp_path / "foreign.pt")
    with pytest.raises(DataFormatError, match=r"unexpected keys \['surprise'\]"):
        load_checkpoint(tmp_path / "foreign.pt")
    torch.save({"state_dict": {}}, tmp_path / "other.pt")
    with pytest.raises(DataFormatError, match="no format"):
        load_checkpoint(tmp_path / "other.pt")
    with pytest.raises(DataFormatError, match="a 'siamese' checkpoint, expected 'fpointnet'"):
        load_checkpoint(path, "fpointnet")
    with pytest.raises(DataFormatError, match="file not found"):
        load_checkpoint(tmp_path / "missing.pt")


@pytest.mark.parametrize("field, value, message", [
    ("epoch", "x", "field 'epoch': expected an integer, got str"),
    ("epoch", True, "field 'epoch': expected an integer, got bool"),
    ("epoch", -3, "field 'epoch': expected an epoch count >= 0, got -3"),
    ("history", None, "field 'history': expected a list, got NoneType"),
    ("history", [1], r"field 'history\[0\]': expected an object per epoch, got int"),
    # metrics.csv, curves.png and the command's summary line read each row's figures as numbers
    ("history", [{"epoch": 1, "loss": 0.5}, {"loss": 0.4}], r"field 'history\[1\].epoch': expected 2, got None"),
    ("history", [{"epoch": 1, "loss": 0.5}, {"epoch": 2, "val_dis_thr": "x"}],
     r"field 'history\[1\].val_dis_thr': expected a number or null, got str"),
    ("history", [{"epoch": 1, "loss": True}, {"epoch": 2}],
     r"field 'history\[0\].loss': expected a number or null, got bool"),
    ("optimizer", [], "field 'optimizer': expected an object, got list"),
    ("model", {"weight": 5}, "field 'model.weight': expected a tensor, got int"),
    ("kind", 3, "field 'kind': expected a string, got int"),
])
def test_a_checkpoint_field_of_the_wrong_type_is_named(tmp_path, field, value, message):
    data = {"format": "sianms-checkpoint-1", **vars(small_checkpoint()[1]), field: value}
    torch.save(data, tmp_path / CHECKPOINT)
    with pytest.raises(DataFormatError, match=message):
        load_checkpoint(tmp_path / CHECKPOINT)


def test_a_folder_named_like_a_checkpoint_is_called_a_folder(tmp_path):
    (tmp_path / CHECKPOINT).mkdir()
    with pytest.raises(DataFormatError, match="is a folder, not a checkpoint file"):
        load_checkpoint(tmp_path / CHECKPOINT)


def restore_edited(tmp_path, edit):
    """Resume a run whose checkpoint was saved as ``edit(checkpoint)``; restore into a fresh Adam."""
    net, checkpoint = small_checkpoint()
    with RunFolder.open(tmp_path / "run", kind="siamese", config=checkpoint.config) as run:
        run.save(edit(checkpoint), curves=False)
    resumed = RunFolder.open(tmp_path / "run", kind="siamese", config=checkpoint.config, resume=True)
    with resumed:
        resumed.restore(net, torch.optim.Adam(net.parameters()))


def with_moment(checkpoint, moment):
    optimizer = checkpoint.optimizer
    state = {**optimizer["state"], 1: {**optimizer["state"][1], "exp_avg": moment}}
    return replace(checkpoint, optimizer={**optimizer, "state": state})


@pytest.mark.parametrize("edit, message", [
    (lambda checkpoint: replace(checkpoint, optimizer={"x": 1}),
     "field 'optimizer': the optimizer state does not fit"),
    # torch loads Adam's moments whatever their shape: the first step had ended in a traceback
    (lambda checkpoint: with_moment(checkpoint, torch.zeros(5)),
     r"field 'optimizer': state 1 'exp_avg' has shape \(5,\), its weight \(2,\) \(another config\?\)$"),
    # an edited epoch of 5 over 2 rows of history had been resumed at epoch 6
    (lambda checkpoint: replace(checkpoint, epoch=5), r"field 'epoch': 5 epochs done, but the history holds 2 rows$"),
])
def test_a_resume_from_a_checkpoint_that_does_not_fit_names_the_field(tmp_path, edit, message):
    with pytest.raises(DataFormatError, match=f"checkpoint.pt: {message}"):
        restore_edited(tmp_path, edit)


def test_weights_that_do_not_fit_name_the_key(tmp_path):
    _, checkpoint = small_checkpoint()
    with pytest.raises(DataFormatError, match=r"field 'model.weight': shape \(2, 3\), this model has \(4, 3\)"):
        load_state(torch.nn.Linear(3, 4), checkpoint.model, tmp_path / "c.pt")
    with pytest.raises(DataFormatError, match="field 'model.0.weight'"):
        load_state(torch.nn.Sequential(torch.nn.Linear(3, 2)), checkpoint.model, tmp_path / "c.pt")


def test_run_folder_refuses_resumes_and_overwrites(tmp_path):
    out = tmp_path / "run"
    config = {"dim": 2, "epochs": 3}
    with RunFolder.open(out, kind="siamese", config=config) as run:
        _, checkpoint = small_checkpoint()
        checkpoint.config = config
        run.save(checkpoint, curves=False)
    # curves.png too: a run that ends cleanly leaves its latest checkpoint's tables complete
    assert sorted(p.name for p in out.iterdir() if not p.name.startswith(".")) == [CHECKPOINT, CONFIG, CURVES, METRICS]
    with pytest.raises(OutputExistsError, match="--resume .* or --overwrite"):
        RunFolder.open(out, kind="siamese", config=config)
    resumed = RunFolder.open(out, kind="siamese", config={"dim": 2, "epochs": 5}, resume=True, may_differ=("epochs",))
    assert resumed.resumed.epoch == 2
    with pytest.raises(SianmsError, match="config differs in dim"):
        RunFolder.open(out, kind="siamese", config={"dim": 3, "epochs": 3}, resume=True)
    with pytest.raises(SianmsError, match="--resume continues the run in the folder and --overwrite starts it afresh"):
        RunFolder.open(out, kind="siamese", config=config, resume=True, overwrite=True)
    replacing = RunFolder.open(out, kind="siamese", config=config, overwrite=True)
    assert (out / CHECKPOINT).exists()  # deleted only once the folder's lock is held
    with replacing:
        assert not (out / CHECKPOINT).exists()
    assert RunFolder.open(out, kind="siamese", config=config, resume=True).resumed is None  # nothing to resume


def test_a_foreign_folder_or_file_is_refused(tmp_path):
    (tmp_path / "theirs").mkdir()
    (tmp_path / "theirs" / "notes.txt").write_text("x")
    with pytest.raises(OutputExistsError, match="holds no sianms run"):
        RunFolder.open(tmp_path / "theirs", kind="siamese", config={}, overwrite=True)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputExistsError, match="not a folder"):
        RunFolder.open(tmp_path / "file", kind="siamese", config={})


def test_overwrite_refuses_a_folder_whose_run_files_are_someone_elses(tmp_path):
    """config.json and checkpoint.pt are common names: only a sianms run's make a folder a run."""
    cases = ((CONFIG, '{"my": "settings"}'), (CONFIG, '{"kind": "siamese"'), (CHECKPOINT, "weights"))
    for i, (name, content) in enumerate(cases):
        theirs = tmp_path / str(i)
        theirs.mkdir()
        (theirs / name).write_text(content)
        (theirs / METRICS).write_text("a,b\n")
        with pytest.raises(OutputExistsError, match="holds no sianms run"):
            RunFolder.open(theirs, kind="siamese", config={}, overwrite=True)
        assert (theirs / name).read_text() == content and (theirs / METRICS).read_text() == "a,b\n"


def test_overwrite_leaves_a_running_run_its_files(tmp_path):
    """A second run told to overwrite a folder another run is writing is refused by the lock
    before it deletes anything."""
    from sianms_cli.io import FolderBusyError

    config = {"dim": 2}
    with RunFolder.open(tmp_path / "run", kind="siamese", config=config) as running:
        _, checkpoint = small_checkpoint()
        running.save(checkpoint, curves=False)
        with pytest.raises(FolderBusyError):
            RunFolder.open(tmp_path / "run", kind="siamese", config=config, overwrite=True).__enter__()
        assert (tmp_path / "run" / CHECKPOINT).is_file() and (tmp_path / "run" / CONFIG).is_file()


def test_a_second_writer_is_refused(tmp_path):
    from sianms_cli.io import FolderBusyError

    with RunFolder.open(tmp_path / "run", kind="siamese", config={}):
        with pytest.raises(FolderBusyError):
            RunFolder.open(tmp_path / "run", kind="siamese", config={}, resume=True).__enter__()


def test_a_run_that_cannot_take_its_lock_leaves_no_folder(tmp_path, monkeypatch):
    """A full disk when the lock file gets its pid: one error naming the lock file, and the run
    folder this run made is gone again."""
    import errno
    import os

    def full(*_):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", full)
    with pytest.raises(OutputError, match=r"cannot write .*run/\.sianms\.lock: No space left on device"):
        RunFolder.open(tmp_path / "run", kind="siamese", config={}).__enter__()
    assert list(tmp_path.iterdir()) == []


def test_a_busy_folder_is_left_as_the_other_run_has_it(tmp_path, monkeypatch):
    """What the run holding the lock wrote after this run looked at the folder is not this run's to remove."""
    from contextlib import contextmanager

    from sianms_cli.io import FolderBusyError
    from sianms_cli.training import run as run_module

    out = tmp_path / "run"

    @contextmanager
    def held_by_another(lock_path, *, what, blocking=False):
        (out / CHECKPOINT).write_text("the other run's")
        raise FolderBusyError(f"{what} is in use by another sianms process (pid 1)")
        yield

    monkeypatch.setattr(run_module, "exclusive_lock", held_by_another)
    with pytest.raises(FolderBusyError):
        RunFolder.open(out, kind="siamese", config={}).__enter__()
    assert (out / CHECKPOINT).read_text() == "the other run's"


def test_a_resume_with_nothing_left_to_train_completes_the_tables_an_interrupt_cut_short(tmp_path):
    out = tmp_path / "run"
    _, checkpoint = small_checkpoint()
    with pytest.raises(KeyboardInterrupt):
        with RunFolder.open(out, kind="siamese", config=checkpoint.config) as run:
            run.save(checkpoint, curves=False)
            (out / METRICS).write_text("epoch\n")  # as if the interrupt came while they were written
            raise KeyboardInterrupt
    assert not (out / CURVES).exists()
    with RunFolder.open(out, kind="siamese", config=checkpoint.config, resume=True):
        pass
    assert (out / CURVES).read_bytes().startswith(b"\x89PNG")
    assert (out / METRICS).read_text() == metrics_csv(checkpoint.history)


def test_a_resume_redraws_curves_an_interrupt_left_behind_the_checkpoint(tmp_path):
    """F-PointNets draws every few epochs: an interrupt while the last epoch's curves are drawn
    leaves an earlier epoch's curves.png, which the resume must not take for the latest."""
    import os

    out = tmp_path / "run"
    _, checkpoint = small_checkpoint()
    with pytest.raises(KeyboardInterrupt):
        with RunFolder.open(out, kind="siamese", config=checkpoint.config) as run:
            run.save(checkpoint)
            run.save(checkpoint, curves=False)
            raise KeyboardInterrupt
    stale = (out / CHECKPOINT).stat().st_mtime_ns - 10**9
    os.utime(out / CURVES, ns=(stale, stale))
    with RunFolder.open(out, kind="siamese", config=checkpoint.config, resume=True):
        pass
    assert (out / CURVES).stat().st_mtime_ns > (out / CHECKPOINT).stat().st_mtime_ns


def test_curves_and_metrics(tmp_path):
    history = [{"epoch": 1, "loss": 1.5, "auc": float("nan")}, {"epoch": 2, "loss": 0.25, "auc": 0.75, "new": 3}]
    assert metrics_csv(history) == "epoch,loss,auc,new\n1,1.5,,\n2,0.25,0.75,3\n"
    run = RunFolder.open(tmp_path / "run", kind="siamese", config={})
    run.panels = [("loss", ["loss"]), ("auc", ["auc", "missing"])]
    with run:
        _, checkpoint = small_checkpoint()
        checkpoint.history = history
        run.save(checkpoint)
    assert (tmp_path / "run" / CURVES).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_schedule_seeds_and_device():
    assert [step_decay(1e-4, 0.1, 8, e) for e in (0, 7, 8, 16)] == pytest.approx([1e-4, 1e-4, 1e-5, 1e-6])
    assert np.array_equal(epoch_generator(3, 4).integers(0, 1000, 5), epoch_generator(3, 4).integers(0, 1000, 5))
    assert not np.array_equal(epoch_generator(3, 4).integers(0, 1000, 5), epoch_generator(3, 5).integers(0, 1000, 5))
    assert choose_device("cpu").type == "cpu"
    assert choose_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(SianmsError, match="--device must be"):
        choose_device("tpu")
    if not torch.cuda.is_available():
        with pytest.raises(SianmsError, match="CUDA is not available"):
            choose_device("cuda")


def test_a_run_killed_as_it_wrote_its_first_file_is_started_again(tmp_path):
    """A kill while config.json was first written leaves the lock and its temporary file: the
    folder is still the run's, not someone else's."""
    out = tmp_path / "run"
    out.mkdir()
    (out / ".sianms.lock").write_text("")
    (out / ".config.json.4242.0123abcd.partial").write_text("")
    with RunFolder.open(out, kind="siamese", config={"dim": 2}):
        pass
    assert (out / CONFIG).is_file()
    (out / ".notes.txt.4242.0123abcd.partial").write_text("")  # a temporary name, but of no run file
    (out / CONFIG).unlink()
    with pytest.raises(OutputExistsError, match="holds no sianms run"):
        RunFolder.open(tmp_path / "run", kind="siamese", config={"dim": 2})


def test_a_run_resumes_only_on_the_caches_it_began_on(tmp_path):
    """Each checkpoint keeps its caches' content fingerprints; a cache prepared anew at the same
    path (another seed) had been trained on from the resumed epoch on, mixing two runs in one."""
    out = tmp_path / "run"
    config = {"dim": 2, "epochs": 3}
    began = {"--cache": "a" * 64, "--val-cache": "b" * 64}
    with RunFolder.open(out, kind="siamese", config=config, inputs=began) as run:
        _, checkpoint = small_checkpoint()
        checkpoint.config = config
        run.save(checkpoint, curves=False)
    assert load_checkpoint(out / CHECKPOINT).extra["inputs"] == began
    assert RunFolder.open(out, kind="siamese", config=config, resume=True, inputs=began).resumed.epoch == 2
    for rank_writes in (True, False):
        with pytest.raises(SianmsError, match=r"cannot resume .*: the content of --cache changed since the run began"):
            RunFolder.open(out, kind="siamese", config=config, resume=True, write=rank_writes,
                           inputs={**began, "--cache": "c" * 64})
    with pytest.raises(SianmsError, match="the content of --val-cache changed"):
        RunFolder.open(out, kind="siamese", config=config, resume=True, inputs={"--cache": "a" * 64})
    assert RunFolder.open(out, kind="siamese", config=config, overwrite=True, inputs={"--cache": "c" * 64})


def test_an_epoch_ending_on_a_non_finite_loss_stops_the_training_in_one_line():
    """--lr 1000 made the siamese validation end in linear_sum_assignment's traceback, and
    F-PointNets write NaN weights that eval then blamed on a results file."""
    check_losses_finite({"epoch": 1, "lr": 1e-3, "train_loss": 0.5, "val_auc": float("nan")})  # validation may be NaN
    for value in (float("nan"), float("inf")):
        with pytest.raises(SianmsError) as stopped:
            check_losses_finite({"epoch": 3, "lr": 1000.0, "train_total": value, "train_mask": 0.1})
        assert str(stopped.value) == (f"training diverged in epoch 3: train_total is {value} at learning rate 1000; "
                                      "start afresh (--overwrite) with a lower --lr")


def test_leaving_the_process_group_frees_the_ddp_wrappers_that_hold_it_first(tmp_path, monkeypatch):
    """A DDP wrapper outlived its training in a reference cycle; destroyed at interpreter shutdown,
    the group's gloo threads aborted a rank now and then (a flaky two-rank sweep test)."""
    import gc
    import weakref

    import torch.distributed as dist

    from sianms_cli.training.run import leave_process_group

    dist.init_process_group("gloo", init_method=f"file://{tmp_path / 'store'}", rank=0, world_size=1)
    destroy = dist.destroy_process_group
    seen = []
    monkeypatch.setattr(dist, "destroy_process_group", lambda: (seen.append(alive() is None), destroy()))
    class Training:  # a wrapper in a reference cycle, as DDP's own often is
        pass

    gc.disable()  # no automatic collection in between: what is left is what shutdown would meet
    try:
        training = Training()
        training.itself, training.wrapper = training, torch.nn.parallel.DistributedDataParallel(torch.nn.Linear(3, 2))
        training.wrapper(torch.ones(4, 3)).sum().backward()
        alive = weakref.ref(training.wrapper)
        del training
        assert alive() is not None, "only the collector frees a cycle"
        leave_process_group()
    finally:
        gc.enable()
    assert seen == [True] and not dist.is_initialized()


def test_overwrite_with_a_folder_in_a_run_files_place_deletes_nothing(tmp_path):
    """A folder named config.json was found only by the deletions: checkpoint.pt had gone before the error."""
    out = tmp_path / "run"
    config = {"dim": 2}
    with RunFolder.open(out, kind="siamese", config=config) as run:
        _, checkpoint = small_checkpoint()
        checkpoint.config = config
        run.save(checkpoint, curves=False)
    (out / METRICS).unlink()
    (out / METRICS).mkdir()
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(OutputExistsError, match=f"^{out / METRICS} is a folder where the run writes a file; remove"):
        with RunFolder.open(out, kind="siamese", config=config, overwrite=True):
            pass
    assert sorted(p.name for p in out.iterdir()) == before and (out / CHECKPOINT).is_file()
