"""The pipeline file: loading, defaults and error messages naming the key."""

from pathlib import Path

import pytest

from mpipe.config import ConfigError
from mpipe.pipeline import PARAMETER_NAMES, load_pipeline

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "pipelines" / "simplified_clarinet.yaml"


def test_shipped_pipeline_loads():
    cfg = load_pipeline(SHIPPED)
    assert cfg.calibration_path == (ROOT / "calibration" / "simplified_clarinet.yaml").resolve()
    assert cfg.inversion.free == PARAMETER_NAMES
    assert cfg.inversion.lam == 0.013
    assert cfg.inversion.bounds.absolute("p_m", 1000.0) == (500.0, 2000.0)
    assert cfg.executor.kind == "local"


def write(tmp_path, text, calibration=True):
    if calibration:
        (tmp_path / "cal.yaml").write_text("name: x\n")
    path = tmp_path / "pipe.yaml"
    path.write_text(text)
    return path


def test_minimal_file_takes_defaults(tmp_path):
    cfg = load_pipeline(write(tmp_path, "calibration: cal.yaml\n"))
    assert cfg.inversion.start == "history"
    assert cfg.inversion.optimiser == "trust-region"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("inversion: {}\n", r"calibration: missing required key"),
        ("calibration: cal.yaml\nfoo: 1\n", r"<top level>|foo: unknown key"),
        ("calibration: cal.yaml\ninversion: {lamda: 0.01}\n", r"inversion\.lamda: unknown key"),
        ("calibration: cal.yaml\ninversion: {lam: 13}\n", r"inversion\.lam: .*metres"),
        ("calibration: cal.yaml\ninversion: {free: [k, q]}\n", r"inversion\.free: .*'q'"),
        ("calibration: cal.yaml\ninversion: {free: [k, k]}\n", r"inversion\.free: .*twice"),
        ("calibration: cal.yaml\ninversion: {optimiser: bfgs}\n", r"inversion\.optimiser"),
        (
            "calibration: cal.yaml\ninversion: {bounds: {k: [1.0e+8, 1.0e+6]}}\n",
            r"inversion\.bounds\.k: expected 0 < lower < upper",
        ),
        (
            "calibration: cal.yaml\ninversion: {bounds: {g: [1, 2, 3]}}\n",
            r"inversion\.bounds\.g: expected two numbers",
        ),
        ("calibration: cal.yaml\ninversion: {m: 1.0}\n", r"inversion\.m: start value"),
        (
            "calibration: cal.yaml\ninversion: {window_s: '20 ms'}\n",
            r"inversion\.window_s: expected a number",
        ),
        ("calibration: cal.yaml\ninversion: {signal: both}\n", r"inversion\.signal"),
        ("calibration: cal.yaml\nexecutor: {kind: dask}\n", r"executor\.scheduler: .*address"),
        ("calibration: cal.yaml\nexecutor: {workers: -1}\n", r"executor\.workers"),
        ("calibration: cal.yaml\nsource: x\n", r"source: this key is set by the loader"),
    ],
)
def test_malformed_files_name_the_key(tmp_path, text, match):
    with pytest.raises(ConfigError, match=match):
        load_pipeline(write(tmp_path, text))


def test_missing_calibration_file(tmp_path):
    with pytest.raises(ConfigError, match=r"pipe\.yaml: calibration: no such file"):
        load_pipeline(write(tmp_path, "calibration: nowhere.yaml\n", calibration=False))


def test_error_names_the_file(tmp_path):
    with pytest.raises(ConfigError, match=r"pipe\.yaml"):
        load_pipeline(write(tmp_path, "calibration: cal.yaml\nexecutor: {kind: cloud}\n"))
