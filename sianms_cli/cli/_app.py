"""The Typer application every subcommand module registers on."""

from __future__ import annotations

import functools
import os
import re
import select
import signal
from pathlib import Path
from typing import Callable, NoReturn

import typer

from sianms_cli import __version__
from sianms_cli.errors import SianmsError, bounded_line, check_per_cpu_count, shorten
from sianms_cli.io import describe_os_error, expand_home
from sianms_cli.processes import Terminated, signal_name, signal_received

INTERRUPTED = "finished outputs are kept, a rerun resumes or starts afresh"
_ending_said: list[str] = []  # the one line a run ends with, once said: "interrupted" or "error"

def _typer(name: str, help: str) -> typer.Typer:
    """A command (group) with the project's settings: -h, plain click help, no tracebacks."""
    return typer.Typer(
        name=name,
        help=help,
        no_args_is_help=True,
        add_completion=False,
        context_settings={"help_option_names": ["-h", "--help"]},
        pretty_exceptions_enable=False,
        rich_markup_mode=None,
    )


app = _typer("sianms", "Multi-camera 3D object detection research on nuScenes-format data.")


def command_group(name: str, help: str) -> typer.Typer:
    """A group of subcommands, ``sianms NAME ...``; register its commands with ``command(name, group)``."""
    group = _typer(name, help)
    app.add_typer(group, name=name)
    return group


def _print_version(value: bool) -> None:
    """The version, then the numeric platform that decides an output's last bits (for a bug report)."""
    if value:
        from importlib import metadata

        from sianms_cli.provenance import numeric_platform

        record = numeric_platform()
        try:
            torch = metadata.version("torch")
        except metadata.PackageNotFoundError:
            torch = "not installed"
        typer.echo(f"sianms {__version__}\n"
                   f"{record['cpu_vendor']} {record['vector_width']} CPU, {record['kernels']} kernels; "
                   f"Python {record['python']}, numpy {record['numpy']}, numba {record['numba']}, torch {torch}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Multi-camera 3D object detection research on nuScenes-format data."""


class ProgressBar:
    """A tqdm bar behind the library's :class:`~sianms_cli.progress.Progress`; nothing when quiet.

    Use as a context manager so the bar is closed however the command ends.
    """

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.bar = None

    def start(self, total: float, unit: str, description: str) -> None:
        if self.quiet:
            return
        from tqdm import tqdm

        if self.bar is not None:
            self.bar.close()
        scale = unit == "B"
        # disable=None: no bar when stderr is not a terminal; in a log its carriage returns would
        # put the bar in front of the error line
        self.bar = tqdm(total=total, unit=unit, unit_scale=scale, desc=description, leave=False, disable=None)

    def advance(self, amount: float = 1) -> None:
        if self.bar is not None:
            self.bar.update(amount)

    def __enter__(self) -> ProgressBar:
        return self

    def __exit__(self, *exc) -> None:
        if self.bar is not None:
            self.bar.close()


def follower_rank() -> int | None:
    """This process's rank when it is a non-zero rank under torchrun (which sets RANK), else None."""
    rank = os.environ.get("RANK", "0")
    return None if rank == "0" else int(rank) if rank.isdigit() else None


def use_torch_threads(threads: int | None) -> None:
    """Apply --threads after checking it (torch is imported here, never when the CLI starts)."""
    if threads is not None:
        check_per_cpu_count("--threads", threads)
        import torch

        torch.set_num_threads(threads)


def say_interrupted(signum: int) -> None:
    """The one line an interrupted run ends with (rank 0's alone under torchrun), naming the signal."""
    if follower_rank() is None:
        typer.echo(f"interrupted ({signal_name(signum)}); {INTERRUPTED}", err=True)
    _ending_said.append("interrupted")


def say_error(line: str) -> None:
    """A failed command's one ``error:`` line, on stderr: a character that does not print (a newline
    in a file name, an undecodable byte) is written as its escape, so the line stays one line, and a
    line longer than :data:`~sianms_cli.errors.LINE_LIMIT` loses its middle
    (:func:`~sianms_cli.errors.bounded_line`)."""
    typer.echo(bounded_line("".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii")
                                    for ch in line)), err=True)
    _ending_said.append("error")


