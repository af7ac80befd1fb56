"""Synthetic observations used by the tests and benchmarks: the structure they promise."""

import numpy as np

from featmap.simulation.segments import indoor_loop_walls, observe_indoor_loop, observe_revisits


def test_revisits_see_every_wall_in_every_pass_near_its_line():
    rng = np.random.default_rng(0)
    walls = np.array([[0.0, 0.0, 20.0, 0.0], [30.0, 5.0, 30.0, 25.0]])
    segments, scan = observe_revisits(walls, 4, 10, rng, clutter_fraction=0.0)
    assert segments.shape == (2 * 4 * 10, 4)
    assert len(np.unique(scan)) < len(scan)                       # walls share scans
    first = segments[: 4 * 10 * 2].reshape(4, 2, 10, 4)[:, 0]     # (pass, view) of wall 0
    assert np.abs(first[..., [1, 3]]).max() < 0.5                 # within noise + pose error of y = 0
    lengths = np.hypot(*(first[..., 2:] - first[..., :2]).reshape(-1, 2).T)
    assert lengths.min() > 0.3 * 20 - 0.5 and lengths.max() < 20 + 0.5   # partial views, at least 30 %
    with_clutter, _ = observe_revisits(walls, 4, 10, rng, clutter_fraction=0.2)
    assert 0.15 < 1 - len(segments) / len(with_clutter) < 0.25


def test_indoor_loop_scans_see_few_walls_each_and_views_are_partial():
    rng = np.random.default_rng(1)
    walls = indoor_loop_walls(rng, loop_m=(30.0, 20.0))
    segments, scan = observe_indoor_loop(walls, 2, rng, loop_m=(30.0, 20.0))
    per_scan = np.bincount(scan - scan.min())
    assert 2 <= np.median(per_scan) <= 15
    assert len(np.unique(scan)) == 2 * int(np.ceil(100.0 / 0.35))
    seg_len = np.hypot(*(segments[:, 2:] - segments[:, :2]).T)
    assert seg_len.max() <= 2 * 6.0 + 0.2                           # clipped to the 6 m range disc
