"""The bottom floor: every file and folder sianms writes, and every JSON file it reads.

Writes are atomic: the content goes to a hidden temporary name in the destination folder
(``.<name>.<pid>.<random>.partial``) and is renamed over the destination only when complete,
so a killed run never leaves a file that looks finished. New files and folders get the
permissions the user's umask gives (``open``/``mkdir`` with 0o666/0o777), never the 0o600 of
``mkstemp``: on a shared cluster a colleague can read what a run wrote.

An OS failure while writing (read-only folder, disk full, a folder where a file should be)
becomes one :class:`OutputError` naming the path and the cause; the temporary file is
removed and the destination is untouched.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
import re
import secrets
import shutil
import stat
from contextlib import contextmanager, suppress
from pathlib import Path
from typing import IO, Any, Callable, Iterator, Literal, Mapping, TypeVar

import orjson

from sianms_cli.errors import DataFormatError, OutputExistsError, SianmsError

PARTIAL_SUFFIX = ".partial"
CLAIM_SUFFIX = ".claim"  # beside a staging folder: see build_folder
RECORD_MAX_BYTES = 64 * 2**20
"""The most a JSON record sianms writes for people and for its own use can need (eval.json, table.json,
metrics, report.json, a metrics config: kilobytes to a few megabytes): a larger one is not the file meant."""
JSON_MAX_DEPTH = 1024  # orjson refuses deeper documents; the json module's limit moves with Python's version
_BRACKET_OR_STRING = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]')
T = TypeVar("T")
_OPEN_TEMPORARIES: set[Path] = set()  # of the AtomicFiles this process is writing


def discard_open_temporaries() -> None:
    """Delete the temporary files of every AtomicFile this process is writing: for a worker that
    is stopped mid-task and ends at once, without unwinding (``processes``)."""
    for temporary in list(_OPEN_TEMPORARIES):
        with suppress(OSError):
            temporary.unlink()


class OutputError(SianmsError):
    """An output could not be written (the OS said why)."""


def describe_os_error(error: OSError, path: str | Path | None = None) -> str:
    """``<path>: <cause>`` for an OSError, the path taken from the error when not given.

    For ENOTDIR the path is the file that stands where a folder must be, found along the
    path: ``t.sh: not a folder`` rather than ``t.sh/x/y.json: Not a directory``.
    """
    where = path if path is not None else error.filename
    if error.errno == errno.ENOTDIR and where is not None:
        return f"{_first_non_folder(Path(where))}: not a folder"
    # The errno's own words: libraries such as pyarrow put a longer text in strerror.
    cause = os.strerror(error.errno) if error.errno else (error.strerror or str(error) or type(error).__name__)
    return f"{where}: {cause}" if where is not None else cause


def _first_non_folder(path: Path) -> Path:
    """The first of ``path``'s parents, or ``path`` itself, that exists and is not a folder;
    ``path`` when none is (the file went away since the error)."""
    for candidate in (*reversed(path.parents), path):
        if candidate.exists() and not candidate.is_dir():
            return candidate
    return path


@contextmanager
def os_errors_as_output_errors(path: str | Path) -> Iterator[None]:
    """Turn an OSError raised in the block into an :class:`OutputError` naming ``path``."""
    try:
        yield
    except OSError as error:
        raise OutputError(f"cannot write {describe_os_error(error, path)}") from None


def partial_name(path: Path) -> Path:
    """A hidden, unique temporary name beside ``path``."""
    return path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}{PARTIAL_SUFFIX}")


_PARTIAL_NAME = re.compile(rf"\.(.+)\.[0-9]+\.[0-9a-f]{{8}}{re.escape(PARTIAL_SUFFIX)}")


def partial_of(name: str) -> str | None:
    """The file name a :func:`partial_name` was made for (a killed write leaves one), or None."""
    match = _PARTIAL_NAME.fullmatch(name)
    return match.group(1) if match else None


def real_path(path: str | Path) -> Path:
    """``path`` absolute, through every symbolic link. Unlike ``Path.resolve`` on Python 3.11,
    which raises RuntimeError (a traceback) for a link loop, a loop is left for the first use of
    the path to report as the OS error it is ("Too many levels of symbolic links")."""
    return Path(os.path.realpath(path))


def check_outside_dataroot(path: str | Path, dataroot: str | Path, flag: str, command: str) -> None:
    """Refuse a ``flag`` file inside the dataroot of a ``command`` that only reads the dataset
    (with --overwrite, an --out naming one of its tables would replace that table)."""
    if real_path(path).is_relative_to(real_path(dataroot)):
        raise SianmsError(f"{flag}: {path} is inside the dataroot {dataroot}, which {command} only reads; "
                          "write it elsewhere")


def expand_home(path: Path) -> Path:
    """``path`` with a leading ``~`` or ``~user`` made the home folder's, as the shell does for
    ``--out ~/x`` but not for ``--out=~/x`` nor after ``file:``: a folder named ``~`` is never wanted."""
    try:
        return path.expanduser()
    except RuntimeError:  # ~nobody-here/x
        raise SianmsError(f"{path}: no home folder is known for {path.parts[0]}") from None


def make_folder(path: str | Path) -> Path:
    """Create ``path`` and its parents as the umask allows; an existing folder is fine."""
    path = Path(path)
    with os_errors_as_output_errors(path):
        try:
            path.mkdir(parents=True, exist_ok=True)
        except FileExistsError as error:
            # With exist_ok, mkdir raises this only when ``path`` is there but is not a folder:
            # ENOTDIR says so (describe_os_error), EEXIST's "File exists" misleads; a link that
            # leads nowhere (or into a loop of links) is said to be one.
            if path.is_symlink() and not path.exists():
                raise FileNotFoundError(errno.ENOENT, "a link that leads to no folder (nowhere, or a loop of links)",
                                        str(path)) from error
            raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(path)) from error
    return path


class AtomicFile:
    """A file written under a hidden temporary name beside ``path``, for streaming writers.

    :attr:`stream` is the open file; :meth:`commit` closes it and renames it to ``path``;
    :meth:`discard` closes it and deletes it. Writers that keep several files open at once
    (the dataset tables, the Parquet files of a cache shard) hold one each.
    """

    def __init__(self, path: str | Path, *, text: bool = False) -> None:
        self.path = Path(path)
        make_folder(self.path.parent)
        refuse_non_file(self.path)
        self.temporary = partial_name(self.path)
        _OPEN_TEMPORARIES.add(self.temporary)
        descriptor = None
        try:
            with os_errors_as_output_errors(self.path):
                descriptor = os.open(self.temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            self.stream: IO = (open(descriptor, "w", encoding="utf-8", newline="\n") if text
                               else open(descriptor, "wb"))
        except BaseException:  # an interrupt may land once the file exists, before anyone holds it
            if descriptor is not None and not hasattr(self, "stream"):
                os.close(descriptor)
            with suppress(OSError):  # a read-only folder refuses even to unlink what is not there
                self.temporary.unlink(missing_ok=True)
            _OPEN_TEMPORARIES.discard(self.temporary)
            raise

    def commit(self, *, replace: bool = True) -> Path:
        """Close and rename into place; on failure (a full disk) the temporary file is deleted. Without
        ``replace``, a file that is at ``path`` by now (made since it was checked) is kept and this one
        dropped: :class:`DestinationChangedError`."""
        try:
            with os_errors_as_output_errors(self.path):
                self.stream.close()
                if not replace:
                    if not _move_unless_there(self.temporary, self.path):
                        raise _changed(self.path)
                else:
                    os.replace(self.temporary, self.path)
        except BaseException:
            self.discard()
            raise
        _OPEN_TEMPORARIES.discard(self.temporary)
        return self.path

    def discard(self) -> None:
        """Close (ignoring a failing flush: the content is dropped) and delete the file."""
        try:
            self.stream.close()
        except OSError:
            pass
        self.temporary.unlink(missing_ok=True)
        _OPEN_TEMPORARIES.discard(self.temporary)


@contextmanager
def atomic_file(path: str | Path, *, text: bool = False) -> Iterator[IO]:
    """A stream whose content appears at ``path`` only when the block completes.

    The parent folder is created if needed. On any error (or interrupt) the temporary file
    is removed and ``path`` is left as it was.
    """
    file = AtomicFile(path, text=text)
    try:
        with os_errors_as_output_errors(path):
            yield file.stream
    except BaseException:
        file.discard()
        raise
    file.commit()


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_file`)."""
    with atomic_file(path) as stream:
        stream.write(data)
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return write_bytes(path, text.encode("utf-8"))