def exit_code_after_signals(code: int) -> int:
    """``code``, or 130 / 143 / 129 when SIGINT / SIGTERM / SIGHUP came, with the interrupted line if the command
    did not say it: the signal came while typer parsed the command line, or a library swallowed
    the KeyboardInterrupt and the run went on. A command that already failed with its error line
    keeps its code and its one line: torchrun signals a rank whose peer died just after that rank
    said so."""
    signum = signal_received()
    if signum is None or "error" in _ending_said:
        return code
    if not _ending_said:
        say_interrupted(signum)
    return 128 + signum


def is_out_of_memory(error: BaseException) -> bool:
    """Python's MemoryError, torch's CPU allocator refusing (a RuntimeError it names by its
    message only) or torch.OutOfMemoryError (CUDA), told apart without importing torch."""
    return (isinstance(error, MemoryError) or type(error).__name__ == "OutOfMemoryError"
            or "can't allocate memory" in str(error))


def describe_out_of_memory(error: BaseException) -> str:
    """``out of memory (<what was asked>)``: the allocation, not the allocator's source line."""
    asked = re.search(r"(?:you tried to allocate|Tried to allocate) [^.(]+", str(error))
    return f"out of memory ({asked.group(0).strip()})" if asked else "out of memory"


def home_expanded(value: object) -> object:
    """A path (or list of paths) with a leading ``~`` made the home folder's (:func:`~sianms_cli.io.expand_home`)."""
    if isinstance(value, list) and all(isinstance(item, Path) for item in value):
        return [home_expanded(item) for item in value]
    return expand_home(value) if isinstance(value, Path) else value


def refuse_undecodable(function: Callable, arguments: dict[str, object]) -> None:
    """Refuse, naming its flag, a value of the command line that is not valid UTF-8 (``--out $'x\\xff'``):
    Python holds its bytes as lone surrogates, which any output that records the path (a manifest, a
    config, a Parquet file's metadata) cannot hold, so a run would write a cache that no command can
    then read. Checked before the command runs: nothing is written."""
    for name, value in arguments.items():
        for item in value if isinstance(value, (list, tuple)) else (value,):
            if not isinstance(item, (str, Path)):
                continue
            text = str(item)
            try:
                text.encode("utf-8")
            except UnicodeEncodeError as error:
                raw = os.fsencode(text)
                shown = raw.decode("utf-8", "backslashreplace")
                position = len(text[:error.start].encode("utf-8", "surrogateescape"))
                raise SianmsError(f"{flag_name(function, name)}: {shorten(shown)} is not valid UTF-8 (byte "
                                  f"0x{raw[position]:02x} at {position}); sianms records its paths as text: rename "
                                  "it or choose another path") from None


def flag_name(function: Callable, name: str) -> str:
    """How the command line spells the parameter ``name`` of a command ``function``: its option's long
    flag (``--json`` for ``as_json``), or its argument's metavar (``EVAL``)."""
    import inspect

    declared = inspect.signature(function).parameters.get(name)
    default = declared.default if declared is not None else None
    if isinstance(default, typer.models.ArgumentInfo):
        return default.metavar or name.upper()
    flags = [flag for flag in getattr(default, "param_decls", None) or () if flag.startswith("--")]
    return max(flags, key=len).split("/")[0] if flags else f"--{name.replace('_', '-')}"


