"""The pipeline file: loading, defaults and error messages naming the key."""

import dataclasses
from pathlib import Path

import hypothesis
import hypothesis.strategies as st
import pytest
import yaml

from mpipe.core.config import ConfigError
from mpipe.inversion.settings import PARAMETER_NAMES, REMOVED_KEYS
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


def _every_leaf():
    """Every key of a pipeline file, from the classes the loader builds."""
    from mpipe.core.config import settings_of
    from mpipe.pipeline.settings import PipelineConfig

    rows = settings_of(PipelineConfig)
    for row in rows:
        assert row.doc, f"{row.key}: every setting needs a one-line meaning"
    return {r.key for r in rows if not r.section} - {"source"}


def test_every_user_tier_key_names_a_setting():
    # a renamed or removed setting must leave the user tier too (else the tier lists a ghost)
    from mpipe.pipeline.settings import USER_SETTINGS, PipelineConfig

    sections = {f.name for f in dataclasses.fields(PipelineConfig)}
    every = _every_leaf()
    for section, keys in USER_SETTINGS.items():
        assert not section or section in sections, section
        for key in keys:
            path = f"{section}.{key}" if section else key
            assert any(k == path or k.startswith(path + ".") for k in every), path


def test_shipped_pipeline_shows_the_user_tier_each_key_explained():
    from mpipe.pipeline.settings import is_user_setting

    text = SHIPPED.read_text()
    shipped = _leaf_keys(yaml.safe_load(text))
    user = {k for k in _every_leaf() if is_user_setting(k)}
    assert shipped == user
    assert 20 <= len(shipped) <= 40  # issue 23: the 20-40 settings a user changes
    assert len(_every_leaf()) > 2 * len(user)  # the rest stay out of the way
    # every key line follows its own comment (unit and meaning)
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.strip() and not line.lstrip().startswith("#") and not line.endswith(":"):
            if "#" not in line:  # a section line carries its comment on the same line
                assert lines[i - 1].lstrip().startswith("#"), f"{line!r} has no comment"


def test_shipped_pipeline_is_the_defaults_but_for_the_calibration():
    from mpipe.pipeline.settings import PipelineConfig

    cfg = load_pipeline(SHIPPED)
    default = PipelineConfig(calibration="../calibration/simplified_clarinet.yaml")
    assert dataclasses.replace(cfg, source="") == default


def test_printed_defaults_read_back_as_the_defaults(tmp_path):
    from mpipe.pipeline.settings import PipelineConfig, pipeline_yaml

    (tmp_path / "cal.yaml").write_text("name: x\n")
    path = tmp_path / "pipe.yaml"
    for every in (False, True):
        path.write_text(pipeline_yaml(calibration="cal.yaml", every=every))
        cfg = load_pipeline(path)
        assert dataclasses.replace(cfg, source="") == PipelineConfig(calibration="cal.yaml")
        printed = _leaf_keys(yaml.safe_load(path.read_text()))
        assert (printed == _every_leaf()) if every else (len(printed) <= 40)
    # a changed value is written and flagged against its default
    changed = dataclasses.replace(cfg, inversion=dataclasses.replace(cfg.inversion, hop_s=0.01))
    text = pipeline_yaml(changed)
    assert "hop_s: 0.01" in text and "(default 0.02)" in text


def test_an_advanced_key_set_in_a_file_works_and_is_shown(tmp_path):
    from mpipe.pipeline.settings import is_user_setting, pipeline_yaml

    path = write(
        tmp_path,
        "calibration: cal.yaml\ninversion:\n  design_points: 16\n  local_starts: 8\n"
        "separation: {smooth_s: 2.0}\n",
    )
    cfg = load_pipeline(path)
    assert cfg.inversion.design_points == 16 and cfg.separation.smooth_s == 2.0
    assert not is_user_setting("inversion.design_points")
    text = pipeline_yaml(cfg)
    printed = _leaf_keys(yaml.safe_load(text))
    user = {k for k in _every_leaf() if is_user_setting(k)}
    # the user tier, and the advanced keys whose value is not the default (local_starts: 8
    # is the default: it changes nothing and is not shown)
    assert printed == user | {"inversion.design_points", "separation.smooth_s"}
    assert "design_points: 16" in text and "(default 256)" in text
    # what is printed reads back into the same configuration
    again = write(tmp_path, text)
    assert dataclasses.replace(load_pipeline(again), source="") == dataclasses.replace(
        cfg, source=""
    )


@pytest.mark.parametrize(
    "text",
    [
        "calibration: cal.yaml\ninversion: {desing_points: 16}\n",
        "calibration: cal.yaml\nseparation: {smoth_s: 1}\n",
        "calibration: cal.yaml\ninversion: {bounds: {q: [1, 2]}}\n",
    ],
)
def test_an_unknown_key_is_a_one_line_error(tmp_path, text):
    with pytest.raises(ConfigError) as info:
        load_pipeline(write(tmp_path, text))
    message = str(info.value)
    assert "\n" not in message and "pipe.yaml" in message and "unknown key" in message
    # the list of keys the section accepts names the advanced keys too
    assert "design_points" in message or "smooth_s" in message or "y_m" in message


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("fast_objective: false", "compiled model"),
        ("warm_secant: false", "secant trust region"),
        ("jacobian: differences", "forward sensitivities"),
        ("cold_start: step1", "global"),
        ("start: rest", "measured history"),
        ("settle_s: 0.25", "lead_s"),
        ("step1_solver: nelder-mead", "linear least squares"),
        ("step1_every_window: true", "cold-started windows"),
    ],
)
def test_a_removed_key_says_it_was_removed_and_what_replaces_it(tmp_path, text, says):
    # a pipeline file written for mpipe before issue 23 (an upgrading user's) gets one line
    # naming the key as removed, not an "unknown key" with a list of 40 others
    with pytest.raises(ConfigError) as info:
        load_pipeline(write(tmp_path, f"calibration: cal.yaml\ninversion: {{{text}}}\n"))
    message = str(info.value)
    key = text.partition(":")[0]
    assert message.startswith(f"{tmp_path / 'pipe.yaml'}: inversion.{key}: removed from mpipe")
    assert "\n" not in message and says in message and "unknown key" not in message


