"""Loading the repository's scripts and benchmarks (files, not packages) as modules in tests."""

from __future__ import annotations

import importlib.util
import sys
from contextlib import contextmanager
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


@contextmanager
def repo_script(relative_path: str):
    """The module of ``ROOT / relative_path``, registered in ``sys.modules`` under its stem while in use (a
    dataclass looks its module up there while it is made)."""
    path = ROOT / relative_path
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module
    try:
        spec.loader.exec_module(module)
        yield module
    finally:
        del sys.modules[path.stem]
