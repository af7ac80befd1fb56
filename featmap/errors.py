"""One exception hierarchy for everything featmap reports to users.

The CLI catches :class:`FeatmapError` and prints ``str(error)`` on one line; every message names the
file, flag or config key to fix. Anything else that escapes is a bug and keeps its traceback.
"""

from __future__ import annotations

import reprlib

_SHOWN = reprlib.Repr()
_SHOWN.maxlevel, _SHOWN.maxstring, _SHOWN.maxother, _SHOWN.maxlong = 2, 60, 60, 40
_SHOWN.maxlist = _SHOWN.maxtuple = _SHOWN.maxdict = _SHOWN.maxset = _SHOWN.maxfrozenset = 4

class FeatmapError(Exception):
    """Base class of all errors featmap reports to users as one line."""


class ConfigError(FeatmapError):
    """An invalid configuration value, an unknown key or a bad ``--set`` override."""


class InputFileError(FeatmapError):
    """A malformed input file (segments CSV, world file, GeoJSON, ...)."""

    def __init__(self, path, message: str, line: int | None = None):
        where = f"{path}" if line is None else f"{path}:{line}"
        super().__init__(f"{where}: {message}")
        self.path = path
        self.line = line


class DatasetError(FeatmapError):
    """A KITTI raw drive that is missing, truncated or malformed."""


class WorldError(FeatmapError):
    """An invalid simulator world file."""


class DownloadError(FeatmapError):
    """A failed or unverifiable download."""


def shown(value) -> str:
    """``repr(value)`` cut short for an error message (at most 60 characters per item, four items per
    container and two levels, each cut marked ``...``): a value read from a user's file can be any size, YAML aliases
    can make it exponentially large, and the message stays one short line."""
    return _SHOWN.repr(value)
