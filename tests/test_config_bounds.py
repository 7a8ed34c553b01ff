"""The configuration loader's bounds: hostile YAML, YAML 1.2 scalars, keys checked together."""

import os

import pytest

from tracker.config import MAX_SENSOR_PIXELS, ConfigError, load_config
from tracker.yaml_bounded import MAX_DEPTH, parse_yaml


def write(tmp_path, text):
    path = tmp_path / "cfg.yaml"
    path.write_text(text)
    return path


def refused(tmp_path, text) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(write(tmp_path, text))
    message = str(info.value)
    assert "\n" not in message and len(message) < 300, message
    assert message.startswith(f"{tmp_path / 'cfg.yaml'}: ")
    return message


BILLION_LAUGHS = "".join(
    f"{name}: &{name} [{', '.join([f'*{prev}'] * 9) if prev else ', '.join(['lol'] * 9)}]\n"
    for prev, name in zip([None, *"abcdefgh"], "abcdefghi", strict=True))


def test_alias_bomb_is_refused_before_it_is_built(tmp_path):
    assert BILLION_LAUGHS.count("\n") == 9
    message = refused(tmp_path, BILLION_LAUGHS)
    assert "found aliases that expand to more than 100,000 values" in message


def test_a_few_aliases_are_fine(tmp_path):
    cfg = load_config(write(tmp_path, "sim:\n  rate_deg_s: &r [0.1, 0.2, 0.3]\n"
                                      "camera: {width: &w 1024, height: *w}\n"))
    assert cfg.sim.rate_deg_s == (0.1, 0.2, 0.3) and cfg.camera.height == 1024


def test_recursive_alias_is_refused(tmp_path):
    assert "an alias to a value that contains it" in refused(tmp_path, "a: &a [1, *a]\n")


@pytest.mark.parametrize("depth", [MAX_DEPTH + 1, 5000])
def test_deep_nesting_is_refused_without_recursion(tmp_path, depth):
    message = refused(tmp_path, "camera: " + "[" * depth + "]" * depth + "\n")
    assert f"nesting deeper than {MAX_DEPTH} levels" in message


def test_huge_integer_is_refused(tmp_path):
    assert "found an integer of 31 digits, expected at most 30" in refused(
        tmp_path, "camera:\n  width: " + "9" * 31 + "\n")
    assert "characters, expected at most 4096" in refused(
        tmp_path, "camera:\n  width: " + "9" * 5000 + "\n")


def test_duplicate_keys_are_refused_in_sections_and_at_top(tmp_path):
    message = refused(tmp_path, "camera:\n  width: 100\n  width: 200\n")
    assert ("at line 3, column 3: found the key 'width' a second time (first at line 2, "
            "column 3), expected each key once") in message
    assert "found the key 'camera' a second time" in refused(
        tmp_path, "camera: {}\nsim: {}\ncamera: {}\n")


def test_merge_keys_may_be_overridden():
    data = parse_yaml("base: &b {width: 800, height: 600}\ncamera:\n  <<: *b\n  width: 640\n")
    assert data["camera"] == {"width": 640, "height": 600}


@pytest.mark.parametrize("text, value", [
    ("1e-6", 1e-6), ("1.5E3", 1500.0), (".5", 0.5), ("2.", 2.0), ("-1e+2", -100.0),
    (".inf", float("inf")), ("0x10", 16), ("0o17", 15), ("012", 12), ("-7", -7),
    ("true", True), ("False", False), ("~", None), ("null", None),
    ("yes", "yes"), ("off", "off"), ("1_000", "1_000"), ("1:30", "1:30"),
    ("2026-01-01", "2026-01-01"),
])
def test_plain_scalars_follow_the_yaml_1_2_core_schema(text, value):
    assert parse_yaml(f"v: {text}\n") == {"v": value}


def test_yaml_1_2_float_is_a_number_in_the_configuration(tmp_path):
    cfg = load_config(write(tmp_path, "identify:\n  max_prob_false: 1e-9\n"
                                      "sim:\n  exposure_ms: 5e1\n"))
    assert cfg.identify.max_prob_false == 1e-9 and cfg.sim.exposure_ms == 50.0


