"""Errors a user can cause and fix.

Every error raised for bad input is a :class:`SianmsError`; the CLI prints its message
on one line and exits with code 2, never a traceback. Our own invariants use ``assert``.
"""

from __future__ import annotations

import os
from pathlib import Path


class SianmsError(Exception):
    """Bad input or a refused operation, described so the user can act on it."""

    exit_code = 2

    def __reduce__(self):
        # Raised in a worker process, the error crosses back to the parent by pickling; the
        # default would call __init__ with the message alone, which subclasses do not take.
        return _rebuild, (type(self), self.args, self.__dict__)


def _rebuild(cls: type[SianmsError], args: tuple, state: dict) -> SianmsError:
    error = cls.__new__(cls)
    Exception.__init__(error, *args)
    error.__dict__.update(state)
    return error


QUOTE_LIMIT = 200
"""Characters of an offending value an error line quotes: a field holding megabytes is named, not echoed."""


def shorten(text: str, limit: int = QUOTE_LIMIT) -> str:
    """``text`` itself when at most ``limit`` characters long, else its first ``limit`` and how long it was."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text):,} characters in all)"


def quote(value: object, limit: int = QUOTE_LIMIT) -> str:
    """An offending value as an error line shows it: a string in quotes, anything else as its ``repr``,
    cut to ``limit`` characters (:func:`shorten`)."""
    text = value if isinstance(value, str) else repr(value)
    if len(text) <= limit:
        return f"'{text}'" if isinstance(value, str) else text
    return f"'{text[:limit]}...' ({len(text):,} characters in all)"


LINE_LIMIT = 2_000
"""The most characters of an error line: past it, the middle is left out (:func:`bounded_line`)."""


def bounded_line(line: str, limit: int = LINE_LIMIT) -> str:
    """``line`` whole when at most ``limit`` characters long, else its start (the file, record and field) and its
    end (what to do) with the middle left out and counted: a value no quoting bounded (a library's message
    that echoes its input) still makes a line that a terminal and a log hold."""
    if len(line) <= limit:
        return line
    head, tail = limit // 2, limit // 4
    return f"{line[:head]}... ({len(line) - head - tail:,} characters left out) ...{line[-tail:]}"


class DataFormatError(SianmsError):
    """A file, or one record and field in it, does not follow its format.

    The message always starts with the file, then the record token and the field when
    they are known: ``<path>: record <token>: field '<field>': <what is wrong>``.
    """

    def __init__(
        self,
        path: str | Path,
        message: str,
        *,
        token: str | None = None,
        field: str | None = None,
    ) -> None:
        self.path = str(path)
        self.token = token
        self.field = field
        self.detail = message
        where = [self.path]
        if token is not None:  # a record's token or a field's name comes from the file: bounded as any value
            where.append(f"record {shorten(str(token))}")
        if field is not None:
            where.append(f"field '{shorten(str(field))}'")
        super().__init__(": ".join(where) + f": {message}")


class OutputExistsError(SianmsError):
    """A command was asked to write where finished outputs already exist."""


SEED_LIMIT = 2**63
"""Seeds are below this: every generator they feed (numpy's, torch's) and every file that
records them (JSON, Parquet int64) takes them whole."""


def check_seed(seed: int) -> None:
    """Refuse a ``--seed`` outside [0, 2**63)."""
    if not 0 <= seed < SEED_LIMIT:
        raise SianmsError(f"--seed must be between 0 and 2**63 - 1, got {seed}")


PER_CPU_LIMIT = 4
"""``--workers`` and ``--threads`` are at most this many per usable CPU. Each worker is a CPU-bound
process of its own (one torch thread, a few hundred MB) and each torch thread a CPU-bound thread:
past the CPUs they add memory and contention, not speed, and far past them they are a typo that
exhausts memory or the process limit (``--threads 100000`` had crashed OpenBLAS)."""


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity mask where the OS has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def check_per_cpu_count(flag: str, count: int) -> None:
    """Refuse a count of workers or threads below 1 or above PER_CPU_LIMIT per usable CPU."""
    if count < 1:
        raise SianmsError(f"{flag} must be at least 1, got {count}")
    most = PER_CPU_LIMIT * usable_cpus()
    if count > most:
        raise SianmsError(f"{flag} must be at most {most} ({PER_CPU_LIMIT} per CPU this process may use), "
                          f"got {count}")


def check_workers(workers: int) -> None:
    """Refuse a ``--workers`` the machine cannot hold, before anything is written."""
    check_per_cpu_count("--workers", workers)


MAX_EPOCHS = 10_000  # 50 times the original F-PointNets' 201: more is a typo that would run for ever


def check_epochs(epochs: int, flag: str = "--epochs") -> None:
    """Refuse an epoch count outside [1, :data:`MAX_EPOCHS`]."""
    if not 1 <= epochs <= MAX_EPOCHS:
        raise SianmsError(f"{flag} must be in [1, {MAX_EPOCHS:,}], got {epochs}")
