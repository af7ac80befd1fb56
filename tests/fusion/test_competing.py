"""The two competing algorithms: their behaviour, and the weakness the paper describes."""

import numpy as np
import pytest

from featmap.fusion import FusionConfig, fuse
from featmap.fusion.base import cluster_orientations, orientation_embedding
from featmap.fusion.density import DensityConfig, fuse_density
from featmap.fusion.meanshift import MeanShiftConfig, fuse_meanshift
from featmap.fusion.proposed import ProposedConfig, fuse_proposed
from featmap.simulation.segments import observe_walls


def _street(rng, gap=15.0):
    walls = np.array([[0, 0, 30, 0], [0, gap, 30, gap]], float)
    return observe_walls(walls, 20, 0.03, rng, min_fraction=0.7, first_scan=np.array([0, 0]))


@pytest.mark.parametrize("fuse_fn", [fuse_meanshift, fuse_density])
def test_one_wall_in_many_scans_becomes_few_features(fuse_fn):
    rng = np.random.default_rng(0)
    segs, scan = observe_walls(np.array([0.0, 0.0, 25.0, 0.0]), 30, 0.03, rng, min_fraction=0.8)
    result = fuse_fn(segs, scan)
    assert 1 <= len(result.segments) <= 3
    assert np.abs(result.segments[:, [1, 3]]).max() < 0.05


def test_wrap_around_orientations_cluster_together():
    theta = np.deg2rad(np.array([179.0, 179.5, 0.5, 1.0, 90.0, 89.0]))
    labels = cluster_orientations(theta, np.deg2rad(3.0))
    assert len(set(labels[:4])) == 1 and labels[4] == labels[5] and labels[0] != labels[4]
    emb = orientation_embedding(np.deg2rad(np.array([179.0, -1.0 + 180.0])))
    assert np.allclose(emb[0], emb[1])
    # a wall drawn once east-to-west (179 deg) and once west-to-east (1 deg): one feature
    rng = np.random.default_rng(1)
    a, _ = observe_walls(np.array([0.0, 0.0, 20.0, 0.35]), 10, 0.01, rng, min_fraction=0.9)   # ~1 deg
    b, _ = observe_walls(np.array([20.0, 0.35, 0.0, 0.0]), 10, 0.01, rng, min_fraction=0.9)   # ~181 deg
    segs = np.vstack([a, b])
    scan = np.arange(len(segs))
    for name in ("meanshift", "density", "proposed"):
        assert len(fuse(name, segs, scan).segments) == 1, name


def test_exactly_vertical_walls():
    rng = np.random.default_rng(2)
    segs, scan = observe_walls(np.array([[4.0, 0.0, 4.0, 20.0], [-6.0, 0.0, -6.0, 20.0]]), 12, 0.0, rng,
                               first_scan=np.array([0, 0]))
    for fn in (fuse_meanshift, fuse_density):
        result = fn(segs, scan)
        xs = np.sort(result.segments[:, [0, 2]].mean(axis=1))
        assert len(result.segments) >= 2 and np.allclose(xs[[0, -1]], [-6.0, 4.0], atol=1e-6)


def test_large_bandwidth_merges_the_two_sides_of_a_street_but_the_proposed_method_does_not():
    rng = np.random.default_rng(3)
    segs, scan = _street(rng)
    # the paper's Section 4: orientation first, then space; a bandwidth larger than the street puts both
    # façades into one cluster and the merged feature lands in the middle of the road
    wide = fuse_meanshift(segs, scan, MeanShiftConfig(center_bandwidth_m=20.0))
    assert len(wide.segments) == 1
    assert 5.0 < wide.segments[0, [1, 3]].mean() < 10.0
    wide_density = fuse_density(segs, scan, DensityConfig(lateral_eps_m=16.0))
    assert len(wide_density.segments) == 1 and 5.0 < wide_density.segments[0, [1, 3]].mean() < 10.0
    # the proposed method keeps the walls apart on the same input, whatever its delta and gamma
    for delta in (5.0, 20.0):
        proposed = fuse_proposed(segs, scan, FusionConfig().proposed.model_copy(update={"delta_deg": delta}))
        assert len(proposed.segments) == 2
        assert sorted(proposed.segments[:, [1, 3]].mean(axis=1)) == pytest.approx([0.0, 15.0], abs=0.05)


def test_competing_methods_keep_every_cluster():
    # no support filter: a fence seen twice, 1.5 m in front of a wall. Density clustering keeps it as a
    # feature of its own; mean shift (3 m bandwidth) merges it into a wall cluster and drags that feature
    # off the wall (the paper's Figure 5); the proposed method with the paper's count rule drops it
    # (support 2 < 4) and keeps the wall.
    rng = np.random.default_rng(4)
    segs, scan = observe_walls(np.array([0.0, 0.0, 40.0, 0.0]), 20, 0.03, rng)
    segs = np.vstack([segs, [[15.0, 1.5, 19.0, 1.5], [15.1, 1.52, 19.1, 1.5]]])
    scan = np.concatenate([scan, [3, 4]])
    fence = [len(segs) - 2, len(segs) - 1]

    proposed = fuse_proposed(segs, scan, ProposedConfig(min_support_length_m=None))
    assert len(proposed.segments) == 1 and np.abs(proposed.segments[0, [1, 3]]).max() < 0.05
    assert (proposed.labels[fence] == -1).all()

    density = fuse_density(segs, scan)
    f = density.labels[fence[0]]
    assert density.labels[fence[1]] == f and density.support[f] == 2
    assert density.segments[f, [1, 3]] == pytest.approx([1.5, 1.5], abs=0.05)
    assert (density.labels[:-2] != f).all()

    meanshift = fuse_meanshift(segs, scan)
    f = meanshift.labels[fence[0]]
    assert meanshift.support[f] > 2                               # merged with wall segments ...
    assert 0.1 < meanshift.segments[f, [1, 3]].mean() < 1.4      # ... and dragged off the wall
