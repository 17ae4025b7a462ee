"""How a long library call reports progress without knowing who shows it.

The library takes a :class:`Progress` and calls :meth:`~Progress.start` once it knows how
much work there is, then :meth:`~Progress.advance` as it goes. The CLI passes one that draws
a tqdm bar (``cli/_app.py``); tests and other callers pass nothing and get :data:`SILENT`.
"""

from __future__ import annotations

from typing import Protocol


class Progress(Protocol):
    def start(self, total: float, unit: str, description: str) -> None:
        """The work ahead: ``total`` units named ``unit``."""

    def advance(self, amount: float = 1) -> None:
        """``amount`` more units are done."""


class _Silent:
    def start(self, total: float, unit: str, description: str) -> None:
        pass

    def advance(self, amount: float = 1) -> None:
        pass


SILENT: Progress = _Silent()
