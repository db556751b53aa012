"""Property tests of the event container invariants (rdnet.events.core / recording)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rdnet.errors import ValidationError
from rdnet.events import EVENT_DTYPE, Events, Frames, Recording, concatenate

SETTINGS = settings(max_examples=60, deadline=None)


@st.composite
def valid_arrays(draw, min_size: int = 0, max_size: int = 120):
    """(structured array, width, height) satisfying every invariant."""
    width = draw(st.integers(1, 400))
    height = draw(st.integers(1, 300))
    n = draw(st.integers(min_size, max_size))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    arr = np.empty(n, EVENT_DTYPE)
    start = draw(st.integers(-10**12, 10**12))
    # many repeated timestamps: steps of 0 are frequent
    arr["t"] = start + np.cumsum(rng.integers(0, 3, n) * rng.integers(0, 1000, n))
    arr["x"] = rng.integers(0, width, n)
    arr["y"] = rng.integers(0, height, n)
    arr["p"] = rng.integers(0, 2, n)
    return arr, width, height


@SETTINGS
@given(valid_arrays())
def test_valid_arrays_are_accepted_unchanged(data):
    arr, w, h = data
    ev = Events(arr.copy(), w, h)
    assert len(ev) == arr.shape[0]
    assert ev.shape == (h, w)
    np.testing.assert_array_equal(ev.array, arr)
    ev2 = Events.from_columns(arr["t"], arr["x"], arr["y"], arr["p"], w, h)
    np.testing.assert_array_equal(ev2.array, arr)


@SETTINGS
@given(valid_arrays(min_size=2), st.data())
def test_any_decreasing_timestamp_is_rejected(data, draw):
    arr, w, h = data
    i = draw.draw(st.integers(1, arr.shape[0] - 1))
    arr = arr.copy()
    arr["t"][i] = arr["t"][i - 1] - draw.draw(st.integers(1, 10**6))
    with pytest.raises(ValidationError) as e:
        Events(arr, w, h)
    assert e.value.field == "t"


@SETTINGS
@given(valid_arrays(min_size=1), st.data(), st.sampled_from(["x", "y"]))
def test_any_coordinate_off_sensor_is_rejected(data, draw, axis):
    arr, w, h = data
    limit = w if axis == "x" else h
    i = draw.draw(st.integers(0, arr.shape[0] - 1))
    arr = arr.copy()
    arr[axis][i] = draw.draw(st.integers(limit, 65535))
    with pytest.raises(ValidationError) as e:
        Events(arr, w, h)
    assert e.value.field == axis


@SETTINGS
@given(valid_arrays(min_size=1), st.data())
def test_any_polarity_above_one_is_rejected(data, draw):
    arr, w, h = data
    i = draw.draw(st.integers(0, arr.shape[0] - 1))
    arr = arr.copy()
    arr["p"][i] = draw.draw(st.integers(2, 255))
    with pytest.raises(ValidationError) as e:
        Events(arr, w, h)
    assert e.value.field == "p"


@SETTINGS
@given(valid_arrays(), st.data())
def test_slice_time_equals_boolean_mask(data, draw):
    arr, w, h = data
    ev = Events(arr, w, h)
    lo = int(arr["t"].min()) if arr.size else 0
    hi = int(arr["t"].max()) if arr.size else 0
    t0 = draw.draw(st.integers(lo - 5, hi + 5))
    t1 = draw.draw(st.integers(lo - 5, hi + 5))
    sl = ev.slice_time(t0, t1)
    mask = (arr["t"] >= t0) & (arr["t"] < t1)
    np.testing.assert_array_equal(sl.array, arr[mask])
    np.testing.assert_array_equal(ev.select(mask).array, arr[mask])


@SETTINGS
@given(valid_arrays(), st.lists(st.integers(0, 120), max_size=5))
def test_concatenate_of_consecutive_parts_restores_the_whole(data, cuts):
    arr, w, h = data
    ev = Events(arr, w, h)
    bounds = sorted({0, len(ev), *[min(c, len(ev)) for c in cuts]})
    parts = [ev[a:b] for a, b in zip(bounds[:-1], bounds[1:])] or [ev]
    np.testing.assert_array_equal(concatenate(parts).array, arr)


@SETTINGS
@given(valid_arrays(min_size=2), valid_arrays(min_size=2))
def test_concatenate_sort_is_a_stable_merge(d1, d2):
    a1, w, h = d1
    a2 = d2[0].copy()
    a2["x"] %= w
    a2["y"] %= h
    e1, e2 = Events(a1, w, h), Events(a2, w, h)
    merged = concatenate([e2, e1], sort=True)
    both = np.concatenate([a2, a1])
    np.testing.assert_array_equal(merged.array, both[np.argsort(both["t"], kind="stable")])
    if a2["t"][-1] > a1["t"][0]:
        with pytest.raises(ValidationError):
            concatenate([e2, e1])


def test_concatenate_rejects_different_sensors_and_nothing(events_factory, rng):
    with pytest.raises(ValidationError):
        concatenate([events_factory(rng, 5, 10, 10), events_factory(rng, 5, 11, 10)])
    with pytest.raises(ValidationError):
        concatenate([])


def test_counts_and_statistics(events_factory, rng):
    ev = events_factory(rng, 5000, 32, 24)
    on, off = ev.count_per_pixel(1), ev.count_per_pixel(0)
    assert on.shape == (24, 32)
    assert ev.count_per_pixel().sum() == 5000
    np.testing.assert_array_equal(ev.signed_count_per_pixel(), on - off)
    assert ev.on_fraction == pytest.approx(on.sum() / 5000)
    assert ev.rate_hz == pytest.approx(5000 / (ev.duration_us * 1e-6))


def test_structured_array_without_event_fields_is_rejected():
    bad = np.zeros(3, dtype=[("a", "i8"), ("b", "u2"), ("c", "u2"), ("d", "u1")])
    with pytest.raises(ValidationError):
        Events(bad, 10, 10)
    with pytest.raises(ValidationError):
        Events(np.zeros(3), 10, 10)
    with pytest.raises(ValidationError):
        Events.empty(0, 10)


def test_other_structured_dtypes_are_converted():
    src = np.zeros(2, dtype=[("t", "<u8"), ("x", "<i4"), ("y", "<i4"), ("p", "?"), ("extra", "f4")])
    src["t"] = [5, 7]
    src["p"] = [True, False]
    ev = Events(src, 4, 4)
    assert ev.array.dtype == EVENT_DTYPE
    np.testing.assert_array_equal(ev.p, [1, 0])


def test_frames_and_recording_checks(rng):
    im = rng.random((3, 4, 5), dtype=np.float32)
    with pytest.raises(ValidationError, match="frames/t"):
        Frames(im, [0, 2, 1], 0)
    with pytest.raises(ValidationError, match="frames/images"):
        Frames(im.astype(np.int32), [0, 1, 2], 0)
    with pytest.raises(ValidationError, match="frames/images"):
        Frames(np.full((1, 2, 2), np.nan, np.float32), [0], 0)
    fr = Frames(im, [0, 1, 2], 4)
    assert fr.exposure_window(1) == (-1, 3)
    with pytest.raises(ValidationError, match="frames/images"):
        Recording(6, 4, frames=fr)
    with pytest.raises(ValidationError):
        Recording(5, 4)
    rec = Recording(5, 4, frames=fr)
    assert rec.summary()["frames"] == 3 and rec.summary()["events"] == 0
