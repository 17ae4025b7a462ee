"""The bottom floor: atomic writes, umask permissions, OS errors, JSON reading, locks."""

import errno
import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from sianms_cli import io
from sianms_cli.errors import DataFormatError, OutputExistsError


def mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


def test_write_bytes_replaces_and_leaves_no_temporary(tmp_path):
    path = tmp_path / "deep" / "file.bin"
    io.write_bytes(path, b"one")
    io.write_bytes(path, b"two")
    assert path.read_bytes() == b"two"
    assert [p.name for p in path.parent.iterdir()] == ["file.bin"]


@pytest.mark.parametrize("mask, file_mode, folder_mode", [(0o022, 0o644, 0o755), (0o077, 0o600, 0o700),
                                                          (0o002, 0o664, 0o775)])
def test_files_and_folders_get_the_umask_permissions(tmp_path, umask, mask, file_mode, folder_mode):
    umask(mask)
    io.write_json(tmp_path / "a" / "x.json", {"b": 1})
    with io.atomic_file(tmp_path / "a" / "y.txt", text=True) as stream:
        stream.write("text")
    staging = io.staging_folder(tmp_path / "out")
    assert mode(tmp_path / "a" / "x.json") == file_mode
    assert mode(tmp_path / "a" / "y.txt") == file_mode
    assert mode(tmp_path / "a") == folder_mode
    assert mode(staging) == folder_mode


def test_write_json_is_sorted_and_indented(tmp_path):
    io.write_json(tmp_path / "x.json", {"b": 1, "a": [1, 2]})
    assert (tmp_path / "x.json").read_text() == '{\n  "a": [\n    1,\n    2\n  ],\n  "b": 1\n}\n'


def test_an_error_inside_the_block_leaves_the_destination_untouched(tmp_path):
    path = tmp_path / "x.txt"
    path.write_text("old")
    with pytest.raises(RuntimeError):
        with io.atomic_file(path, text=True) as stream:
            stream.write("new")
            raise RuntimeError("boom")
    assert path.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]


def test_disk_full_is_one_output_error_naming_the_path(full_disk):
    with pytest.raises(io.OutputError, match=rf"cannot write {full_disk}/x\.bin: No space left on device"):
        io.write_bytes(full_disk / "x.bin", bytes(1 << 20))
    assert list(full_disk.iterdir()) == []


def test_read_only_folder_is_one_output_error_naming_the_path(tmp_path, monkeypatch):
    def refuse(*args, **kwargs):  # what open() says in a read-only folder (root ignores chmod)
        raise OSError(errno.EROFS, "Read-only file system", str(args[0]))

    monkeypatch.setattr(io.os, "open", refuse)
    with pytest.raises(io.OutputError, match=r"cannot write \S*/x\.bin: Read-only file system"):
        io.write_bytes(tmp_path / "x.bin", b"data")


def test_a_folder_where_a_file_should_be(tmp_path):
    (tmp_path / "x.json").mkdir()
    with pytest.raises(io.OutputError, match="x.json: it is a folder"):
        io.write_json(tmp_path / "x.json", {})
    with pytest.raises(io.OutputError, match="it is a folder"):
        io.check_writable_output(tmp_path / "x.json", overwrite=True)


@pytest.mark.parametrize("under", ["x.json", "deeper/x.json"])
def test_a_file_where_a_folder_should_be(tmp_path, under):
    # mkdir says "File exists" for the file itself and "Not a directory" below it; both name
    # the file in the way.
    (tmp_path / "t.sh").write_text("")
    with pytest.raises(io.OutputError) as caught:
        io.write_json(tmp_path / "t.sh" / under, {})
    assert str(caught.value) == f"cannot write {tmp_path}/t.sh: not a folder"
    with pytest.raises(io.OutputError) as caught:
        io.staging_folder(tmp_path / "t.sh" / under)
    assert str(caught.value) == f"cannot write {tmp_path}/t.sh: not a folder"


def test_describe_os_error_names_the_file_in_the_way(tmp_path, monkeypatch):
    (tmp_path / "t.sh").write_text("")
    monkeypatch.chdir(tmp_path)
    with pytest.raises(NotADirectoryError) as caught:
        open("t.sh/a/b.json", "w")
    assert io.describe_os_error(caught.value) == "t.sh: not a folder"
    assert io.describe_os_error(caught.value, "t.sh/a") == "t.sh: not a folder"


