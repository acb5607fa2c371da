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


# --- tone holes and fingerings ---------------------------------------------------------

HOLES = [
    {"name": "h1", "position": 0.50, "radius": 0.003, "chimney": 0.003},
    {"name": "h2", "position": 0.60, "radius": 0.0035, "chimney": 0.003},
]


def holed_dict(**changes):
    data = shipped_dict()
    data["bore"]["holes"] = [dict(h) for h in HOLES]
    data["fingerings"] = {"xx": [], "xo": ["h2"], "oo": ["h1", "h2"]}
    data["fingering"] = "xx"
    for key, value in changes.items():
        if value is DELETE:
            data.pop(key)
        else:
            data[key] = value
    return data


def test_fingerings_open_their_holes(tmp_path):
    path = write(tmp_path, holed_dict())
    cal = load_calibration(path)
    assert cal.fingering == "xx" and cal.bore.open_holes == ()
    assert {f.name for f in cal.fingerings} == {"xx", "xo", "oo"}
    cal = load_calibration(path, "oo")
    assert cal.fingering == "oo" and set(cal.bore.open_holes) == {"h1", "h2"}
    assert cal.with_fingering("xo").bore.open_holes == ("h2",)


def one_line_error(path, fingering=None):
    with pytest.raises(ConfigError) as err:
        load_calibration(path, fingering)
    text = str(err.value)
    assert "\n" not in text and text.startswith(str(path))
    return text


@pytest.mark.parametrize(
    "hole, message",
    [
        ({"position": 0.9}, r"not inside the bore \(0 to 0.8182 m\)"),
        ({"position": 0.8170}, "not inside the bore"),
        ({"radius": 0.008}, r"larger than the bore's radius 0.0075 m"),
        ({"position": 0.603}, "overlap"),
        ({"name": "h2"}, "two holes are named 'h2'"),
        ({"position": 0.27}, "lies between the microphones and the reference plane"),
        ({"radius": 0.03}, "expected a value in|larger than"),
    ],
)
def test_bad_holes_are_one_line_errors(tmp_path, hole, message):
    data = holed_dict()
    data["bore"]["holes"][0].update(hole)
    assert re.search(message, one_line_error(write(tmp_path, data)))


def test_a_hole_on_a_cone_must_fit_its_radius_there(tmp_path):
    # the shipped cone widens from 6 mm at 0.0316 m to 7.5 mm at 0.0826 m
    data = holed_dict()
    data["bore"]["holes"][0].update(position=0.04, radius=0.0062)
    assert "larger than the bore's radius" in one_line_error(write(tmp_path, data))
    data["bore"]["holes"][0].update(position=0.075, radius=0.0062)
    assert load_calibration(write(tmp_path, data)).bore.holes[0].radius == 0.0062


def test_a_register_hole_before_the_reference_plane_is_allowed(tmp_path):
    data = holed_dict()
    data["bore"]["holes"][0].update(position=0.15)
    assert load_calibration(write(tmp_path, data)).bore.holes[0].position == 0.15


@pytest.mark.parametrize(
    "changes, fingering, message",
    [
        ({}, "ox", "unknown fingering 'ox'; expected one of "),
        ({"fingering": "nope"}, None, "fingering: unknown fingering 'nope'"),
        ({"fingerings": {"xx": ["h9"]}}, None, "fingerings.xx: no hole named 'h9'"),
        ({}, "xx,ox", "unknown fingering 'ox'; expected one of "),
        ({"fingerings": ["h1"]}, None, "fingerings: expected a mapping"),
        ({"fingerings": {"xx": "h1"}}, None, "fingerings.xx: expected a list of hole names"),
    ],
)
def test_bad_fingerings_are_one_line_errors(tmp_path, changes, fingering, message):
    text = one_line_error(write(tmp_path, holed_dict(**changes)), fingering)
    assert message in text


def test_fingering_of_a_file_without_fingerings(tmp_path):
    assert "the file has no fingerings" in one_line_error(SHIPPED, "xx")
    data = holed_dict(fingerings=DELETE, fingering=DELETE)
    assert load_calibration(write(tmp_path, data)).bore.open_holes == ()  # all closed
    data["bore"]["open_holes"] = ["h1"]
    assert "set by the loader from the fingering" in one_line_error(write(tmp_path, data))
