"""README.md and docs/*.md: every relative link (and heading anchor) points at something
that exists, and every docs page is listed in README's "Documentation" section."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces -> '-'."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def _links(text: str) -> list[str]:
    text = re.sub(r"```.*?```", "", text, flags=re.S)          # code blocks are not links
    return [u for u in re.findall(r"\]\(([^)\s]+)\)", text) if not re.match(r"[a-z]+://|mailto:", u)]


def test_slug_follows_github():
    assert _slug("Sim-to-real calibration (`rdnet calibrate`)") == "sim-to-real-calibration-rdnet-calibrate"
    assert _slug("The proof") == "the-proof"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_resolve(page):
    broken = []
    for url in _links(page.read_text()):
        path, _, anchor = url.partition("#")
        target = (page.parent / path).resolve() if path else page
        if not target.exists():
            broken.append(url)
        elif anchor and target.suffix == ".md":
            heads = {_slug(h) for h in re.findall(r"^#+ (.*)$", target.read_text(), re.M)}
            if anchor not in heads:
                broken.append(url)
    assert not broken, f"{page.relative_to(ROOT)}: broken links {broken}"


def test_every_docs_page_is_listed_in_readme():
    readme = (ROOT / "README.md").read_text()
    section = readme.split("## Documentation", 1)[1]
    missing = [p.name for p in PAGES[1:] if f"docs/{p.name}" not in section]
    assert not missing, f"docs pages not listed under README's Documentation: {missing}"


@pytest.mark.parametrize("page, table, module, markers", [
    ("README.md", "results/ablation.md", "report", ("README_START", "README_END")),
    ("README.md", "results/calibration_goals.md", "report", ("CALIBRATION_START", "CALIBRATION_END")),
    ("README.md", "results/restoration_goals.md", "goals", ("GOALS_START", "GOALS_END")),
    ("docs/cli.md", "results/restore_real/summary.md", "report", ("RESTORE_REAL_START", "RESTORE_REAL_END"))])
def test_readme_tables_are_the_generated_ones(page, table, module, markers):
    """The docs' generated tables are the committed outputs of their stages, verbatim
    (`python stages/report.py --sync-readme` after `dvc repro`; the restoration goals:
    `python stages/restoration_goals.py --sync-readme`). ``module``: the
    ``rdnet.study`` module that defines the markers."""
    import importlib

    from rdnet.study import report
    mod = importlib.import_module(f"rdnet.study.{module}")
    start, end = (getattr(mod, m) for m in markers)
    assert report.readme_block((ROOT / page).read_text(), start, end) == (ROOT / table).read_text()
