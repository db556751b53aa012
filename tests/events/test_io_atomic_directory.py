"""atomic_directory: a staged folder lands whole, merges into an existing one, or vanishes."""
import pytest

from rdnet.errors import FormatError
from rdnet.events.io._common import atomic_directory


def test_new_folder_appears_only_on_success(tmp_path):
    target = tmp_path / "a" / "out"
    with atomic_directory(target) as stage:
        (stage / "sub").mkdir()
        (stage / "sub" / "f.txt").write_text("1")
        assert not target.exists()
    assert (target / "sub" / "f.txt").read_text() == "1"
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["out"]


def test_existing_folder_gets_staged_files_and_keeps_the_others(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "old.txt").write_text("old")
    (tmp_path / "out" / "f.txt").write_text("before")
    with atomic_directory(tmp_path / "out") as stage:
        (stage / "f.txt").write_text("after")
    assert {p.name: p.read_text() for p in (tmp_path / "out").iterdir()} == {"old.txt": "old", "f.txt": "after"}
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_failure_leaves_nothing(tmp_path):
    (tmp_path / "keep").mkdir()
    (tmp_path / "keep" / "f.txt").write_text("before")
    for target in (tmp_path / "new", tmp_path / "keep"):
        with pytest.raises(RuntimeError):
            with atomic_directory(target) as stage:
                (stage / "f.txt").write_text("half")
                raise RuntimeError("boom")
    assert [p.name for p in tmp_path.iterdir()] == ["keep"]
    assert (tmp_path / "keep" / "f.txt").read_text() == "before"
    (tmp_path / "file").write_text("x")
    with pytest.raises(FormatError, match="not a folder"):
        with atomic_directory(tmp_path / "file"):
            pass
