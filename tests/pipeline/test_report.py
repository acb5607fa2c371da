"""A take's report: the summary of its windows, parameters and verdict; rendered end to end."""

import os
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from mpipe.pipeline.report import flag_windows, overall_verdict, parameter_summary


def test_summary_lists_windows_that_are_not_ok():
    windows = pd.DataFrame(
        {
            "window": [0, 1, 2, 3],
            "t_start_s": [0.0, 0.02, 0.04, 0.06],
            "k": [8.6e6, 8.7e6, 1e8, np.nan],
            "status": ["ok", "ok", "at-bound", "failed"],
            "status_reason": ["", "", "on a bound: k=upper", "step 1 failed"],
        }
    )
    flags = flag_windows(windows)
    assert flags["window"].tolist() == [2, 3]
    assert flags["status"].tolist() == ["at-bound", "failed"]
    assert "k=upper" in flags["reason"][0]
    # 2 of 4 windows ok, no note column: flagged one by one, the take PASSes
    assert overall_verdict(True, windows)[1] == "pass"
    assert "2 of 4 windows ok" in overall_verdict(True, windows)[0]
    assert overall_verdict(False, windows)[1] == "fail"
    assert overall_verdict(True, windows.iloc[2:])[1] == "fail"  # no window ok
    assert overall_verdict(True, windows.iloc[:2])[1] == "pass"
    params = parameter_summary(windows).set_index("parameter")
    # only the ok windows make the median and the quartiles
    assert params.loc["k", "n_windows"] == 2
    assert params.loc["k", "median"] == pytest.approx(8.65e6)
    assert params.loc["k", "unit"] == "Pa/m"


def test_segment_tables_give_each_note_its_own_line():
    import pandas as pd

    from mpipe.pipeline.report import segment_tables

    segs = pd.DataFrame({
        "segment": [0, 1, 2, 3], "label": ["silence", "note", "silence", "note"],
        "start_s": [0.0, 0.1, 0.5, 0.75], "duration_s": [0.1, 0.4, 0.25, 0.4],
        "note": ["", "G#2 +8 c", "", "G#2 +9 c"], "f0_hz": [np.nan, 104.3, np.nan, 104.4],
        "regime": ["silence", "fundamental", "silence", "fundamental"],
        "spl_db": [110.0, 154.4, 110.0, 156.0], "windows": [0, 17, 0, 19],
        "ok_windows": [0, 13, 0, 15], "p_m_median": [np.nan, 1807.0, np.nan, 2001.0],
        "p_m_se": [np.nan, 3.0, np.nan, np.nan],
    })  # fmt: skip
    played, params = segment_tables(segs)
    assert list(played["segment"]) == [1, 3]
    assert list(played["ok_windows"]) == ["13 of 17", "15 of 19"]
    assert list(params["p_m [Pa]"]) == ["1807 ± 3", "2001"]  # no SE: none is claimed


def test_an_infinite_se_reads_undetermined_not_held_fixed():
    # a bare value means "held fixed" (docs/outputs.md): an infinite SE must read otherwise
    import pandas as pd

    from mpipe.pipeline.html_report import fmt
    from mpipe.pipeline.report import segment_tables

    segs = pd.DataFrame({
        "segment": [0, 1], "label": ["note", "note"], "start_s": [0.0, 0.5],
        "duration_s": [0.4, 0.4], "note": ["G#2", "G#2"], "f0_hz": [104.3, 104.4],
        "regime": ["fundamental"] * 2, "spl_db": [154.4, 156.0], "windows": [17, 19],
        "ok_windows": [13, 15], "p_m_median": [1807.0, 2001.0], "p_m_se": [np.inf, np.nan],
    })  # fmt: skip
    _, params = segment_tables(segs)
    assert list(params["p_m [Pa]"]) == ["1807 ± ∞ (undetermined)", "2001"]
    assert fmt(float("inf")) == "∞" and fmt(float("nan")) == "–"


