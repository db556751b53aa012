"""The Makefile's install pins (``STUDY_PINS``, ``TORCH_SPEC``: the versions the study's
bytes in ``dvc.lock`` were checked with) stay inside ``pyproject.toml``'s ranges, so ``make install`` and a plain
``pip install rdnet`` agree on what rdnet supports."""
import re
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

tomllib = pytest.importorskip("tomllib")

ROOT = Path(__file__).resolve().parents[1]


def make_variable(name: str) -> str:
    """The value of ``NAME ?= ...`` in the Makefile, continuation lines joined."""
    text = (ROOT / "Makefile").read_text().replace("\\\n", " ")
    m = re.search(rf"^{name}\s*\??=\s*(.*)$", text, re.M)
    assert m, f"Makefile: no {name}"
    return m.group(1).split("#", 1)[0]


def pins(value: str) -> dict[str, str]:
    out = {}
    for token in value.split():
        if token.startswith("-"):        # pip options (--index-url URL) and their values
            continue
        if "==" not in token:
            if "://" in token:
                continue
            raise AssertionError(f"Makefile pin {token!r} is not NAME==VERSION")
        name, version = token.split("==", 1)
        out[canonicalize_name(name)] = version
    return out


def project_requirements() -> dict[str, Requirement]:
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    return {canonicalize_name(r.name): r for r in map(Requirement, deps)}


def test_pins_parse_the_makefiles_form():
    assert pins("numpy==2.4.6 h5py==3.16.0") == {"numpy": "2.4.6", "h5py": "3.16.0"}
    assert pins("torch==2.13.0 --index-url https://download.pytorch.org/whl/cu126") == {"torch": "2.13.0"}
    with pytest.raises(AssertionError, match="NAME==VERSION"):
        pins("numpy>=2")


def test_study_pins_are_exact_and_inside_pyproject_ranges():
    study = pins(make_variable("STUDY_PINS"))
    assert {"numpy", "h5py", "numba", "opencv-python-headless", "scikit-image"} <= set(study)
    reqs = project_requirements()
    outside = {n: (v, str(reqs[n].specifier)) for n, v in study.items()
               if n in reqs and not reqs[n].specifier.contains(v, prereleases=True)}
    assert not outside, f"Makefile STUDY_PINS outside pyproject.toml's ranges: {outside}"


def test_torch_spec_is_inside_pyprojects_range():
    torch = pins(make_variable("TORCH_SPEC"))["torch"]
    assert project_requirements()["torch"].specifier.contains(torch)
