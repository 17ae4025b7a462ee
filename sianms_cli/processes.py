"""Worker processes that stop when the run stops, and SIGTERM and SIGHUP handled like Ctrl-C.

A multi-process command (synth, prepare) runs its workers in :func:`worker_pool`. Workers
ignore SIGINT and SIGHUP, so a Ctrl-C in the terminal, or the terminal closing (sent to the whole
process group), reaches the parent only; :func:`interrupt_on_signals` makes SIGTERM and SIGHUP (an
ssh session dropped, a terminal closed) raise :class:`Terminated` (a KeyboardInterrupt) there too.
Either way the exception unwinds the parent through its cleanup code, and leaving
:func:`worker_pool` terminates and joins every worker: no process outlives the run and no worker
writes after the parent has cleaned up. A parent killed outright (SIGKILL, the OOM killer) cleans
nothing up; its workers notice they are orphaned and exit within a second. A caller that consumes
results in a generator wraps it in ``contextlib.closing``, so an interrupt
between two results also closes the pool before the caller cleans up.
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import Any, Callable, Iterable, Iterator

from sianms_cli.errors import SianmsError
from sianms_cli.io import discard_open_temporaries


TASK_TORCH_THREADS = 1
"""Torch threads a scene task runs on, in a worker and in the parent alike: on some CPUs (AMD
EPYC, measured) a matrix kernel sums in another order on another thread count, at some batch
sizes, so a job's bytes would depend on ``--workers``; parallelism comes from the workers."""


@contextmanager
def task_torch_threads() -> Iterator[None]:
    """Run the block on :data:`TASK_TORCH_THREADS` torch threads, restoring the count after
    (torch is imported here: a job without it never pays for the import)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(TASK_TORCH_THREADS)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM, or SIGHUP (``signum``)."""

    def __init__(self, signum: int = signal.SIGTERM) -> None:
        super().__init__()
        self.signum = signum


INTERRUPTING = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals a run stops on, cleaning up: it ends with 128 + the signal's number (130, 143, 129)."""

_SIGNALS_RECEIVED: list[int] = []


def _raise_interrupt(signum: int, frame: Any) -> None:
    _SIGNALS_RECEIVED.append(signum)
    raise KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


def signal_name(signum: int) -> str:
    """``SIGINT``, ``SIGTERM``, ``SIGHUP``."""
    return signal.Signals(signum).name


_DELIVER_AGAIN = threading.Event()


def _deliver_again_when_asked() -> None:
    while True:
        _DELIVER_AGAIN.wait()
        _DELIVER_AGAIN.clear()
        os.kill(os.getpid(), _SIGNALS_RECEIVED[-1])


def _interrupt_again(unraisable: Any) -> None:
    """An interrupt that landed in a finaliser or a weakref callback (the garbage collector ran
    when the signal came) is one Python cannot raise: it would print the callback's traceback and
    carry on. Say nothing and have the signal delivered again, from a thread waiting for that
    (sending it from here would run the handler here), so that it lands once the callback has
    returned and the interrupt unwinds the run."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt) and _SIGNALS_RECEIVED:
        _DELIVER_AGAIN.set()
    else:
        sys.__unraisablehook__(unraisable)


def interrupt_on_signals() -> None:
    """From now on SIGINT raises KeyboardInterrupt and SIGTERM or SIGHUP :class:`Terminated` in the
    main thread, and :func:`signal_received` remembers the first: a library that swallows the
    exception (a C callback, an ``except`` around an import) cannot make a run look finished,
    and one raised where Python cannot raise it is delivered again (:func:`_interrupt_again`)."""
    for signum in INTERRUPTING:
        signal.signal(signum, _raise_interrupt)
    if _ignore_signals_at_shutdown not in _AT_SHUTDOWN:  # registered first, so it runs last
        atexit.register(_ignore_signals_at_shutdown)
        _AT_SHUTDOWN.append(_ignore_signals_at_shutdown)
    if sys.unraisablehook is not _interrupt_again:
        threading.Thread(target=_deliver_again_when_asked, name="sianms-interrupt-again", daemon=True).start()
        sys.unraisablehook = _interrupt_again


_AT_SHUTDOWN: list[Callable[[], None]] = []


def _ignore_signals_at_shutdown() -> None:
    """The last exit handler: SIGINT and SIGTERM are ignored while the interpreter tears down.
    Python puts back the default action of a signal it handled as it finalises, so one landing
    in the teardown after every exit handler (a second or more once torch is loaded) killed the
    process: 130 or 143 without a word, for a command that had finished. An ignored signal keeps
    the code the command chose; the handlers before this one still end the process at once
    (:func:`exit_on_signals`)."""
    for signum in INTERRUPTING:
        signal.signal(signum, signal.SIG_IGN)


def exit_on_signals(code: int) -> None:
    """From now on SIGINT, SIGTERM and SIGHUP end the process at once with ``code``: the command has
    finished and said how. A signal during interpreter shutdown (torchrun stopping every rank
    once one failed) would otherwise raise inside a library's finaliser and print its traceback."""

    def exit_now(signum: int, frame: Any) -> None:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):  # closed, or a broken pipe: nothing more can be said
                pass
        os._exit(code)

    for signum in INTERRUPTING:
        signal.signal(signum, exit_now)


