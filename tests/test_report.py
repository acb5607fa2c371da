from html.parser import HTMLParser

import pandas as pd

from mpipe.report import Section, write_report


class Collector(HTMLParser):
    def __init__(self):
        super().__init__()
        self.images, self.tags = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        if tag == "img":
            self.images.append(dict(attrs)["src"])


def test_report_links_images_relatively_and_escapes_text(tmp_path):
    img = tmp_path / "take" / "validation" / "impedance.png"
    img.parent.mkdir(parents=True)
    img.write_bytes(b"\x89PNG")
    table = pd.DataFrame({"t_s": [0.0, 0.02], "k_pa_per_m": [8.66e6, 8.7e6]})
    out = write_report(
        tmp_path / "take" / "report.html",
        "take <1>",
        "mpipe 0.1",
        [Section("Validation", "a & b", ("pass", "pass"), (img,), (("windows", table),))],
    )
    text = out.read_text()
    parser = Collector()
    parser.feed(text)
    assert parser.images == ["validation/impedance.png"]
    assert (out.parent / parser.images[0]).exists()
    assert "take &lt;1&gt;" in text and "a &amp; b" in text
    assert "8.66e+06" in text and "<script" not in text
