"""The README's result tables are the ones the scripts wrote into docs/ (no stale copy)."""

import pytest

from tests.repo_scripts import ROOT, repo_script


@pytest.fixture(scope="module")
def db():
    with repo_script("scripts/doc_blocks.py") as module:
        yield module


def test_every_readme_table_matches_its_docs_page(db):
    readme = db.blocks((ROOT / "README.md").read_text())
    docs = db.doc_blocks(ROOT)
    for name, body in readme.items():
        assert name in docs, f"README table '{name}' has no docs page block (run its script)"
        page, expected = docs[name]
        assert body == expected, f"README table '{name}' differs from {page.name}: run scripts/doc_blocks.py"


def test_block_round_trip(db, tmp_path):
    (tmp_path / "docs").mkdir()
    page = tmp_path / "docs" / "r.md"
    db.replace_block(page, "t", "| a |\n|---|\n| 1 |")
    db.replace_block(page, "t", "| a |\n|---|\n| 2 |")
    assert db.blocks(page.read_text()) == {"t": "| a |\n|---|\n| 2 |\n"}
    (tmp_path / "README.md").write_text("x\n<!-- table:t -->\nold\n<!-- /table -->\ny\n")
    assert db.sync_readme(tmp_path) == ["t"]
    assert (tmp_path / "README.md").read_text() == "x\n<!-- table:t -->\n| a |\n|---|\n| 2 |\n<!-- /table -->\ny\n"
