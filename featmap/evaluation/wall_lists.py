"""Eye-checked wall lists of single scans, and how one scan's extraction scores against them.

A wall list (a YAML file, see ``tests/extraction/real_scan_walls.yaml``) gives, per scan and in the
scan's own (velodyne) frame, the walls a reader can see (each must be found), optional structure (a
segment on it is fine either way), clutter boxes (cars, hedges, trees: no segment may lie in one) and
how many segments may lie on nothing listed. Scoring is pure numpy: segments in, a
:class:`WallListScore` out.

A wall is *matched* when the segments lying on it cover at least ``min_coverage`` of it, with its
ends shortened by ``tolerance_m`` (its endpoints are approximate). A segment *lies on* a listed line
when at least half of its length is within ``tolerance_m`` of it (and of its extent) at most 10 deg
away in direction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from featmap.config import InvalidYamlError, load_yaml_text
from featmap.errors import InputFileError
from featmap.evaluation.truth_metrics import lies_on

STEP_M = 0.10
ANGLE_DEG = 10.0


@dataclass(frozen=True)
class ListedLine:
    """A wall drawn by eye: ``p``, ``q`` (2,) endpoints (metres, the scan's frame); ``known_miss``:
    why the current extractor does not find it (empty when it should)."""

    name: str
    p: np.ndarray
    q: np.ndarray
    known_miss: str = ""

    @property
    def segment(self) -> np.ndarray:
        return np.concatenate([self.p, self.q])

    @property
    def length(self) -> float:
        return float(np.hypot(*(self.q - self.p)))


@dataclass(frozen=True)
class ScanWallList:
    """What can be seen in one scan: required walls, optional structure, clutter boxes (K, 4) ``x0 x1 y0 y1``,
    how many segments may lie on nothing listed, and (``known_clutter``) why the current extractor
    still puts a segment in a clutter box (empty when it should not)."""

    walls: list[ListedLine]
    optional: list[ListedLine] = field(default_factory=list)
    clutter_names: list[str] = field(default_factory=list)
    clutter: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    max_unlisted: int = 0
    known_clutter: str = ""


@dataclass(frozen=True)
class WallLists:
    """Every scan's list (keyed by the scan's path relative to the data root) and the matching rule."""

    scans: dict[str, ScanWallList]
    tolerance_m: float = 0.5
    min_coverage: float = 0.9


@dataclass(frozen=True)
class WallListScore:
    """How one scan's segments (K, 4) compare with its list.

    Attributes:
        coverage: (W,) share of each required wall (ends shortened by the tolerance) that segments cover.
        found: (W,) coverage >= min_coverage.
        status: (K,) per segment: "wall", "optional", "clutter" (lies in a clutter box) or "unlisted".
        on_wall: (K,) index of the listed line (walls first, then optional) the segment lies on, or -1.
    """

    coverage: np.ndarray
    found: np.ndarray
    status: np.ndarray
    on_wall: np.ndarray

    @property
    def n_clutter(self) -> int:
        return int((self.status == "clutter").sum())

    @property
    def n_unlisted(self) -> int:
        return int((self.status == "unlisted").sum())


def _samples(segment: np.ndarray, step: float = STEP_M) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` along a (4,) segment (both ends included) and its unit direction (2,)."""
    p, q = segment[:2], segment[2:]
    length = float(np.hypot(*(q - p)))
    n = max(2, int(np.ceil(length / step)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    direction = (q - p) / length if length > 0 else np.array([1.0, 0.0])
    return p + t * (q - p), direction


def _shortened(line: ListedLine, by: float) -> np.ndarray:
    """(4,) the listed line with ``by`` cut off both ends (at most 40 % of it from each end)."""
    cut = min(by, 0.4 * line.length)
    u = (line.q - line.p) / line.length
    return np.concatenate([line.p + cut * u, line.q - cut * u])


def _share_on(pts: np.ndarray, direction: np.ndarray, line: ListedLine, tolerance_m: float) -> float:
    """The share of a segment's samples ``pts`` (S, 2) (direction (2,)) that lie on the listed ``line``."""
    ok, _ = lies_on(pts, np.tile(direction, (len(pts), 1)), line.segment, tolerance_m, ANGLE_DEG)
    return float(ok.mean())


def lying_on(segments: np.ndarray, line: ListedLine, tolerance_m: float = 0.5) -> np.ndarray:
    """(K,) True for the (K, 4) ``segments`` that lie on the listed ``line`` (at least half of each, as
    :func:`score_wall_list` places a segment on a wall)."""
    segments = np.asarray(segments, float).reshape(-1, 4)
    return np.array([_share_on(*_samples(seg), line, tolerance_m) >= 0.5 for seg in segments], dtype=bool)


def score_wall_list(segments: np.ndarray, wall_list: ScanWallList, tolerance_m: float = 0.5,
                    min_coverage: float = 0.9) -> WallListScore:
    """Score (K, 4) segments (the scan's frame) against ``wall_list``; see the module docstring."""
    segments = np.asarray(segments, float).reshape(-1, 4)
    listed = list(wall_list.walls) + list(wall_list.optional)
    coverage = np.zeros(len(wall_list.walls))
    for w, line in enumerate(wall_list.walls):
        pts, direction = _samples(_shortened(line, tolerance_m))
        covered = np.zeros(len(pts), bool)
        for seg in segments:
            ok, _ = lies_on(pts, np.tile(direction, (len(pts), 1)), seg, tolerance_m, ANGLE_DEG)
            covered |= ok
        coverage[w] = covered.mean()
    status = np.full(len(segments), "unlisted", dtype=object)
    on_wall = np.full(len(segments), -1)
    for k, seg in enumerate(segments):
        pts, direction = _samples(seg)
        best = 0.0
        for w, line in enumerate(listed):
            share = _share_on(pts, direction, line, tolerance_m)
            if share >= 0.5 and share > best:
                best, on_wall[k] = share, w
        if on_wall[k] >= 0:
            status[k] = "wall" if on_wall[k] < len(wall_list.walls) else "optional"
            continue
        box = wall_list.clutter
        inside = ((pts[:, None, 0] >= box[None, :, 0]) & (pts[:, None, 0] <= box[None, :, 1])
                  & (pts[:, None, 1] >= box[None, :, 2]) & (pts[:, None, 1] <= box[None, :, 3]))
        if len(box) and inside.mean(axis=0).max() >= 0.5:
            status[k] = "clutter"
    return WallListScore(coverage=coverage, found=coverage >= min_coverage, status=status.astype(str),
                         on_wall=on_wall)


# --- reading ----------------------------------------------------------------------------------------

def _line(raw, path: Path, where: str) -> ListedLine:
    try:
        p, q = np.asarray(raw["p"], float), np.asarray(raw["q"], float)
        if p.shape != (2,) or q.shape != (2,) or not (np.isfinite(p).all() and np.isfinite(q).all()):
            raise ValueError
        if np.hypot(*(q - p)) == 0:
            raise ValueError
    except (KeyError, TypeError, ValueError):
        raise InputFileError(path, f"{where}: expected {{name, p: [x, y], q: [x, y]}} with p != q, got {raw!r}") from None
    return ListedLine(str(raw.get("name", where)), p, q, str(raw.get("known_miss", "")))


def read_wall_lists(path: str | Path) -> WallLists:
    """Read a wall-list YAML file; a one-line InputFileError naming the file and entry when malformed."""
    path = Path(path)
    try:
        data = load_yaml_text(path.read_text(), str(path))   # strict as a config file: a key given twice is an error
    except FileNotFoundError:
        raise InputFileError(path, "wall list not found") from None
    except InvalidYamlError as exc:
        raise InputFileError(path, f"not valid YAML ({exc.problem})", exc.line) from None
    if not isinstance(data, dict) or not isinstance(data.get("scans"), dict):
        raise InputFileError(path, "expected a mapping with 'scans: {scan path: {walls, optional, clutter, max_unlisted}}'")
    scans = {}
    for name, entry in data["scans"].items():
        if not isinstance(entry, dict):
            raise InputFileError(path, f"scan {name!r}: expected a mapping")
        walls = [_line(w, path, f"scan {name!r} wall #{k}") for k, w in enumerate(entry.get("walls") or [])]
        optional = [_line(w, path, f"scan {name!r} optional #{k}") for k, w in enumerate(entry.get("optional") or [])]
        names, boxes = [], []
        for k, c in enumerate(entry.get("clutter") or []):
            box = np.asarray(c.get("box", []) if isinstance(c, dict) else [], float)
            if box.shape != (4,) or box[0] >= box[1] or box[2] >= box[3]:
                raise InputFileError(path, f"scan {name!r} clutter #{k}: expected box [x_min, x_max, y_min, y_max], got {c!r}")
            names.append(str(c.get("name", f"clutter #{k}")))
            boxes.append(box)
        scans[str(name)] = ScanWallList(walls, optional, names, np.asarray(boxes, float).reshape(-1, 4),
                                        int(entry.get("max_unlisted", 0)), str(entry.get("known_clutter", "")))
    return WallLists(scans, float(data.get("tolerance_m", 0.5)), float(data.get("min_coverage", 0.9)))
