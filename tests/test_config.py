"""Configuration: defaults, validation messages, the printed YAML."""

import subprocess
import sys

import pytest
import yaml

from tracker.config import (
    Config,
    ConfigError,
    config_from_dict,
    iter_knobs,
    load_config,
    render_yaml,
)


def write(tmp_path, text):
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    return path


def test_defaults_when_no_file():
    cfg = load_config(None)
    assert cfg == Config()
    assert cfg.camera.width == 1600 and cfg.camera.height == 1300


def test_values_are_read_and_coerced(tmp_path):
    cfg = load_config(write(tmp_path, "camera:\n  focal_length_mm: 8\n  cx: 799.25\n"))
    assert cfg.camera.focal_length_mm == 8.0 and isinstance(cfg.camera.focal_length_mm, float)
    assert cfg.camera.cx == 799.25
    assert cfg.camera.width == 1600  # untouched keys keep their defaults


def test_config_is_frozen():
    with pytest.raises(AttributeError):
        Config().camera.width = 3


@pytest.mark.parametrize("text, message", [
    ("camera:\n  widht: 5\n", r"cfg.yaml: camera.widht: found an unknown key, expected one of:"),
    ("camrea: {}\n", r"cfg.yaml: camrea: found an unknown section"),
    ("camera:\n  width: '1600'\n", r"camera.width: found '1600' \(str\), expected an integer"),
    ("camera:\n  width: 1.5\n", r"camera.width: found 1.5 \(float\), expected an integer"),
    ("camera:\n  width: true\n", r"camera.width: found True \(bool\), expected an integer"),
    ("camera:\n  focal_length_mm: -3\n",
     r"camera.focal_length_mm: found -3 \(int\), expected a number in \[0.1, 10000\]"),
    ("camera:\n  bit_depth: 9\n", r"camera.bit_depth: found 9 \(int\), expected one of 8, 10"),
    ("camera:\n  cx: .nan\n", r"camera.cx: found nan \(float\), expected a number or null"),
    ("camera: 5\n", r"camera: found 5 \(int\), expected a mapping of keys"),
    ("- 1\n- 2\n", r"\(top level\): found \[1, 2\] \(list\), expected a mapping of sections"),
    ("camera: {width: 3\n", r"\(YAML syntax\) at line 2, column 1"),
])
def test_bad_values_name_file_key_found_and_expected(tmp_path, text, message):
    with pytest.raises(ConfigError, match=message) as info:
        load_config(write(tmp_path, text))
    assert "\n" not in str(info.value)


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match=r"nope.yaml: cannot read the file"):
        load_config(tmp_path / "nope.yaml")


def test_empty_file_gives_defaults(tmp_path):
    assert load_config(write(tmp_path, "")) == Config()


def test_rendered_yaml_round_trips_and_documents_every_key():
    text = render_yaml(Config())
    assert config_from_dict(yaml.safe_load(text)) == Config()
    for section, key, _default, _unit, doc in iter_knobs():
        assert doc, f"{section}.{key} has no description"
        assert f"  {key}:" in text


def test_cli_config_prints_and_bad_file_exits_2_without_traceback(tmp_path):
    good = write(tmp_path, "camera:\n  focal_length_mm: 25\n")
    out = subprocess.run([sys.executable, "-m", "tracker.cli", "config", "--config", str(good)],
                         capture_output=True, text=True, check=True).stdout
    assert yaml.safe_load(out)["camera"]["focal_length_mm"] == 25.0
    bad = write(tmp_path, "camera:\n  width: -1\n")
    proc = subprocess.run([sys.executable, "-m", "tracker.cli", "config", "--config", str(bad)],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().endswith("camera.width: found -1 (int), expected an integer in "
                                        "[1, 65535]")
