"""Reed parameters: YAML loading, validation messages, stability bound, optimiser vector."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from mpipe.core.config import ConfigError
from mpipe.reed.parameters import (
    VECTOR_FIELDS,
    InvalidReedError,
    ReedParameters,
    check_stability,
    load_reed,
    stability_limit,
)

ROOT = Path(__file__).resolve().parents[2]
TABLE1 = ROOT / "calibration" / "reed_table1.yaml"

TABLE1_TEXT = """\
k: 8.66e6
S: 7.62e-5
y_m: 4.0e-4
p_m: 1800
lambda: 0.013
m: 0.05
g: 3000
k_c: 8.23e10
"""


def write(tmp_path, text, name="reed.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def table1():
    return ReedParameters(
        k=8.66e6, S=7.62e-5, y_m=4e-4, p_m=1800.0, lam=0.013, m=0.05, g=3000.0, k_c=8.23e10
    )


def test_shipped_table1_file():
    reed = load_reed(TABLE1)
    assert reed == table1()
    assert reed.y_c == 2.4e-4 and reed.alpha == 2.0
    # physics.md K: sqrt(k/m)/(2 pi) is about 2.1 kHz for Table 1
    assert reed.resonance_hz == pytest.approx(math.sqrt(8.66e6 / 0.05) / (2 * math.pi))
    assert 2000 < reed.resonance_hz < 2200


def test_defaults_and_lambda_mapping(tmp_path):
    reed = load_reed(write(tmp_path, TABLE1_TEXT))
    assert reed.lam == 0.013
    assert reed.y_c == 2.4e-4 and reed.alpha == 2.0
    assert reed.to_mapping()["lambda"] == 0.013
    assert all(isinstance(getattr(reed, f.name), float) for f in dataclasses.fields(reed))


def test_field_name_lam_is_an_unknown_key(tmp_path):
    text = TABLE1_TEXT.replace("lambda:", "lam:")
    with pytest.raises(ConfigError, match=r"reed\.yaml: lam: unknown key.*lambda"):
        load_reed(write(tmp_path, text))


def test_unknown_key_names_file_and_key(tmp_path):
    with pytest.raises(ConfigError, match=r"reed\.yaml: mass: unknown key"):
        load_reed(write(tmp_path, TABLE1_TEXT + "mass: 0.05\n"))


def test_missing_key(tmp_path):
    text = "\n".join(line for line in TABLE1_TEXT.splitlines() if not line.startswith("g:"))
    with pytest.raises(ConfigError, match=r"reed\.yaml: g: missing required key"):
        load_reed(write(tmp_path, text))


def test_contact_beyond_closure_rejected(tmp_path):
    with pytest.raises(ConfigError, match=r"reed\.yaml: y_c: .*y_c <= y_m"):
        load_reed(write(tmp_path, TABLE1_TEXT + "y_c: 4.1e-4\n"))
    with pytest.raises(InvalidReedError, match="y_c"):
        dataclasses.replace(table1(), y_c=5e-4)
    # contact from closure (y_c = y_m) is a valid reed
    assert load_reed(write(tmp_path, TABLE1_TEXT + "y_c: 4.0e-4\n")).y_c == 4e-4


@pytest.mark.parametrize(
    ("line", "key", "pattern"),
    [
        ("k: -8.66e6", "k", "positive"),
        ("p_m: 0", "p_m", "positive"),
        ("y_m: 0.4", "y_m", "implausible.*0.4 mm is 4e-4"),  # millimetres typed as metres
        ("lambda: 13", "lambda", "implausible.*13 mm is 0.013"),
        ("g: fast", "g", "expected a number"),
    ],
)
def test_bad_values_name_the_key(tmp_path, line, key, pattern):
    name = line.split(":")[0]
    text = "\n".join(
        line if row.startswith(name + ":") else row for row in TABLE1_TEXT.splitlines()
    )
    with pytest.raises(ConfigError, match=rf"reed\.yaml: {key}: .*{pattern}"):
        load_reed(write(tmp_path, text))


def test_zero_contact_stiffness_switches_contact_off():
    assert dataclasses.replace(table1(), k_c=0.0).k_c == 0.0


def test_stability_bound():
    reed = table1()
    # physics.md G.5: 2 sqrt(m/k) = 1.5e-4 s for Table 1
    assert stability_limit(reed) == pytest.approx(2 * math.sqrt(0.05 / 8.66e6))
    check_stability(reed, 100_000.0)
    fs_min = 1.0 / stability_limit(reed)
    check_stability(reed, fs_min * 1.01)
    with pytest.raises(ValueError, match=r"T = 1/fs .* not below 2 sqrt\(m/k\)"):
        check_stability(reed, fs_min * 0.99)
    # contact at closure stiffens the reed, so the contact-aware bound is stricter
    k_eff = 8.66e6 + 2 * 8.23e10 * (4e-4 - 2.4e-4)
    assert stability_limit(reed, contact=True) == pytest.approx(2 * math.sqrt(0.05 / k_eff))
    with pytest.raises(ValueError, match="k_eff"):
        check_stability(reed, fs_min * 1.01, contact=True)


def test_vector_round_trip():
    reed = table1()
    x = reed.as_vector()
    assert x.tolist() == [8.66e6, 7.62e-5, 4e-4, 1800.0, 0.05, 3000.0, 0.013, 8.23e10]
    assert VECTOR_FIELDS == ("k", "S", "y_m", "p_m", "m", "g", "lam", "k_c")
    assert ReedParameters.from_vector(x) == reed
    other = ReedParameters.from_vector(x * 1.01, y_c=2e-4, alpha=1.5)
    assert other.y_c == 2e-4 and other.alpha == 1.5
    np.testing.assert_allclose(other.as_vector(), x * 1.01)
    with pytest.raises(InvalidReedError, match="expected 8 values"):
        ReedParameters.from_vector(x[:7])
