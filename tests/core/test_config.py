"""Configuration classes: building from YAML, commented YAML out, the key listing."""

from __future__ import annotations

import dataclasses
from typing import Literal

import pytest
import yaml

from mpipe.core.config import (
    ConfigError,
    Where,
    between,
    build,
    describe_keys,
    settings_of,
    spec,
    to_commented_yaml,
    yaml_scalar,
)


@dataclasses.dataclass(frozen=True)
class Inner:
    width_m: float = spec("m", "a width", between(0.0, 1.0), default=0.5)
    pair: tuple[float, ...] = spec("Hz", "a band", default=(1.0, 2.0))


@dataclasses.dataclass(frozen=True)
class Outer:
    name: str = spec("", "a required name")
    mode: Literal["a", "b"] = spec("", "a choice", default="a")
    count: int = spec("", "a count", default=3)
    inner: Inner = spec("", "a section", default=Inner())
    other: Inner = spec("", "another section", default=Inner())


def _build(text: str) -> Outer:
    return build(Outer, yaml.safe_load(text), Where("f.yaml"))


def test_every_key_is_listed_with_unit_meaning_and_default():
    rows = settings_of(Outer)
    keys = [r.key for r in rows]
    assert keys == [
        "name",
        "mode",
        "count",
        "inner",
        "inner.width_m",
        "inner.pair",
        "other",
        "other.width_m",
        "other.pair",
    ]
    by_key = {r.key: r for r in rows}
    assert by_key["name"].default is dataclasses.MISSING and not by_key["name"].section
    assert by_key["inner"].section and by_key["inner.width_m"].default == 0.5
    assert by_key["other.pair"].unit == "Hz" and by_key["other.pair"].default == (1.0, 2.0)
    assert describe_keys(Outer) == [(r.key, r.unit, r.doc) for r in rows]


def test_all_keys_written_read_back_equal():
    obj = Outer(name="x", count=5, inner=Inner(width_m=0.25))
    text = to_commented_yaml(obj)
    assert _build(text) == obj
    assert "# [m] a width (default 0.5)" in text and "count: 5" in text


def test_show_picks_keys_and_drops_empty_sections():
    obj = Outer(name="x", count=5, other=Inner(pair=(3.0, 4.0)))
    seen = []

    def show(key: str, changed: bool) -> bool:
        seen.append((key, changed))
        return key in {"name", "inner.width_m"} or changed

    text = to_commented_yaml(obj, show=show)
    data = yaml.safe_load(text)
    # name (required, so always "changed"), the picked key, and the changed ones
    assert data == {
        "name": "x",
        "count": 5,
        "inner": {"width_m": 0.5},
        "other": {"pair": [3.0, 4.0]},
    }
    assert ("mode", False) in seen and ("other.pair", True) in seen and ("count", True) in seen
    # the keys left out hold their defaults: the text reads back into the same object
    assert _build(text) == obj
    # nothing picked: no text at all (not an empty section header)
    assert to_commented_yaml(Inner(), show=lambda key, changed: False) == ""


def test_an_unknown_key_is_one_line_naming_file_and_key():
    with pytest.raises(ConfigError) as info:
        _build("name: x\ninner: {widht_m: 0.1}\n")
    message = str(info.value)
    assert message.startswith("f.yaml: inner.widht_m: unknown key") and "\n" not in message
    assert "(did you mean width_m?)" in message and message.endswith(
        "expected one of: pair, width_m"
    )
    # nothing close: no guess, the list only
    with pytest.raises(ConfigError, match=r"zzz: unknown key; expected one of: count, inner"):
        _build("name: x\nzzz: 1\n")


def test_a_value_out_of_range_names_the_key_and_unit():
    with pytest.raises(ConfigError, match=r"f\.yaml: inner\.width_m: .*\[m\]"):
        _build("name: x\ninner: {width_m: 2.0}\n")


@pytest.mark.parametrize("value", [1e-5, 0.1, 1 / 3, 8.23e10, -0.01, 2.4e-4, 1e300, 123456.0])
def test_floats_are_written_so_that_yaml_reads_them_back_exactly(value):
    assert yaml.safe_load(f"x: {yaml_scalar(value)}")["x"] == value


def test_a_key_given_twice_is_refused_with_its_lines_and_a_merge_is_not():
    # Issue 33: PyYAML keeps the last of two equal keys without a word
    from mpipe.core.config import ConfigError, parse_yaml

    with pytest.raises(
        ConfigError, match=r"^f.yaml: key 'b' given twice \(lines 2 and 4\); keep one$"
    ):
        parse_yaml("a: 1\nb: 2\nc: 3\nb: 4\n", "f.yaml")
    with pytest.raises(ConfigError, match=r"key 'x' given twice \(lines 3 and 4\)"):
        parse_yaml("a:\n  - y: 1\n    x: 2\n    x: 3\n", "f.yaml")  # nested in a list
    with pytest.raises(ConfigError, match=r"key 'x' given twice \(line 1\)"):
        parse_yaml("{x: 1, x: 2}", "f.yaml")  # a flow mapping on one line
    # the same key in two different mappings is no duplicate; a merge may be overridden
    assert parse_yaml("a: {x: 1}\nb: {x: 2}\n", "f.yaml") == {"a": {"x": 1}, "b": {"x": 2}}
    merged = parse_yaml("base: &b {x: 1, y: 2}\nc:\n  <<: *b\n  x: 5\n", "f.yaml")
    assert merged["c"] == {"x": 5, "y": 2}
