"""What segments lie on when they lie on no building wall: the simulator's objects, by kind.

The simulated counterpart of the real scans' *segments on clutter* (``docs/real_scans.md``, where a
segment on a hedge, a car or a tree is counted by eye): a simulated drive knows every object it holds
(``objects_local.json``), so each stretch of a segment that lies on no building wall (the complement of
EVALUATION.md's precision: :func:`featmap.evaluation.truth_metrics.building_samples`) is put down to the
nearest one. Its kind is, in this order:

- ``hedge``, ``fence``, ``car`` or ``pole``: such an object's outline (a hedge's or fence's line, a car's
  four sides, a pole's axis) lies within ``OBJECT_REACH_M``;
- ``tree``: a tree's trunk lies within ``TREE_REACH_M`` (its crown is not in the file; the generator's
  crowns are 1-3 m in radius);
- ``beside a wall``: a building wall lies within ``OBJECT_REACH_M`` (a fit off by more than the precision
  tolerance or turned by more than its angle, or a wall's plane continued past its end);
- ``nothing near``: none of these.

Approximate by design: a hedge under a tree's crown counts as hedge wherever its line is near; a car's
outline is its footprint. Pure functions of arrays and of the objects' records, all in the truth's
local frame (metres).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from featmap.evaluation.truth_metrics import GroundTruth, building_samples

CLUTTER_KINDS = ("hedge", "fence", "car", "pole", "tree", "beside a wall", "nothing near")
"""The kinds of stretch off every building wall, in the order they are tested."""
OBJECT_REACH_M = 1.0
"""A stretch lies on an object (or beside a wall) whose outline is at most this far (metres)."""
TREE_REACH_M = 3.5
"""... and on a tree whose trunk is at most this far (metres): its crown spreads 1-3 m around it."""
SAMPLE_M = 0.1
"""Spacing of the points an object's outline is sampled at (metres)."""


@dataclass(frozen=True)
class ClutterObjects:
    """The simulator's non-building objects as point sets (local frame, metres).

    Attributes:
        points: (P, 2) points along every hedge and fence line and car side (every ``SAMPLE_M``) and at
            every pole's axis.
        kind: (P,) index into ``CLUTTER_KINDS`` of the object each point belongs to.
        trunks: (T, 2) tree trunk positions.
        owner: (P,) and trunk_owner: (T,) index into ``names`` of the object each point or trunk belongs to.
        names: (O,) each object's id (``"<kind> <i>"`` for a record without one).
        object_kind: (O,) each object's kind (index into ``CLUTTER_KINDS``).
        heights: (O,) each object's height (metres; NaN for a record without one, e.g. a tree).
    """

    points: np.ndarray
    kind: np.ndarray
    trunks: np.ndarray
    owner: np.ndarray
    trunk_owner: np.ndarray
    names: tuple[str, ...]
    object_kind: np.ndarray
    heights: np.ndarray

    @classmethod
    def from_records(cls, objects: list[dict]) -> "ClutterObjects":
        """From ``objects_local.json``'s records (``kind``, ``id``, ``height`` and a GeoJSON-like ``geometry``
        in the drive's own local frame, the frame of :func:`~featmap.evaluation.references.load_simulator_truth`
        without ``frame``); buildings and unknown kinds are left out."""
        points, kinds, owners, trunks, trunk_owners, names, object_kind, heights = [], [], [], [], [], [], [], []
        for obj in objects:
            kind, geom = obj.get("kind"), obj.get("geometry") or {}
            if kind in ("hedge", "fence"):
                line = np.asarray(geom["coordinates"], float).reshape(-1, 2)
            elif kind == "car":
                ring = np.asarray(geom["coordinates"][0], float).reshape(-1, 2)
                line = np.vstack([ring, ring[:1]])
            elif kind == "pole":
                line = np.asarray(geom["coordinates"], float).reshape(1, 2)
            elif kind == "tree":
                trunks.append(np.asarray(geom["coordinates"], float).reshape(2))
                trunk_owners.append(len(names))
            else:
                continue
            if kind != "tree":
                dense = _densify(line)
                points.append(dense)
                kinds.append(np.full(len(dense), CLUTTER_KINDS.index(kind)))
                owners.append(np.full(len(dense), len(names)))
            names.append(str(obj.get("id") or f"{kind} {len(names)}"))
            object_kind.append(CLUTTER_KINDS.index(kind))
            heights.append(float(obj.get("height", np.nan)))
        return cls(np.concatenate(points) if points else np.zeros((0, 2)),
                   np.concatenate(kinds) if kinds else np.zeros(0, np.int64),
                   np.asarray(trunks, float).reshape(-1, 2),
                   np.concatenate(owners) if owners else np.zeros(0, np.int64),
                   np.asarray(trunk_owners, np.int64), tuple(names), np.asarray(object_kind, np.int64),
                   np.asarray(heights, float))


