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
