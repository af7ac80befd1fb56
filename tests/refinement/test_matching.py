"""Scan pairs at every time scale; segment matches with known distances and weights."""

import numpy as np

from featmap.refinement.matching import scan_pairs, segment_matches


def _brute_force_pairs(pos, radius):
    n = len(pos)
    out = {(i, i + 1) for i in range(n - 1)}
    for i in range(n):
        for sign in (1, -1):
            k = 1
            while 2 ** k < n:
                cands = [i + sign * o for o in range(2 ** k, min(2 ** (k + 1), n)) if 0 <= i + sign * o < n]
                if cands:
                    d = [np.hypot(*(pos[c] - pos[i])) for c in cands]
                    best = int(np.argmin(d))
                    if d[best] <= radius:
                        out.add((min(i, cands[best]), max(i, cands[best])))
                k += 1
    return out


def test_scan_pairs_are_the_nearest_partner_of_every_time_scale():
    pos = np.cumsum(np.random.default_rng(3).normal(0, 1, (90, 2)), axis=0)
    got = scan_pairs(pos, 6.0)
    assert set(map(tuple, got.tolist())) == _brute_force_pairs(pos, 6.0)
    assert (got[:, 0] < got[:, 1]).all()
    # a revisit: the last scans come back to the start and are paired with it
    loop = np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 64)), np.sin(np.linspace(0, 2 * np.pi, 64))]) * 20
    assert (0, 63) in set(map(tuple, scan_pairs(loop, 5.0).tolist()))


def test_two_parallel_segments_match_with_their_distance_and_overlap():
    segs = np.array([[0.0, 0.0, 4.0, 0.0],        # scan 0
                     [2.0, 0.1, 6.0, 0.1],        # scan 1: 0.1 m away, 2 m overlap
                     [0.0, 3.0, 4.0, 3.0]])       # scan 1: far, not matched
    scan = np.array([0, 1, 1])
    m = segment_matches(segs, scan, np.array([[0, 1]]), gate=0.5, angle_deg=5, margin=0.0, min_overlap=0.5)
    assert m.n_pairs == 2                          # one match in each direction
    assert np.allclose(np.abs(m.residuals()), 0.1)
    assert np.allclose(m.weight, 1.0)              # half of the 2 m overlap per Gauss point
    assert set(m.source.tolist()) == {0, 1} and (m.source != m.target).all()
    # beyond the gate, across an angle, or overlapping too little: nothing
    assert len(segment_matches(segs, scan, np.array([[0, 1]]), 0.05, 5, 0.0, 0.5)) == 0
    turned = segs.copy()
    turned[1] = [2.0, 0.1, 6.0, 0.6]               # 7 degrees
    assert len(segment_matches(turned, scan, np.array([[0, 1]]), 0.5, 5, 0.0, 0.5)) == 0
    assert len(segment_matches(segs, scan, np.array([[0, 1]]), 0.5, 5, 0.0, 2.5)) == 0


def test_matches_keep_the_nearest_segment_of_each_scan():
    segs = np.array([[0.0, 0.0, 4.0, 0.0], [0.0, 0.3, 4.0, 0.3], [0.0, 0.05, 4.0, 0.05]])
    m = segment_matches(segs, np.array([0, 1, 1]), np.array([[0, 1]]), 0.5, 5, 0.0, 0.5)
    from_0 = m.source == 0
    assert from_0.sum() == 2 and np.allclose(np.abs(m.residuals()[from_0]), 0.05)


def _sorted_matches(m):
    rows = np.column_stack([m.source, m.target, m.point, m.base, m.normal, m.weight])
    return rows[np.lexsort(rows.T[::-1])]


def test_reused_candidates_give_the_same_matches_as_a_fresh_search():
    """While the scans move less than half the slack, the candidates are built once and the matches equal a
    fresh search's; a larger move rebuilds them (and still matches a fresh search)."""
    from featmap.refinement.base import correct_segments
    from featmap.refinement.matching import MatchCandidates

    rng = np.random.default_rng(5)
    n_scans, per = 12, 30
    scan = np.repeat(np.arange(n_scans), per)
    direction = rng.choice([0.0, np.pi / 2, 0.3], len(scan)) + rng.normal(0, 0.01, len(scan))
    mid = rng.uniform(-15, 15, (len(scan), 2))
    half = rng.uniform(0.5, 4, len(scan))[:, None] * np.column_stack([np.cos(direction), np.sin(direction)])
    segments = np.column_stack([mid - half, mid + half])
    anchors = np.cumsum(rng.normal(0, 1, (n_scans, 2)), axis=0)
    pairs = scan_pairs(anchors, 40.0)
    candidates = MatchCandidates(slack_m=0.5, slack_deg=1.0)
    for step, (shift, turn, gate) in enumerate([(0.0, 0.0, 1.0), (0.1, 0.003, 1.0), (0.12, 0.004, 0.5),
                                                (0.6, 0.0, 0.5), (0.6, 0.02, 0.25)]):
        c = np.column_stack([rng.uniform(-shift, shift, (n_scans, 2)) / np.sqrt(2), rng.uniform(-turn, turn, n_scans)])
        current = correct_segments(segments, scan, anchors, c)
        fresh = segment_matches(current, scan, pairs, gate, 5.0, 0.5, 0.3)
        reused = segment_matches(current, scan, pairs, gate, 5.0, 0.5, 0.3, candidates=candidates)
        assert fresh.n_pairs > 20 and reused.n_pairs == fresh.n_pairs, step
        assert np.array_equal(_sorted_matches(reused), _sorted_matches(fresh)), step
        assert candidates.builds == (1 if step < 3 else step - 1), step
