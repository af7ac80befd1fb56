"""Rigid alignment of drives' maps before a batch merges them: known offsets come back, agreeing drives stay."""

import numpy as np
import pytest

from featmap.refinement.base import correct_segments
from featmap.refinement.drives import DriveAlignmentConfig, align_drives


def _blocks(rng, noise=0.01):
    """Walls of ten buildings on both sides of a 100 m street (x along the street)."""
    walls = []
    for bx in range(0, 100, 20):
        for by in (-15, 15):
            x0, y0, x1, y1 = bx, by, bx + 12, by + (8 if by > 0 else -8)
            walls += [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]
    walls = np.array(walls, float)
    return walls + rng.normal(0, noise, walls.shape)


def _moved(segments, motion):
    about = 0.5 * (segments[:, :2] + segments[:, 2:]).mean(axis=0)
    return correct_segments(segments, np.zeros(len(segments), int), about[None], np.asarray(motion, float)[None])


@pytest.mark.parametrize("motion", [(0.6, -0.4, 1.5), (-1.5, 1.2, -1.0), (0.3, 0.0, 0.5)])
def test_a_drive_off_as_a_whole_comes_back(motion):
    rng = np.random.default_rng(0)
    walls = _blocks(rng)
    first, second = walls[:30], walls[8:] + rng.normal(0, 0.01, walls[8:].shape)   # they share 22 walls
    off = _moved(second, (motion[0], motion[1], np.deg2rad(motion[2])))
    result = align_drives([first, off])
    assert result.applied and np.all(result.corrections[0] == 0)
    back = result.segments(np.vstack([first, off]), np.r_[np.zeros(len(first), int), np.ones(len(off), int)])
    assert np.abs(back[:len(first)] - first).max() == 0              # the first drive holds the frame
    assert np.abs(back[len(first):] - second).max() < 0.02           # within noise of where it was
    assert result.stats["agreeing_after_m"] > 5 * result.stats["agreeing_before_m"] and result.stats["agreeing_after_m"] > 400


def test_drives_that_agree_or_do_not_overlap_stay_as_they_are():
    rng = np.random.default_rng(1)
    walls = _blocks(rng)
    for maps in ([walls[:30], walls[8:] + rng.normal(0, 0.01, walls[8:].shape)],   # agree within noise
                 [walls[:20], walls[20:] + [0.0, 300.0, 0.0, 300.0]],            # far apart
                 [walls[:20]], []):
        result = align_drives(maps)
        assert not result.applied and np.all(result.corrections == 0)
    assert not align_drives([walls[:30], _moved(walls[8:], (0.5, 0.0, 0.0))], DriveAlignmentConfig(enabled=True,
                            min_improvement=1e9)).applied                 # the rule that keeps them is the config's


def test_a_drive_along_one_street_moves_only_across_it():
    """Walls along x only: the offset along the street is not observable, so the prior keeps it at zero."""
    rng = np.random.default_rng(2)
    fronts = np.array([[x, y, x + 15, y] for x in range(0, 200, 20) for y in (-12, 12)], float)
    first = fronts + rng.normal(0, 0.01, fronts.shape)
    second = fronts + rng.normal(0, 0.01, fronts.shape)
    result = align_drives([first, second + [3.0, 0.5, 3.0, 0.5]])      # 3 m along, 0.5 m across
    assert result.applied
    dx, dy, dyaw = result.corrections[1]
    assert abs(dy + 0.5) < 0.02 and abs(np.rad2deg(dyaw)) < 0.05
    assert abs(dx) < 0.05                                               # not slid along the street
