"""Reading JSON files with one-line errors that name the file (and the line for syntax errors)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from featmap.errors import InputFileError, shown

Model = TypeVar("Model", bound=BaseModel)


def read_json(path: str | Path, missing: str = "file not found") -> Any:
    """Parse the JSON file at ``path``; ``missing`` is the message when it does not exist.

    ``NaN``, ``Infinity`` and ``-Infinity`` (which Python's json module accepts but JSON does not have) are a
    one-line error naming the file and the constant, so no non-finite number gets past the reader."""
    path = Path(path)
    try:
        return json.loads(path.read_text(), parse_constant=lambda constant: _not_finite(path, constant),
                          parse_float=lambda text: _finite_float(path, text))
    except FileNotFoundError:
        raise InputFileError(path, missing) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(path, f"cannot read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise InputFileError(path, f"not valid JSON ({exc.msg})", line=exc.lineno) from None
    except RecursionError:
        raise InputFileError(path, "not valid JSON (nested too deeply)") from None
    except ValueError as exc:           # an integer of more digits than Python converts
        raise InputFileError(path, f"not valid JSON ({exc})") from None


def _not_finite(path: Path, constant: str):
    raise InputFileError(path, f"not valid JSON ({constant} is not a finite number)")


def _finite_float(path: Path, text: str) -> float:
    value = float(text)
    if not math.isfinite(value):            # 1e400: beyond a double, read as inf
        raise InputFileError(path, f"not valid JSON ({shown(text)} is beyond the range of a number)")
    return value


def validate_record(path: str | Path, data: Any, model: type[Model], what: str) -> Model:
    """``data`` (read from the file at ``path``) as a ``model``; else a one-line error naming the file, the
    first offending key and what is wrong: ``not a featmap {what}: 'key' message``."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        if not where:                           # a check of the whole record: its own message
            raise InputFileError(Path(path), f"not a featmap {what}: {err['msg'].removeprefix('Value error, ')}") from None
        raise InputFileError(Path(path), f"not a featmap {what}: '{where}' {err['msg'].lower()}") from None
