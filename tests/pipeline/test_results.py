"""``load_run`` on a folder that a run did not finish: it says so, and names a damaged file.

The folders are laid out as ``mpipe run`` lays them (one folder per stage, a manifest.json
when the stage finished); the windows table is written by the pipeline's own writer.
"""

from __future__ import annotations

import json
import logging

import numpy as np
import pandas as pd
import pytest

from mpipe import load_run
from mpipe.core.errors import UserError
from mpipe.inversion.table.records import WINDOW_SCHEMA, write_windows


def _run_folder(root, finished=("separation", "translation", "validation", "conditioning")):
    take = root / "take"
    for stage in ("separation", "translation", "validation", "conditioning", "inversion"):
        (take / stage).mkdir(parents=True)
    for stage in finished:
        (take / stage / "manifest.json").write_text(json.dumps({"summary": {"verdict": "pass"}}))
    pd.DataFrame({"block": [0, 1], "temperature_c": [20.0, 20.0]}).to_csv(
        take / "separation" / "blocks.csv", index=False
    )
    return take


def test_a_half_written_run_says_which_stages_did_not_finish(tmp_path, caplog):
    take = _run_folder(tmp_path)  # killed during the inversion: no windows.csv yet
    with caplog.at_level(logging.WARNING):
        run = load_run(tmp_path)
    assert run.unfinished == ("inversion", "resynthesis")
    assert any("unfinished run: inversion, resynthesis" in r.message for r in caplog.records)
    assert "UNFINISHED" in repr(run) and len(run.tables["blocks"]) == 2
    # the table the unfinished stage writes: a KeyError that says why, not a bare 'windows'
    with pytest.raises(KeyError, match="stage 'inversion' did not finish"):
        run.tables["windows"]
    with pytest.raises(KeyError, match=r"this run has blocks"):
        run.tables["nonsense"]
    assert take.is_dir()


def test_a_run_stopped_by_a_failed_validation_is_not_unfinished(tmp_path):
    take = _run_folder(tmp_path)
    (take / "validation" / "manifest.json").write_text(json.dumps({"summary": {"verdict": "fail"}}))
    (take / "conditioning" / "manifest.json").unlink()
    assert load_run(tmp_path).unfinished == ()


def test_a_truncated_windows_table_is_one_line_naming_the_file(tmp_path):
    take = _run_folder(tmp_path, finished=(
        "separation", "translation", "validation", "conditioning", "inversion"))  # fmt: skip
    flag = next(c.name for c in WINDOW_SCHEMA if c.dtype == "bool")
    path = take / "inversion" / "windows.csv"
    n = 30
    write_windows(pd.DataFrame({"status": ["ok"] * n, "k": np.linspace(8e6, 9e6, n),
                                flag: [True] * n}), path)  # fmt: skip
    path.write_bytes(path.read_bytes()[:-8])  # the disk filled while it was written
    with pytest.raises(UserError) as info:
        load_run(tmp_path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: cannot be read"), message
    assert "truncated or damaged" in message
