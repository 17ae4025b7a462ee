"""Where the compiled kernels (numba's ``cache=True`` functions) keep their machine code.

numba stores it beside the source, in the package's ``__pycache__`` folders, else in the user's
cache folder under HOME; when neither is writable (a system-wide install run by another user, a
container run as a user without a home) it raises at the first decorated function, and a command
ended in a traceback as it imported its kernels, after writing part of its outputs. So, before
numba loads (:func:`choose_kernel_cache`, run when the package is imported), a folder is chosen
in this order, the first that is writable:

1. ``NUMBA_CACHE_DIR``, when set (numba's own variable: the user's choice);
2. the package's ``__pycache__`` folders (numba's default; nothing is changed);
3. the user's cache folder, ``$XDG_CACHE_HOME/sianms/kernels`` or ``~/.cache/sianms/kernels``;
4. ``sianms-kernels-<uid>`` in the temporary folder, made by this user and writable by no other
   (machine code read from a folder someone else can write would run as this user).

With none of them, the kernels are compiled in every process without a cache: a few seconds
more per command, never a failure.

Stdlib only: this module runs before numpy and numba are imported.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import os
import stat
import sys
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any, Literal, MutableMapping

PACKAGE = Path(__file__).resolve().parent
KERNEL_PACKAGES = ("evaluation", "metrics", "synth")
"""The subpackages whose modules hold ``cache=True`` kernels (numba caches beside each source file)."""


def is_writable_folder(folder: Path) -> bool:
    """Whether ``folder`` is, or can be made, a folder this process can create files in (a read-only
    filesystem says no even to root)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError:
        return False
    return True


def is_private_folder(folder: Path) -> bool:
    """Whether ``folder`` (made if missing, mode 0o700) is a real folder of this user that no one else can
    write to: what a shared temporary folder must be to hold code this user will run."""
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        status = folder.lstat()
    except OSError:
        return False
    return (stat.S_ISDIR(status.st_mode) and status.st_uid == os.getuid()
            and not status.st_mode & (stat.S_IWGRP | stat.S_IWOTH) and is_writable_folder(folder))


def user_cache_folder(environ: MutableMapping[str, str]) -> Path | None:
    """``$XDG_CACHE_HOME/sianms/kernels``, else ``~/.cache/sianms/kernels``; None without either."""
    base = environ.get("XDG_CACHE_HOME") or (str(Path(environ["HOME"]) / ".cache") if environ.get("HOME") else "")
    return Path(base) / "sianms" / "kernels" if base else None


def kernel_cache_folder(environ: MutableMapping[str, str] = os.environ) -> Path | None | Literal[False]:
    """The folder for numba's cache (module docstring); None where numba's default beside the source
    serves, False where no folder is writable."""
    chosen = environ.get("NUMBA_CACHE_DIR")
    if chosen and is_writable_folder(Path(chosen)):
        return Path(chosen)
    if all(is_writable_folder(PACKAGE / name / "__pycache__") for name in KERNEL_PACKAGES):
        return None
    user = user_cache_folder(environ)
    if user is not None and is_writable_folder(user):
        return user
    try:
        temporary = Path(tempfile.gettempdir()) / f"sianms-kernels-{os.getuid()}"
    except FileNotFoundError:  # Python found no writable temporary folder either
        return False
    return temporary if is_private_folder(temporary) else False


def choose_kernel_cache(environ: MutableMapping[str, str] = os.environ) -> None:
    """Point numba's cache at :func:`kernel_cache_folder`, or turn the cache off where none is writable.

    Sets ``NUMBA_CACHE_DIR`` in ``environ`` (read by numba when it loads; inherited by the command's
    worker processes and torchrun ranks); where numba is loaded already, its config too."""
    folder = kernel_cache_folder(environ)
    if folder is None:
        return
    if folder is False:
        environ.pop("NUMBA_CACHE_DIR", None)
        compile_without_cache()
        return
    environ["NUMBA_CACHE_DIR"] = str(folder)
    if "numba" in sys.modules:
        sys.modules["numba"].config.CACHE_DIR = str(folder)


def compile_without_cache() -> None:
    """Make ``cache=True`` a no-op: every process compiles the kernels it calls.

    numba is not imported here (it loads numpy, which must wait for the kernel settings of
    :mod:`sianms_cli.kernels`): its dispatcher is changed as it loads (:class:`_UncachedDispatcher`),
    or now where it is loaded already."""
    dispatcher = sys.modules.get("numba.core.dispatcher")
    if dispatcher is not None:
        _never_cache(dispatcher)
    elif not any(isinstance(finder, _UncachedDispatcher) for finder in sys.meta_path):
        sys.meta_path.insert(0, _UncachedDispatcher())


def _never_cache(dispatcher: ModuleType) -> None:
    dispatcher.Dispatcher.enable_caching = lambda self: None


class _UncachedDispatcher(importlib.abc.MetaPathFinder):
    """Finds ``numba.core.dispatcher`` as Python would, and has :func:`_never_cache` run once it has loaded."""

    def find_spec(self, name: str, path: Any, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if name != "numba.core.dispatcher":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is None or spec.loader is None:
            return spec
        load = spec.loader.exec_module

        def exec_module(module: ModuleType) -> None:
            load(module)
            _never_cache(module)

        spec.loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec
