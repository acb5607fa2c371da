"""Recording sessions: the file checked before any work; the tables, resumed and on Dask.

The session of three short virtual takes (two instruments, so two calibrations; the
four-hole clarinet's takes in two fingerings) runs once, killed in its second take after
that take's inversion (a KeyboardInterrupt raised when the line saying so is printed: an
event, not a delay), then resumed. Its tables are checked against each take's own note
table, and the killed take's rows against the same take run through on a Dask cluster of
two workers (independent of the interruption and of the local process).
"""

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import soundfile as sf
import yaml

from mpipe.cli.commands import session as session_command
from mpipe.cli.main import main
from mpipe.cli.virtual_takes import SynthOptions, make_take
from mpipe.core.errors import UserError
from mpipe.pipeline.session import load_session
from mpipe.pipeline.session_table import PLAYED, note_verdict, write_session_tables

ROOT = Path(__file__).resolve().parents[2]
PLAIN = ROOT / "calibration" / "simplified_clarinet.yaml"
HOLES = ROOT / "calibration" / "four_hole_clarinet.yaml"


def _pipeline(folder: Path) -> Path:
    """The light pipeline of tests/pipeline/test_batch.py (three windows per take)."""
    data = yaml.safe_load((ROOT / "pipelines" / "simplified_clarinet.yaml").read_text())
    data["calibration"] = str(PLAIN)
    data["executor"] = {"kind": "local", "workers": 1}
    data["conditioning"] = {"edge_s": 0.25}
    data["inversion"]["hop_s"] = 0.04
    data["inversion"].update(design_points=16, local_starts=2)
    path = folder / "pipeline.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


# --- the file, checked before any work (no take is run) -----------------------------------


@pytest.fixture
def folder(tmp_path):
    """A pipeline and three silent 3-channel takes long enough for a window."""
    _pipeline(tmp_path)
    for name in ("a", "b", "c"):
        sf.write(tmp_path / f"{name}.wav", np.zeros((48000, 3)), 48000)
    (tmp_path / "holes.yaml").write_text(HOLES.read_text())
    return tmp_path


def _write(folder: Path, text: str) -> Path:
    path = folder / "session.yaml"
    path.write_text(text)
    return path


