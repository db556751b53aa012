"""README's results block is the report stage's table, not typed by hand."""
from pathlib import Path

from rdnet.study.report import README_END, README_START

ROOT = Path(__file__).resolve().parents[2]


def test_readme_results_block_matches_generated_table():
    readme = (ROOT / "README.md").read_text()
    block = readme.split(README_START, 1)[1].split(README_END, 1)[0].strip()
    table = (ROOT / "results" / "ablation.md").read_text().strip()
    assert block == table
