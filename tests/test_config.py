import pytest
import yaml

from nbvdata.core.config import ConfigError, SimConfig, load_config, to_yaml


def test_defaults_are_the_authors_settings():
    config = SimConfig()
    assert (config.sensor.width, config.sensor.height) == (176, 144)
    assert (config.sensor.hfov, config.sensor.vfov) == (0.77, 0.61)
    assert (config.grid.prob_hit, config.grid.prob_miss) == (0.7, 0.4)
    assert (config.grid.clamp_min, config.grid.clamp_max) == (0.1192, 0.971)
    assert config.views.radius == 0.4 and config.grid.size == 32


def test_unknown_key_names_the_closest_setting(tmp_path):
    with pytest.raises(ConfigError, match=r"views\.cont'; did you mean 'views\.count'"):
        load_config(SimConfig, overrides=["views.cont=3"])
    path = tmp_path / "bad.yaml"
    path.write_text("sensr:\n  width: 10\n")
    with pytest.raises(ConfigError, match="did you mean 'sensor'"):
        load_config(SimConfig, path)


@pytest.mark.parametrize("override, message", [
    ("grid.size=33", "must be even"),
    ("sensor.near=2.0", "near < far"),
    ("views.count=zero", "must be an integer"),
    ("views.layout=cube", "must be one of"),
    ("coverage.metric=manhattan", "must be one of"),
    ("views", "expected key=value"),
])
def test_bad_values_state_the_rule(override, message):
    with pytest.raises(ConfigError, match=message):
        load_config(SimConfig, overrides=[override])


def test_file_then_overrides_and_yaml_round_trip(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("views:\n  count: 64\nsensor:\n  width: 32\n")
    config = load_config(SimConfig, path, ["sensor.width=40", "grid.extent=0.4"])
    assert config.views.count == 64 and config.sensor.width == 40 and config.grid.extent == 0.4
    again = tmp_path / "again.yaml"
    again.write_text(to_yaml(config))
    assert load_config(SimConfig, again) == config
    assert yaml.safe_load(to_yaml(config))["grid"]["size"] == 32


def test_missing_and_broken_files(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        load_config(SimConfig, tmp_path / "none.yaml")
    broken = tmp_path / "broken.yaml"
    broken.write_text("views: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(SimConfig, broken)


def test_numbers_in_exponent_notation_are_numbers_in_files_flags_and_overrides(tmp_path, capsys):
    """YAML 1.1 (PyYAML) reads 1e-5 as text: a float setting takes it as the number it spells."""
    from nbvtrain.cli import main
    from nbvtrain.networks.config import TrainConfig

    assert yaml.safe_load("lr: 1e-5")["lr"] == "1e-5"  # the quirk this guards against
    path = tmp_path / "train.yaml"
    path.write_text("lr: 1e-5\nnear_best: 9E-1\n")
    config = load_config(TrainConfig, path, ["dropout=+2.5e-1"])
    assert (config.lr, config.near_best, config.dropout) == (1e-5, 0.9, 0.25)
    assert load_config(SimConfig, overrides=["sensor.noise_std=2e-3"]).sensor.noise_std == 0.002
    for text in ("1e", "e-5", "1e-5x", "one"):  # still refused: not a number
        with pytest.raises(ConfigError, match="must be a number"):
            load_config(TrainConfig, overrides=[f"lr={text}"])
    # the flag: str(1e-05) is '1e-05', which reached the settings as text and was refused
    assert main(["fit", str(tmp_path / "none"), "--lr", "1e-5", "--out", str(tmp_path / "run")]) == 2
    assert "no such shard or folder" in capsys.readouterr().err
