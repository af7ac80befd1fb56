"""Which scans to compare, and which of their segments see the same wall.

Two steps, both vectorised over the whole run:

1. :func:`scan_pairs`: pairs of scans whose sensors were within ``radius`` of each other. Of all
   the partners of a scan, one per *time scale* is kept in each direction: the nearest (in space)
   among the scans 1, 2-3, 4-7, 8-15, ... positions later, and the same backwards. Every scale,
   from the next scan to a revisit minutes later, ties the scan in, at ``O(F log F)`` pairs.
2. :func:`segment_matches`: for every scan pair ``(i, j)``, each segment ``a`` of scan ``i`` is
   matched to the nearest near-parallel segment ``b`` of scan ``j`` that it overlaps (``a``'s part
   whose projection falls on ``b``, extended by a margin). The squared distance of that part of
   ``a`` to ``b``'s line, integrated along it, is a quadratic in the position along ``a``, so two
   Gauss points (weight half the overlap each) give it exactly: each match becomes two
   point-to-line residuals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_GAUSS = 0.5 / np.sqrt(3.0)


def scan_pairs(positions: np.ndarray, radius: float, block: int = 4_000_000) -> np.ndarray:
    """(P, 2) scan pairs ``i < j`` (positions in time order) to compare: for every scan and every time
    scale ``2**k <= |j - i| < 2**(k+1)``, the nearest partner (in space) of that scale in each direction.

    Args:
        positions: (F, 2) sensor positions in the world frame.
        radius: scans farther apart than this (metres) are not compared (consecutive scans always are).
    """
    positions = np.asarray(positions, float).reshape(-1, 2)
    n = len(positions)
    if n < 2:
        return np.zeros((0, 2), np.int64)
    found = [np.arange(n - 1) * n + np.arange(1, n)]
    k = 1
    while 2 ** k < n:
        lo, hi = 2 ** k, min(2 ** (k + 1), n)
        offsets = np.arange(lo, hi)
        rows = max(1, block // len(offsets))
        for first in range(0, n - lo, rows):
            i = np.arange(first, min(first + rows, n - lo))
            for sign in (1, -1):           # partner later (j = i + o) or earlier (the scan j = i + lo.., partner j - o)
                own = i if sign == 1 else i + lo
                other = own[:, None] + sign * offsets[None, :]
                valid = (other >= 0) & (other < n)
                d = np.where(valid, np.hypot(*(positions[np.clip(other, 0, n - 1)] - positions[own][:, None, :])
                                             .transpose(2, 0, 1)), np.inf)
                best = np.argmin(d, axis=1)
                ok = d[np.arange(len(own)), best] <= radius
                a, b = own[ok], other[ok, best[ok]]
                found.append(np.minimum(a, b) * n + np.maximum(a, b))
        k += 1
    key = np.unique(np.concatenate(found))
    return np.column_stack([key // n, key % n])


@dataclass(frozen=True)
class Matches:
    """Point-to-line residuals between segments of different scans (world frame, current poses).

    ``R`` residuals: the point ``point`` on a segment of scan ``source`` should lie on the line
    through ``base`` with unit normal ``normal``, a segment of scan ``target``.

    Attributes:
        point: (R, 2) Gauss points on the source segments.
        source, target: (R,) scan positions.
        base: (R, 2) first endpoint of the target segment.
        normal: (R, 2) unit normal of the target segment.
        weight: (R,) metres of overlap each residual stands for.
        n_pairs: segment pairs matched (two residuals each).
    """

    point: np.ndarray
    source: np.ndarray
    target: np.ndarray
    base: np.ndarray
    normal: np.ndarray
    weight: np.ndarray
    n_pairs: int

    def __len__(self) -> int:
        return len(self.point)

    def residuals(self) -> np.ndarray:
        """(R,) signed distances of the points to their lines."""
        return np.einsum("ij,ij->i", self.point - self.base, self.normal)

    @staticmethod
    def empty() -> "Matches":
        z2, zi = np.zeros((0, 2)), np.zeros(0, np.int64)
        return Matches(z2, zi, zi, z2, z2, np.zeros(0), 0)


def _combinations(pairs: np.ndarray, start: np.ndarray, count: np.ndarray, chunk: int):
    """Yield (segment a, segment b, pair index) for every segment of scan i x every segment of scan j of
    each pair, in chunks of about ``chunk`` combinations."""
    ki, kj = count[pairs[:, 0]], count[pairs[:, 1]]
    n = ki * kj
    ends = np.cumsum(n)
    lo = 0
    while lo < len(pairs):
        hi = int(np.searchsorted(ends, (ends[lo - 1] if lo else 0) + chunk, side="right"))
        hi = max(hi, lo + 1)
        sl = slice(lo, hi)
        nn = n[sl]
        pid = np.repeat(np.arange(lo, hi), nn)
        local = np.arange(nn.sum()) - np.repeat(np.cumsum(nn) - nn, nn)
        a = start[pairs[pid, 0]] + local // kj[pid]
        b = start[pairs[pid, 1]] + local % kj[pid]
        yield a, b, pid
        lo = hi


class MatchCandidates:
    """The segment combinations of scan pairs that may match, reused while the segments move little.

    :func:`segment_matches` looks at every segment of scan ``i`` against every segment of scan ``j`` of
    every pair (tens of millions of combinations on a long drive) and keeps the near-parallel ones whose
    circles touch; the refinement asks again at every iteration with the same pairs while the poses
    barely move. This keeps the combinations that pass those two tests with ``slack_m`` more reach and
    ``slack_deg`` more angle, and reuses them while no segment end has moved more than ``slack_m / 2``
    nor turned more than ``slack_deg / 2`` since (the pairs, the segments' scans and the angle being the
    same, and the reach no larger): every combination that passes the tests then is among them, so the
    matches are the same as a fresh search would find. Otherwise it searches afresh.
    """

    def __init__(self, slack_m: float = 0.5, slack_deg: float = 1.0):
        self.slack_m = float(slack_m)
        self.slack_deg = float(slack_deg)
        self.builds = 0
        self._built: tuple | None = None      # (pairs, scan, angle_deg, reach, segments, unit, chunks)

    def get(self, segments: np.ndarray, scan: np.ndarray, pairs: np.ndarray, start: np.ndarray, count: np.ndarray,
            geo: "_Geometry", reach: float, angle_deg: float, chunk: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Chunks of (a, b, pair index) combinations, a superset of those passing the tests at ``reach`` and
        ``angle_deg`` for the current ``segments`` (never splitting a pair across chunks)."""
        if not self._valid(segments, scan, pairs, geo, reach, angle_deg):
            loose_sin = np.sin(np.deg2rad(min(angle_deg + self.slack_deg, 90.0)))
            chunks = [_near(geo, a, b, pid, loose_sin, reach + self.slack_m)
                      for a, b, pid in _combinations(pairs, start, count, chunk)]
            self._built = (pairs.copy(), scan.copy(), angle_deg, reach, segments.copy(), geo.unit.copy(), chunks)
            self.builds += 1
        return self._built[6]

    def _valid(self, segments, scan, pairs, geo, reach, angle_deg) -> bool:
        if self._built is None:
            return False
        b_pairs, b_scan, b_angle, b_reach, b_segments, b_unit, _ = self._built
        if (b_angle != angle_deg or reach > b_reach or not np.array_equal(b_pairs, pairs)
                or not np.array_equal(b_scan, scan)):
            return False
        moved = np.max(np.abs(segments - b_segments)) * np.sqrt(2) if len(segments) else 0.0
        turned = np.max(np.abs(geo.unit[:, 0] * b_unit[:, 1] - geo.unit[:, 1] * b_unit[:, 0])) if len(segments) else 0.0
        return bool(moved <= self.slack_m / 2 and turned <= np.sin(np.deg2rad(self.slack_deg / 2)))