def write_json(path: str | Path, data: Any) -> Path:
    """Write ``data`` as :func:`json_text` (indented JSON with sorted keys)."""
    return write_text(path, json_text(data))


def json_text(data: Any) -> str:
    """``data`` as indented JSON with sorted keys (diff-friendly, reproducible)."""
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def refuse_non_file(path: Path) -> None:
    """Refuse an output path that holds something other than a file: a folder, or a device, pipe
    or socket (an atomic write would rename a file over ``/dev/null``)."""
    if path.is_dir():
        raise OutputError(f"cannot write {path}: it is a folder")
    if path.exists() and not path.is_file():
        raise OutputError(f"cannot write {path}: not a regular file")


def write_files_together(contents: Mapping[Path, str | bytes], *, overwrite: bool = False) -> None:
    """Write each ``{path: content}`` (a text as UTF-8) under its temporary name, then rename them
    all into place.

    A file that was not there when checked, or another than was, by the time of the rename (another run's,
    a user's) is kept, and none is written (:class:`DestinationChangedError`). A failure (a full disk, a
    file where a folder must be) leaves none of the paths written and none replaced: the temporary files
    are removed, a file already renamed when a later rename fails is deleted, and the file it replaced,
    renamed aside first, is put back. Refuses a folder, and an existing file unless ``overwrite``.
    """
    files: list[AtomicFile] = []
    committed: list[Path] = []
    set_aside: dict[Path, Path] = {}  # destination: its earlier file, under a temporary name
    seen: dict[Path, Snapshot | None] = {}  # destination: what was there when it was checked
    try:
        for path, content in contents.items():
            files.append(AtomicFile(check_writable_output(path, overwrite=overwrite)))
            seen[files[-1].path] = snapshot(path)
            with os_errors_as_output_errors(path):
                files[-1].stream.write(content.encode("utf-8") if isinstance(content, str) else content)
                files[-1].stream.flush()  # a full disk fails here, before anything is renamed
        for file in files:
            if seen[file.path] is not None:
                set_aside[file.path] = partial_name(file.path)
                with os_errors_as_output_errors(file.path):
                    os.replace(file.path, set_aside[file.path])
                if snapshot(set_aside[file.path]) != seen[file.path]:  # replaced since: put back as it is
                    raise _changed(file.path)
            committed.append(file.commit(replace=False))
    except BaseException:
        for file in files:
            file.discard()
        for path in committed:
            path.unlink(missing_ok=True)
        for path, aside in set_aside.items():
            if aside.exists():
                os.replace(aside, path)
        raise
    for aside in set_aside.values():
        aside.unlink(missing_ok=True)


