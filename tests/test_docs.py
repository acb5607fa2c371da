"""The documentation stands on its own: every relative link resolves inside the repository."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)#\s]+)(?:#[^)]*)?\)")


#: The README is the front door (what, quickstart, stages, commands, where the docs are);
#: the reference and the physics live in docs/.
README_MAX_LINES = 150


def test_readme_stays_a_front_door():
    lines = (ROOT / "README.md").read_text().count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines: move the detail to docs/"


def test_readme_names_every_page_of_the_docs():
    readme = (ROOT / "README.md").read_text()
    missing = [
        p.name for p in sorted((ROOT / "docs").glob("*.md")) if f"docs/{p.name}" not in readme
    ]
    assert not missing, f"README's Documentation section does not name: {missing}"


def test_relative_links_resolve_inside_the_repository():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    assert len(pages) >= 3
    for page in pages:
        text = page.read_text()
        assert "../shared" not in text, f"{page.name} points outside the repository"
        for target in LINK.findall(text):
            if "://" in target:
                continue
            path = (page.parent / target).resolve()
            assert path.is_relative_to(ROOT), f"{page.name}: {target} leaves the repository"
            assert path.exists(), f"{page.name}: {target} does not exist"


def test_no_page_offers_a_removed_setting():
    # the keys and choices issue 23 removed are named only in settings.md's table of
    # removed settings (what became of each); a page or the shipped pipeline file that
    # offers one sends a user into a one-line error
    from mpipe.inversion.settings import REMOVED_CHOICES, REMOVED_KEYS

    patterns = []
    for key in REMOVED_KEYS:
        # a plain word (start, jacobian) counts only as a YAML key: line start, ` { or ,
        distinct = rf"\b{key}\b" if "_" in key else rf"(?m:^\s*|[`{{,]\s*){key}:"
        patterns.append(rf"inversion\.{key}\b|{distinct}")
    patterns += [rf"{key}: ['\"]?{c}\b" for key, cs in REMOVED_CHOICES.items() for c in cs]
    found = re.compile("|".join(patterns))
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for page in [*pages, *sorted((ROOT / "pipelines").glob("*.yaml"))]:
        text = page.read_text().partition("\n## Removed settings\n")[0]
        hits = [m.group(0) for m in found.finditer(text)]
        assert not hits, f"{page.name} offers removed settings: {hits}"


def _anchors(page: Path) -> set[str]:
    # GitHub's heading anchors: lower case, punctuation dropped, spaces as hyphens
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    titles = re.findall(r"^#+\s+(.+?)\s*$", text, flags=re.M)
    return {re.sub(r"[^\w\- ]", "", t.lower()).replace(" ", "-") for t in titles}


def test_link_anchors_name_a_heading_of_their_page():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    for page in pages:
        for target, anchor in re.findall(r"\]\(([^)#\s]*)#([^)\s]+)\)", page.read_text()):
            path = (page.parent / target).resolve() if target else page
            if path.suffix == ".md" and path.exists():
                assert anchor in _anchors(path), f"{page.name}: {target}#{anchor}: no such heading"


# --- docs and messages in step (issue 33) ----------------------------------------------------

OFFERED = re.compile(r"(\S+): unknown key.*expected one of: (.*)$")


def _offered(load, mapping) -> tuple[str, list[str]]:
    """The key path an unknown-key error names, and the keys it offers."""
    from mpipe.core.config import ConfigError

    try:
        load(mapping)
    except ConfigError as exc:
        match = OFFERED.search(str(exc))
        assert match, str(exc)
        return match[1], match[2].split(", ")
    raise AssertionError(f"{mapping} was accepted")


def _refusal(load, mapping) -> str:
    from mpipe.core.config import ConfigError

    try:
        load(mapping)
    except (ConfigError, ValueError, TypeError) as exc:
        return str(exc)
    return ""


def _nest(path: list[str], leaf: dict) -> dict:
    for key in reversed(path):
        leaf = {key: leaf}
    return leaf


def _check_offers(load, base: dict, path: list[str], depth: int) -> list[str]:
    """Keys offered by an unknown-key error below ``path`` that are then refused as unknown."""
    bad = []
    named, keys = _offered(load, {**base, **_nest(path, {"no_such_key": 1})})
    prefix = named.rsplit(".", 1)[0].split(": ")[-1] + "." if path else ""
    for key in keys:
        message = _refusal(load, {**base, **_nest(path, {key: 0.01})})
        if f"{prefix}{key}: unknown key" in message or f" {key}: unknown key" in message:
            bad.append(".".join([*path, key]))
        if depth and f"{prefix}{key}: expected a mapping" in message:
            bad += _check_offers(load, base, [*path, key], depth - 1)
    return bad


def test_every_key_an_unknown_key_error_offers_is_accepted(tmp_path):
    # a score's reed width was `lambda` in the docs, the error offered `lam`, and `lam` was
    # then refused: every key an error offers must be one the file accepts
    import yaml

    from mpipe.core.config import Where
    from mpipe.pipeline.settings import load_pipeline
    from mpipe.reed.parameters import reed_from_mapping
    from mpipe.reed.score import score_from_mapping

    def pipeline(data):
        path = tmp_path / "pipe.yaml"
        path.write_text(yaml.safe_dump(data))
        return load_pipeline(path, check_calibration=False)

    def note(data):
        return score_from_mapping({"notes": [{"duration": 0.5, **data}]}, "s.yaml")

    bad = _check_offers(note, {}, [], 1)
    bad += _check_offers(
        lambda d: score_from_mapping({"notes": [{"duration": 0.5}], **d}), {}, [], 0
    )
    bad += _check_offers(lambda d: reed_from_mapping(d, Where("r.yaml")), {}, [], 0)
    bad += _check_offers(pipeline, {"calibration": "c.yaml"}, [], 2)
    assert not bad, f"offered by an unknown-key error, then refused as unknown: {bad}"
    # the reed width is spelt as in the docs in both the reed file and a score
    assert "lambda" in _offered(note, {"no_such_key": 1})[1]
    assert "lambda" in _offered(lambda d: reed_from_mapping(d, Where("r.yaml")), {"x": 1})[1]
    assert "`lambda`" in (ROOT / "docs" / "virtual_takes.md").read_text()


def test_the_api_examples_write_only_into_the_folder_they_name():
    # issue 33: the API example wrote track_windows/ into the current folder
    page = (ROOT / "docs" / "python_api.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", page, flags=re.S)
    writing = [b for b in blocks if re.search(r"checkpoint=|\.to_csv\(|savez", b)]
    assert writing
    for block in writing:
        named = re.search(r"^(\w+) = Path\(\"(\w+)\"\)", block, flags=re.M)
        assert named, f"an example that writes names its folder first:\n{block}"
        for target in re.findall(r"checkpoint=([^),]+)", block):
            assert target.startswith(f"{named[1]} /"), target


def _commands(parser, path=()):
    """(command words, option strings of each option) of every leaf command of a parser."""
    import argparse

    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, [a.option_strings for a in parser._actions if a.option_strings]
        return
    for name, sub in subs[0].choices.items():
        yield from _commands(sub, (*path, name))


def test_the_readme_synopsis_names_every_option_of_every_command():
    # issue 33: the synopsis of synth-take lacked --fs-model, --onset, --bits and
    # --no-mic-calibration; every option now appears on its command's lines (--force and
    # --fingering, which most commands take, in the paragraph below the synopsis)
    from mpipe.cli.main import build_parser

    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Command line", 1)[1]
    block = section.split("```", 2)[1]
    after = section.split("```", 2)[2].split("\n## ", 1)[0]
    assert "`--force`" in after and "`--fingering NAME`" in after
    entries: dict[tuple, str] = {}
    key = None
    for line in block.splitlines():
        if line.startswith("mpipe "):
            words = line.split()[1:]
            key = tuple(words[:2] if words[0] == "calibrate" else words[:1])
            entries[key] = ""
        if key is not None:
            entries[key] += " " + line.split("  # ")[0]
    missing = []
    for path, options in _commands(build_parser()):
        assert path in entries, f"README's synopsis has no line for mpipe {' '.join(path)}"
        for strings in options:
            if "--help" in strings or strings[-1] in ("--force", "--fingering"):
                continue
            if not any(re.search(rf"(?<![\w-]){re.escape(o)}(?![\w-])", entries[path])
                       for o in strings):  # fmt: skip
                missing.append(f"mpipe {' '.join(path)} {strings[-1]}")
    assert not missing, f"README's synopsis does not name: {missing}"


#: Keys of the calibration dataclasses that the loader sets (and refuses in a file).
LOADER_SET = ("source", "bore.open_holes", "bore.measured_input")


def _file_keys(cls, prefix=""):
    """Every key path a configuration dataclass reads: ``a.b``, ``a.list[].c``."""
    import dataclasses
    import types
    import typing

    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        tp, path, inner = hints[f.name], prefix + f.name, None
        for arg in (tp, *typing.get_args(tp)):
            for a in (arg, *typing.get_args(arg)):
                if dataclasses.is_dataclass(a):
                    inner = a
        listed = typing.get_origin(tp) is tuple or any(
            typing.get_origin(a) is tuple
            for a in typing.get_args(tp)
            if typing.get_origin(tp) in (typing.Union, types.UnionType)
        )
        yield path + ("[]" if listed and inner else "")
        if inner is not None:
            yield from _file_keys(inner, path + ("[]." if listed else "."))


def test_every_calibration_key_is_documented(tmp_path):
    # issue 33: calibration_file.md did not document holes, fingerings or measured
    from mpipe.core.config import ConfigError
    from mpipe.measurement.calibration import Calibration, load_calibration

    page = (ROOT / "docs" / "calibration_file.md").read_text()
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    every = list(_file_keys(Calibration))
    keys = [
        k.replace("fingerings[]", "fingerings")  # in the file, a mapping name -> open holes
        for k in every
        if not any(k == s or k.startswith(s + ".") for s in LOADER_SET)
        and not k.startswith("fingerings[].")
        # a section's keys are named, not the section (a list's row names its items' keys)
        and (k.endswith("[]") or not any(o.startswith(k + ".") for o in every))
    ]
    assert {"bore.holes[]", "bore.holes[].chimney", "bore.measured", "fingerings"} <= set(keys)
    missing = []
    for key in keys:
        if "[]." in key:  # a list's item key is named in its list's row
            parent, leaf = key.rsplit(".", 1)
            row = [r for r in rows if r.split("|")[1].strip() == f"`{parent}`"]
            if not row or f"`{leaf}`" not in row[0]:
                missing.append(key)
        elif not any(f"`{key}`" in r.split("|")[1] for r in rows):
            missing.append(key)
    assert not missing, f"docs/calibration_file.md's table does not name: {missing}"
    # what the loader sets is refused in a file (so it needs no row)
    text = (ROOT / "calibration" / "simplified_clarinet.yaml").read_text()
    for key, value in (("source", "x"), ("bore.open_holes", "[]"), ("bore.measured_input", "1")):
        path = tmp_path / "cal.yaml"
        if "." in key:
            path.write_text(text.replace("bore:\n", f"bore:\n  {key.split('.')[1]}: {value}\n", 1))
        else:
            path.write_text(text + f"{key}: {value}\n")
        try:
            load_calibration(path)
        except ConfigError as exc:
            assert key in str(exc)
        else:
            raise AssertionError(f"{key} accepted in a calibration file")


def test_the_fingered_phrase_says_what_it_plays_and_playing_md_what_the_code_does():
    # issue 42: the score said "the fourth note 30 dB softer" with every note at p_m 1800;
    # playing.md said a fingering change makes other fingerings' results wrong and that a
    # phrase's validation compares one f0's harmonics (each note has its own bore and its
    # own validation now)
    import yaml

    root = Path(__file__).resolve().parents[1]
    text = (root / "examples" / "scores" / "fingered_phrase.yaml").read_text()
    notes = yaml.safe_load(text)["notes"]
    header = "".join(line for line in text.splitlines() if line.startswith("#"))
    if "softer" in header or "louder" in header:
        assert len({n.get("p_m") for n in notes}) > 1, "a dynamic the notes do not play"
    else:
        assert len({n.get("p_m") for n in notes}) == 1 and "1800" in header
    playing = (root / "docs" / "playing.md").read_text()
    assert "inversion of other fingerings are then wrong" not in playing
    assert "only the harmonics of that one f0" not in playing
    assert "note by note" in playing and "its own fingering's bore" in playing
