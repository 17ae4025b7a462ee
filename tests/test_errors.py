"""User errors survive the trip from a worker process to the parent whole."""

import os
import pickle
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from sianms_cli.cli._app import command
from sianms_cli.errors import DataFormatError, SianmsError
from sianms_cli.metrics.results import ResultsFormatError
from sianms_cli.processes import Terminated, worker_pool


@pytest.mark.parametrize("error", [
    SianmsError("--seed must be between 0 and 2**63 - 1, got -1"),
    DataFormatError("cache/frustums/scene-0001.parquet", "not a readable Parquet file", field="x"),
    ResultsFormatError("results.json", "must be a number in [0, 1], got 1.5", token="abc", field="detection_score",
                       box_index=3),
])
def test_a_pickled_error_keeps_its_message_and_fields(error):
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is type(error) and str(copy) == str(error) and copy.__dict__ == error.__dict__


def _fail(path: str) -> None:
    raise DataFormatError(path, "not a readable Parquet file", field="footer")


def test_an_error_raised_in_a_worker_reaches_the_parent_as_itself():
    with pytest.raises(DataFormatError, match="^shard.parquet: field 'footer': not a readable Parquet file$"):
        with worker_pool(1) as pool:
            list(pool.imap(_fail, ["shard.parquet"]))


def probe_app(failure: BaseException):
    """A one-command application whose command raises ``failure``, wrapped as every sianms command is."""
    import typer

    probe = typer.Typer()

    @command("fail", probe)
    def fail() -> None:
        raise failure

    @command("other", probe)  # a second command keeps typer from collapsing the group into its command
    def other() -> None:
        pass

    return probe


@pytest.mark.parametrize("rank", [None, "0", "1"])
def test_under_torchrun_only_rank_0_says_it_was_interrupted(monkeypatch, rank):
    from typer.testing import CliRunner

    if rank is None:
        monkeypatch.delenv("RANK", raising=False)
    else:
        monkeypatch.setenv("RANK", rank)
    result = CliRunner().invoke(probe_app(Terminated()), ["fail"])
    assert result.exit_code == 143
    said = "interrupted (SIGTERM); finished outputs are kept, a rerun resumes or starts afresh\n"
    assert result.output == ("" if rank == "1" else said)


def test_a_hang_up_ends_a_command_as_sigterm_does_with_129(monkeypatch):
    """A closed terminal or a dropped ssh session (SIGHUP) had ended a run with 129 and no word."""
    from typer.testing import CliRunner

    monkeypatch.delenv("RANK", raising=False)
    result = CliRunner().invoke(probe_app(Terminated(signal.SIGHUP)), ["fail"])
    assert (result.exit_code, result.output) == (129, "interrupted (SIGHUP); finished outputs are kept, a rerun "
                                                      "resumes or starts afresh\n")


@pytest.mark.parametrize("rank, prefix", [(None, "error: "), ("0", "error: "), ("3", "error: rank 3: ")])
def test_under_torchrun_another_ranks_error_names_its_rank(monkeypatch, rank, prefix):
    from typer.testing import CliRunner

    if rank is None:
        monkeypatch.delenv("RANK", raising=False)
    else:
        monkeypatch.setenv("RANK", rank)
    result = CliRunner().invoke(probe_app(SianmsError("--epochs: must be >= 1")), ["fail"])
    assert result.exit_code == 2 and result.output == f"{prefix}--epochs: must be >= 1\n"


