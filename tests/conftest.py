"""Shared test fixtures: paths of the real recordings and small random recordings."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from rdnet.events import EVENT_DTYPE, Events, Frames, Recording

ROOT = Path(__file__).resolve().parents[1]
#: Committed copy of the DAVIS346 AEDAT 4 file (input data of a fresh clone).
DAVIS346_AEDAT4 = ROOT / "data" / "real" / "davis346_road" / "davis346.aedat4"
#: Read-only real data beside the repository (CI has it at ../shared).
SHARED_REAL = ROOT.parent / "shared" / "real"
ECD_SHAPES_TXT = SHARED_REAL / "ecd_shapes_subset" / "events.txt"
PROPHESEE_EVT2_RAW = SHARED_REAL / "prophesee_gen3_sparklers" / "sparklers.raw"
PROPHESEE_EVT3_RAW = SHARED_REAL / "prophesee_evk4_night" / "night.raw"
DVXPLORER_AEDAT4 = SHARED_REAL / "dvxplorer_person" / "dvxplorer.aedat4"


def pytest_collection_modifyitems(config, items):
    """Tests marked ``first`` run before all others (a stable sort: the rest keep their
    order). ``make test`` runs the suite in pytest-xdist workers (``--dist worksteal``):
    the longest test then starts at once and the other workers share the rest."""
    items.sort(key=lambda item: item.get_closest_marker("first") is None)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


def random_events(rng: np.random.Generator, n: int, width: int = 64, height: int = 48,
                  t0_us: int = 0, span_us: int = 1_000_000) -> Events:
    """``n`` valid events (sorted times in [t0, t0 + span], repeated times allowed)."""
    arr = np.empty(n, EVENT_DTYPE)
    arr["t"] = np.sort(rng.integers(t0_us, t0_us + span_us + 1, n))
    arr["x"] = rng.integers(0, width, n)
    arr["y"] = rng.integers(0, height, n)
    arr["p"] = rng.integers(0, 2, n)
    return Events(arr, width, height)


def random_frames(rng: np.random.Generator, n: int, width: int = 64, height: int = 48, *,
                  color: bool = False, dtype=np.uint8, period_us: int = 40_000,
                  exposure_us: int = 10_000) -> Frames:
    shape = (n, height, width, 3) if color else (n, height, width)
    if np.dtype(dtype) == np.uint8:
        images = rng.integers(0, 256, shape).astype(np.uint8)
    else:
        images = rng.random(shape, dtype=np.float32)
    t = 20_000 + period_us * np.arange(n, dtype=np.int64)
    return Frames(images, t, np.full(n, exposure_us, np.int64))


@pytest.fixture
def make_recording(rng):
    """Factory: ``make_recording(n_events=1000, n_frames=0, color=False, dtype=np.uint8)``."""
    def make(n_events: int | None = 1000, n_frames: int = 0, *, color: bool = False, dtype=np.uint8,
             width: int = 64, height: int = 48, sensor: str = "TEST64", attrs: dict | None = None) -> Recording:
        ev = None if n_events is None else random_events(rng, n_events, width, height)
        fr = random_frames(rng, n_frames, width, height, color=color, dtype=dtype) if n_frames else None
        return Recording(width, height, events=ev, frames=fr, sensor=sensor, attrs=dict(attrs or {}))
    return make


def assert_same_recording(a: Recording, b: Recording, *, sensor: bool = True) -> None:
    """Bit-identical content (events, frames, size; sensor name optionally)."""
    assert (a.width, a.height) == (b.width, b.height)
    if sensor:
        assert a.sensor == b.sensor
    assert (a.events is None) == (b.events is None)
    if a.events is not None:
        assert a.events.array.dtype == b.events.array.dtype == EVENT_DTYPE
        np.testing.assert_array_equal(a.events.array, b.events.array)
    assert (a.frames is None) == (b.frames is None)
    if a.frames is not None:
        assert a.frames.images.dtype == b.frames.images.dtype
        np.testing.assert_array_equal(a.frames.images, b.frames.images)
        np.testing.assert_array_equal(a.frames.t_us, b.frames.t_us)
        np.testing.assert_array_equal(a.frames.exposure_us, b.frames.exposure_us)


@pytest.fixture
def same_recording():
    return assert_same_recording


@pytest.fixture
def events_factory():
    return random_events


def copy_pairs(src_path: Path, dst_path: Path, replace=()) -> Path:
    """A copy of the HDF5 pairs file ``src_path`` (datasets and attributes) with the
    datasets named in ``replace`` turned into empty HDF5 groups (bad-input tests)."""
    import h5py
    with h5py.File(src_path, "r") as src, h5py.File(dst_path, "w") as dst:
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        for k in src:
            if k in replace:
                dst.create_group(k)
            else:
                src.copy(k, dst)
    return dst_path


@pytest.fixture
def pairs_copier():
    return copy_pairs


@pytest.fixture
def davis346_path() -> Path:
    """The committed DAVIS346 AEDAT 4 file (part of the repository)."""
    assert DAVIS346_AEDAT4.is_file(), f"{DAVIS346_AEDAT4} is missing from the checkout"
    return DAVIS346_AEDAT4


@pytest.fixture
def ecd_path() -> Path:
    """The ECD 'shapes' subset beside the repository (../shared/real). CI always has it,
    so there its absence is a failure; a local checkout without ../shared skips."""
    return shared_file(ECD_SHAPES_TXT)


def shared_file(path: Path) -> Path:
    """``path`` under ../shared/real: a failure on CI when missing, an xfail elsewhere."""
    if not path.is_file():
        if os.environ.get("CI"):
            raise AssertionError(f"{path} missing on CI (../shared must sit beside the repo)")
        pytest.xfail(f"{path} not available outside CI")
    return path


@pytest.fixture
def sparklers_path() -> Path:
    """Prophesee Gen3 EVT 2.0 RAW (../shared/real; 521,252 events, 640 x 480)."""
    return shared_file(PROPHESEE_EVT2_RAW)


@pytest.fixture
def night_path() -> Path:
    """Prophesee EVK4 EVT 3.0 RAW (../shared/real; 1,218,618 events, 1280 x 720)."""
    return shared_file(PROPHESEE_EVT3_RAW)


@pytest.fixture
def dvxplorer_path() -> Path:
    """iniVation DVXplorer AEDAT 4 without frames (../shared/real; 111,954 events, 320 x 240)."""
    return shared_file(DVXPLORER_AEDAT4)
