"""Markdown tables (for comparison.md, docs/results.md and benchmark reports)."""

from __future__ import annotations

from typing import Any, Sequence


def format_cell(value: Any, digits: int = 4) -> str:
    """A cell's text: ``-`` for None, floats with ``digits`` decimals (one decimal from 10 up)."""
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}" if abs(value) < 10 else f"{value:.1f}"
    return str(value)


def markdown_table(header: Sequence[str], rows: Sequence[Sequence[Any]], digits: int = 4) -> str:
    """A GitHub-flavoured Markdown table (no trailing newline); strings are written as they are."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(format_cell(v, digits) for v in row) + " |" for row in rows]
    return "\n".join(lines)
