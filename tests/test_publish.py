"""Publishing looks again: an output folder or file is replaced only while it holds what the command saw at
its start. A folder a user made while a report ran, or another run's output, had been deleted without
--overwrite; two runs racing for one --out now end with one published and one refused, nothing lost."""

import pytest

from sianms_cli import io
from sianms_cli.io import DestinationChangedError, publish, snapshot, write_files_together
from sianms_cli.reporting import report


@pytest.fixture(params=["renameat2", "fallback"])
def rename(request, monkeypatch):
    """Each test runs with Linux's one-step renames, and with the check-then-rename kept for other systems."""
    if request.param == "fallback":
        monkeypatch.setattr(io, "_renameat2", lambda source, target, flags: False)
    return request.param


def staged(tmp_path, name="staging", text="new"):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "report.md").write_text(text)
    return folder


def test_an_absent_destination_is_taken(tmp_path, rename):
    out = tmp_path / "out"
    assert publish(staged(tmp_path), out, snapshot(out)) == out
    assert (out / "report.md").read_text() == "new" and not (tmp_path / "staging").exists()


@pytest.mark.parametrize("appeared", ["empty folder", "folder with a file", "file"])
def test_a_destination_that_appeared_meanwhile_is_left_as_it_is(tmp_path, rename, appeared):
    out = tmp_path / "out"
    seen = snapshot(out)
    assert seen is None
    if appeared == "file":
        out.write_text("mine")
    else:
        out.mkdir()
        if appeared == "folder with a file":
            (out / "notes.txt").write_text("mine")
    before = snapshot(out)
    with pytest.raises(DestinationChangedError) as raised:
        publish(staged(tmp_path), out, seen)
    assert str(raised.value).startswith(f"{out} changed while this run worked")
    assert snapshot(out) == before and (tmp_path / "staging" / "report.md").read_text() == "new"


def test_a_destination_written_to_meanwhile_is_left_as_it_is(tmp_path, rename):
    out = staged(tmp_path, "out", "old")
    seen = snapshot(out)
    (out / "notes.txt").write_text("mine")
    before = snapshot(out)
    with pytest.raises(DestinationChangedError):
        publish(staged(tmp_path), out, seen)
    assert snapshot(out) == before and (out / "notes.txt").read_text() == "mine"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["out", "staging"]


def test_an_unchanged_destination_is_replaced_and_its_old_content_deleted(tmp_path, rename):
    out = staged(tmp_path, "out", "old")
    assert publish(staged(tmp_path), out, snapshot(out)) == out
    assert (out / "report.md").read_text() == "new"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["out"]


def test_a_destination_gone_meanwhile_is_taken(tmp_path, rename):
    """Nothing of anyone's is there to lose."""
    out = staged(tmp_path, "out", "old")
    seen = snapshot(out)
    (out / "report.md").unlink()
    out.rmdir()
    assert publish(staged(tmp_path), out, seen) == out and (out / "report.md").read_text() == "new"


def test_two_runs_racing_for_one_out_end_with_one_winner_and_one_refusal(tmp_path, rename):
    out = tmp_path / "out"
    seen_by_first, seen_by_second = snapshot(out), snapshot(out)
    first, second = staged(tmp_path, "first", "first"), staged(tmp_path, "second", "second")
    publish(first, out, seen_by_first)
    with pytest.raises(DestinationChangedError):
        publish(second, out, seen_by_second)
    assert (out / "report.md").read_text() == "first"
    old = staged(tmp_path, "again", "third")  # with --overwrite both saw the first run's output
    seen_by_third, seen_by_fourth = snapshot(out), snapshot(out)
    publish(old, out, seen_by_third)
    with pytest.raises(DestinationChangedError):
        publish(second, out, seen_by_fourth)
    assert (out / "report.md").read_text() == "third"


def test_a_report_does_not_delete_a_folder_made_while_it_ran(eval_folders, tmp_path, monkeypatch):
    evaluation = eval_folders.make_eval(tmp_path / "eval")
    out = tmp_path / "report"
    draw = report.draw_figures

    def user_meanwhile(*arguments, **options):
        out.mkdir()
        (out / "notes.txt").write_text("precious")
        return draw(*arguments, **options)

    monkeypatch.setattr(report, "draw_figures", user_meanwhile)
    with pytest.raises(DestinationChangedError):
        report.run(report.ReportConfig(eval=str(evaluation)), out)
    assert [path.name for path in out.iterdir()] == ["notes.txt"] and (out / "notes.txt").read_text() == "precious"
    assert sorted(path.name for path in tmp_path.iterdir()) == ["eval", "report"]  # no staging folder left


@pytest.mark.parametrize("overwrite", [False, True])
def test_files_written_together_keep_a_file_made_or_replaced_since_they_were_checked(tmp_path, rename, monkeypatch,
                                                                                    overwrite):
    summary, sheet = tmp_path / "summary.json", tmp_path / "sheet.jpg"
    if overwrite:
        summary.write_text("earlier")
    commit = io.AtomicFile.commit

    def someone_meanwhile(self, **options):
        if self.path == sheet:
            summary.unlink(missing_ok=True)
            summary.write_text("someone's")
        return commit(self, **options)

    monkeypatch.setattr(io.AtomicFile, "commit", someone_meanwhile)
    with pytest.raises(DestinationChangedError):
        write_files_together({sheet: b"jpeg", summary: "{}"}, overwrite=overwrite)
    assert summary.read_text() == "someone's" and not sheet.exists()
    assert sorted(path.name for path in tmp_path.iterdir()) == ["summary.json"]


def test_an_interrupt_between_the_exchange_and_its_check_puts_the_destination_back(tmp_path, monkeypatch):
    """The caller deletes its staging folder on an interrupt: it must hold this run's output then, not the
    destination's earlier content (unchecked, perhaps someone's)."""
    out = staged(tmp_path, "out", "old")
    seen = snapshot(out)

    def interrupted(path):
        raise KeyboardInterrupt

    monkeypatch.setattr(io, "snapshot", interrupted)
    with pytest.raises(KeyboardInterrupt):
        publish(staged(tmp_path), out, seen)
    assert (out / "report.md").read_text() == "old" and (tmp_path / "staging" / "report.md").read_text() == "new"


@pytest.mark.parametrize("kind", ["file", "link", "link loop"])
def test_a_folder_never_replaces_a_file_or_a_link(tmp_path, rename, kind):
    out = tmp_path / "out"
    if kind == "file":
        out.write_text("mine")
    elif kind == "link":
        (tmp_path / "elsewhere").mkdir()
        out.symlink_to(tmp_path / "elsewhere")
    else:
        out.symlink_to(tmp_path / "loop")
        (tmp_path / "loop").symlink_to(out)
    before = snapshot(out)
    with pytest.raises(io.OutputExistsError, match="exists and is not a folder"):
        publish(staged(tmp_path), out, before)
    assert snapshot(out) == before
