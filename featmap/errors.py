"""One exception hierarchy for everything featmap reports to users.

The CLI catches :class:`FeatmapError` and prints ``str(error)`` on one line; every message names the
file, flag or config key to fix. Anything else that escapes is a bug and keeps its traceback.
"""

from __future__ import annotations


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
