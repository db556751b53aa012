"""The simulator-free latency scan (rdnet.calib.consistency.latency_scan) on streams whose
events are placed by hand: the right net count in every pixel-interval, at uniform random
times inside it, then all delayed by a known latency."""
from types import SimpleNamespace

import numpy as np
import pytest

from rdnet.calib.consistency import latency_scan
from rdnet.events.core import EVENT_DTYPE, Events

H, W, K, DT = 12, 16, 40, 10_000      # pixels, frame intervals, interval (us)


def _recording(latency_us: float, seed: int = 0):
    """Frames with a random log change per pixel and interval and the events an ideal
    sensor (threshold 0.2) would give for it, uniform in time inside the interval, shifted
    by ``latency_us``."""
    rng = np.random.default_rng(seed)
    steps = rng.integers(-3, 4, size=(K, H * W))                 # net events per pixel-interval
    logs = np.concatenate([np.zeros((1, H * W)), np.cumsum(0.2 * steps, axis=0)]).reshape(K + 1, H, W)
    ft = np.arange(K + 1, dtype=np.int64) * DT
    k, pix = np.nonzero(steps)
    n = np.abs(steps[k, pix])
    k, pix, sign = np.repeat(k, n), np.repeat(pix, n), np.repeat(np.sign(steps[k, pix]), n)
    t = ft[k] + 1 + rng.integers(0, DT - 1, size=k.size) + int(latency_us)
    order = np.argsort(t, kind="stable")
    a = np.zeros(k.size, EVENT_DTYPE)
    a["t"], a["x"], a["y"], a["p"] = t[order], pix[order] % W, pix[order] // W, sign[order] > 0
    ctx = SimpleNamespace(frame_t=ft, log_frames=logs.astype(np.float32), width=W, n_pixels=H * W,
                          t0=0, t1=int(ft[-1]) + 1)
    return Events(a, W, H), ctx


@pytest.mark.parametrize("latency_us", [0.0, 3000.0])
def test_scan_recovers_a_known_latency_with_an_interval_around_it(latency_us):
    ev, ctx = _recording(latency_us)
    r = latency_scan(ev, ctx, max_shift_us=6000.0, step_us=500.0, min_change=0.1,
                     rng=np.random.default_rng(1), resamples=100)
    assert r["latency_us"] == pytest.approx(latency_us, abs=300.0)
    assert r["ci95_us"][0] <= latency_us <= r["ci95_us"][1]
    assert r["ci95_us"][1] - r["ci95_us"][0] < 1500.0
    assert not r["at_edge"]
    assert len(r["shifts_us"]) == len(r["correlation"]) == 25
    # the score falls away from the latency on both sides
    c = np.asarray(r["correlation"])
    best = int(np.argmax(c))
    assert c[0] < c[best] and c[-1] < c[best]


def test_scan_is_deterministic_and_does_not_change_the_events():
    ev, ctx = _recording(1000.0)
    before = ev.array.copy()
    a = latency_scan(ev, ctx, max_shift_us=3000.0, step_us=500.0, min_change=0.1, rng=np.random.default_rng(5))
    b = latency_scan(ev, ctx, max_shift_us=3000.0, step_us=500.0, min_change=0.1, rng=np.random.default_rng(5))
    assert a == b
    assert np.array_equal(ev.array, before)


def test_latency_beyond_the_grid_is_flagged():
    ev, ctx = _recording(4000.0)
    r = latency_scan(ev, ctx, max_shift_us=2000.0, step_us=500.0, min_change=0.1, rng=np.random.default_rng(0))
    assert r["at_edge"] and r["latency_us"] == pytest.approx(2000.0)


def test_a_bad_grid_is_refused():
    ev, ctx = _recording(0.0)
    with pytest.raises(ValueError, match="step_us"):
        latency_scan(ev, ctx, max_shift_us=100.0, step_us=500.0, min_change=0.1, rng=np.random.default_rng(0))


def test_frames_that_never_change_give_no_estimate_and_no_error():
    ev, ctx = _recording(0.0)
    still = SimpleNamespace(**{**vars(ctx), "log_frames": np.zeros_like(ctx.log_frames)})
    r = latency_scan(ev, still, max_shift_us=2000.0, step_us=500.0, min_change=0.1, rng=np.random.default_rng(0))
    assert np.isnan(r["latency_us"]) and r["pixel_intervals"] == 0 and r["intervals"] == 0
    assert all(np.isnan(v) for v in r["ci95_us"]) and not r["at_edge"]


@pytest.mark.parametrize("step_us, max_shift_us", [(500.0, 6000.0), (333.3, 25_000.0), (DT / 7, 3 * DT)])
def test_the_sweep_equals_counting_every_shift_anew(step_us, max_shift_us):
    """_shift_sums counts the first shift and then moves only the events that cross a frame
    boundary; for every shift its sums equal a fresh count of the shifted events (grids
    finer and coarser than the frames, up to three intervals wide, events on boundaries)."""
    from rdnet.calib.consistency import _shift_sums, inside_window, log_changes
    ev, ctx = _recording(2000.0, seed=3)
    a = ev.array.copy()
    a["t"][::5] = ctx.frame_t[(np.arange(a.size)[::5] % K) + 1]     # every 5th event on a frame time
    ev = Events(np.sort(a, order="t"), W, H)
    dL = log_changes(ctx)
    mask = (np.abs(dL) >= 0.1) & inside_window(ctx.frame_t, ctx.t0, ctx.t1)[:, None]
    flat = np.flatnonzero(mask)
    kid, y = flat // ctx.n_pixels, dL.ravel()[flat]
    n = int(max_shift_us // step_us)
    shifts = step_us * np.arange(-n, n + 1, dtype=np.float64)
    got = _shift_sums(ev, ctx, shifts, flat, kid, y, K)
    t = ev.array["t"].astype(np.float64)
    pix = ev.array["y"].astype(np.int64) * W + ev.array["x"]
    sign = np.where(ev.array["p"], 1.0, -1.0)
    for i, s in enumerate(shifts):
        k = np.searchsorted(ctx.frame_t, t - s, side="left") - 1
        ok = (k >= 0) & (k < K)
        x = np.zeros((K, ctx.n_pixels))
        np.add.at(x, (k[ok], pix[ok]), sign[ok])
        x = x.ravel()[flat]
        want = [np.bincount(kid, weights=w, minlength=K) for w in (x, x * x, x * y, y, y * y)]
        for j in range(5):                              # bit for bit
            assert np.array_equal(got[i, :, j], want[j]), (i, j)
