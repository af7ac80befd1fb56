"""Every registered method, on the same small inputs with known answers."""

import numpy as np
import pytest

from featmap.errors import ConfigError
from featmap.fusion import FUSION_METHODS, FusionConfig, fuse
from featmap.fusion.registry import get_method, resolve_methods
from featmap.simulation.segments import observe_walls


@pytest.mark.parametrize("name", list(FUSION_METHODS))
def test_every_method_merges_one_wall_and_keeps_far_walls_apart(name):
    rng = np.random.default_rng(0)
    walls = np.array([[0, 0, 30, 0], [0, 15, 30, 15]], float)
    segs, scan = observe_walls(walls, 20, 0.03, rng, min_fraction=0.7, first_scan=np.array([0, 0]))
    result = fuse(name, segs, scan)
    assert 2 <= len(result.segments) <= 4, name
    on_wall = [np.abs(result.segments[:, [1, 3]] - y).max(axis=1) < 0.1 for y in (0.0, 15.0)]
    assert on_wall[0].any() and on_wall[1].any()
    assert (on_wall[0] | on_wall[1]).all()          # nothing lands between the two walls
    assert result.support.sum() == (result.labels >= 0).sum()


@pytest.mark.parametrize("name", list(FUSION_METHODS))
def test_every_method_handles_empty_and_vertical(name):
    empty = fuse(name, np.zeros((0, 4)), np.zeros(0, int))
    assert empty.segments.shape == (0, 4)
    rng = np.random.default_rng(1)
    segs, scan = observe_walls(np.array([5.0, 0.0, 5.0, 20.0]), 10, 0.0, rng)
    result = fuse(name, segs, scan)
    assert len(result.segments) == 1
    assert np.allclose(result.segments[0, [0, 2]], 5.0)


def test_unknown_method_names_allowed_values():
    with pytest.raises(ConfigError, match="unknown method 'kmeans'; allowed: proposed, meanshift, density"):
        get_method("kmeans")
    assert resolve_methods("all") == list(FUSION_METHODS)
    assert resolve_methods("density,proposed") == ["density", "proposed"]


def test_every_method_has_its_config_section_with_its_defaults():
    cfg = FusionConfig()
    for name, method in FUSION_METHODS.items():
        section = getattr(cfg, name)
        assert type(section) is method.config_type and section == method.config_type()
    assert set(FusionConfig.model_fields) == set(FUSION_METHODS) | {"refine", "corners"}


@pytest.mark.parametrize("name", list(FUSION_METHODS))
def test_every_method_takes_its_own_section(name):
    """A section's setting reaches its method: an angle tolerance of 0.5 deg splits two views 1.5 deg apart
    and merges them at 10 deg."""
    segs = np.array([[0, 0, 20, 0], [0, 0, 20, 20 * np.tan(np.deg2rad(1.5))]] * 4, float)
    scan = np.arange(len(segs))
    key = {"proposed": "delta_deg", "meanshift": "orientation_bandwidth_deg", "density": "orientation_bandwidth_deg"}[name]
    off = {"refine": {"max_offset_m": 0.0}}          # (refinement would split the 10 deg cluster again)
    tight = FusionConfig.model_validate({name: {key: 0.5, **({"min_support": 1} if name == "proposed" else {})}, **off})
    loose = FusionConfig.model_validate({name: {key: 10.0, **({"min_support": 1} if name == "proposed" else {})}, **off})
    assert len(fuse(name, segs, scan, tight)) == 2
    assert len(fuse(name, segs, scan, loose)) == 1


@pytest.mark.parametrize("name", ["proposed", "meanshift", "density"])
def test_every_method_reports_progress_up_to_its_total_and_the_same_result(name):
    from featmap.fusion.registry import prepare_method
    from featmap.simulation.segments import city_walls, observe_revisits

    prepare_method(name)
    rng = np.random.default_rng(1)
    segments, scan = observe_revisits(city_walls(6, rng), 3, 8, rng)
    calls = []
    with_progress = fuse(name, segments, scan, progress=lambda done, total: calls.append((done, total)))
    assert calls and calls[-1][0] == calls[-1][1] > 0
    assert np.array_equal(with_progress.labels, fuse(name, segments, scan).labels)
