"""Worker processes end with the run: on success, on an interrupt, and when one of them dies."""

import os
import subprocess
import sys
import time

import pytest

from sianms_cli.io import atomic_file
from sianms_cli.processes import ORPHAN_CHECK_SECONDS, WorkerDied, worker_pool


def test_results_in_order_and_as_they_finish():
    with worker_pool(2) as pool:
        assert list(pool.imap(abs, [-3, 1, -2])) == [3, 1, 2]
        assert sorted(pool.imap_unordered(abs, [-3, 1, -2])) == [1, 2, 3]


def test_a_worker_killed_mid_task_is_an_error_not_a_hang():
    with pytest.raises(WorkerDied, match="a worker process died before finishing its task"):
        with worker_pool(2) as pool:
            list(pool.imap(os._exit, [9]))


def test_an_interrupt_terminates_running_workers(process_tree):
    with pytest.raises(KeyboardInterrupt):
        with worker_pool(2) as pool:
            pool.imap_unordered(time.sleep, [60, 60])
            deadline = time.monotonic() + 30
            while len(process_tree.workers(os.getpid())) < 2 and time.monotonic() < deadline:
                time.sleep(0.05)
            workers = process_tree.workers(os.getpid())
            raise KeyboardInterrupt
    assert workers and not [pid for pid in workers if process_tree.alive(pid)]


def write_forever(path):
    """A task that is stopped while it writes ``path``."""
    with atomic_file(path) as stream:
        stream.write(b"half")
        time.sleep(60)


def test_a_worker_stopped_mid_write_leaves_no_temporary_file(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with worker_pool(2) as pool:
            pool.imap_unordered(write_forever, [tmp_path / "a.bin", tmp_path / "b.bin"])
            deadline = time.monotonic() + 30
            while len(list(tmp_path.iterdir())) < 2 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert len(list(tmp_path.iterdir())) == 2  # both temporaries are there
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


PARENT = """
import time
from sianms_cli.processes import worker_pool
with worker_pool(2) as pool:
    pool.imap_unordered(time.sleep, [60, 60])
    time.sleep(60)
"""


def test_workers_of_a_parent_killed_outright_exit_on_their_own(process_tree):
    parent = subprocess.Popen([sys.executable, "-c", PARENT])
    try:
        deadline = time.monotonic() + 60
        while len(process_tree.workers(parent.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = process_tree.workers(parent.pid)
    finally:
        parent.kill()  # SIGKILL: no cleanup code runs in the parent
        parent.wait()
    assert len(workers) == 2
    deadline = time.monotonic() + 10 * ORPHAN_CHECK_SECONDS
    while any(process_tree.alive(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in workers if process_tree.alive(pid)]