def _near(geo: "_Geometry", a: np.ndarray, b: np.ndarray, pid: np.ndarray, sin_max: float, reach: float):
    """The combinations (a, b, pid) whose segments are within ``asin(sin_max)`` of parallel and whose circles
    (plus ``reach``) touch."""
    ok = np.abs(geo.unit[a, 0] * geo.unit[b, 1] - geo.unit[a, 1] * geo.unit[b, 0]) <= sin_max
    a, b, pid = a[ok], b[ok], pid[ok]
    d = geo.mid[a] - geo.mid[b]
    ok = np.hypot(d[:, 0], d[:, 1]) <= geo.half[a] + geo.half[b] + reach
    return a[ok], b[ok], pid[ok]


def segment_matches(segments: np.ndarray, scan: np.ndarray, pairs: np.ndarray, gate: float, angle_deg: float,
                    margin: float, min_overlap: float, chunk: int = 2_000_000,
                    candidates: MatchCandidates | None = None) -> Matches:
    """Match the segments of every scan pair in both directions.

    Args:
        segments: (N, 4) current world segments, sorted by ``scan``.
        scan: (N,) scan position of each segment (sorted).
        pairs: (P, 2) scan pairs from :func:`scan_pairs`.
        gate: the overlapping part of ``a`` lies within this distance of ``b``'s line at both its ends (m).
        angle_deg: ``a`` and ``b`` are within this angle of parallel.
        margin: ``a`` may project this far beyond ``b``'s endpoints (m).
        min_overlap: shorter overlaps are not matched (m).
        candidates: reuse the combinations worth testing between calls (the same matches, faster while
            the segments move little); None searches every combination.
    """
    segments = np.asarray(segments, float).reshape(-1, 4)
    if len(pairs) == 0 or len(segments) == 0:
        return Matches.empty()
    pairs = np.asarray(pairs, np.int64)
    n_scans = max(int(scan.max()), int(pairs.max())) + 1          # scans without segments may be paired too
    count = np.bincount(scan, minlength=n_scans)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    geo = _Geometry(segments)
    sin_max = np.sin(np.deg2rad(angle_deg))
    reach = gate + margin
    if candidates is not None:
        chunks = candidates.get(segments, np.asarray(scan), pairs, start, count, geo, reach, angle_deg, chunk)
    else:
        chunks = _combinations(pairs, start, count, chunk)
    parts = []
    for a, b, pid in chunks:
        # Cheap tests first: near-parallel, and the two segments' circles (plus the gate) touch.
        a, b, pid = _near(geo, a, b, pid, sin_max, reach)
        for src, tgt, key in ((a, b, 2 * pid), (b, a, 2 * pid + 1)):      # a on b's line, and b on a's
            found = _overlaps(geo, src, tgt, key, gate, margin, min_overlap)
            if found is not None:
                parts.append(found)
    if not parts:
        return Matches.empty()
    src, tgt, t_lo, t_hi, overlap = (np.concatenate(x) for x in zip(*parts))
    mid, half = 0.5 * (t_lo + t_hi), _GAUSS * (t_hi - t_lo)
    p1, vec = geo.p1[src], geo.vec[src]
    pts = np.concatenate([p1 + (mid - half)[:, None] * vec, p1 + (mid + half)[:, None] * vec])
    twice = lambda x: np.concatenate([x, x])  # noqa: E731
    return Matches(point=pts, source=twice(scan[src]), target=twice(scan[tgt]), base=twice(geo.p1[tgt]),
                   normal=twice(geo.normal[tgt]), weight=twice(0.5 * overlap), n_pairs=len(src))