def test_an_interrupt_a_library_swallowed_still_ends_the_run_as_interrupted(monkeypatch, capsys):
    """A KeyboardInterrupt raised in a C callback (numba's compiler) or caught by a library is lost;
    the signal is not: the command line ends with 130 and the interrupted line all the same."""
    from sianms_cli import processes
    from sianms_cli.cli import _app

    monkeypatch.setattr(processes, "_SIGNALS_RECEIVED", [])
    monkeypatch.setattr(_app, "_ending_said", [])
    monkeypatch.delenv("RANK", raising=False)
    handlers = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        processes.interrupt_on_signals()
        assert _app.exit_code_after_signals(0) == 0
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1)
        except KeyboardInterrupt:
            pass  # swallowed
        assert _app.exit_code_after_signals(0) == 130
    finally:
        signal.signal(signal.SIGINT, handlers[0])
        signal.signal(signal.SIGTERM, handlers[1])
    assert capsys.readouterr().err == f"interrupted (SIGINT); {_app.INTERRUPTED}\n"


def test_a_signal_after_the_error_line_keeps_the_one_line_and_its_code(monkeypatch, capsys):
    """torchrun signals a rank whose peer died just after that rank said so: no second line."""
    from sianms_cli import processes
    from sianms_cli.cli import _app

    monkeypatch.setattr(processes, "_SIGNALS_RECEIVED", [signal.SIGTERM])
    monkeypatch.setattr(_app, "_ending_said", [])
    monkeypatch.delenv("RANK", raising=False)
    _app.say_error("error: another process of this torchrun run stopped")
    assert _app.exit_code_after_signals(1) == 1
    assert capsys.readouterr().err == "error: another process of this torchrun run stopped\n"


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)])
def test_a_signal_while_the_command_line_starts_is_one_line(signum, code):
    """The executable handles the three signals from its first statement: no traceback out of an import."""
    probe = ("import os, time; from sianms_cli import entry; "
             "[entry.signal.signal(s, entry._end_while_starting) for s in (entry.signal.SIGINT, entry.signal.SIGTERM, "
             f"entry.signal.SIGHUP)]; os.kill(os.getpid(), {int(signum)}); time.sleep(10)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    name = signal.Signals(signum).name
    assert (done.returncode, done.stderr) == (code, f"interrupted ({name}) while starting; nothing was written\n")
    assert 'sianms = "sianms_cli.entry:main"' in (Path(__file__).parents[1] / "pyproject.toml").read_text()


@pytest.mark.parametrize("world, error, lost", [
    ("2", RuntimeError("[gloo/transport/tcp/pair.cc:537] Read error [127.0.0.1]:1: Connection reset by peer."), True),
    ("2", type("DistBackendError", (RuntimeError,), {})("NCCL communicator was aborted"), True),
    ("2", RuntimeError("mat1 and mat2 shapes cannot be multiplied"), False),
    ("1", RuntimeError("Connection reset by peer"), False),
])
def test_a_collective_that_lost_another_rank_is_one_error_line_with_exit_code_1(monkeypatch, world, error, lost):
    from typer.testing import CliRunner

    monkeypatch.setenv("WORLD_SIZE", world)
    monkeypatch.setenv("RANK", "0")
    result = CliRunner().invoke(probe_app(error), ["fail"])
    if lost:
        assert (result.exit_code, result.output) == (1, "error: another process of this torchrun run stopped; its "
                                                         "own lines or torchrun's failure summary say why\n")
    else:
        assert result.exception is error


def test_a_signal_after_the_command_ended_exits_at_once_with_its_code():
    """torchrun stops every rank once one failed: a SIGTERM that lands in a library's finaliser,
    after the command said how it ended, must not raise there and print a traceback."""
    script = ("import os, signal, time\n"
              "from sianms_cli.processes import exit_on_signals\n"
              "exit_on_signals(3)\n"
              "os.kill(os.getpid(), signal.SIGTERM)\n"
              "time.sleep(30)\n")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stderr) == (3, "")


