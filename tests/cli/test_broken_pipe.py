"""Output piped to a reader that has gone (`sianms zoo | head -1`) ends quietly, as SIGPIPE ends a
Unix tool: exit 141 and no error line."""

import os
import subprocess
import sys

import pytest


@pytest.mark.skipif(not hasattr(os, "pipe") or sys.platform == "win32", reason="POSIX pipes")
def test_a_closed_reader_ends_the_command_quietly_with_141():
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first line: every write breaks the pipe
    try:
        finished = subprocess.run([sys.executable, "-m", "sianms_cli", "zoo"], stdout=write_end,
                                  stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert (finished.returncode, finished.stderr) == (141, "")


def test_a_reader_that_stays_gets_everything():
    finished = subprocess.run([sys.executable, "-m", "sianms_cli", "zoo"], capture_output=True, text=True,
                              timeout=120)
    assert finished.returncode == 0 and finished.stdout.startswith("zoo:") and finished.stderr == ""
