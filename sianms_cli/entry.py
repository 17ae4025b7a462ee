"""The ``sianms`` executable: signals handled from its first statement, then the command line.

Importing the command line takes a few tenths of a second (typer, numpy, the subcommands); a
SIGINT, SIGTERM or SIGHUP then would end in a traceback from the middle of an import. Until the command
line is ready, each ends the process at once with the interrupted line: nothing has
been written yet. From then on :func:`sianms_cli.cli.main` handles them.

Before numpy or torch loads, the arithmetic libraries are asked for their AVX2 kernels
(:mod:`sianms_cli.kernels`), so a seed gives the same bytes on AVX2 and AVX-512 machines; the
trainings run the CPU's own kernels instead (:func:`~sianms_cli.kernels.native_by_default`).
The command's worker processes and torchrun ranks inherit the setting.
"""

import os
import signal


def _end_while_starting(signum: int, frame: object) -> None:
    os.write(2, f"interrupted ({signal.Signals(signum).name}) while starting; nothing was written\n".encode())
    os._exit(128 + signum)


def main() -> None:
    for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(signum, _end_while_starting)
    import sys

    from sianms_cli.kernels import native_by_default, use_avx2_kernels

    use_avx2_kernels(native_default=native_by_default(sys.argv[1:]))
    from sianms_cli.cli import main as command_line

    command_line()