def test_a_session_resolves_each_takes_calibration_and_fingering(folder):
    s = load_session(_write(folder, (
        "pipeline: pipeline.yaml\nfingering: xxoo\ntakes:\n"
        "  - {take: a.wav, calibration: holes.yaml, notes: first}\n"
        "  - {take: b.wav, name: second, calibration: holes.yaml, fingering: xxxo}\n"
        "  - {take: [c.wav, a.wav, b.wav], name: mono, calibration: holes.yaml}\n"
    )))  # fmt: skip
    assert [t.name for t in s.takes] == ["a", "second", "mono"]
    assert [t.fingering for t in s.takes] == ["xxoo", "xxxo", "xxoo"]
    assert s.takes[0].calibration == folder / "holes.yaml" and s.takes[0].notes == "first"
    assert len(s.takes[2].files) == 3
    assert s.config_of(s.takes[1]).fingering == "xxxo"
    # no calibration given: the pipeline's
    plain = load_session(_write(folder, "pipeline: pipeline.yaml\ntakes: [a.wav]\n"))
    assert plain.takes[0].calibration == PLAIN and plain.takes[0].fingering is None


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("pipeline: pipeline.yaml\ntakes: [a.wav]\ntakes: [b.wav]\n",
         r"key 'takes' given twice \(lines 2 and 3\)"),
        ("pipeline: pipeline.yaml\ntakes:\n  - {take: a.wav, colour: red}\n",
         r"takes\[0\]: colour: unknown key \(expected one of: take, name,"),
        ("pipeline: pipeline.yaml\ntakes:\n  - a.wav\n  - {take: d.wav, name: cc}\n",
         r"takes\[1\] \(cc\): take: no such file .*d\.wav"),
        ("pipeline: pipeline.yaml\ntakes:\n  - {take: a.wav, calibration: holes.yaml, "
         "fingering: xoxo}\n", r"takes\[0\] \(a\): fingering: .*'xoxo'"),
        ("pipeline: pipeline.yaml\ntakes:\n  - a.wav\n  - {take: b.wav, name: a}\n",
         r"takes\[1\] \(a\): name: takes\[0\] has this name too"),
        ("pipeline: pipeline.yaml\ntakes:\n  - {take: a.wav, score: pipeline.yaml}\n",
         r"takes\[0\] \(a\): score: .*pipeline\.yaml"),
        ("pipeline: none.yaml\ntakes: [a.wav]\n", r"session\.yaml: pipeline: no such file"),
        ("pipeline: pipeline.yaml\ntakes: []\n", r"session\.yaml: takes: expected a list"),
        ("pipeline: pipeline.yaml\ntakes:\n  - {take: a.wav, name: ../up}\n",
         r"takes\[0\] \(\.\./up\): name: '\.\./up' cannot be a folder name"),
    ],
)  # fmt: skip
def test_a_bad_session_file_is_one_line_naming_file_take_and_key(folder, text, expected, capsys):
    path = _write(folder, text)
    with pytest.raises(UserError, match=expected):
        load_session(path)
    assert main(["session", str(path), "-o", str(folder / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0], err
    assert not (folder / "out").exists()  # before any work


def test_a_file_listed_twice_says_so_and_its_advice_works(folder):
    # it was a name clash ("give one of them another 'name'"), and renaming one met a
    # second refusal ("listed twice")
    path = _write(folder, "pipeline: pipeline.yaml\ntakes:\n  - a.wav\n  - b.wav\n  - a.wav\n")
    with pytest.raises(UserError) as info:
        load_session(path)
    message = str(info.value)
    assert "takes[2] (a): take:" in message and "a.wav is listed twice" in message, message
    assert "takes[0] lists it too" in message and "remove one" in message
    # the advice followed: one entry removed
    path = _write(folder, "pipeline: pipeline.yaml\ntakes:\n  - a.wav\n  - b.wav\n")
    assert [t.name for t in load_session(path).takes] == ["a", "b"]


def test_a_calibration_other_than_the_takes_own_is_refused(folder):
    # a take with its own calibration beside it (as synth-take writes) read with another:
    # its pressures would scale by the ratio of the sensitivities
    shutil.copy(PLAIN, folder / "a.calibration.yaml")
    path = _write(folder, "pipeline: pipeline.yaml\ntakes:\n  - {take: a.wav, "
                          "calibration: holes.yaml}\n")  # fmt: skip
    with pytest.raises(UserError, match=r"takes\[0\] \(a\): calibration: .* differs from the"):
        load_session(path)


@pytest.mark.parametrize(
    ("option", "expected"),
    [
        (["--scheduler", "tcp://10.0.0.5"], "--scheduler: malformed scheduler address"),
        (["--scheduler", "HTTP"], "--scheduler: tcp://127.0.0.1:"),
        (["--workers", "0"], "--workers: expected a number in 1-4096, got 0"),
    ],
)
def test_where_the_takes_run_is_checked_before_any_work(folder, option, expected, capsys):
    from tests.core.test_cluster import http_server

    pipe = folder / "pipeline.yaml"
    data = yaml.safe_load(pipe.read_text())
    data["executor"]["connect_timeout_s"] = 0.5
    pipe.write_text(yaml.safe_dump(data))
    path = _write(folder, "pipeline: pipeline.yaml\ntakes: [a.wav]\n")
    with http_server() as address:
        argv = [a.replace("HTTP", address) for a in option]
        assert main(["session", str(path), "-o", str(folder / "out"), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
    assert option[1] != "HTTP" or "not a Dask scheduler: it sent nothing" in err[0]
    assert not (folder / "out").exists()


def test_a_notes_verdict():
    row = {"segment": 2, "note_number": 1, "windows": 4, "ok_windows": 4}
    assert note_verdict(row, "pass", [])[0] == "PASS"
    assert note_verdict({**row, "ok_windows": 0}, "pass", [])[0] == "FAIL"
    assert note_verdict({**row, "ok_windows": 3}, "pass", [])[0] == "CHECK"
    assert note_verdict(row, "cannot-verify", [])[0] == "CHECK"
    # the check names the note by its number in the take (1), not its segment id (2)
    mine = "the model cannot play note 1 (0.1-0.5 s): ..."
    assert note_verdict(row, "pass", [mine]) == ("CHECK", mine)
    assert note_verdict(row, "pass", [mine.replace("note 1", "note 2")])[0] == "PASS"
    assert note_verdict(row, "pass", ["median relative residual 0.3 ..."])[0] == "CHECK"


# --- a session run: killed, resumed, and on Dask ------------------------------------------

#: (take, instrument, fingering, mouth pressure Pa): two calibrations, two fingerings.
TAKES = (
    ("plain", PLAIN, None, 1700.0),
    ("open_h4", HOLES, "xxxo", 2000.0),
    ("closed", HOLES, "xxxx", 1900.0),
)


def _finished_take(out: Path, name: str, segments: dict, checks=(), verdict="pass") -> None:
    """A take's folder as mpipe run leaves it, as far as the session tables read it."""
    import json

    for stage, summary in (
        ("validation", {"verdict": verdict}),
        ("inversion", {"take_checks": list(checks), "status_counts": {"ok": 4}, "windows": 4}),
    ):
        (out / name / stage).mkdir(parents=True, exist_ok=True)
        (out / name / stage / "manifest.json").write_text(json.dumps({"summary": summary}))
    n = len(segments["start_s"])
    table = {"segment": range(1, n + 1), "label": ["note"] * n, "duration_s": [0.4] * n,
             "f0_hz": [150.0] * n, "pitch_cents": [0.0] * n, "note": ["D3"] * n,
             "regime": ["fundamental"] * n, "spl_db": [150.0] * n, "windows": [2] * n,
             "ok_windows": [2] * n, "p_m_se": [20.0] * n, **segments}  # fmt: skip
    pd.DataFrame(table).to_csv(out / name / "inversion" / "segments.csv", index=False)


def test_each_note_names_its_own_fingering_and_what_the_score_played(folder):
    # a take in two fingerings with the calibration's default (xxxx) for its second note;
    # its score played xxoo at 1800 Pa, then xxxx at 1500 Pa (the truth beside the result)
    (folder / "score.yaml").write_text(
        "end: 0.05\nnotes:\n"
        "  - {duration: 0.5, fingering: xxoo, p_m: 1800, attack: 0.02}\n"
        "  - {duration: 0.5, fingering: xxxx, p_m: [[0, 1400], [0.5, 1600]]}\n"
    )
    path = _write(folder, "pipeline: pipeline.yaml\ntakes:\n  - {take: a.wav, calibration: "
                          "holes.yaml, score: score.yaml}\n")  # fmt: skip
    session = load_session(path)
    out = folder / "out"
    measured = {"start_s": [0.01, 0.52], "end_s": [0.49, 1.0], "fingering": ["xxoo", ""],
                "p_m_median": [1700.0, 1500.0]}  # fmt: skip
    _finished_take(out, "a", measured)
    written = write_session_tables(session, out, {"a": object()})
    notes = pd.read_csv(written["notes"], keep_default_na=False, na_values=[""])
    assert list(notes["fingering"]) == ["xxoo", "xxxx"]  # not the list, not blank
    assert list(notes["played_note"]) == [1, 2]
    # the score's p_m at the middle of each note's sounding span: 1800; 1400 -> 1600 at 0.25 s
    np.testing.assert_allclose(notes["played_p_m"], [1800.0, 1500.0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(notes["p_m_minus_played"], [-100.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(notes["p_m_rel_to_played"], [-100 / 1800, 0.0], atol=1e-9)
    assert list(notes["played_fingering"]) == ["xxoo", "xxxx"]
    assert list(notes["fingering_as_played"]) == [True, True]


def test_the_console_says_the_state_session_takes_csv_says(folder, capsys, monkeypatch):
    # the console said "phrase: ok" where session_takes.csv said check
    from mpipe.pipeline import batch

    path = _write(folder, "pipeline: pipeline.yaml\ntakes:\n  - a.wav\n")
    out = folder / "out"
    checks = ["the cold start's minimum was reached by 1 of its 8 short searches"]
    _finished_take(out, "a", {"start_s": [0.1], "end_s": [0.9], "p_m_median": [1700.0]}, checks)

    class Run:
        records = {"inversion": type("R", (), {"summary": {"status_counts": {"ok": 4},
                                                          "status_line": "4 ok"}})(),
                   "validation": type("R", (), {"summary": {"verdict": "pass"}})()}  # fmt: skip

    def run_takes(configs, cals, takes, out, force, client, **kw):
        return [(takes[0], Run(), 1.0)]

    monkeypatch.setattr(session_command, "run_takes", run_takes)
    assert main(["session", str(path), "-o", str(out)]) == 0
    takes = pd.read_csv(out / "session_takes.csv", keep_default_na=False)
    assert list(takes["state"]) == ["check"]
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("  a: "))
    assert line.startswith("  a: check;"), line
    assert batch.summary_lines([([path], Run(), 1.0)], ["a"])[0].startswith("  a: ok;")


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """The session's files: ``(folder, session file)``."""
    folder = tmp_path_factory.mktemp("session")
    reed = yaml.safe_load((ROOT / "calibration" / "reed_table1.yaml").read_text())
    entries = []
    for i, (name, cal, fingering, p_m) in enumerate(TAKES):
        (folder / f"{name}.reed.yaml").write_text(yaml.safe_dump({**reed, "p_m": p_m}))
        options = SynthOptions(duration_s=0.62, snr_db=60.0, seed=21 + i, fingering=fingering)
        made = make_take(cal, folder / f"{name}.reed.yaml", folder / f"{name}.flac", options)
        # the take's own calibration (beside it) named, as a lab's file would
        entries.append({"take": made.audio.name, "calibration": made.calibration.name,
                        "fingering": fingering, "notes": f"take {i}"})  # fmt: skip
    _pipeline(folder)
    path = folder / "session.yaml"
    path.write_text(yaml.safe_dump({"pipeline": "pipeline.yaml", "takes": entries}))
    return folder, path


@pytest.fixture(scope="module")
def resumed(session):
    """The session killed after its second take's inversion, then resumed: its OUT."""
    folder, path = session
    out = folder / "out"
    said = []

    def say(line):
        said.append(line)
        if line.startswith("[open_h4] 5/6 inversion: done"):
            raise KeyboardInterrupt  # as Ctrl-C would, at this line

    mp = pytest.MonkeyPatch()
    mp.setattr(session_command, "write", say)
    try:
        assert main(["session", str(path), "-o", str(out), "--workers", "1"]) == 130
    finally:
        mp.undo()
    killed = {
        "said": said,
        "tables": (out / "session.csv").exists(),
        "resynthesis": (out / "open_h4" / "resynthesis" / "manifest.json").exists(),
    }
    said_again = []
    mp.setattr(session_command, "write", said_again.append)
    try:
        assert main(["session", str(path), "-o", str(out), "--workers", "1"]) == 0
    finally:
        mp.undo()
    return out, killed, said_again


def _notes(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / "session.csv", keep_default_na=False, na_values=[""])


def test_a_killed_session_resumes_where_it_stopped(resumed):
    out, killed, said = resumed
    assert not killed["tables"] and not killed["resynthesis"]
    # the finished take is not redone, the killed one resumes after its inversion
    plain = [s for s in said if s.startswith("[plain] ") and "/6 " in s]
    assert len(plain) == 6 and all("already done, skipped" in s for s in plain)
    redone = [s.split(":")[0] for s in said if s.startswith("[open_h4] ") and ": done" in s]
    assert redone == ["[open_h4] 6/6 resynthesis"]
    assert any(s.startswith("[closed] 5/6 inversion: done") for s in said)
    # every line of the run says its take, but the session's own
    assert all(s.startswith(("[plain]", "[open_h4]", "[closed]", "session ")) for s in said)


def test_the_session_table_holds_each_takes_note_table(resumed, session):
    out, *_ = resumed
    notes = _notes(out)
    takes = pd.read_csv(out / "session_takes.csv", keep_default_na=False)
    assert list(takes["take"]) == [t[0] for t in TAKES]
    assert list(takes["state"].isin(["ok", "check"])) == [True] * 3
    assert list(takes["fingering"]) == ["", "xxxo", "xxxx"]
    assert takes["calibration"].nunique() == 3 and list(takes["take_notes"])[1] == "take 1"
    assert list(notes["take"].unique()) == [t[0] for t in TAKES]
    for name, _, fingering, _ in TAKES:
        own = pd.read_csv(out / name / "inversion" / "segments.csv")
        own = own[own["label"] == "note"].reset_index(drop=True)
        rows = notes[notes["take"] == name].reset_index(drop=True)
        assert len(rows) == len(own) >= 1
        assert list(rows["note"]) == list(range(1, len(own) + 1))
        assert set(rows["fingering"].fillna("")) == {fingering or ""}
        for old, new in PLAYED.items():
            assert list(rows[new]) == list(own[old]), (name, old)
        for q in ("p_m", "p_M", "gamma", "zeta", "k", "y_m", "f_r"):
            for part in ("median", "se"):
                np.testing.assert_array_equal(rows[f"{q}_{part}"], own[f"{q}_{part}"])
        assert set(rows["verdict"]) <= {"PASS", "CHECK", "FAIL"}
    parquet = pd.read_parquet(out / "session.parquet")
    assert list(parquet.columns) == list(notes.columns) and len(parquet) == len(notes)
    # the two fingerings of one instrument play two pitches
    f0 = notes.groupby("take")["f0_hz"].first()
    assert f0["open_h4"] > f0["closed"] * 1.05


def test_on_dask_with_two_workers_the_same_tables(resumed, session, dask_cluster, tmp_path):
    # the killed take run through on the cluster (the other two found finished there)
    out, *_ = resumed
    folder, path = session
    again = folder / "out_dask"
    shutil.copytree(out, again)
    shutil.rmtree(again / "open_h4")
    for table in ("session.csv", "session.parquet", "session_takes.csv"):
        (again / table).unlink()
    status = main(["session", str(path), "-o", str(again), "--scheduler", dask_cluster[1]])
    assert status == 0
    pd.testing.assert_frame_equal(_notes(again), _notes(out))
    for table in ("session_takes.csv",):
        assert (again / table).read_text() == (out / table).read_text()