def test_yes_is_not_a_boolean(tmp_path):
    assert refused(tmp_path, "identify:\n  enabled: yes\n").endswith(
        "identify.enabled: found 'yes' (str), expected true or false")


@pytest.mark.parametrize("text, found", [
    ("camera:\n  cx: !!timestamp 2001-12-14\n", "found the tag !!timestamp"),
    ("camera:\n  width: !!python/object:os.system x\n", "found the tag !!python/object"),
    ("camera:\n  width: !!int xyz\n", "found 'xyz' tagged int, expected an integer"),
    ("camera:\n  cx: !!float xyz\n", "found 'xyz' tagged float, expected a number"),
    ("identify:\n  enabled: !!bool maybe\n", "found 'maybe' tagged bool, expected true or false"),
    ("x: !!set {a, b}\n", "found the tag !!set"),
    ("a: 1\n---\nb: 2\n", "found another document, expected valid YAML"),
    ("\x00\x01", "found the control character U+0000"),
])
def test_tags_and_odd_documents_give_one_line(tmp_path, text, found):
    assert found in refused(tmp_path, text)


def test_huge_values_are_shown_cut_short(tmp_path):
    message = refused(tmp_path, "camera:\n  width: [" + ", ".join(["123456789"] * 1000) + "]\n")
    assert "found [123456789, 123456789, 123456789, 123456789, ...] (list)" in message


@pytest.mark.parametrize("text, message", [
    ("capture:\n  exposure_min_us: 200000\n  exposure_max_us: 100000\n",
     "capture.exposure_min_us: found 200000, more than capture.exposure_max_us (100000), "
     "expected exposure_min_us <= exposure_max_us"),
    ("capture:\n  exposure_us: 150000\n",
     "capture.exposure_us: found 150000, more than capture.exposure_max_us (100000)"),
    ("capture:\n  gain: 20\n", "capture.gain: found 20, more than capture.gain_max (16)"),
    ("service:\n  retry_initial_s: 10\n",
     "service.retry_initial_s: found 10, more than service.retry_max_s (1)"),
    ("link:\n  reopen_backoff_max_s: 0.1\n",
     "link.reopen_backoff_s: found 0.5, more than link.reopen_backoff_max_s (0.1)"),
    ("identify:\n  min_matched: 50\n",
     "identify.min_matched: found 50, more than identify.verify_stars (40)"),
    ("camera:\n  width: 65535\n  height: 65535\n",
     f"camera.width x camera.height: found 65535 x 65535 = 4,294,836,225 pixels, expected "
     f"at most {MAX_SENSOR_PIXELS:,}"),
    ("camera:\n  cx: 5000\n", "camera.cx: found 5000, expected a pixel inside the image, "
                              "in [-0.5, 1599.5]"),
])
def test_keys_that_contradict_each_other_are_refused(tmp_path, text, message):
    assert message in refused(tmp_path, text)


def test_largest_sensor_allowed_loads(tmp_path):
    cfg = load_config(write(tmp_path, "camera:\n  width: 8192\n  height: 4096\n"))
    assert cfg.camera.width * cfg.camera.height == MAX_SENSOR_PIXELS


def test_config_that_is_not_a_regular_file_is_refused_without_reading(tmp_path):
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match=r"fifo.yaml: cannot read the file: a named pipe "
                                          r"\(FIFO\), not a regular file"):
        load_config(fifo)
    with pytest.raises(ConfigError, match=r"cannot read the file: a character device"):
        load_config("/dev/zero")
    with pytest.raises(ConfigError, match=r"cannot read the file: a folder"):
        load_config(tmp_path)
    big = tmp_path / "big.yaml"
    big.write_text("#" * (1 << 20) + "\n")
    with pytest.raises(ConfigError, match=r"big.yaml: cannot read the file: 1,048,577 bytes, "
                                          r"more than the 1,048,576 allowed"):
        load_config(big)
