"""Worker processes that stop when the run stops, and SIGTERM handled like Ctrl-C.

A multi-process command (synth, prepare) runs its workers in :func:`worker_pool`. Workers
ignore SIGINT, so a Ctrl-C in the terminal (sent to the whole process group) reaches the
parent only; :func:`terminate_on_sigterm` makes SIGTERM raise :class:`Terminated` (a
KeyboardInterrupt) there too. Either way the exception unwinds the parent through its
cleanup code, and leaving :func:`worker_pool` terminates and joins every worker: no
process outlives the run and no worker writes after the parent has cleaned up.
"""

from __future__ import annotations

import multiprocessing
import signal
from contextlib import contextmanager
from multiprocessing.pool import Pool
from typing import Any, Callable, Iterator


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM."""


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated()


def terminate_on_sigterm() -> None:
    """From now on SIGTERM raises :class:`Terminated` in the main thread."""
    signal.signal(signal.SIGTERM, _raise_terminated)


def _start_worker(initializer: Callable[..., None] | None, initargs: tuple) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if initializer is not None:
        initializer(*initargs)


@contextmanager
def worker_pool(
    workers: int,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
) -> Iterator[Pool]:
    """A pool of ``workers`` fresh ("spawn") processes, all gone when the block is left.

    A clean exit lets the workers finish (close and join); an exception or an interrupt
    terminates them at once.
    """
    context = multiprocessing.get_context("spawn")
    pool = context.Pool(workers, initializer=_start_worker, initargs=(initializer, initargs))
    try:
        yield pool
        pool.close()
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()