def test_window_table_gives_each_value_with_its_se_note_pitch_and_reason_in_words():
    from mpipe.pipeline.report_windows import window_table

    windows = pd.DataFrame({
        "window": [3, 4], "t_start_s": [0.29, 0.71], "segment": [1, 3],
        "phase": ["sustain", "release"], "f0_hz": [104.3, 221.0],
        "pitch_cents": [1200 * np.log2(104.3 / 440), 1200 * np.log2(221 / 442)],
        "status": ["ok", "low-dof"], "p_m": [1800.4, 1927.0], "p_m_se": [26.3, np.inf],
        "p_M": [3468.0, np.nan], "p_M_se": [88.0, np.nan], "gamma": [0.5184, 0.6],
        "gamma_se": [0.0056, np.nan], "relative_residual": [0.005, 0.2],
        "n_eff": [20.0, 5.71], "dof": [12.0, -2.29],
        "status_reason": ["", "n_eff - p = -2.29 < 1: the residual cannot measure the noise"],
    })  # fmt: skip
    segments = pd.DataFrame({"segment": [0, 1, 2, 3],
                             "label": ["silence", "note", "silence", "note"]})  # fmt: skip
    table = window_table(windows, segments).replace("\u00a0", " ", regex=True)  # no-break
    assert list(table["note"]) == [1, 2]  # numbered as the notes table numbers them
    assert list(table["p_m"]) == ["1800 ± 26", "1927 (undetermined)"]
    assert list(table["p_M"]) == ["3468 ± 88", "–"]
    assert list(table["gamma"]) == ["0.5184 ± 0.0056", "0.6"]  # no SE: none claimed
    # pitch as a note name, with the take's own A4 (442 Hz for the second row)
    assert list(table["pitch"]) == ["G#2 +8 c", "A3 +0 c"]
    assert list(table["f0_hz"]) == [104.3, 221.0]
    # no negative degrees of freedom as a number: what they mean, with both counts
    reason = table["reason"].iloc[1]
    assert "-2.29" not in reason and "n_eff - p" not in reason
    assert reason.startswith("fewer effective residual samples (5.7) than free parameters (8)")
    assert reason.endswith("the residual cannot measure the noise")


def test_reason_words_keep_a_positive_shortfall_and_other_reasons():
    from mpipe.inversion.trust.status_words import reason_words

    row = {"status_reason": "dof = 0.812 < 1: SEs rough; relative residual 0.159 > 0.1",
           "n_eff": 8.812, "dof": 0.812}  # fmt: skip
    words = reason_words(row)
    assert words.startswith("less than one residual degree of freedom (8.8 effective samples "
                            "for 8 free parameters): SEs rough")  # fmt: skip
    assert words.endswith("relative residual 0.159 > 0.1")
    assert reason_words({"status_reason": "on a bound: k=upper"}) == "on a bound: k=upper"
    assert reason_words({"status_reason": np.nan}) == ""


# ---- the report of a fingered phrase, end to end (issue 33's "done when") -------------------

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FINGERED = ROOT / "calibration" / "four_hole_clarinet.yaml"
# two short tongued notes of one fingering, blown differently
PHRASE = """
notes:
  - {gap: 0.04, duration: 0.3, tongued: true, tongue_hold: 0.02, attack: 0.02, release: 0.03,
     p_m: 1800.0}
  - {gap: 0.1, duration: 0.3, tongued: true, tongue_hold: 0.02, attack: 0.02, release: 0.03,
     p_m: 2200.0, y_m: 3.8e-4}
end: 0.04
"""


class Tables(HTMLParser):
    """Every table of a page: caption, headers and the text of each cell, by rows."""

    def __init__(self):
        super().__init__()
        self.tables, self._cell = [], None

    def handle_starttag(self, tag, attrs):
        if tag == "table":
            self.tables.append({"caption": "", "headers": [], "rows": []})
        elif tag == "tr" and self.tables:
            self.tables[-1]["rows"].append([])  # the header row stays empty: dropped below
        elif tag in ("td", "th", "caption"):
            self._cell = tag

    def handle_data(self, data):
        if self._cell == "caption":
            self.tables[-1]["caption"] += data
        elif self._cell == "th":
            self.tables[-1]["headers"].append(data)
        elif self._cell == "td":
            self.tables[-1]["rows"][-1].append(data)

    def handle_endtag(self, tag):
        if tag in ("td", "th", "caption"):
            self._cell = None


