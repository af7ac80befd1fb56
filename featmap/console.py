"""The command line's reporter: rich progress bars, tables and one-line messages on the terminal."""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Callable, Iterator


class RichReporter:
    """Draws progress bars and tables with rich; warnings go to stderr as ``featmap: warning: ...``."""

    def __init__(self) -> None:
        from rich.console import Console

        self.console = Console(highlight=False, width=None if os.isatty(1) else 140)

    @contextlib.contextmanager
    def progress(self, description: str, total: int | None) -> Iterator[Callable[[int], None]]:
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                   TimeRemainingColumn)

        columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                   TextColumn("eta"), TimeRemainingColumn())
        with Progress(*columns, console=self.console, transient=False) as progress:
            task = progress.add_task(description, total=total)
            yield lambda n=1: progress.advance(task, n)

    def info(self, text: str) -> None:
        self.console.print(text, markup=False)

    def warning(self, text: str) -> None:
        print(f"featmap: warning: {text}", file=sys.stderr)

    def table(self, title: str, columns: list[str], rows: list[list[str]]) -> None:
        from rich.table import Table

        table = Table(title=title)
        for i, col in enumerate(columns):
            table.add_column(col, justify="left" if i == 0 else "right")
        for row in rows:
            table.add_row(*row)
        self.console.print(table)