def test_several_removed_keys_are_named_in_one_line(tmp_path):
    # an earlier mpipe's shipped file wrote every key out: all removed ones at once, so the
    # user does not meet them one run at a time
    text = "calibration: cal.yaml\ninversion: {lam: 0.013, fast_objective: true, start: history}\n"
    with pytest.raises(ConfigError) as info:
        load_pipeline(write(tmp_path, text))
    message = str(info.value)
    assert "\n" not in message and "inversion: fast_objective, start: removed" in message
    assert "docs/settings.md" in message


@pytest.mark.parametrize("choice", ["powell", "nelder-mead"])
def test_a_removed_optimiser_says_what_to_use(tmp_path, choice):
    with pytest.raises(ConfigError, match=rf"inversion\.optimiser: '{choice}' was removed.*"
                       "trust-region.*rosenbrock"):  # fmt: skip
        load_pipeline(
            write(tmp_path, f"calibration: cal.yaml\ninversion: {{optimiser: {choice}}}\n")
        )


def test_the_settings_page_is_in_sync():
    # docs/settings.md is generated from the settings' specs: regenerate and compare
    from mpipe.pipeline.settings import settings_markdown

    page = (ROOT / "docs" / "settings.md").read_text(encoding="utf-8")
    assert page == settings_markdown(), (
        "docs/settings.md is out of date: run "
        "`mpipe config --all --markdown -o docs/settings.md --force`"
    )


def test_the_settings_page_documents_every_key_with_its_tier():
    # read the tables back: every key once, its tier, its default as the loader reads it
    from mpipe.pipeline.settings import PipelineConfig, is_user_setting, settings_markdown

    rows, section = {}, ""
    page, _, removed = settings_markdown().partition("\n## Removed settings\n")
    # the removed keys have their own table, each with what became of it
    assert all(f"| `inversion.{key}` |" in removed for key in REMOVED_KEYS)
    for line in page.splitlines():
        if line.startswith("## "):
            section = line.split("`")[1] + "." if "`" in line else ""
        elif line.startswith("| `"):
            cells = [c.strip() for c in line.strip("|").split(" | ")]
            key = section + cells[0].strip("`")
            assert key not in rows, f"{key} documented twice"
            rows[key] = cells
    assert set(rows) == _every_leaf()
    defaults = PipelineConfig(calibration="x")
    for key, (_, tier, unit, default, meaning) in rows.items():
        assert tier == ("user" if is_user_setting(key) else "advanced"), key
        assert meaning and unit, key
        if default != "(required)":
            value = defaults
            for part in key.split("."):
                value = getattr(value, part)
            read = yaml.safe_load(f"x: {default.strip('`')}")["x"]
            assert read == (list(value) if isinstance(value, tuple) else value), key


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
    # given its own calibration (mpipe run --calibration) accepts the file, the others say
    # to set it
    from mpipe.cli.main import main
    from mpipe.core.config import ConfigError
    from mpipe.pipeline.settings import load_pipeline

    assert main(["config", "-o", str(tmp_path / "my.yaml")]) == 0
    with pytest.raises(ConfigError, match="calibration: still the placeholder CALIBRATION.yaml"):
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


def _tweakable():
    from mpipe.core.config import settings_of
    from mpipe.pipeline.settings import PipelineConfig

    return sorted(
        r.key
        for r in settings_of(PipelineConfig)
        if not r.section and type(r.default) in (float, int, bool)
    )


@hypothesis.settings(max_examples=60, deadline=None)
@hypothesis.given(
    changes=st.dictionaries(st.sampled_from(_tweakable()), st.floats(0.5, 2.0), max_size=5),
    every=st.booleans(),
)
def test_what_config_prints_reads_back_into_the_same_pipeline(changes, every):
    # any mix of user-tier and advanced keys away from their defaults: the printed text
    # (user tier, or --all) holds every changed key and reads back into the same pipeline
    from mpipe.core.config import Where, build
    from mpipe.pipeline.settings import PipelineConfig, is_user_setting, pipeline_yaml

    defaults = PipelineConfig(calibration="cal.yaml")
    data: dict = {"calibration": "cal.yaml"}
    for key, factor in changes.items():
        section, name = key.split(".", 1)
        default = getattr(getattr(defaults, section), name)
        if isinstance(default, bool):
            value = not default
        elif isinstance(default, int):
            value = max(1, round(default * factor))
        else:
            value = default * factor if default else factor - 0.5
        data.setdefault(section, {})[name] = value
    try:
        cfg = build(PipelineConfig, data, Where("pipe.yaml"))
    except ConfigError:
        hypothesis.reject()  # a change outside its allowed range: refused, as it must be
    text = pipeline_yaml(cfg, every=every)
    printed = yaml.safe_load(text)
    assert build(PipelineConfig, printed, Where("printed")) == cfg
    leaves = _leaf_keys(printed)
    for key in changes:
        section, name = key.split(".", 1)
        if getattr(getattr(cfg, section), name) != getattr(getattr(defaults, section), name):
            assert key in leaves
    if not every:
        assert all(is_user_setting(k) or k in changes for k in leaves)
