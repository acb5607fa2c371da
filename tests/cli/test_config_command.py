"""``mpipe config``: the user tier, ``--all`` and the reference page."""

from __future__ import annotations

from pathlib import Path

import yaml

from mpipe.cli.main import main
from mpipe.core.config import settings_of
from mpipe.pipeline.settings import PipelineConfig, is_user_setting

ROOT = Path(__file__).resolve().parents[2]


def _leaves(data, prefix=""):
    out = set()
    for k, v in data.items():
        out |= _leaves(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k}
    return out


EVERY = {r.key for r in settings_of(PipelineConfig) if not r.section} - {"source"}
USER = {k for k in EVERY if is_user_setting(k)}


def test_plain_config_prints_the_user_tier(capsys):
    assert main(["config"]) == 0
    out = capsys.readouterr().out
    assert _leaves(yaml.safe_load(out)) == USER
    assert "`mpipe config --all` lists them" in out and "docs/settings.md" in out


def test_all_prints_every_setting(capsys):
    assert main(["config", "--all"]) == 0
    assert _leaves(yaml.safe_load(capsys.readouterr().out)) == EVERY
    # with a pipeline file: every key, resolved from the file
    assert main(["config", "--all", str(ROOT / "pipelines" / "simplified_clarinet.yaml")]) == 0
    data = yaml.safe_load(capsys.readouterr().out)
    assert _leaves(data) == EVERY
    assert data["calibration"] == "../calibration/simplified_clarinet.yaml"


def test_markdown_prints_the_reference_page(tmp_path, capsys):
    target = tmp_path / "settings.md"
    assert main(["config", "--all", "--markdown", "-o", str(target)]) == 0
    assert target.read_text() == (ROOT / "docs" / "settings.md").read_text()
    # the page documents the defaults: a pipeline file is refused in one line
    assert main(["config", "--markdown", str(ROOT / "pipelines" / "simplified_clarinet.yaml")]) == 2
    err = capsys.readouterr().err
    assert "--markdown" in err and "PIPELINE" in err and err.count("\n") == 1
