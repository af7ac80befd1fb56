"""Marked blocks in Markdown files: the tables the README quotes from docs/, kept identical.

A block is ``<!-- table:NAME -->`` ... ``<!-- /table -->``. Scripts that measure something write their
block into their docs page (:func:`replace_block`); ``python scripts/doc_blocks.py`` copies every block
of docs/*.md into README.md where the README has a block of that name (the README chooses which tables it
shows). tests/test_docs.py fails when a README block differs from its docs page's.

    .venv/bin/python scripts/doc_blocks.py          # sync README.md from docs/*.md
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"<!-- table:(?P<name>[\w-]+) -->\n(?P<body>.*?)<!-- /table -->", re.S)


def blocks(text: str) -> dict[str, str]:
    """name -> body of every block in ``text``."""
    return {m.group("name"): m.group("body") for m in BLOCK.finditer(text)}


def replace_block(path: Path, name: str, body: str) -> None:
    """Set block ``name`` of the file at ``path`` to ``body`` (appended at the end when missing)."""
    body = body.rstrip("\n") + "\n"
    text = path.read_text() if path.exists() else ""
    new = f"<!-- table:{name} -->\n{body}<!-- /table -->"
    if name in blocks(text):
        text = BLOCK.sub(lambda m: new if m.group("name") == name else m.group(0), text)
    else:
        text = text.rstrip("\n") + ("\n\n" if text else "") + new + "\n"
    path.write_text(text)


def rich_table_markdown(table) -> str:
    """A rich ``Table`` (as a benchmark prints it) as a Markdown table, its title above in italics."""
    from rich.text import Text

    from featmap.io.markdown import markdown_table

    header = [Text.from_markup(str(c.header)).plain for c in table.columns]
    columns = [[Text.from_markup(str(cell)).plain if isinstance(cell, str) else str(cell) for cell in c.cells]
               for c in table.columns]
    rows = [list(row) for row in zip(*columns)]
    title = f"*{Text.from_markup(str(table.title)).plain}*\n\n" if table.title else ""
    return title + markdown_table(header, rows)


def write_tables(path: Path, prefix: str, tables: list, note: str = "") -> list[str]:
    """Write each rich table into block ``<prefix>_<k>`` of ``path`` (``note`` above the first); the names."""
    names = []
    for k, table in enumerate(tables):
        name = f"{prefix}_{k + 1}"
        replace_block(path, name, (note + "\n\n" if note and k == 0 else "") + rich_table_markdown(table))
        names.append(name)
    return names


def doc_blocks(root: Path = ROOT) -> dict[str, tuple[Path, str]]:
    """name -> (docs page, body) of every block under docs/."""
    out = {}
    for page in sorted((root / "docs").glob("*.md")):
        for name, body in blocks(page.read_text()).items():
            out[name] = (page, body)
    return out


def sync_readme(root: Path = ROOT) -> list[str]:
    """Copy every docs block into README.md where the README has it; returns the names copied."""
    readme = root / "README.md"
    text = readme.read_text()
    found = doc_blocks(root)
    names = [n for n in blocks(text) if n in found]
    for name in names:
        text = BLOCK.sub(lambda m: f"<!-- table:{name} -->\n{found[name][1]}<!-- /table -->"
                         if m.group("name") == name else m.group(0), text)
    readme.write_text(text)
    return names


if __name__ == "__main__":
    copied = sync_readme()
    print(f"README.md: {len(copied)} block(s) copied from docs/: {', '.join(copied) or '-'}")
    sys.exit(0)