@pytest.fixture(scope="module")
def fingered_run(tmp_path_factory):
    from mpipe.cli.virtual_takes import SynthOptions, make_take
    from mpipe.pipeline.orchestration import run_take
    from mpipe.pipeline.settings import load_pipeline

    folder = tmp_path_factory.mktemp("phrase")
    score = folder / "score.yaml"
    score.write_text(PHRASE)
    options = SynthOptions(duration_s=None, score=str(score), snr_db=45.0, seed=3,
                           fingering="xxoo")  # fmt: skip
    take = make_take(FINGERED, ROOT / "calibration" / "reed_table1.yaml",
                     folder / "take" / "phrase.flac", options)  # fmt: skip
    data = yaml.safe_load((ROOT / "pipelines" / "simplified_clarinet.yaml").read_text())
    data["calibration"] = str(take.calibration)
    data["fingering"] = "xxoo"
    data["executor"] = {"kind": "local", "workers": 1}
    # a few windows per note; a smaller cold start and the front end's temperature: the
    # report is under test here, not the search (tests/inversion test those)
    data["inversion"].update(hop_s=0.08, design_points=64,
                             local_starts=3)  # fmt: skip
    pipe = folder / "pipeline.yaml"
    pipe.write_text(yaml.safe_dump(data))
    lines: list[str] = []
    run = run_take(load_pipeline(pipe), take.calibration, [take.audio], folder / "out",
                   say=lines.append)  # fmt: skip
    (run.folder.parent / "console.txt").write_text("\n".join(lines))
    return run.folder


def test_a_note_has_one_number_in_console_tables_and_figures(fingered_run):
    # a silence before each note: the notes are not segments 1 and 2, yet the take's notes
    # 1 and 2 everywhere (issue 42: "note 3", "note 2 (segment 3)", "note segment 5")
    from mpipe.inversion.output.tracks_plot import tracks_figure
    from mpipe.inversion.preparation.segments import note_label
    from mpipe.inversion.table.records import read_windows

    for stage in ("conditioning", "inversion"):
        segs = pd.read_csv(fingered_run / stage / "segments.csv")
        notes = segs[segs["label"] == "note"]
        assert list(notes["note_number"]) == [1, 2], stage
        assert list(notes["segment"]) != [1, 2]  # the test means something
        assert (segs.loc[segs["label"] != "note", "note_number"] == 0).all()
    by_segment = dict(zip(notes["segment"], notes["note_number"], strict=True))
    windows = read_windows(fingered_run / "inversion" / "windows.csv")
    assert list(windows["note_number"]) == [by_segment[g] for g in windows["segment"]]
    # segments.png's labels and tracks.png's title
    assert [note_label(r).split(":")[0] for _, r in notes.iterrows()] == ["1", "2"]
    fig = tracks_figure(windows, segs, "xxoo")
    try:
        title = fig._suptitle.get_text()
        assert "note 1:" in title and "note 2:" in title and "note 3" not in title
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)
    # the console: the inversion's note lines, and never a segment id for a note
    console = (fingered_run.parent / "console.txt").read_text()
    starts = [f"note {n} at {t:.3f} s" for n, t in zip([1, 2], notes["start_s"], strict=True)]
    assert all(s in console for s in starts), console
    assert "(segment" not in console and "note segment" not in console
    assert set(re.findall(r"\bnote (\d+)\b", console)) <= {"1", "2"}, console
    # the report's tables: what was played and the per-window table's note column
    text = (fingered_run / "report.html").read_text()
    assert "Uncertainty budget of note 1 (from" in text and "Uncertainty budget of note 2" in text