def signal_received() -> int | None:
    """The first SIGINT, SIGTERM or SIGHUP since :func:`interrupt_on_signals`, or None."""
    return _SIGNALS_RECEIVED[0] if _SIGNALS_RECEIVED else None


ORPHAN_CHECK_SECONDS = 1.0


def _exit_when_orphaned(parent: int) -> None:
    """Watch (in a daemon thread) for the parent's death, and end this worker within
    ORPHAN_CHECK_SECONDS of it: a parent killed by SIGKILL runs no cleanup, and its workers
    would otherwise compute, and write, on their own."""
    while os.getppid() == parent:
        time.sleep(ORPHAN_CHECK_SECONDS)
    discard_open_temporaries()
    os._exit(1)


def _discard_and_exit(signum: int, frame: Any) -> None:
    """A worker stopped mid-task (the pool terminates it on an interrupt): delete the files it was
    writing and end now. Not by raising: the pool's loop in the worker would catch it and start
    its next task."""
    discard_open_temporaries()
    os._exit(128 + signum)


def _start_worker(parent: int, initializer: Callable[..., None] | None, initargs: tuple) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)  # a closed terminal signals the group: the parent stops the pool
    signal.signal(signal.SIGTERM, _discard_and_exit)
    threading.Thread(target=_exit_when_orphaned, args=(parent,), daemon=True).start()
    if initializer is not None:
        initializer(*initargs)


class WorkerDied(SianmsError):
    """A worker process ended without finishing its task (killed, e.g. by the OOM killer)."""

    exit_code = 1


class WorkerPool:
    """Tasks run in worker processes, results as they finish or in task order."""

    def __init__(self, executor: ProcessPoolExecutor) -> None:
        self._executor = executor

    def imap(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        """Start ``function(item)`` for every item now; their results, in item order."""
        futures = [self._executor.submit(function, item) for item in items]
        return (_result(future) for future in futures)

    def imap_unordered(self, function: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        """Start ``function(item)`` for every item now; their results, as each one finishes."""
        futures = [self._executor.submit(function, item) for item in items]
        return (_result(future) for future in as_completed(futures))

    def terminate(self) -> None:
        """Stop every worker now, running tasks included."""
        # ProcessPoolExecutor has no public way to stop running tasks before Python 3.14
        # (terminate_workers); its process table is the only handle on them.
        for process in list((self._executor._processes or {}).values()):
            process.terminate()
        self._executor.shutdown(wait=True, cancel_futures=True)


def _result(future: Future) -> Any:
    try:
        return future.result()
    except BrokenProcessPool:
        raise WorkerDied("a worker process died before finishing its task (killed by a signal, or out of "
                         "memory?); finished outputs are kept, a rerun resumes") from None


@contextmanager
def worker_pool(
    workers: int,
    initializer: Callable[..., None] | None = None,
    initargs: tuple = (),
) -> Iterator[WorkerPool]:
    """A pool of ``workers`` fresh ("spawn") processes, all gone when the block is left.

    A clean exit lets the workers finish; an exception or an interrupt terminates them at
    once. A worker that dies mid-task (SIGKILL, the OOM killer) raises :class:`WorkerDied`
    instead of leaving the run waiting for a result that never comes.
    """
    executor = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_start_worker, initargs=(os.getpid(), initializer, initargs))
    pool = WorkerPool(executor)
    try:
        yield pool
    except BaseException:
        pool.terminate()
        raise
    executor.shutdown(wait=True)
