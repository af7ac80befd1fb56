"""benchmarks/revisited_street.py: the sensor positions of the synthetic revisited street."""

import numpy as np

from featmap.simulation.segments import city_walls, observe_revisits
from tests.repo_scripts import repo_script


def test_the_sensor_stands_on_the_street_in_front_of_the_wall_being_passed():
    with repo_script("benchmarks/revisited_street.py") as street:
        rng = np.random.default_rng(1)
        walls = city_walls(12, rng)
        segs, scan = observe_revisits(walls, 2, 20, rng, clutter_fraction=0.05)
        xy = street.street_sensor_positions(walls, scan, 20)
    assert xy.shape == (len(scan), 2) and np.isfinite(xy).all()
    for s in np.unique(scan):                                    # one position per scan
        assert (xy[scan == s] == xy[scan == s][0]).all()
    # scan 5 k of a pass is the first view of wall k (20 views, 4 walls per scan: a new wall every 5 scans)
    for k, street_side in ((4, [0.0, 7.5]), (5, [0.0, -7.5]), (6, [7.5, 0.0]), (7, [-7.5, 0.0])):
        first = np.flatnonzero(scan == 5 * k)[0]
        assert np.allclose(xy[first], walls[k, :2] + street_side)
    # and it moves along the wall with the views until the next wall's views begin: scan 34 is 4/20 along wall 6
    later = np.flatnonzero(scan == 5 * 6 + 4)[0]
    assert np.allclose(xy[later], walls[6, :2] + 0.2 * (walls[6, 2:] - walls[6, :2]) + [7.5, 0.0])
