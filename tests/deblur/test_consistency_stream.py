"""The streamed event-frame consistency (ConsistencyAccumulator) against the whole-stream
compare_consistency: synthetic recordings (irregular frame times, events exactly on frame
times and outside the frames, windows on and off the frame times, a lagging stream) and
the committed DAVIS346 recording (raw vs BAF, 50 ms windows as rdnet restore feeds them)."""
import math

import numpy as np
import pytest

from rdnet.baselines import baf_filter
from rdnet.config import section
from rdnet.deblur.consistency import ConsistencyAccumulator, LogFrames, compare_consistency
from rdnet.events import Events, Frames
from rdnet.restore.stream import windows


def assert_same_scores(got: dict, want: dict, rel: float = 1e-9) -> None:
    """Same streams and keys; counts equal, floats within ``rel`` (NaN where NaN)."""
    assert list(got) == list(want)
    for name in want:
        assert list(got[name]) == list(want[name]), name
        for key, w in want[name].items():
            g = got[name][key]
            if isinstance(w, float) and math.isnan(w):
                assert math.isnan(g), (name, key, g)
            elif key in ("active", "events"):
                assert g == w, (name, key)
            else:
                assert g == pytest.approx(w, rel=rel, abs=1e-12), (name, key)


def _synthetic(seed=0, W=23, H=17, n_frames=12):
    """Frames at irregular times (multiples of 1 ms) with random log changes; a raw stream
    that roughly follows them (ON/OFF counts ~ dL / 0.2 plus noise), with events exactly on
    frame times, before the first and after the last frame; a 'restored' subset of it."""
    rng = np.random.default_rng(seed)
    ft = 10_000 + np.r_[0, np.cumsum(rng.integers(3, 10, n_frames - 1))] * 1000
    logi = np.cumsum(rng.normal(0, 0.3, (n_frames, H, W)), axis=0) - 1.5
    frames = Frames(np.clip(np.exp(logi), 0, 1).astype(np.float32), ft, np.full(n_frames, 500))
    dL = np.diff(np.log(frames.grey() + np.float32(0.01)), axis=0)
    n = np.round(np.abs(dL) / 0.2 + rng.normal(0, 0.7, dL.shape)).clip(0).astype(int)
    k, y, x = np.nonzero(n)
    k, y, x = (np.repeat(v, n[k, y, x]) for v in (k, y, x))
    p = (dL[k, y, x] > 0).astype(np.uint8)
    t = ft[k] + 1 + (rng.random(k.size) * (ft[k + 1] - ft[k])).astype(np.int64)   # in (t_k, t_k+1]
    m = 300                                            # noise, half of it exactly on frame times
    t = np.r_[t, rng.integers(ft[0] - 5000, ft[-1] + 5000, m), rng.choice(ft, m)]
    x = np.r_[x, rng.integers(0, W, 2 * m)]
    y = np.r_[y, rng.integers(0, H, 2 * m)]
    p = np.r_[p, rng.integers(0, 2, 2 * m)].astype(np.uint8)
    o = np.argsort(t, kind="stable")
    raw = Events.from_columns(t[o], x[o], y[o], p[o], W, H)
    restored = raw.select(rng.random(len(raw)) < 0.7)
    return frames, raw, restored


def _feed(acc, streams: dict, window_us: int, lags: dict | None = None, start: int | None = None):
    """Feed the accumulator window by window as rdnet restore does: stream ``name`` gets its
    events in [t0 + lag, t1 + lag) with until = t1 + lag. Returns the most intervals open."""
    lags = lags or {}
    t_all = np.concatenate([ev.t - lags.get(name, 0) for name, ev in streams.items()])
    t0 = int(t_all.min()) if start is None else start
    most = 0
    while t0 <= int(t_all.max()):
        for name, ev in streams.items():
            lag = lags.get(name, 0)
            acc.add(name, ev.slice_time(t0 + lag, t0 + window_us + lag), t0 + window_us + lag)
            most = max(most, acc.open_intervals)
        t0 += window_us
    return most