def test_check_writable_output_refuses_existing_file_without_overwrite(tmp_path):
    path = tmp_path / "x.json"
    path.write_text("{}")
    with pytest.raises(OutputExistsError, match="--overwrite"):
        io.check_writable_output(path, overwrite=False)
    assert io.check_writable_output(path, overwrite=True) == path
    dangling = tmp_path / "link.json"
    dangling.symlink_to(tmp_path / "nowhere.json")
    with pytest.raises(OutputExistsError, match="link.json exists; pass --overwrite"):
        io.check_writable_output(dangling, overwrite=False)


def test_a_device_or_pipe_is_never_replaced(tmp_path):
    """An atomic write renames a file over its destination: over /dev/null that would make it a file."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(io.OutputError, match="cannot write .*pipe: not a regular file"):
        io.check_writable_output(fifo, overwrite=True)
    with pytest.raises(io.OutputError, match="cannot write .*pipe: not a regular file"):
        io.write_bytes(fifo, b"x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and [p.name for p in tmp_path.iterdir()] == ["pipe"]


def test_read_json_names_file_line_and_column(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{\n  "a": 1,\n  "b": }\n')
    with pytest.raises(DataFormatError, match=r"bad\.json: invalid JSON at line 3, column 8"):
        io.read_json(path)
    with pytest.raises(DataFormatError, match="missing.json: file not found"):
        io.read_json(tmp_path / "missing.json")
    (tmp_path / "latin.json").write_bytes(b'"\xe9"')
    with pytest.raises(DataFormatError, match="not valid UTF-8 at byte 1"):
        io.read_json(tmp_path / "latin.json")
    (tmp_path / "deep.json").write_text("[" * 5000 + "]" * 5000)  # the json module would overflow the stack
    with pytest.raises(DataFormatError, match=r"deep\.json: invalid JSON: nested deeper than 1024 levels"):
        io.read_json(tmp_path / "deep.json")
    (tmp_path / "deep_enough.json").write_text("[" * 1024 + "]" * 1024)
    value, depth = io.read_json(tmp_path / "deep_enough.json"), 1
    while value:
        value, depth = value[0], depth + 1
    assert depth == 1024


def test_publish_folder_replaces_and_leaves_nothing_aside(tmp_path):
    destination = tmp_path / "data"
    destination.mkdir()
    (destination / "old.txt").write_text("old")
    staging = io.staging_folder(destination)
    (staging / "new.txt").write_text("new")
    io.publish_folder(staging, destination)
    assert [p.name for p in destination.iterdir()] == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["data"]


def test_an_interrupt_while_the_old_folder_is_deleted_still_deletes_it(tmp_path, monkeypatch):
    destination = tmp_path / "data"
    destination.mkdir()
    (destination / "old.txt").write_text("old")
    staging = io.staging_folder(destination)
    (staging / "new.txt").write_text("new")
    remove = io.shutil.rmtree
    calls = []

    def interrupted_once(path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 1:
            raise KeyboardInterrupt
        remove(path, *args, **kwargs)

    monkeypatch.setattr(io.shutil, "rmtree", interrupted_once)
    with pytest.raises(KeyboardInterrupt):
        io.publish_folder(staging, destination)
    assert [p.name for p in tmp_path.iterdir()] == ["data"] and (destination / "new.txt").is_file()


def test_an_interrupt_between_the_renames_puts_the_old_folder_back(tmp_path, monkeypatch):
    """Where the OS has no one-step exchange (renameat2), publishing renames twice."""
    monkeypatch.setattr(io, "_renameat2", lambda source, target, flags: False)
    destination = tmp_path / "data"
    destination.mkdir()
    (destination / "old.txt").write_text("old")
    staging = io.staging_folder(destination)
    replace = io.os.replace

    def interrupted_second(source, target):
        if Path(source) == staging:
            raise KeyboardInterrupt
        replace(source, target)

    monkeypatch.setattr(io.os, "replace", interrupted_second)
    with pytest.raises(KeyboardInterrupt):
        io.publish_folder(staging, destination)
    assert (destination / "old.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["data", staging.name])


@pytest.mark.parametrize("failure", [ValueError("bad record"), KeyboardInterrupt()])
def test_build_folder_publishes_a_complete_folder_or_leaves_the_old_one(tmp_path, failure):
    destination = tmp_path / "report"
    destination.mkdir()
    (destination / "old.txt").write_text("old")

    def fail(staging):
        (staging / "half.txt").write_text("half")
        raise failure

    with pytest.raises(type(failure)):
        io.build_folder(destination, fail)
    assert [p.name for p in tmp_path.iterdir()] == ["report"] and (destination / "old.txt").read_text() == "old"

    def write(staging):
        (staging / "new.txt").write_text("new")
        return 7

    assert io.build_folder(destination, write) == (destination, 7)
    assert [p.name for p in destination.iterdir()] == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["report"]


def test_a_staging_folder_a_killed_run_left_is_deleted_by_the_next_build(tmp_path):
    destination = tmp_path / "data"
    script = (f"import os, signal\nfrom sianms_cli import io\n"
              f"def build(staging):\n    (staging / 'half.bin').write_bytes(bytes(4096))\n"
              f"    os.kill(os.getpid(), signal.SIGKILL)\n"
              f"io.build_folder({str(destination)!r}, build)\n")
    killed = subprocess.run([sys.executable, "-c", script], check=False)
    assert killed.returncode == -signal.SIGKILL
    left = sorted(p.name for p in tmp_path.iterdir())
    assert len(left) == 2 and left[0].endswith(".partial") and left[1] == left[0] + io.CLAIM_SUFFIX

    assert io.build_folder(destination, lambda staging: (staging / "x").write_text("x"))[0] == destination
    assert [p.name for p in tmp_path.iterdir()] == ["data"]


def test_a_staging_folder_whose_claim_is_held_or_absent_is_left_alone(tmp_path):
    destination = tmp_path / "data"
    working, unclaimed, other = (io.partial_name(destination), io.partial_name(destination),
                                 io.partial_name(tmp_path / "data2"))
    for folder in (working, unclaimed, other):
        folder.mkdir()
    io.claim_of(other).touch()
    held = io.try_lock(io.claim_of(working))  # another run at work, on this host or another
    try:
        assert io.remove_abandoned_staging(destination) == []
        io.build_folder(destination, lambda staging: None)
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            ["data", working.name, io.claim_of(working).name, unclaimed.name, other.name, io.claim_of(other).name])
    finally:
        io.release_lock(held)
    assert io.remove_abandoned_staging(destination) == [working]
    assert not io.claim_of(working).exists() and unclaimed.is_dir() and other.is_dir()


def test_a_claim_deleted_before_it_was_locked_is_replaced(tmp_path, monkeypatch):
    destination, lock = tmp_path / "data", io.fcntl.flock
    calls = []

    def another_run_cleans_first(descriptor, operation):
        calls.append(operation)
        if len(calls) == 1:  # the race: another run found this claim unlocked, with no folder yet, and deleted it
            io.remove_abandoned_staging(destination)
        lock(descriptor, operation)

    monkeypatch.setattr(io.fcntl, "flock", another_run_cleans_first)
    io.build_folder(destination, lambda staging: (staging / "x").write_text("x"))
    assert [p.name for p in tmp_path.iterdir()] == ["data"] and (destination / "x").read_text() == "x"
    assert calls[0] == calls[-1] == io.fcntl.LOCK_EX and len(calls) == 3  # the first claim lost, a second made


def test_a_staging_folder_that_cannot_be_made_is_named_by_its_destination(read_only_folder):
    with pytest.raises(io.OutputError) as caught:
        io.staging_folder(read_only_folder / "out")
    assert str(caught.value) == f"cannot write {read_only_folder}/out: Read-only file system"


def test_working_folder_and_its_parents_are_recognised(tmp_path, monkeypatch):
    (tmp_path / "a" / "b").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "a" / "b")
    assert io.is_inside_working_folder(".")
    assert io.is_inside_working_folder("..")
    assert not io.is_inside_working_folder("c")


def test_exclusive_lock_refuses_a_second_holder_and_names_the_first(tmp_path):
    lock = tmp_path / ".lock"
    with io.exclusive_lock(lock, what="the cache"):
        held = io.try_lock(lock)
        assert held is None
        with pytest.raises(io.FolderBusyError,
                           match=rf"the cache is in use by another sianms process \(pid {os.getpid()}\)"):
            with io.exclusive_lock(lock, what="the cache"):
                pass
    descriptor = io.try_lock(lock)
    assert descriptor is not None
    io.release_lock(descriptor)


def test_a_lock_that_cannot_be_taken_leaves_only_what_was_there(tmp_path, monkeypatch):
    """A full disk when the lock file gets its pid: the error names the lock file; the lock file
    and the folder this call made are gone, a folder and a lock file that were there stay."""
    def full(*_):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", full)
    fresh = tmp_path / "new" / ".lock"
    with pytest.raises(io.OutputError, match=r"cannot write .*new/\.lock: No space left on device"):
        with io.exclusive_lock(fresh, what="new"):
            pass
    assert list(tmp_path.iterdir()) == []
    kept = tmp_path / "old" / ".lock"
    kept.parent.mkdir()
    kept.write_text("")
    with pytest.raises(io.OutputError):
        with io.exclusive_lock(kept, what="old"):
            pass
    assert [entry.name for entry in kept.parent.iterdir()] == [".lock"]
    (tmp_path / "other").mkdir()
    with pytest.raises(io.OutputError):
        with io.exclusive_lock(tmp_path / "other" / ".lock", what="other"):
            pass
    assert (tmp_path / "other").is_dir() and list((tmp_path / "other").iterdir()) == []


def test_sha256_of(tmp_path):
    (tmp_path / "x").write_bytes(b"abc")
    assert io.sha256_of(tmp_path / "x") == "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"


def test_nesting_is_measured_outside_strings_on_any_python():
    # The json module's own limit moved with Python (about 1,000 levels on 3.11, 5,000 parsed on
    # 3.12.3, 50,000 on 3.13): the limit is counted here, brackets inside strings not counted.
    assert not io.nested_too_deep('{"a": "' + "[" * 2000 + '"}')
    assert not io.nested_too_deep('["\\"' + "[" * 2000 + '"]')  # an escaped quote does not end the string
    assert not io.nested_too_deep("[" * 1024 + "]" * 1024)
    assert io.nested_too_deep("[" * 1025 + "]" * 1025)
    assert not io.nested_too_deep("[[]]" * 2000)  # many brackets, shallow


@pytest.mark.parametrize("text", [False, True])
def test_an_interrupt_as_the_temporary_file_is_created_leaves_no_file(tmp_path, monkeypatch, text):
    """Ctrl-C landing once the temporary file exists but before anyone holds it: the file goes
    with it (a 0-byte leftover had made the next run refuse the folder as someone else's)."""
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(io, "open", interrupted, raising=False)
    with pytest.raises(KeyboardInterrupt):
        io.AtomicFile(tmp_path / "manifest.json", text=text)
    assert list(tmp_path.iterdir()) == [] and not [path for path in io._OPEN_TEMPORARIES if path.parent == tmp_path]


def test_texts_written_together_put_back_the_files_they_replaced_when_a_rename_fails(tmp_path, monkeypatch):
    """`metrics --out r.json --details d.json --overwrite` whose second rename failed had left
    neither the old r.json nor the new one."""
    report, details = tmp_path / "r.json", tmp_path / "d.json"
    report.write_text("old report")
    details.write_text("old details")
    real_move = io._move_unless_there
    failures = []

    def second_rename_fails(source, destination):
        if Path(destination) == details and Path(source).name.startswith(".d.json.") and not failures:
            failures.append(source)
            raise OSError(errno.EIO, os.strerror(errno.EIO))
        return real_move(source, destination)

    monkeypatch.setattr(io, "_move_unless_there", second_rename_fails)
    with pytest.raises(io.OutputError, match="d.json"):
        io.write_files_together({report: "new report", details: "new details"}, overwrite=True)
    assert failures and (report.read_text(), details.read_text()) == ("old report", "old details")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["d.json", "r.json"]
    io.write_files_together({report: "new report", details: "new details"}, overwrite=True)
    assert (report.read_text(), details.read_text()) == ("new report", "new details")
    assert sorted(path.name for path in tmp_path.iterdir()) == ["d.json", "r.json"]