def _densify(polyline: np.ndarray, step: float = SAMPLE_M) -> np.ndarray:
    """(Q, 2) points at most ``step`` apart along a (K, 2) polyline, its vertices included."""
    out = [polyline[:1]]
    for a, b in zip(polyline[:-1], polyline[1:]):
        n = max(1, int(np.ceil(np.hypot(*(b - a)) / step)))
        out.append(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    return np.concatenate(out)


@dataclass(frozen=True)
class OffWall:
    """The stretches of K segments that lie on no building wall (S samples), and what each lies on.

    Attributes:
        owner: (S,) the segment of each sample; length: (S,) the segment length each sample stands for
            (metres); kind: (S,) index into ``CLUTTER_KINDS``.
        segment_length: (K,) each segment's length (metres).
        obj: (S,) index into :attr:`ClutterObjects.names` of the object each sample lies on (-1 beside a
            wall or with nothing near).
    """

    owner: np.ndarray
    length: np.ndarray
    kind: np.ndarray
    segment_length: np.ndarray
    obj: np.ndarray

    def metres_by_kind(self) -> np.ndarray:
        """(len(CLUTTER_KINDS),) the off-wall length of each kind (metres)."""
        return np.bincount(self.kind, weights=self.length, minlength=len(CLUTTER_KINDS))

    def segments_on(self, min_share: float = 0.5, min_length_m: float = 0.0) -> np.ndarray:
        """(K,) the kind each segment lies on (index into ``CLUTTER_KINDS``): of the segments whose off-wall
        length is at least ``min_share`` of them, the kind that holds the largest part of it; -1 for the
        others and for segments shorter than ``min_length_m``."""
        n = len(self.segment_length)
        kind = _largest_part(self.owner, self.length, self.kind, n, len(CLUTTER_KINDS))
        off = np.bincount(self.owner, weights=self.length, minlength=n)
        kind[(off < min_share * self.segment_length) | (self.segment_length < min_length_m)] = -1
        return kind

    def objects_on(self, n_objects: int, min_share: float = 0.5) -> np.ndarray:
        """(K,) the object each segment lies on (index into :attr:`ClutterObjects.names`, of ``n_objects``):
        of the segments :meth:`segments_on` puts on a hedge, fence, car, pole or tree, the object of that
        kind holding the largest part of it; -1 for the others."""
        kind = self.segments_on(min_share)
        mine = (self.obj >= 0) & (self.kind == kind[self.owner])
        return _largest_part(self.owner[mine], self.length[mine], self.obj[mine], len(kind), n_objects)

    def counts_on(self) -> list[int]:
        """How many segments lie on each kind of ``CLUTTER_KINDS`` (:meth:`segments_on`)."""
        on = self.segments_on()
        return np.bincount(on[on >= 0], minlength=len(CLUTTER_KINDS)).tolist()


def _largest_part(owner: np.ndarray, length: np.ndarray, value: np.ndarray, n: int, n_values: int) -> np.ndarray:
    """(n,) per segment, which ``value`` (of ``n_values``) its samples (``owner``, ``length``: (S,)) hold the
    largest length of; -1 for a segment with no sample."""
    out = np.full(n, -1, dtype=np.int64)
    if not len(owner):
        return out
    per = np.zeros((n, n_values))
    np.add.at(per, (owner, value), length)
    some = per.sum(axis=1) > 0
    out[some] = per[some].argmax(axis=1)
    return out


def walls_on(segments: np.ndarray, truth: GroundTruth, min_share: float = 0.5) -> np.ndarray:
    """(K,) the building wall (index into ``truth.walls``) that holds the largest part of each of (K, 4)
    ``segments`` lying on walls (EVALUATION.md's tolerances), where walls hold at least ``min_share`` of it;
    -1 for the others."""
    segments = np.asarray(segments, float).reshape(-1, 4)
    seg_length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    _, owner, weight, _, wall, _ = building_samples(segments, truth)
    on = wall >= 0
    out = _largest_part(owner[on], weight[on], wall[on], len(segments), len(truth.walls))
    held = np.bincount(owner[on], weights=weight[on], minlength=len(segments))
    out[held < min_share * seg_length] = -1
    return out


def off_wall(segments: np.ndarray, truth: GroundTruth, objects: ClutterObjects) -> OffWall:
    """Where (K, 4) ``segments`` lie on no building wall of ``truth`` (EVALUATION.md's tolerances) and the kind
    of what each such stretch lies on (see the module docstring)."""
    segments = np.asarray(segments, float).reshape(-1, 4)
    seg_length = np.hypot(segments[:, 2] - segments[:, 0], segments[:, 3] - segments[:, 1])
    samples, owner, weight, _, wall, _ = building_samples(segments, truth)
    off = wall < 0
    samples, owner, weight = samples[off], owner[off], weight[off]
    kind = np.full(len(samples), CLUTTER_KINDS.index("nothing near"), dtype=np.int64)
    obj = np.full(len(samples), -1, dtype=np.int64)
    if not len(samples):
        return OffWall(owner, weight, kind, seg_length, obj)
    undecided = np.ones(len(samples), bool)

    def near(points: np.ndarray, reach: float) -> tuple[np.ndarray, np.ndarray]:
        """The undecided samples with one of ``points`` within ``reach`` (indices) and that point's index;
        they are decided now."""
        todo = np.flatnonzero(undecided)
        if not len(points) or not len(todo):
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        dist, nearest = cKDTree(points).query(samples[todo], distance_upper_bound=reach)
        hit = np.isfinite(dist)
        undecided[todo[hit]] = False
        return todo[hit], nearest[hit]

    at, nearest = near(objects.points, OBJECT_REACH_M)
    kind[at], obj[at] = objects.kind[nearest], objects.owner[nearest]
    at, nearest = near(objects.trunks, TREE_REACH_M)
    kind[at], obj[at] = CLUTTER_KINDS.index("tree"), objects.trunk_owner[nearest]
    if len(truth.walls):
        wall_points = np.concatenate([_densify(w.reshape(2, 2)) for w in truth.walls])
        kind[near(wall_points, OBJECT_REACH_M)[0]] = CLUTTER_KINDS.index("beside a wall")
    return OffWall(owner, weight, kind, seg_length, obj)