def is_peer_lost(error: BaseException) -> bool:
    """Whether a collective failed because another rank of this torchrun run is gone (killed,
    out of memory, its own error): torch's distributed errors, or gloo's socket read failing."""
    if int(os.environ.get("WORLD_SIZE", "1")) <= 1:
        return False
    return (type(error).__name__ in ("DistBackendError", "DistNetworkError")
            or any(words in str(error) for words in ("Connection reset by peer", "Connection closed by peer")))


def raise_as_interrupted_or_again(error: Exception) -> NoReturn:
    """End as interrupted when a signal came (a library caught its KeyboardInterrupt and raised an
    error of its own instead: pybind11 makes it a TypeError in matplotlib's drawing), else raise
    ``error`` on: a bug's traceback, or typer's own exit."""
    signum = signal_received()
    if signum is None or isinstance(error, (typer.Exit, typer.Abort)):
        raise error
    say_interrupted(signum)
    raise typer.Exit(128 + signum) from None


def standard_output_reader_gone() -> bool:
    """Whether standard output is a pipe whose reading end has been closed (poll reports an
    error on the writing end), as opposed to another pipe of the command breaking."""
    try:
        poller = select.poll()
        poller.register(1, select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, AttributeError):  # no fd 1, or no poll() on this platform
        return False


def command(name: str, group: typer.Typer | None = None) -> Callable[[Callable], Callable]:
    """Register a subcommand (of ``group``, default the root) whose failures end in one ``error:``
    line, never a traceback.

    A user error or an OS error (read-only folder, disk full, a folder where a file should be) exits
    with code 2; output piped to a reader that has gone (``sianms zoo | head``) ends quietly with
    141, as SIGPIPE ends a Unix tool; running out of memory, or losing another rank of a torchrun
    run, with 1 (as a worker killed for it); an interrupt with 130 (SIGINT), 143 (SIGTERM) or 129
    (SIGHUP: a closed terminal or a dropped ssh session), after the library's cleanup has run. Under
    torchrun every rank stops with the same code, but only rank 0 says it was interrupted (torchrun
    signals them all at once), and another rank's error line names its rank (it may be its own: a
    shard only it reads). A path that starts with ``~`` is taken from the home folder
    (:func:`home_expanded`).
    """

    def register(function: Callable) -> Callable:
        @functools.wraps(function)
        def run(*args, **kwargs):
            rank = follower_rank()
            prefix = "error: " if rank is None else f"error: rank {rank}: "
            try:
                refuse_undecodable(function, kwargs)
                return function(*args, **{name: home_expanded(value) for name, value in kwargs.items()})
            except SianmsError as error:
                say_error(f"{prefix}{error}")
                raise typer.Exit(error.exit_code) from None
            except BrokenPipeError as error:
                if not standard_output_reader_gone():
                    say_error(f"{prefix}{describe_os_error(error)}")
                    raise typer.Exit(2) from None
                # `sianms zoo | head`: the reader has what it wanted; end quietly, as a Unix tool
                # killed by SIGPIPE does, and keep Python's exit-time flush from failing again.
                os.dup2(os.open(os.devnull, os.O_WRONLY), 1)
                raise typer.Exit(128 + signal.SIGPIPE) from None
            except OSError as error:
                say_error(f"{prefix}{describe_os_error(error)}")
                raise typer.Exit(2) from None
            except (MemoryError, RuntimeError) as error:
                if is_out_of_memory(error):
                    say_error(f"{prefix}{describe_out_of_memory(error)}")
                elif is_peer_lost(error):
                    say_error(f"{prefix}another process of this torchrun run stopped; its own lines or "
                              "torchrun's failure summary say why")
                else:
                    raise_as_interrupted_or_again(error)
                raise typer.Exit(1) from None
            except KeyboardInterrupt as interrupt:
                signum = interrupt.signum if isinstance(interrupt, Terminated) else signal.SIGINT
                say_interrupted(signum)
                raise typer.Exit(128 + signum) from None
            except Exception as error:
                raise_as_interrupted_or_again(error)

        return (app if group is None else group).command(name)(run)

    return register
