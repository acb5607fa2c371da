"""The pipeline file: loading, defaults and error messages naming the key."""

from pathlib import Path

import pytest

from mpipe.core.config import ConfigError
from mpipe.inversion.settings import PARAMETER_NAMES
from mpipe.pipeline.settings import load_pipeline

ROOT = Path(__file__).resolve().parents[2]
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
    assert cfg.inversion.optimiser == "trust-region"
    # the shipped pipeline writes out the same inversion defaults as the code holds
    shipped = load_pipeline(
        Path(__file__).resolve().parents[2] / "pipelines" / "simplified_clarinet.yaml"
    )
    assert shipped.inversion == cfg.inversion


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


def _leaf_keys(data, prefix=""):
    keys = set()
    for k, v in data.items():
        if isinstance(v, dict):
            keys |= _leaf_keys(v, f"{prefix}{k}.")
        else:
            keys.add(prefix + k)
    return keys


def test_shipped_pipeline_shows_every_setting_of_every_stage():
    import dataclasses

    import yaml

    from mpipe.core.config import describe_keys
    from mpipe.pipeline.settings import PipelineConfig

    expected = set()
    for key, _, doc in describe_keys(PipelineConfig):
        assert doc, f"{key}: every setting needs a one-line meaning"
        expected.add(key)
    # sections are not leaves, and `source` is set by the loader
    sections = {f.name for f in dataclasses.fields(PipelineConfig)} - {"calibration", "source"}
    expected -= sections | {"source", "inversion.bounds"}
    shipped = _leaf_keys(yaml.safe_load(SHIPPED.read_text()))
    assert not expected - shipped, f"missing from {SHIPPED.name}: {sorted(expected - shipped)}"


def test_printed_defaults_read_back_as_the_defaults(tmp_path):
    import dataclasses

    from mpipe.pipeline.settings import PipelineConfig, pipeline_yaml

    (tmp_path / "cal.yaml").write_text("name: x\n")
    path = tmp_path / "pipe.yaml"
    path.write_text(pipeline_yaml(calibration="cal.yaml"))
    cfg = load_pipeline(path)
    assert dataclasses.replace(cfg, source="") == PipelineConfig(calibration="cal.yaml")
    # a changed value is written and flagged against its default
    changed = dataclasses.replace(cfg, inversion=dataclasses.replace(cfg.inversion, hop_s=0.01))
    text = pipeline_yaml(changed)
    assert "hop_s: 0.01" in text and "(default 0.02)" in text


@pytest.mark.parametrize("value", [1e-5, 0.1, 1 / 3, 8.23e10, -0.01, 2.4e-4, 1e300, 123456.0])
def test_floats_are_written_so_that_yaml_reads_them_back_exactly(value):
    import yaml

    from mpipe.core.config import _yaml_scalar

    assert yaml.safe_load(f"x: {_yaml_scalar(value)}")["x"] == value


def test_config_command_prints_and_refuses_to_overwrite(tmp_path, capsys):
    from mpipe.cli.main import main

    assert main(["config", str(SHIPPED)]) == 0
    out = capsys.readouterr().out
    assert "# [dB] tolerance on the mean |magnitude error| over coherent bins" in out
    assert "max_band_db: 1.5" in out
    target = tmp_path / "p.yaml"
    target.write_text("mine")
    assert main(["config", "-o", str(target)]) == 2
    assert target.read_text() == "mine"


def test_a_calibration_given_as_the_pipeline_and_back_is_named(tmp_path):
    from mpipe.core.config import ConfigError
    from mpipe.measurement.calibration import load_calibration

    cal = ROOT / "calibration" / "simplified_clarinet.yaml"
    pipe = ROOT / "pipelines" / "simplified_clarinet.yaml"
    with pytest.raises(ConfigError, match="this is a calibration file"):
        load_pipeline(cal)
    with pytest.raises(ConfigError, match="this is a pipeline file"):
        load_calibration(pipe)


def test_the_config_placeholder_does_not_block_a_given_calibration(tmp_path, capsys):
    # Issue 19: `mpipe config > my.yaml` writes calibration: CALIBRATION.yaml; a command
    # given its own calibration (mpipe run --calibration) accepts the file, the others name
    # the missing calibration
    from mpipe.cli.main import main
    from mpipe.core.config import ConfigError
    from mpipe.pipeline.settings import load_pipeline

    assert main(["config", "-o", str(tmp_path / "my.yaml")]) == 0
    with pytest.raises(ConfigError, match="calibration: no such file .*CALIBRATION.yaml"):
        load_pipeline(tmp_path / "my.yaml")
    assert load_pipeline(tmp_path / "my.yaml", check_calibration=False).calibration
    cal = Path(__file__).resolve().parents[2] / "calibration" / "simplified_clarinet.yaml"
    argv = ["run", str(tmp_path / "my.yaml"), str(tmp_path / "none.wav"), "-o", str(tmp_path)]
    assert main([*argv, "--calibration", str(cal)]) == 2
    assert "none.wav: no such take file" in capsys.readouterr().err
    # mpipe separate names its own calibration: the placeholder does not block it either
    sep = [
        "separate",
        str(tmp_path / "none.wav"),
        str(cal),
        "--pipeline",
        str(tmp_path / "my.yaml"),
    ]
    assert main([*sep, "-o", str(tmp_path / "sep")]) == 2
    assert "CALIBRATION.yaml" not in capsys.readouterr().err


def test_the_model_is_low_passed_with_the_measurements_filter(tmp_path):
    import numpy as np

    from mpipe.core.filters import design_lowpass

    cal = (ROOT / "calibration" / "simplified_clarinet.yaml").resolve()
    path = tmp_path / "p.yaml"
    path.write_text(
        f"calibration: {cal}\ntranslation:\n  lowpass_hz: 6000.0\n  transition_hz: 800.0\n"
        "  stopband_db: 80.0\n"
    )
    cfg = load_pipeline(path)
    measured = design_lowpass(1e5, 6000.0, 800.0, 80.0)
    np.testing.assert_array_equal(cfg.inversion.lowpass.design(1e5).taps, measured.taps)
    # the old key of the model's own low-pass is refused, naming where the filter is set
    path.write_text(f"calibration: {cal}\ninversion:\n  lowpass_hz: 7000.0\n")
    with pytest.raises(ConfigError, match="inversion.lowpass_hz: .* translation.lowpass_hz"):
        load_pipeline(path)
