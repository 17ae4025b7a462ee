"""Errors a user can cause and fix.

Every error raised for bad input is a :class:`SianmsError`; the CLI prints its message
on one line and exits with code 2, never a traceback. Our own invariants use ``assert``.
"""

from __future__ import annotations

from pathlib import Path


class SianmsError(Exception):
    """Bad input or a refused operation, described so the user can act on it."""

    exit_code = 2


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
        if token is not None:
            where.append(f"record {token}")
        if field is not None:
            where.append(f"field '{field}'")
        super().__init__(": ".join(where) + f": {message}")


class OutputExistsError(SianmsError):
    """A command was asked to write where finished outputs already exist."""
