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


def test_a_clash_with_an_existing_entry_moves_nothing(tmp_path):
    """A staged file whose name is a folder in the target (or a staged folder whose name is
    a file there) is found before anything moves: a FormatError naming it, the target as
    it was, the staging folder gone."""
    out = tmp_path / "out"
    (out / "b.txt").mkdir(parents=True)
    with pytest.raises(FormatError, match=r"b\.txt.*is a folder"):
        with atomic_directory(out) as stage:
            (stage / "a.txt").write_text("1")          # sorts before the clash: must not land
            (stage / "b.txt").write_text("2")
    assert sorted(p.name for p in out.iterdir()) == ["b.txt"] and (out / "b.txt").is_dir()
    (out / "b.txt").rmdir()
    (out / "sub").write_text("a file")
    with pytest.raises(FormatError, match=r"sub.*not a folder"):
        with atomic_directory(out) as stage:
            (stage / "a.txt").write_text("1")
            (stage / "sub").mkdir()
            (stage / "sub" / "f.png").write_text("x")
    assert sorted(p.name for p in out.iterdir()) == ["sub"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_check_output_folder_fails_before_the_work(tmp_path):
    from rdnet.events.io._common import check_output_folder
    assert check_output_folder(tmp_path / "new" / "deeper", ("model.pt",)) == tmp_path / "new" / "deeper"
    assert not (tmp_path / "new").exists()                       # creates nothing
    (tmp_path / "f").write_text("x")
    with pytest.raises(FormatError, match=r"f: exists and is not a folder"):
        check_output_folder(tmp_path / "f")
    with pytest.raises(FormatError, match=r"f: is not a folder"):
        check_output_folder(tmp_path / "f" / "below")
    (tmp_path / "o" / "model.pt").mkdir(parents=True)
    with pytest.raises(FormatError, match=r"model\.pt: exists and is a folder"):
        check_output_folder(tmp_path / "o", ("last.pt", "model.pt"))


def test_check_output_folder_probes_the_write(tmp_path, monkeypatch):
    """The write check creates a temporary file where the folder will be made (os.access
    says yes to root on a read-only mount); a refusal there names the folder."""
    import tempfile

    from rdnet.events.io._common import check_output_folder

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(tempfile, "TemporaryFile", refuse)
    with pytest.raises(FormatError, match=r"cannot be written to \(Permission denied\)"):
        check_output_folder(tmp_path / "new")
    assert list(tmp_path.iterdir()) == []