def test_an_interrupt_that_lands_in_a_finaliser_is_delivered_again_without_a_traceback():
    """The garbage collector may run a weakref callback or a ``__del__`` when the signal comes
    (seen in ``sianms report``): Python cannot raise there, and printed the callback's traceback
    while the run went on; now the interrupt unwinds the run, silently, and any other exception
    a finaliser loses is still printed."""
    probe = textwrap.dedent("""
        import os, signal, time
        from sianms_cli import processes
        processes.interrupt_on_signals()
        class Interrupting:
            def __del__(self):
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(1)
        try:
            thing = Interrupting()
            del thing
            time.sleep(10)
            print("not interrupted")
        except KeyboardInterrupt:
            print("interrupted", processes.signal_received())
    """)
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stdout, done.stderr) == (0, "interrupted 2\n", "")
    other = ("from sianms_cli import processes; processes.interrupt_on_signals()\n"
             "class Failing:\n    def __del__(self):\n        raise ValueError('lost in a finaliser')\n"
             "thing = Failing(); del thing")
    done = subprocess.run([sys.executable, "-c", other], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "ValueError: lost in a finaliser" in done.stderr


@pytest.mark.parametrize("failure", [TypeError("affine_transform(): incompatible function arguments"),
                                     RuntimeError("a library's own words")])
def test_an_error_a_library_made_of_an_interrupt_ends_as_interrupted(monkeypatch, failure):
    """pybind11 turned the KeyboardInterrupt of a Ctrl-C into a TypeError inside matplotlib (seen
    killing sianms report): with a signal received, any error ends as the interrupt, in one line;
    without one it stays a bug's traceback."""
    from typer.testing import CliRunner

    from sianms_cli import processes
    from sianms_cli.cli import _app

    monkeypatch.delenv("RANK", raising=False)
    monkeypatch.setattr(_app, "_ending_said", [])
    result = CliRunner().invoke(probe_app(failure), ["fail"])
    assert result.exception is failure
    monkeypatch.setattr(processes, "_SIGNALS_RECEIVED", [signal.SIGINT])
    result = CliRunner().invoke(probe_app(failure), ["fail"])
    assert (result.exit_code, result.output) == (130, f"interrupted (SIGINT); {_app.INTERRUPTED}\n")


@pytest.mark.parametrize("name, shown", [("odd\nname", "odd\\nname"), ("tab\there", "tab\\there")])
def test_a_file_name_with_a_control_character_keeps_the_error_one_line(tmp_path, name, shown):
    """A newline in a path had split the error over two lines."""
    (tmp_path / name).write_text("a file where the output folder should be")
    result = subprocess.run([sys.executable, "-m", "sianms_cli", "report", str(tmp_path / name)],
                            capture_output=True, text=True)
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert result.stderr.startswith("error: ") and shown in result.stderr


@pytest.mark.parametrize("command", [["synth", "--scenes", "1", "--sensors", "none", "--out"],
                                     ["info", "--dataroot", "{data}", "--out"]])
def test_a_symbolic_link_loop_is_one_error_line(tmp_path, tiny_dataroot, command):
    """Path.resolve raises RuntimeError on a loop (Python 3.11): a traceback, exit 1."""
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    arguments = [part.format(data=tiny_dataroot) for part in command] + [str(tmp_path / "a")]
    result = subprocess.run([sys.executable, "-m", "sianms_cli", *arguments], capture_output=True, text=True)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert result.stderr.startswith("error: ") and str(tmp_path / "a") in result.stderr


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_in_the_interpreter_teardown_keeps_the_code_the_command_chose(signum):
    """Python puts back a handled signal's default action as it finalises: one landing in the
    teardown (a second or more once torch is loaded) had killed a finished command, 130 or 143
    without a word."""
    script = textwrap.dedent(f"""
        import os, sys, time
        from sianms_cli.processes import exit_on_signals, interrupt_on_signals

        class Late:  # a module global: collected in the teardown, after every exit handler
            def __del__(self):
                os.kill(os.getpid(), {int(signum)})
                time.sleep(0.3)

        interrupt_on_signals()
        late = Late()
        exit_on_signals(0)
        sys.exit(0)
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert (done.returncode, done.stderr) == (0, "")
