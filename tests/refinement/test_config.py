"""The refinement section of the config: its defaults, presets, and one-line errors for bad values."""

import pytest

from featmap.errors import ConfigError
from featmap.pipeline import load_config
from featmap.refinement import REFINEMENT_METHODS, get_refinement


def test_defaults_and_the_indoor_preset():
    cfg = load_config()
    assert cfg.refinement.method == "pose_graph"
    assert cfg.refinement.pose_graph.absolute_sigma_m == 0.5           # GPS/INS poses: an absolute prior
    indoor = load_config("indoor_2d").refinement.pose_graph
    assert indoor.absolute_sigma_m is None and indoor.motion_sigma_m_per_sqrt_m > 0   # odometry poses
    assert set(REFINEMENT_METHODS) == {"none", "pose_graph", "scan_to_map", "fixed_lag"}


@pytest.mark.parametrize("override,needle", [
    ("refinement.method=icp", "'refinement.method' must be one of"),
    ("refinement.pose_graph.gates_m=[1.0,-0.5]", "every gate must be positive"),
    ("refinement.pose_graph.gates_m=[]", "'refinement.pose_graph.gates_m'"),
    ("refinement.pose_graph.min_improvement=0.5", "'refinement.pose_graph.min_improvement' input should be greater than or equal to 1"),
    ("refinement.pose_graph.absolute_sigma_m=0", "'refinement.pose_graph.absolute_sigma_m' input should be greater than 0"),
    ("refinement.pose_graph.angle_deg=90", "'refinement.pose_graph.angle_deg' input should be less than 90"),
    ("refinement.scan_to_map.window_scans=0", "'refinement.scan_to_map.window_scans' input should be greater than or equal to 1"),
    ("refinement.pose_graph.gate=1", "unknown key 'refinement.pose_graph.gate'"),
    ("refinement.drives.gates_m=[2.0,0]", "'refinement.drives.gates_m' value error, every gate must be positive"),
    ("refinement.drives.prior_sigma_m=0", "'refinement.drives.prior_sigma_m' input should be greater than 0"),
])
def test_bad_values_are_one_line_errors(override, needle):
    with pytest.raises(ConfigError) as err:
        load_config(None, [override])
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_unknown_method_names_the_allowed_ones():
    with pytest.raises(ConfigError, match="refinement.method 'icp': unknown; allowed: none, pose_graph, scan_to_map"):
        get_refinement("icp")
