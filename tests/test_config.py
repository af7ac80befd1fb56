from pathlib import Path

import pytest

from featmap.errors import ConfigError
from featmap.pipeline.config import FeatmapConfig, default_config_yaml, load_config, save_config

ROOT = Path(__file__).resolve().parents[1]


def test_shipped_default_yaml_matches_the_models():
    assert load_config(ROOT / "configs" / "default.yaml") == FeatmapConfig()
    # and it is exactly the rendering of the defaults (every key documented)
    assert (ROOT / "configs" / "default.yaml").read_text() == default_config_yaml()   # `featmap config > ...`


def test_precedence_defaults_yaml_set(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("fusion:\n  proposed:\n    delta_deg: 7\n    eta_m: 0.8\n")
    cfg = load_config(path, ["fusion.proposed.delta_deg=3"])
    assert cfg.fusion.proposed.delta_deg == 3          # --set wins over YAML
    assert cfg.fusion.proposed.eta_m == 0.8            # YAML wins over defaults
    assert cfg.fusion.proposed.gamma == FeatmapConfig().fusion.proposed.gamma


def test_a_section_set_whole_keeps_the_yaml_keys_it_does_not_name(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("fusion:\n  refine:\n    max_offset_m: 0.2\n  proposed:\n    eta_m: 0.8\n")
    cfg = load_config(path, ["fusion.refine={split_gap_m: 0.3}", "fusion={proposed: {delta_deg: 3}}"])
    assert cfg.fusion.refine.split_gap_m == 0.3 and cfg.fusion.refine.max_offset_m == 0.2
    assert cfg.fusion.proposed.delta_deg == 3 and cfg.fusion.proposed.eta_m == 0.8
    assert load_config(path, ["fusion.refine={max_offset_m: 0.1}"]).fusion.refine.max_offset_m == 0.1


def test_save_and_reload_round_trip(tmp_path):
    cfg = load_config(None, ["fusion.corners.mode=midpoint", "extraction.ransac_planes.seed=4"])
    save_config(cfg, tmp_path / "config.yaml")
    assert load_config(tmp_path / "config.yaml") == cfg


@pytest.mark.parametrize("override,message", [
    ("fusion.proposed.gamma=1.5", r"'fusion.proposed.gamma' input should be less than or equal to 1 \(got 1.5\)"),
    ("fusion.proposed.eta_m=-1", r"'fusion.proposed.eta_m' input should be greater than or equal to 0"),
    ("fusion.proposed.delta=5", r"unknown key 'fusion.proposed.delta' \(did you mean 'fusion.proposed.delta_deg'\?\)"),
    ("fusion.corners.mode=bogus", r"'fusion.corners.mode' must be one of 'midpoint', 'intersection' or 'none'"),
    ("fusion.proposed.min_support=many", r"'fusion.proposed.min_support' input should be a valid integer"),
    ("novalue", r"expected KEY=VALUE"),
])
def test_bad_values_name_the_key_and_the_allowed_values(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(None, [override])


def test_unknown_key_in_yaml(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("fusion:\n  proposed:\n    gama: 0.2\n")
    with pytest.raises(ConfigError, match=r"bad.yaml: unknown key 'fusion.proposed.gama' \(did you mean 'fusion.proposed.gamma'\?\)"):
        load_config(path)


def test_missing_and_malformed_yaml(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "broken.yaml"
    bad.write_text("fusion: [1, 2\n")
    with pytest.raises(ConfigError, match=r"broken.yaml:\d+: not valid YAML"):
        load_config(bad)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("42\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_config(scalar)


@pytest.mark.parametrize("override,message", [
    ("fusion.proposed.min_support=true", r"'fusion.proposed.min_support' input should be a valid integer \(got True\)"),
    ("fusion.proposed.delta_deg='5'", r"'fusion.proposed.delta_deg' input should be a valid number"),
    ("output.plots=1", r"'output.plots' input should be a valid boolean"),
])
def test_types_are_strict(override, message):
    """``min_support: true`` is not 1 and a quoted number is not a number."""
    with pytest.raises(ConfigError, match=message):
        load_config(None, [override])
    assert load_config(None, ["fusion.proposed.delta_deg=5"]).fusion.proposed.delta_deg == 5.0   # int for float: fine
    # an unquoted exponent is a number (YAML 1.1 alone would read 1e1 as a string); a quoted one is not
    assert load_config(None, ["fusion.proposed.delta_deg=1e1"]).fusion.proposed.delta_deg == 10.0
    with pytest.raises(ConfigError, match="should be a valid number"):
        load_config(None, ["fusion.proposed.delta_deg='1e1'"])


def test_config_file_that_is_not_utf8_or_is_a_folder(tmp_path):
    bad = tmp_path / "latin1.yaml"
    bad.write_bytes("fusion:\n  proposed: {delta_deg: 5}  # \xe9t\xe9\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=r"latin1.yaml: not UTF-8 text"):
        load_config(bad)
    with pytest.raises(ConfigError, match=r"is a folder, expected a YAML file"):
        load_config(tmp_path)


def test_a_name_that_yaml_reads_as_a_boolean_stays_a_name():
    with pytest.raises(ConfigError, match="unknown tile source 'no'"):      # read as the name 'no', not False
        load_config(None, ["output.tile_source=no"])
    assert load_config(None, ["output.tile_source=https://127.0.0.1/{z}/{x}/{y}.png"]).output.tile_source.startswith("https")
    assert load_config(None, ["output.plots=no"]).output.plots is False       # a boolean where one is meant
    # a choice among names: YAML's 'off' is the word off, which is not one of them
    with pytest.raises(ConfigError, match=r"must be one of 'midpoint', 'intersection' or 'none' \(got 'off'\)"):
        load_config(None, ["fusion.corners.mode=off"])
    assert load_config(None, ["fusion.corners.mode=none"]).fusion.corners.mode == "none"


def test_a_key_given_twice_in_a_yaml_file_is_an_error_naming_its_line(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("fusion:\n  proposed:\n    delta_deg: 5\n    gamma: 0.3\n    delta_deg: 7\n")
    with pytest.raises(ConfigError, match=r"c\.yaml:5: not valid YAML \('delta_deg' is given twice\)"):
        load_config(path)
    path.write_text("fusion:\n  proposed:\n    delta_deg: 5\nfusion:\n  proposed:\n    gamma: 0.3\n")
    with pytest.raises(ConfigError, match=r"c\.yaml:4: .*'fusion' is given twice"):
        load_config(path)
    path.write_text("fusion:\n  proposed:\n    delta_deg: 7\n  meanshift: {}\n")            # same name, other mappings
    assert load_config(path).fusion.proposed.delta_deg == 7


def test_numbers_with_an_exponent_and_no_dot_are_numbers_in_yaml_files(tmp_path):
    # PyYAML (YAML 1.1) reads 5e-1 as the string '5e-1'; a config file means the number, as --set does
    path = tmp_path / "c.yaml"
    path.write_text("fusion:\n  proposed:\n    eta_m: 5e-1\n    delta_deg: 1e1\n")
    config = load_config(path)
    assert config.fusion.proposed.eta_m == 0.5 and config.fusion.proposed.delta_deg == 10.0
    path.write_text("output:\n  tile_source: '1e3'\n")                 # quoted: still the text
    with pytest.raises(ConfigError, match="unknown tile source '1e3'"):
        load_config(path)
    path.write_text("output:\n  tile_source: 1e3x\n")                  # starts like a number: still text
    with pytest.raises(ConfigError, match="unknown tile source '1e3x'"):
        load_config(path)


def test_yaml_merge_keys_are_not_duplicates(tmp_path):
    from featmap.config import read_yaml_mapping

    path = tmp_path / "c.yaml"
    path.write_text("base: &b {delta_deg: 5, gamma: 0.3}\nfusion:\n  proposed: {<<: *b, gamma: 0.4}\n")
    assert read_yaml_mapping(path)["fusion"] == {"proposed": {"delta_deg": 5, "gamma": 0.4}}
    path.write_text("base: &b {delta_deg: 5}\nfusion:\n  proposed: {<<: *b, gamma: 0.4, gamma: 0.5}\n")
    with pytest.raises(ConfigError, match="'gamma' is given twice"):
        read_yaml_mapping(path)
