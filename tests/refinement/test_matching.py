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
