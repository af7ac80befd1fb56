"""How the library tells the user what it is doing, without printing: a :class:`Reporter` passed in.

The library calls ``reporter.progress(...)``, ``info``, ``warning`` and ``table``; the command line
passes a reporter that draws rich progress bars and tables (:mod:`featmap.console`), tests and
batch workers pass :class:`NullReporter` or :class:`RecordingReporter`.
"""

from __future__ import annotations

import contextlib
from typing import Callable, ContextManager, Iterable, Iterator, Protocol, TypeVar

T = TypeVar("T")


class Reporter(Protocol):
    def progress(self, description: str, total: int | None) -> ContextManager[Callable[[int], None]]:
        """A context whose value advances the bar by a number of finished items."""
        ...

    def info(self, text: str) -> None: ...

    def warning(self, text: str) -> None: ...

    def table(self, title: str, columns: list[str], rows: list[list[str]]) -> None: ...


class NullReporter:
    """Reports nothing."""

    @contextlib.contextmanager
    def progress(self, description: str, total: int | None) -> Iterator[Callable[[int], None]]:
        yield lambda n=1: None

    def info(self, text: str) -> None:
        pass

    def warning(self, text: str) -> None:
        pass

    def table(self, title: str, columns: list[str], rows: list[list[str]]) -> None:
        pass


class RecordingReporter(NullReporter):
    """Keeps every message and table (for tests and for summaries written to files)."""

    def __init__(self) -> None:
        self.infos: list[str] = []
        self.warnings: list[str] = []
        self.tables: list[tuple[str, list[str], list[list[str]]]] = []

    def info(self, text: str) -> None:
        self.infos.append(text)

    def warning(self, text: str) -> None:
        self.warnings.append(text)

    def table(self, title: str, columns: list[str], rows: list[list[str]]) -> None:
        self.tables.append((title, columns, rows))


def track(reporter: Reporter, iterable: Iterable[T], total: int | None, description: str) -> Iterator[T]:
    """Iterate ``iterable`` while advancing a progress bar of ``reporter``."""
    with reporter.progress(description, total) as advance:
        for item in iterable:
            yield item
            advance(1)
