"""Reading JSON files with one-line errors that name the file (and the line for syntax errors)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from featmap.errors import InputFileError


def read_json(path: str | Path, missing: str = "file not found") -> Any:
    """Parse the JSON file at ``path``; ``missing`` is the message when it does not exist."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputFileError(path, missing) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise InputFileError(path, f"not valid JSON ({exc.msg})", line=exc.lineno) from None