class _Geometry:
    """Per-segment quantities used by the matching: endpoints, direction, unit normal, midpoint, half length."""

    def __init__(self, segments: np.ndarray):
        self.p1 = segments[:, :2]
        self.vec = segments[:, 2:] - self.p1
        self.length = np.hypot(self.vec[:, 0], self.vec[:, 1])
        self.unit = np.where(self.length[:, None] > 0, self.vec / np.maximum(self.length, 1e-12)[:, None], 0.0)
        self.normal = np.column_stack([-self.unit[:, 1], self.unit[:, 0]])
        self.mid = self.p1 + 0.5 * self.vec
        self.half = 0.5 * self.length


def _overlaps(geo: _Geometry, src: np.ndarray, tgt: np.ndarray, key: np.ndarray, gate: float, margin: float,
              min_overlap: float):
    """The part of each source segment whose projection falls on its target (extended by ``margin``), kept
    when it is at least ``min_overlap`` long and lies within ``gate`` of the target's line at both ends; one
    target per (source segment, ``key``), the nearest. Returns (src, tgt, t_lo, t_hi, overlap) or None."""
    base, ub, nb = geo.p1[tgt], geo.unit[tgt], geo.normal[tgt]
    p1, vec = geo.p1[src], geo.vec[src]
    rel = p1 - base
    s1 = rel[:, 0] * ub[:, 0] + rel[:, 1] * ub[:, 1]
    ds = vec[:, 0] * ub[:, 0] + vec[:, 1] * ub[:, 1]
    safe = np.where(np.abs(ds) > 1e-12, ds, 1e-12)
    t1 = np.clip((-margin - s1) / safe, 0.0, 1.0)
    t2 = np.clip((geo.length[tgt] + margin - s1) / safe, 0.0, 1.0)
    t_lo, t_hi = np.minimum(t1, t2), np.maximum(t1, t2)
    overlap = (t_hi - t_lo) * geo.length[src]
    r0 = rel[:, 0] * nb[:, 0] + rel[:, 1] * nb[:, 1]
    dr = vec[:, 0] * nb[:, 0] + vec[:, 1] * nb[:, 1]
    far = np.maximum(np.abs(r0 + t_lo * dr), np.abs(r0 + t_hi * dr))
    ok = (overlap >= min_overlap) & (far <= gate) & (geo.length[src] > 0) & (geo.length[tgt] > 0)
    if not ok.any():
        return None
    src, tgt, key, t_lo, t_hi, overlap, far = src[ok], tgt[ok], key[ok], t_lo[ok], t_hi[ok], overlap[ok], far[ok]
    order = np.lexsort((far, key, src))
    first = np.ones(len(order), bool)
    first[1:] = (src[order][1:] != src[order][:-1]) | (key[order][1:] != key[order][:-1])
    sel = order[first]
    return src[sel], tgt[sel], t_lo[sel], t_hi[sel], overlap[sel]
