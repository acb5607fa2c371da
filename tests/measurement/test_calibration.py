"""Each configuration mistake gives an error naming the file, the key path and what was expected."""

import re
from pathlib import Path

import pytest
import yaml

from mpipe.core.config import ConfigError
from mpipe.measurement.calibration import load_calibration

SHIPPED = Path(__file__).resolve().parents[2] / "calibration" / "simplified_clarinet.yaml"


def shipped_dict():
    return yaml.safe_load(SHIPPED.read_text())


def write(tmp_path, data):
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_shipped_file_loads(shipped_calibration):
    cal = shipped_calibration
    assert cal.bore.length == pytest.approx(0.8182)
    assert [m.position for m in cal.microphones] == [0.2482, 0.2682, 0.2882]
    assert cal.main_radius == 0.0075
    assert cal.air.temperature_c == 20.0


def mutate(path, value):
    data = shipped_dict()
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    last = keys[-1]
    if value is DELETE:
        del node[last]
    else:
        if isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value
    return data


DELETE = object()

CASES = [
    ("bore.segments.2.radius", 7.5, r"bore\.segments\[2\]\.radius: expected a value in .*metres"),
    ("bore.segments.1.x_start", 0.04, r"bore\.segments\[1\]\.x_start: gap of 0\.0084 m"),
    ("bore.segments.1.x_start", 0.02, r"bore\.segments\[1\]\.x_start: overlap"),
    ("bore.segments.0.x_end", -0.1, r"bore\.segments\[0\]\.x_end: expected a value in"),
    ("bore.segments.2.x_end", 0.05, r"bore\.segments\[2\]\.x_end: expected x_end > x_start"),
    ("bore.segments.0.colour", "red", r"bore\.segments\[0\]\.colour: unknown key"),
    ("bore.segments.0.radius", "wide", r"bore\.segments\[0\]\.radius: .*number"),
    ("air.temperature_c", DELETE, r"air\.temperature_c: missing required key"),
    ("air.temperature_c", 293.15, r"air\.temperature_c: expected a value in .*degrees Celsius"),
    ("microphones.2.position", 0.9, r"microphones\[2\]\.position: microphone at 0\.9 m is outside"),
    ("microphones.2.channel", 2, r"microphones: two microphones share a channel"),
    ("reference_plane", 1.2, r"reference_plane: reference plane at 1\.2 m is outside the bore"),
    ("reference_plane", 0.05, r"microphones: .*one cylindrical segment"),
    ("bore.radiation.model", "baffled", r"bore\.radiation\.model: expected one of"),
    ("bore.radiation.model", "finite-flange", r"bore\.radiation\.flange_radius: required"),
    ("microphones.0.sensitivity", -1.0, r"microphones\[0\]\.sensitivity: expected a positive"),
]


@pytest.mark.parametrize("key,value,message", CASES)
def test_configuration_errors(tmp_path, key, value, message):
    path = write(tmp_path, mutate(key, value))
    with pytest.raises(ConfigError, match=message) as info:
        load_calibration(path)
    assert str(info.value).startswith(str(path))


def test_microphone_count(tmp_path):
    """Any count >= 2 loads; one microphone cannot tell two waves apart."""
    for n in (2, 4):
        data = shipped_dict()
        mics = [dict(data["microphones"][0], name=f"m{i}") for i in range(n)]
        for i, m in enumerate(mics):
            m["position"], m["channel"] = 0.2482 + 0.015 * i, i + 1
        data["microphones"] = mics
        assert len(load_calibration(write(tmp_path, data)).microphones) == n
    data = shipped_dict()
    data["microphones"] = data["microphones"][:1]
    with pytest.raises(ConfigError, match=r"microphones: expected at least 2 microphones.*got 1"):
        load_calibration(write(tmp_path, data))


def test_microphones_outside_the_cylinder(tmp_path):
    data = shipped_dict()
    data["microphones"][0]["position"] = 0.05  # in the mouthpiece cone
    with pytest.raises(ConfigError, match="one cylindrical segment"):
        load_calibration(write(tmp_path, data))


def test_segment_needs_one_radius_form(tmp_path):
    data = shipped_dict()
    data["bore"]["segments"][2]["radius_start"] = 0.0075
    with pytest.raises(ConfigError, match=re.escape("bore.segments[2]: give either 'radius'")):
        load_calibration(write(tmp_path, data))


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_calibration(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("bore: [unclosed")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_calibration(bad)
    bad.write_text("- a list\n")
    with pytest.raises(ConfigError, match="expected a mapping"):
        load_calibration(bad)


def test_exponent_without_sign_or_dot_reads_as_number(tmp_path):
    # YAML 1.1 (PyYAML) reads 75e-4 as a string; users write numbers that way
    text = SHIPPED.read_text().replace("radius: 0.0075", "radius: 75e-4")
    path = tmp_path / "cal.yaml"
    path.write_text(text)
    assert load_calibration(path).bore.segments[2].radius == 0.0075