def check_writable_output(path: str | Path, *, overwrite: bool) -> Path:
    """Refuse an output file that is a folder or a device, or that exists while ``overwrite`` is
    false (a link does, even one that leads nowhere: the write would replace it)."""
    path = Path(path)
    refuse_non_file(path)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise OutputExistsError(f"{path} exists; pass --overwrite to replace it")
    return path


def _kind_of(mode: int) -> str:
    """What a file that is not a regular file is, in words."""
    for test, kind in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a pipe (FIFO)"), (stat.S_ISCHR, "a device"),
                       (stat.S_ISBLK, "a device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return "not a regular file"


@contextmanager
def regular_file(path: str | Path, max_bytes: int | None = None) -> Iterator[IO[bytes]]:
    """``path`` open for reading once it is checked to be a regular file of at most ``max_bytes``.

    An input that is a folder, a pipe, a device or a socket (``/dev/zero`` read until memory runs out,
    a FIFO no one writes to waits for ever) raises DataFormatError naming it, and so does one larger
    than its format has any use for. The file is opened without blocking (a FIFO's open would wait for
    a writer) and checked on the open descriptor, so what is read is what was checked.
    """
    path = Path(path)
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise DataFormatError(path, "file not found") from None
    except IsADirectoryError:
        raise DataFormatError(path, "is a folder, not a file") from None
    except OSError as error:
        raise DataFormatError(path, f"cannot read: {error.strerror or error}") from None
    try:
        status = os.fstat(descriptor)
        if not stat.S_ISREG(status.st_mode):
            raise DataFormatError(path, f"{_kind_of(status.st_mode)}, not a regular file: give a file")
        if max_bytes is not None and status.st_size > max_bytes:
            raise DataFormatError(path, f"{status.st_size:,} bytes, more than the {max_bytes:,} such a file can "
                                        "need: not the file meant?")
        os.set_blocking(descriptor, True)
        handle = os.fdopen(descriptor, "rb")
    except BaseException:
        os.close(descriptor)
        raise
    with handle:
        yield handle


def check_regular_file(path: str | Path, max_bytes: int | None = None) -> Path:
    """Refuse an input that is not a regular file of at most ``max_bytes`` (:func:`regular_file`), for
    a library that opens the file itself."""
    with regular_file(path, max_bytes):
        return Path(path)


def read_json(path: str | Path, max_bytes: int | None = None) -> Any:
    """The JSON document at ``path``, a regular file of at most ``max_bytes`` (:func:`regular_file`).

    A missing or unreadable file, invalid UTF-8 or invalid JSON raises one DataFormatError
    naming the file (with the line and column of a syntax error).
    """
    path = Path(path)
    with regular_file(path, max_bytes) as handle:
        try:
            # a bounded read: a file that grew since it was checked is refused, not read on
            data = handle.read() if max_bytes is None else handle.read(max_bytes + 1)
        except OSError as error:
            raise DataFormatError(path, f"cannot read: {error.strerror or error}") from None
    if max_bytes is not None and len(data) > max_bytes:
        raise DataFormatError(path, f"more than the {max_bytes:,} bytes such a file can need: not the file meant?")
    return decode_json(path, data)


def decode_json(path: str | Path, data: bytes) -> Any:
    """``data`` decoded as JSON; errors name ``path`` with the line and column."""
    too_deep = DataFormatError(path, f"invalid JSON: nested deeper than {JSON_MAX_DEPTH} levels")
    try:
        return orjson.loads(data)
    except orjson.JSONDecodeError as error:
        if "recursion" in str(error):
            raise too_deep from None
    # orjson does not report line and column; the json module does, on the same error.
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise DataFormatError(path, f"not valid UTF-8 at byte {error.start}") from None
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise DataFormatError(path, f"invalid JSON at line {error.lineno}, column {error.colno}: {error.msg}") from None
    except RecursionError:
        raise too_deep from None
    if nested_too_deep(text):
        raise too_deep
    return value


def nested_too_deep(text: str) -> bool:
    """Whether JSON ``text`` nests lists and objects deeper than :data:`JSON_MAX_DEPTH` (brackets
    in strings not counted). The json module's own limit is no guide: Python 3.11 stops near
    1,000 levels, 3.12 parsed 5,000 and 3.13 50,000 (measured). Scans only a text that holds
    more opening brackets than the limit."""
    if text.count("[") + text.count("{") <= JSON_MAX_DEPTH:
        return False
    depth = 0
    for token in _BRACKET_OR_STRING.finditer(text):
        bracket = token.group()
        if bracket in ("[", "{"):
            depth += 1
            if depth > JSON_MAX_DEPTH:
                return True
        elif bracket in ("]", "}"):
            depth -= 1
    return False


def sha256_of(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# --------------------------------------------------------------------------- folders


def staging_folder(destination: str | Path) -> Path:
    """A new, hidden, empty folder beside ``destination`` to build it in (umask permissions).

    An error names ``destination``: the hidden name means nothing to the user who asked for
    it, and the cause (a read-only parent, a full disk) is the same."""
    destination = Path(os.path.abspath(destination))
    make_folder(destination.parent)
    return _make_staging(partial_name(destination), destination)


def _make_staging(staging: Path, destination: Path) -> Path:
    with os_errors_as_output_errors(destination):
        staging.mkdir(mode=0o777)
    return staging


def claim_of(staging: Path) -> Path:
    """The lock file a run holds (``flock``) for as long as its staging folder ``staging`` is its own."""
    return staging.with_name(staging.name + CLAIM_SUFFIX)


def remove_abandoned_staging(destination: str | Path) -> list[Path]:
    """Delete the staging folders of ``destination`` that runs killed outright (SIGKILL, the OOM killer, a
    lost node) left beside it, and return them.

    A staging folder is abandoned when its claim (:func:`claim_of`) is no longer held: the OS releases a
    ``flock`` when its process dies, on this host or, on a network filesystem, on another. A folder whose
    claim is held, or which has no claim (not made by :func:`build_folder`), is left alone; a claim no longer
    held whose folder is gone (a run killed just before making it or just after publishing it) is deleted."""
    destination = Path(os.path.abspath(destination))
    removed = []
    with os_errors_as_output_errors(destination.parent):
        names = os.listdir(destination.parent) if destination.parent.is_dir() else []
    for name in names:
        staging = destination.parent / name.removesuffix(CLAIM_SUFFIX)
        if not name.endswith(CLAIM_SUFFIX) or partial_of(staging.name) != destination.name:
            continue
        try:
            descriptor = os.open(claim_of(staging), os.O_RDWR)  # never created here: a vanished claim is a finished run
        except FileNotFoundError:
            continue
        try:
            try:
                fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                continue  # held: its run is alive
            if staging.is_dir() and not staging.is_symlink():
                remove_folder(staging)
                removed.append(staging)
            claim_of(staging).unlink(missing_ok=True)
        finally:
            os.close(descriptor)
    return removed


def build_folder(destination: str | Path, build: Callable[[Path], T],
                 seen: Snapshot | None | Literal["now"] = "now") -> tuple[Path, T]:
    """Build the folder ``destination`` atomically: ``build`` fills a staging folder beside it
    (:func:`staging_folder`), which then replaces it (:func:`publish`); on a failure or an interrupt
    the staging folder is removed and ``destination`` is left as it was.

    The run holds a claim on its staging folder while it works (:func:`claim_of`), taken before the folder
    is made and given up after it is gone, so the staging folder of a run killed outright is recognised as
    abandoned and deleted by the next build of the same destination (:func:`remove_abandoned_staging`).

    ``seen`` is what the command saw at ``destination`` when it checked it at its start
    (:func:`snapshot`; None: nothing); publishing refuses a destination that has changed since.
    Returns the published folder and what ``build`` returned. The caller has checked that
    ``destination`` may be replaced (``build`` may check again before it returns)."""
    if seen == "now":
        seen = snapshot(destination)
    destination = Path(os.path.abspath(destination))
    make_folder(destination.parent)
    remove_abandoned_staging(destination)
    staging, descriptor = _claim_staging(destination)
    try:
        try:
            _make_staging(staging, destination)
            with errors_name_files_under(destination, staging):
                built = build(staging)
            return publish(staging, destination, seen), built
        except BaseException:
            remove_folder(staging)
            raise
    finally:
        claim_of(staging).unlink(missing_ok=True)
        os.close(descriptor)


def _claim_staging(destination: Path) -> tuple[Path, int]:
    """A new staging name for ``destination`` and the descriptor of its claim, held.

    Another run's :func:`remove_abandoned_staging` may lock and delete a claim between its creation and
    its locking here; a claim that lost its name that way is dropped and a new one made."""
    while True:
        staging = partial_name(destination)
        with os_errors_as_output_errors(destination):
            descriptor = os.open(claim_of(staging), os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        if os.fstat(descriptor).st_nlink:
            return staging, descriptor
        os.close(descriptor)


@contextmanager
def errors_name_files_under(out: Path, staging: Path) -> Iterator[None]:
    """Write errors name the file under ``out``, not under the staging folder.

    The staging folder is removed before the user reads the message, and ``out`` is the path
    they gave. Any OSError under the staging folder (or naming no file) the writers did not
    convert becomes an OutputError here too.
    """
    try:
        yield
    except OutputError as error:
        raise OutputError(str(error).replace(str(staging), str(out))) from None
    except OSError as error:
        if error.filename is not None and not str(error.filename).startswith(str(staging)):
            raise  # an input's (a picture the report embeds): the command's OS-error line names it
        where = str(error.filename or staging).replace(str(staging), str(out))
        raise OutputError(f"cannot write {describe_os_error(error, where)}") from None


Snapshot = frozenset
"""What was at a path (:func:`snapshot`): a frozenset of (relative path, kind, inode, size, mtime) entries."""


def snapshot(path: str | Path) -> Snapshot | None:
    """Every entry at and under ``path`` as (path relative to it, kind, inode, size, modification time), links
    not followed; None when nothing is there. Two snapshots differ when anything was added, removed,
    replaced or written to in between, whatever its name."""
    path = Path(os.path.abspath(path))
    if not os.path.lexists(path):
        return None
    status = path.lstat()
    if not stat.S_ISDIR(status.st_mode):
        return frozenset({(".", stat.S_IFMT(status.st_mode), status.st_ino, status.st_size, status.st_mtime_ns)})
    entries = set()
    pending = [(path, "")]
    while pending:
        folder, prefix = pending.pop()
        entries.add((prefix or ".", stat.S_IFDIR, folder.lstat().st_ino, 0, 0))
        with os.scandir(folder) as listing:
            for entry in listing:
                name = f"{prefix}/{entry.name}" if prefix else entry.name
                if entry.is_dir(follow_symlinks=False):
                    pending.append((Path(entry.path), name))
                else:
                    info = entry.stat(follow_symlinks=False)
                    entries.add((name, stat.S_IFMT(info.st_mode), info.st_ino, info.st_size, info.st_mtime_ns))
    return frozenset(entries)


class DestinationChangedError(OutputExistsError):
    """The destination of a publish changed while the command worked: nothing of it was touched."""


def _changed(destination: Path) -> DestinationChangedError:
    return DestinationChangedError(
        f"{destination} changed while this run worked (another run, or someone, wrote there): it is left as it is "
        "and this run's output was discarded; check what is there, then rerun or choose another --out")


RENAME_NOREPLACE, RENAME_EXCHANGE = 1, 2  # renameat2(2)'s flags (Linux)
_AT_FDCWD = -100


def _renameat2(source: Path, target: Path, flags: int) -> bool:
    """``renameat2(source, target, flags)``: True when done; False where the C library or the filesystem
    lacks it (the caller falls back); an OSError for anything else (EEXIST: the target is there)."""
    import ctypes

    try:
        function = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    function.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    if function(_AT_FDCWD, os.fsencode(source), _AT_FDCWD, os.fsencode(target), flags) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(code, os.strerror(code), str(target))


def publish(staging: Path, destination: str | Path, seen: Snapshot | None) -> Path:
    """Move a finished ``staging`` folder to ``destination``, provided ``destination`` still holds exactly what
    the command saw at its start (``seen``, :func:`snapshot`; None: nothing).

    Checked in the same step as the move where the OS allows (Linux's renameat2): a destination that was
    absent is taken only if it still is (RENAME_NOREPLACE); one that was there is exchanged with the staging
    folder in one step (RENAME_EXCHANGE) and, when what comes out is not what was seen, exchanged back.
    So a folder a user made meanwhile, or another run's output, is never deleted: two runs racing for one
    ``--out`` end with one published and one :class:`DestinationChangedError`, nothing lost. Elsewhere
    the destination is compared just before the moves. A destination seen but gone since is taken as
    absent (nothing of anyone's is there). The old folder is deleted last (:func:`_delete`).
    """
    destination = Path(os.path.abspath(destination))
    with os_errors_as_output_errors(destination):
        if seen is None or not os.path.lexists(destination):  # nothing to replace: taken only while it is so
            if not _move_unless_there(staging, destination):
                raise _changed(destination)
            return destination
        if not stat.S_ISDIR(os.lstat(destination).st_mode):  # a folder replaces a folder, never a file or a link
            raise OutputExistsError(f"{destination}: exists and is not a folder (a file, or a link); choose "
                                    "another --out")
        if _renameat2(staging, destination, RENAME_EXCHANGE):
            old = staging  # the staging folder's name now holds the destination's earlier content
            try:
                unchanged = snapshot(old) == seen
            except BaseException:  # an interrupt before the check: put back, the caller deletes its staging
                unchanged = False
                raise
            finally:
                if not unchanged:
                    _renameat2(staging, destination, RENAME_EXCHANGE)
            if not unchanged:
                raise _changed(destination)
        else:
            if snapshot(destination) != seen:
                raise _changed(destination)
            old = destination.with_name(f".{destination.name}.{os.getpid()}.{secrets.token_hex(4)}.replaced")
            os.replace(destination, old)
            try:
                os.replace(staging, destination)
            except BaseException:  # an interrupt between the two renames: the old folder goes back
                if not destination.exists():
                    os.replace(old, destination)
                raise
    _delete(old)
    return destination


def _move_unless_there(source: Path, target: Path) -> bool:
    """Rename ``source`` to ``target`` unless something is at ``target`` (then False), in one step where the
    OS allows (a plain rename would replace an empty folder made meanwhile)."""
    try:
        if _renameat2(source, target, RENAME_NOREPLACE):
            return True
    except OSError as error:
        if error.errno in (errno.EEXIST, errno.ENOTEMPTY):
            return False
        raise
    if os.path.lexists(target):
        return False
    os.rename(source, target)
    return True


def _delete(old: Path) -> None:
    """Delete the replaced folder, even when an interrupt lands during the deletion (a hidden copy of a whole
    dataset had been left behind): renamed aside, it is no one's now."""
    try:
        remove_folder(old) if old.is_dir() and not old.is_symlink() else old.unlink(missing_ok=True)
    except BaseException:
        remove_folder(old) if old.is_dir() and not old.is_symlink() else old.unlink(missing_ok=True)
        raise


def publish_folder(staging: Path, destination: str | Path) -> Path:
    """Move a finished ``staging`` folder to ``destination``, replacing what is there now (:func:`publish`
    with what is there as what was seen: for a caller that checked ``destination`` just before)."""
    return publish(staging, destination, snapshot(destination))


def remove_folder(path: Path) -> None:
    """Delete a folder this run created (a staging folder); missing is fine."""
    shutil.rmtree(path, ignore_errors=True)


def first_foreign_file(folder: Path, is_own: Callable[[Path], bool]) -> Path | None:
    """The first entry of ``folder`` (by name) that is not a plain file ``is_own`` accepts (a link
    or a folder never is), or None: what ``--overwrite`` must not delete with the folder."""
    return next((entry for entry in sorted(folder.iterdir())
                 if entry.is_symlink() or not entry.is_file() or not is_own(entry)), None)


def is_inside_working_folder(path: str | Path) -> bool:
    """Whether ``path`` is the current folder or one of its parents (never replace those)."""
    target = Path(os.path.abspath(path))
    here = Path.cwd()
    return target == here or target in here.parents


# --------------------------------------------------------------------------- locks


class FolderBusyError(SianmsError):
    """Another process holds the lock this run needs."""


def _open_lock_file(lock_path: Path) -> int:
    """A descriptor of the lock file, created (umask permissions) with its folder if needed."""
    make_folder(lock_path.parent)
    with os_errors_as_output_errors(lock_path):
        return os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o666)


@contextmanager
def exclusive_lock(lock_path: str | Path, *, what: str, blocking: bool = False) -> Iterator[None]:
    """Hold an advisory lock (``flock``) on ``lock_path`` for the block.

    Held by a process, released by the OS when the process ends however it ends, so a killed
    run never leaves a stale lock. With ``blocking`` false a held lock raises
    :class:`FolderBusyError` naming ``what`` and the holder's pid.
    """
    lock_path = Path(lock_path)
    made_folder, made_file = not lock_path.parent.is_dir(), not lock_path.exists()
    try:
        descriptor = _open_lock_file(lock_path)
    except OutputError:
        _remove_made(lock_path, made_file, made_folder)
        raise
    try:
        try:
            _take_lock(descriptor, lock_path, what, blocking)
        except OutputError:  # a full disk, not a busy folder: what this call made is all there is
            _remove_made(lock_path, made_file, made_folder)
            raise
        yield
    finally:
        os.close(descriptor)


def _take_lock(descriptor: int, lock_path: Path, what: str, blocking: bool) -> None:
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
    except OSError as error:
        if error.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise OutputError(f"cannot lock {describe_os_error(error, lock_path)}") from None
        holder = os.pread(descriptor, 32, 0).decode(errors="replace").strip() or "unknown"
        raise FolderBusyError(f"{what} is in use by another sianms process (pid {holder})") from None
    with os_errors_as_output_errors(lock_path):
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, f"{os.getpid()}\n".encode(), 0)


def _remove_made(lock_path: Path, made_file: bool, made_folder: bool) -> None:
    """Undo a lock that was never taken: its file, and its folder if still empty."""
    with suppress(OSError):
        if made_file:
            lock_path.unlink(missing_ok=True)
        if made_folder:
            lock_path.parent.rmdir()


def try_lock(lock_path: str | Path) -> int | None:
    """Take a non-blocking ``flock`` on ``lock_path``: its descriptor, or None when held.

    Release with :func:`release_lock`. For work items several runs share (cache shards).
    """
    descriptor = _open_lock_file(Path(lock_path))
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(descriptor)
        return None
    return descriptor


def release_lock(descriptor: int) -> None:
    os.close(descriptor)
