"""The package keeps its layers and has no import cycles; benchmarks and scripts use the library, not the CLI;
no name is undefined and no import unused.

The layers are declared in pyproject.toml ([tool.importlinter]) and checked with import-linter.
"""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_import_contracts_are_kept():
    lint = Path(sys.executable).parent / "lint-imports"
    res = subprocess.run([str(lint), "--config", str(ROOT / "pyproject.toml"), "--no-cache"], cwd=ROOT,
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]
    assert "2 kept, 0 broken" in res.stdout


def test_no_undefined_name_unused_import_or_syntax_error():
    # pyflakes' checks (F) and syntax errors (E9), as ruff runs them, over every Python file of the repository
    ruff = Path(sys.executable).parent / "ruff"
    res = subprocess.run([str(ruff), "check", "--no-cache", "--select", "F,E9", "featmap", "tests", "scripts",
                          "benchmarks"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-2000:]


def test_benchmarks_and_scripts_do_not_import_the_command_line():
    for path in sorted((ROOT / "benchmarks").glob("*.py")) + sorted((ROOT / "scripts").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not any(n == "featmap.cli" or n.startswith("featmap.cli.") for n in names), path


def test_the_library_never_prints():
    """Only the command line's modules write to the terminal; the library reports through a Reporter."""
    allowed = {"cli.py", "console.py"}
    for path in sorted((ROOT / "featmap").rglob("*.py")):
        if path.name in allowed:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "print":
                raise AssertionError(f"{path.relative_to(ROOT)}:{node.lineno} prints")
