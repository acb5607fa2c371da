"""The HTML page: self-contained, numbered and captioned, units in headers, rendered."""

import base64
import os
import shutil
import subprocess
from html.parser import HTMLParser

import numpy as np
import pandas as pd
import pytest

from mpipe.pipeline.html_report import Figure, Section, fmt, write_report


class Collector(HTMLParser):
    def __init__(self):
        super().__init__()
        self.images, self.links, self.headers, self.captions = [], [], [], []
        self._in = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a["src"])
        for key in ("href", "src"):
            if key in a and tag != "img":
                self.links.append(a[key])
        self._in = tag

    def handle_data(self, data):
        if self._in == "th":
            self.headers.append(data)
        if self._in in ("figcaption", "caption"):
            self.captions.append(data)

    def handle_endtag(self, tag):
        self._in = None


def _png(path, rgb):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(4, 3), dpi=50)
    fig.patch.set_facecolor(rgb)
    fig.savefig(path, facecolor=rgb)
    plt.close(fig)
    return path


@pytest.fixture
def report(tmp_path):
    (tmp_path / "stage").mkdir()
    img = _png(tmp_path / "stage" / "red.png", (1.0, 0.0, 0.0))
    table = pd.DataFrame(
        {"t_start_s": [0.25, 0.3], "k": [8.66e6, 8.7123456e6], "error": ["", "x & y"]}
    )
    resonances = pd.DataFrame({"frequency_theory_hz": [105.0868], "error_cents": [np.nan]})
    out = write_report(
        tmp_path / "take" / "report.html",
        "take <1>",
        "mpipe 0.1",
        [
            Section(
                "Validation",
                "a & b",
                ("pass", "pass"),
                (Figure(img, "red square"),),
                (("resonances", resonances),),
            ),  # fmt: skip
            Section("Windows", "", None, (), (("windows", table),)),
        ],
        summary=Section("Summary", "all fine", ("PASS", "pass")),
    )
    return out, img


def test_report_is_self_contained_numbered_and_has_units(report):
    out, img = report
    text = out.read_text()
    parser = Collector()
    parser.feed(text)
    # the image is inside the file, byte for byte; nothing points outside it
    assert len(parser.images) == 1 and parser.images[0].startswith("data:image/png;base64,")
    assert base64.b64decode(parser.images[0].split(",", 1)[1]) == img.read_bytes()
    assert parser.links == [] and "<script" not in text
    assert "take &lt;1&gt;" in text and "a &amp; b" in text and "x &amp; y" in text
    assert "Figure 1. red square" in parser.captions
    assert [c for c in parser.captions if c.startswith("Table")] == [
        "Table 1. resonances", "Table 2. windows"
    ]  # fmt: skip
    assert {"frequency_theory [Hz]", "error [cent]", "t_start [s]", "k [Pa/m]"} <= set(
        parser.headers
    )
    # rounded to four significant digits, missing values as a dash
    assert "8.712e+06" in text and "8712345" not in text and "105.1" in text
    assert ">–<" in text and ">nan<" not in text.lower()
    # the summary comes first
    assert text.index("Summary") < text.index("Validation")


def test_numbers_are_rounded_to_significant_digits():
    assert fmt(0.011372533717677104) == "0.01137"
    assert fmt(8660000.0) == "8.66e+06"
    assert fmt(1800.0) == "1800"
    assert fmt(float("nan")) == "–" and fmt(None) == "–"
    assert fmt(np.int64(3)) == "3" and fmt(True) == "yes"


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (apt-get install chromium)")
def test_report_renders_in_headless_chromium_without_its_folder(report, tmp_path):
    import matplotlib.image as mpimg

    out, _ = report
    # alone in an empty folder: a report that links its images would render without them
    alone = tmp_path / "alone" / "report.html"
    alone.parent.mkdir()
    shutil.copy(out, alone)
    shot = tmp_path / "shot.png"
    cmd = [CHROMIUM, "--headless", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
           "--window-size=1000,1400", alone.as_uri()]  # fmt: skip
    if os.geteuid() == 0:
        cmd.insert(1, "--no-sandbox")
    subprocess.run(cmd, capture_output=True, timeout=120, check=False)
    assert shot.exists(), "chromium wrote no screenshot"
    pixels = mpimg.imread(shot)[..., :3]
    assert pixels.std() > 0.05, "blank screenshot"
    red = (pixels[..., 0] > 0.9) & (pixels[..., 1] < 0.1) & (pixels[..., 2] < 0.1)
    # the embedded 200 x 150 px red figure is drawn
    assert red.sum() > 0.5 * 200 * 150