def test_report_of_a_fingered_phrase_tables_and_figures(fingered_run):
    from mpipe.inversion.output.tracks_plot import tracks_figure
    from mpipe.inversion.table.records import read_windows
    from mpipe.measurement.calibration import load_calibration

    text = (fingered_run / "report.html").read_text()
    pages = Tables()
    pages.feed(text)

    def table(start):
        (found,) = [t for t in pages.tables if t["caption"].split(". ", 1)[1].startswith(start)]
        return {**found, "rows": [r for r in found["rows"] if r]}

    played = table("What was played, note by note")
    assert len(played["rows"]) == 2 and "f0 [Hz]" in played["headers"]
    # each note plays near the fingering's first resonance (xxoo: about 124 Hz), in Hz
    first = load_calibration(FINGERED, "xxoo")
    from mpipe.inversion.preparation.conditioning import bore_resonances

    f_res = bore_resonances(first)[0]
    f0 = [float(r[played["headers"].index("f0 [Hz]")]) for r in played["rows"]]
    assert all(abs(1200 * np.log2(f / f_res)) < 50 for f in f0), (f0, f_res)
    windows = table("Per-window results")
    heads = windows["headers"]
    for column in ("p_M [Pa]", "gamma [–]", "zeta [–]", "p_m [Pa]", "f0 [Hz]", "pitch"):
        assert column in heads, column
    table = read_windows(fingered_run / "inversion" / "windows.csv")
    assert len(windows["rows"]) == len(table)
    for row, (_, w) in zip(windows["rows"], table.iterrows(), strict=True):
        cell = row[heads.index("p_M [Pa]")]
        if w["status"] == "ok":
            assert "\u00a0±\u00a0" in cell, cell  # every ok window carries its SE
        assert row[heads.index("pitch")].startswith(("A#2", "B2", "C3")), row
    assert "n_eff - p = -" not in text and "dof = -" not in text
    # each note's uncertainty budget (issue 34): p_m, p_M, gamma, zeta with u_c and components
    head = "Uncertainty budget of note"
    budgets = [t for t in pages.tables if t["caption"].split(". ", 1)[1].startswith(head)]
    assert len(budgets) == 2
    for found in budgets:
        heads_b = " ".join(found["headers"])
        assert "u_c" in heads_b and all(c in heads_b for c in ("noise", "model", "rate"))
        names = {r[0] for r in found["rows"] if r}
        assert {"p_m", "p_M", "gamma", "zeta"} <= names, names
    # each note's two periods, labelled with the window's status, and the overlays
    notes = re.findall(r"<figcaption>Figure \d+\. Note (\d): two periods", text)
    assert notes == ["1", "2"]
    assert (
        len(re.findall(r"<figcaption>Figure \d+\. Target .* the title gives the window", text)) == 3
    )
    assert "fingering xxoo" in text or "fingering: xxoo" in text
    segments = pd.read_csv(fingered_run / "inversion" / "segments.csv")
    fig = tracks_figure(table, segments, "xxoo")
    try:
        assert "fingering xxoo" in fig._suptitle.get_text() and " Hz" in fig._suptitle.get_text()
        ok = (table["status"] == "ok").to_numpy()
        lo, hi = fig.axes[0].get_ylim()  # k: the axis holds every ok window, nothing more
        k = table["k"].to_numpy(float)[ok]
        assert lo <= k.min() and k.max() <= hi
        assert hi - lo < 3 * (k.max() - k.min() + 4 * table["k_se"].to_numpy(float)[ok].max())
    finally:
        import matplotlib.pyplot as plt

        plt.close(fig)


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (apt-get install chromium)")
def test_report_of_a_fingered_phrase_renders_headless(fingered_run, tmp_path):
    import matplotlib.image as mpimg

    shot = tmp_path / "shot.png"
    cmd = [CHROMIUM, "--headless", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
           "--window-size=1150,4000", (fingered_run / "report.html").as_uri()]  # fmt: skip
    if os.geteuid() == 0:
        cmd.insert(1, "--no-sandbox")
    subprocess.run(cmd, capture_output=True, timeout=180, check=False)
    assert shot.exists(), "chromium wrote no screenshot"
    pixels = mpimg.imread(shot)[..., :3]
    assert pixels.shape[0] == 4000 and pixels.std() > 0.05, "blank screenshot"
    # the verdict badge (a coloured box) is drawn: CHECK's amber or PASS's green
    badge = ((pixels[..., 0] > 0.95) & (pixels[..., 2] < 0.85)) | (
        (pixels[..., 1] > 0.9) & (pixels[..., 0] < 0.9)
    )
    assert badge.sum() > 500


def test_a_value_is_given_to_the_decimal_place_of_its_two_digit_se():
    from mpipe.pipeline.report_windows import value_se

    def plain(v, se):
        return value_se(v, se).replace("\u00a0", " ")

    assert plain(3205.0, 240.0) == "3205 ± 240"  # not 3205 ± 2.4e+02
    assert plain(0.5381, 0.017) == "0.538 ± 0.017"
    assert plain(8.834e6, 9.6e4) == "(8.834 ± 0.096)×10⁶"
    assert plain(7.688e-5, 3e-6) == "(7.69 ± 0.30)×10⁻⁵"
    assert plain(3136.0, np.inf) == "3136 (undetermined)"
    assert plain(2.4e-4, np.nan) == "0.00024"  # held fixed: no ± at all