@pytest.mark.parametrize("window_us", [7_300, 1_000, 40_000])
def test_streamed_equals_whole_stream_synthetic(window_us):
    frames, raw, restored = _synthetic()
    empty = raw.select(np.zeros(len(raw), bool))
    streams = {"raw": raw, "restored": restored, "none": empty}
    thr_on, thr_off, eps = 0.25, 0.15, 0.01                          # unequal on purpose
    want = compare_consistency(LogFrames.of(frames, raw, eps), streams, thr_on, thr_off)
    acc = ConsistencyAccumulator(frames, list(streams), thr_on, thr_off, eps)
    start = int(frames.t_us[0]) if window_us == 1_000 else None        # 1 ms from a frame: every frame
    if start is not None:                                              # time is a window boundary
        streams_from = {k: v.slice_time(start, 1 << 62) for k, v in streams.items()}
        want = compare_consistency(LogFrames.of(frames, streams_from["raw"], eps), streams_from, thr_on, thr_off)
        streams = streams_from
    most = _feed(acc, streams, window_us, start=start)
    got = acc.scores()
    assert_same_scores(got, want)
    assert repr(acc.scores()) == repr(got)                             # scores() changes nothing
    assert want["raw"]["active"] > 100 and np.isfinite(want["raw"]["r2_fitted"])
    # a stream without events: no gain (NaN), the fitted R^2 is the nominal one
    assert math.isnan(got["none"]["slope"]) and got["none"]["r2_fitted"] == got["none"]["r2_nominal"]
    assert math.isnan(got["none"]["correlation"])
    # only the intervals the windows overlap are open at a time
    assert most <= window_us // 3000 + 2


def test_lagging_stream_and_chunks_without_until():
    """The raw stream ahead of the restored one by a latency shift (rdnet restore
    --calibration), and chunks given without ``until`` (each one's last time)."""
    frames, raw, restored = _synthetic(seed=3)
    want = compare_consistency(LogFrames.of(frames, raw, 0.01), {"raw": raw, "restored": restored}, 0.2, 0.2)
    acc = ConsistencyAccumulator(frames, ["raw", "restored"], 0.2, 0.2, 0.01)
    _feed(acc, {"raw": raw, "restored": restored}, 4_100, lags={"raw": 8_300})
    assert_same_scores(acc.scores(), want)
    acc = ConsistencyAccumulator(frames, ["raw", "restored"], 0.2, 0.2, 0.01)
    cuts = np.r_[np.searchsorted(restored.t, raw.t[::97], side="left"), len(restored)]
    for c, i in enumerate(range(0, len(raw), 97)):          # the restored events before raw's
        acc.add("raw", raw[i:i + 97])                        # next chunk, with each raw chunk
        acc.add("restored", restored[cuts[c]:cuts[c + 1]])
    assert_same_scores(acc.scores(), want)


def test_events_before_a_promised_time_are_refused_and_few_frames():
    frames, raw, _ = _synthetic(seed=1)
    acc = ConsistencyAccumulator(frames, ["raw"], 0.2, 0.2, 0.01)
    acc.add("raw", raw.slice_time(0, 20_000), 20_000)
    with pytest.raises(ValueError, match="raw"):
        acc.add("raw", raw.slice_time(19_000, 30_000), 30_000)
    one = Frames(frames.images[:1], frames.t_us[:1], frames.exposure_us[:1])
    acc = ConsistencyAccumulator(one, ["raw"], 0.2, 0.2, 0.01)
    acc.add("raw", raw)
    assert acc.scores() == {}
    # fewer than 3 active pixel-intervals: everything NaN, as compare_consistency
    still = Frames(np.full((3, 2, 2), 0.5, np.float32), [0, 100, 200], [0, 0, 0])
    two = Events.from_columns(np.array([0, 50, 150, 200]), np.array([0, 0, 1, 1]), np.array([0, 0, 1, 1]),
                              np.array([1, 1, 0, 0], np.uint8), 2, 2)     # the first before interval 0
    acc = ConsistencyAccumulator(still, ["raw"], 0.2, 0.2, 0.01)
    acc.add("raw", two, 300)
    want = compare_consistency(LogFrames.of(still, two, 0.01), {"raw": two}, 0.2, 0.2)
    assert_same_scores(acc.scores(), want)
    assert want["raw"]["active"] == 2 and math.isnan(want["raw"]["r2_fitted"])


def test_streamed_equals_whole_stream_davis346(davis346_path):
    """The committed DAVIS346 recording, raw vs BAF, 50 ms windows as rdnet restore cuts them."""
    from rdnet.events.io import load
    rec = load(davis346_path)
    raw, frames = rec.events, rec.frames
    baf = baf_filter(raw, 10_000)
    s = section({}, "sensor")
    want = compare_consistency(LogFrames.of(frames, raw, s.log_eps), {"raw": raw, "restored": baf},
                               s.threshold_on, s.threshold_off)
    acc = ConsistencyAccumulator(frames, ["raw", "restored"], s.threshold_on, s.threshold_off, s.log_eps)
    most = 0
    for t0, t1, ev in windows(iter([raw]), 50_000):
        acc.add("raw", ev, t1)
        acc.add("restored", baf.slice_time(t0, t1), t1)
        most = max(most, acc.open_intervals)
    assert_same_scores(acc.scores(), want)
    assert want["raw"]["active"] > 100_000 and most <= 3            # 40 ms frames, 50 ms windows
