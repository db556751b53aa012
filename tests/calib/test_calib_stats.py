"""Statistics, discrepancy and event-frame consistency on known synthetic inputs."""
import numpy as np
import pytest

from rdnet.calib import stats as st
from rdnet.calib.consistency import consistency
from rdnet.calib.context import build_context, subsample_events
from rdnet.calib.settings import CalibrateConfig
from rdnet.errors import ConfigError, FormatError
from rdnet.events.core import Events
from rdnet.events.recording import Frames, Recording
from rdnet.sim.interpolate import InterpolateConfig

NONE = InterpolateConfig(method="none")
H = W = 16
STEP = 10_000            # frame period, us
N_FR = 11                # frames at 0 .. 100 ms


def _frames():
    k = np.arange(N_FR, dtype=np.float32)[:, None, None]
    img = np.full((N_FR, H, W), 0.5, np.float32)
    # right half: log intensity (eps = 0.01) rises by 0.4 per frame
    img[:, :, W // 2:] = (0.02 * np.exp(0.4 * k) - 0.01) * np.ones((1, H, W // 2), np.float32)
    return Frames(img, np.arange(N_FR, dtype=np.int64) * STEP, np.zeros(N_FR, np.int64))


def _events():
    t1 = np.arange(0, 100_000, 1000)                 # static pixel (0, 0): ON every 1 ms
    t2 = np.arange(5000, 100_000, 10_000)            # moving pixel (12, 3): OFF every 10 ms
    t = np.concatenate([t1, t2])
    x = np.concatenate([np.zeros_like(t1), np.full_like(t2, 12)])
    y = np.concatenate([np.zeros_like(t1), np.full_like(t2, 3)])
    p = np.concatenate([np.ones_like(t1), np.zeros_like(t2)])
    return Events.from_columns(t, x, y, p, W, H, sort=True)


@pytest.fixture(scope="module")
def ctx():
    rec = Recording(W, H, events=_events(), frames=_frames())
    return build_context(rec, CalibrateConfig(segments=2, time_bin_us=1000, grid_px=8, intensity_bins=4),
                         0.01, interpolate=NONE)


def test_context_window_segments_static(ctx):
    assert (ctx.t0, ctx.t1) == (0, 99_001)
    assert ctx.segments.tolist() == [[0, 49_500], [49_500, 99_001]] or ctx.segments[0, 0] == 0
    assert ctx.fit == (0,) and ctx.held == (1,)
    assert ctx.static[:, : W // 2].all() and not ctx.static[:, W // 2:].any()
    # occupancy: every pixel-second of the window is in some intensity bin
    assert ctx.occupancy.sum() == pytest.approx(H * W * (ctx.t1 - ctx.t0) * 1e-6, rel=1e-9)
    assert ctx.sim_images.shape == (N_FR, H, W)


def test_summary_and_aggregate_known_values(ctx, monkeypatch):
    s = st.summarize(ctx.real, ctx)
    # the only active static pixel is the busiest: trimmed from the noise-floor statistics
    a = st.aggregate(s, ctx, [0, 1])
    assert a["static_rate"] == 0.0 and a["static_on_fraction"] == 0.5
    monkeypatch.setattr(st, "STATIC_TRIM", 0.0)
    assert s.pix.sum() == 110
    a = st.aggregate(s, ctx, [0, 1])
    T = (ctx.t1 - ctx.t0) * 1e-6
    assert a["pixel_rate"][0, 0] == pytest.approx(100 / T)
    assert a["pixel_rate"][3, 12] == pytest.approx(10 / T)
    assert a["static_rate"] == pytest.approx(100 / T / (H * W // 2))
    assert a["static_on_fraction"] == pytest.approx(101 / 102)
    assert a["on_fraction"] == pytest.approx(1 / 12)
    # intervals: 99 of 1 ms (log10 = 3.0) and 9 of 10 ms (log10 = 4.0)
    b3 = np.searchsorted(st.IEI_EDGES, 3.0, side="right")
    b4 = np.searchsorted(st.IEI_EDGES, 4.0, side="right")
    assert a["iei_count"][b3] == 99 and a["iei_count"][b4] == 9 and a["iei_count"].sum() == 108
    # rate over time (1 ms bins, the last one 1001 us): rate x width gives every event back
    assert (a["rate_time"] * np.diff(ctx.time_edges) * 1e-6).sum() == pytest.approx(110)
    # coarse 8x8 map: the top-left cell holds pixel (0, 0)
    # coarse 8x8 map without each cell's busiest pixel: every cell here has at most one
    assert not a["rate_map"].any()
    extra = Events.from_columns(np.array([10, 20, 30]), np.array([1, 1, 1]), np.zeros(3), np.ones(3), W, H)
    both = Events.from_columns(*(np.concatenate([ctx.real.array[k], extra.array[k]]) for k in "txyp"),
                               W, H, sort=True)
    b = st.aggregate(st.summarize(both, ctx), ctx, [0, 1])
    assert b["rate_map"][0, 0] == pytest.approx(3 / T / 63)
    # one segment only: about half the events
    f = st.aggregate(s, ctx, ctx.fit)
    assert f["count"] + st.aggregate(s, ctx, ctx.held)["count"] == 110


def test_band_means():
    assert st.band_means(np.arange(10.0), (0.0, 0.5, 1.0)).tolist() == [2.0, 7.0]
    assert st.band_means(np.arange(1000.0), (0.99, 1.0)).tolist() == [994.5]
    assert st.band_means(np.array([]), (0.0, 1.0)).tolist() == [0.0]


def test_isolated_counts_keep_lone_pixels_of_either_polarity_and_drop_structures():
    n = np.zeros((6, 8), np.int64)
    n[:, 2] = 40                      # an edge: a column of busy pixels, each has a busy neighbour
    n[4, 6] = 50                      # a lone busy pixel (a hot pixel)
    n[4, 5] = 3                       # ... next to a quiet one
    n[0, 7] = 9                       # a lone pixel at the corner (the border has no neighbours)
    iso = st.isolated_counts(n)
    assert iso[4, 6] == 47 and iso[0, 7] == 9
    assert iso[:, 2].max() == 0       # the edge fires in neighbouring pixels: not isolated
    assert (iso >= 0).all() and iso.sum() == 47 + 9
    assert st.isolated_counts(np.full((3, 3), 5)).max() == 0
    assert n[4, 6] == 50              # the input is not changed


def test_isolated_tail_counts_hot_pixels_whatever_their_polarity(ctx):
    """The same hot pixels firing balanced ON / OFF leave the net-rate tail at the scene's
    level but raise the isolated-rate tail as much as one-polarity ones do."""
    s = st.summarize(ctx.real, ctx)
    segs = range(len(ctx.segments))
    base = st.aggregate(s, ctx, segs)
    T, P = float(base["seconds"]), ctx.n_pixels
    # 8 pixels, none next to another or to the two busy pixels of the fixture
    xy = np.array([(5, 5), (9, 9), (2, 12), (13, 13), (6, 1), (14, 8), (3, 8), (10, 14)])
    assert ctx.stride == 1 and P == 256
    hot = xy[:, 1] * ctx.width + xy[:, 0]
    t0 = int(ctx.segments[0, 0])
    out = {}
    for name, pol in (("one", lambda k: np.ones(k, np.int8)), ("mixed", lambda k: np.arange(k) % 2)):
        extra = np.zeros(len(hot) * 200, ctx.real.array.dtype)
        extra["x"] = np.repeat(hot % ctx.width, 200) * ctx.stride
        extra["y"] = np.repeat(hot // ctx.width, 200) * ctx.stride
        extra["t"] = t0 + np.tile(np.linspace(0, T * 1e6 - 1, 200).astype(np.int64), len(hot))
        extra["p"] = np.concatenate([pol(200)] * len(hot))
        arr = np.sort(np.concatenate([ctx.real.array, extra]), order="t")
        out[name] = st.aggregate(st.summarize(Events(arr, ctx.real.width, ctx.real.height), ctx), ctx, segs)
    # band 2 ([0.98, 0.99)) and above hold only hot pixels (8 of 256 pixels, 200 events each)
    rate = 200 / T
    assert out["one"]["pixel_tail"][2:] == pytest.approx(rate)
    assert out["mixed"]["pixel_tail"][2] == pytest.approx(0.0)       # as many ON as OFF: no net rate
    for name in ("one", "mixed"):
        assert out[name]["pixel_isolated"][2:] == pytest.approx(rate)
    assert base["pixel_isolated"][2] < 0.1 * rate
    assert st.distances(out["mixed"], base, ctx)["pixel_isolated"] > 1.0


def test_xcorr_lag_recovers_shift():
    rng = np.random.default_rng(0)
    a = np.convolve(rng.random(400), np.ones(5) / 5, "same")
    b = np.roll(a, 7)
    mask = np.ones(400, bool)
    assert st.xcorr_lag_us(a, b, mask, 1000.0, 20000.0) == pytest.approx(7000.0, abs=200)
    assert st.xcorr_lag_us(b, a, mask, 1000.0, 20000.0) == pytest.approx(-7000.0, abs=200)
    assert st.xcorr_lag_us(a, a, mask, 1000.0, 20000.0) == pytest.approx(0.0, abs=1e-6)


def test_distances_zero_for_identical_and_grow_with_mismatch(ctx, monkeypatch):
    monkeypatch.setattr(st, "STATIC_TRIM", 0.0)
    s = st.summarize(ctx.real, ctx)
    a = st.aggregate(s, ctx, [0, 1])
    d = st.distances(a, a, ctx)
    assert set(d) == set(st.STATISTICS)
    assert all(v == pytest.approx(0.0, abs=1e-12) for v in d.values())
    # flip every polarity: the polarity statistics move, the rate map does not
    arr = ctx.real.array.copy()
    arr["p"] = 1 - arr["p"]
    b = st.aggregate(st.summarize(Events(arr, W, H), ctx), ctx, [0, 1])
    d2 = st.distances(b, a, ctx)
    assert d2["static_on_fraction"] > 1.0 and d2["on_fraction"] > 0.5
    assert d2["rate_map"] == pytest.approx(0.0) and d2["iei"] == pytest.approx(0.0)
    total, terms = st.discrepancy(b, a, ctx)
    assert total == pytest.approx(sum(st.STATISTICS[k] * v for k, v in terms.items()))
    assert st.STATISTICS["lag_smoothed"] == 0.0         # latency's own statistic only: moves no fit
    # a 3 ms delay shows as a lag
    arr = ctx.real.array.copy()
    arr["t"] += 3000
    c = st.aggregate(st.summarize(Events(arr, W, H), ctx), ctx, [0, 1])
    assert st.distances(a, c, ctx)["lag"] > 0.0
    assert st.distances(a, c, ctx)["lag_smoothed"] > 0.0


def test_fraction_gap_counts_only_what_sampling_does_not_explain():
    # p = 0.5 from 98 + 98 events: standard error sqrt(0.25 * (1/100 + 1/100)) = 0.0707
    assert st.fraction_gap(0.55, 0.45, 98, 98) == pytest.approx(0.1 - np.sqrt(0.005))
    assert st.fraction_gap(0.52, 0.48, 98, 98) == 0.0            # inside the error: no evidence
    assert st.fraction_gap(0.48, 0.52, 98, 98) == 0.0            # symmetric
    # many events: the plain difference
    assert st.fraction_gap(0.55, 0.45, 1e9, 1e9) == pytest.approx(0.1, abs=1e-4)
    # element-wise on arrays; a fraction measured on no events counts nothing
    g = st.fraction_gap(np.array([0.9, 0.5]), np.array([0.1, 0.5]), np.array([1e9, 0.0]), np.array([1e9, 0.0]))
    assert g == pytest.approx([0.8, 0.0], abs=1e-4)
    # a smaller sample needs a larger difference to count the same
    assert st.fraction_gap(0.6, 0.5, 200, 200) < st.fraction_gap(0.6, 0.5, 2000, 2000)


def _pearson_lag_reference(sim, real, mask, L):
    """Straightforward loop: per lag k, the Pearson coefficient over the pairs (i, i + k)
    both inside ``mask`` of the rates centred on their masked means (no smoothing)."""
    m = np.asarray(mask, bool)
    a = np.where(m, sim - sim[m].mean(), 0.0)
    b = np.where(m, real - real[m].mean(), 0.0)
    out = []
    for k in range(-L, L + 1):
        num = sa = sb = 0.0
        for i in range(len(a)):
            j = i + k
            if 0 <= j < len(a) and m[i] and m[j]:
                num += a[i] * b[j]
                sa += a[i] ** 2
                sb += b[j] ** 2
        out.append(num / np.sqrt(sa * sb) if sa * sb > 0 else -np.inf)
    return np.array(out)


def test_pearson_lag_curve_matches_a_plain_loop():
    rng = np.random.default_rng(3)
    sim, real = rng.random(40), rng.random(40)
    mask = (np.arange(40) // 7) % 2 == 0
    lags, c = st.pearson_lag_curve(sim, real, mask, 1000.0, 6000.0, smooth_bins=1)
    np.testing.assert_array_equal(lags, np.arange(-6, 7))
    np.testing.assert_allclose(c, _pearson_lag_reference(sim, real, mask, 6), rtol=1e-10)


def test_pearson_lag_is_not_pulled_to_zero_by_interleaved_runs():
    """A slow rate shifted by 2 and -3 bins, seen through 3 runs of 83 bins (as a held-out
    mask): the plain masked sum loses pairs at every run end as the lag grows and reads
    nearly 0; the Pearson lag reads the shift (benchmarks/calib_lag_segments.md)."""
    t = np.arange(500)
    rate = 1.0 + np.sin(2 * np.pi * t / 200.0) ** 2
    mask = (t // 83) % 2 == 1
    for shift in (2, -3):
        real = np.interp(t - shift, t, rate)
        assert st.pearson_lag_us(rate, real, mask, 2000.0, 20000.0) == pytest.approx(shift * 2000.0, abs=150.0)
        assert abs(st.xcorr_lag_us(rate, real, mask, 2000.0, 20000.0)) < abs(shift) * 2000.0 * 0.5


def test_pearson_lag_degenerate_inputs():
    flat, ramp = np.ones(30), np.arange(30.0)
    on = np.ones(30, bool)
    assert st.pearson_lag_us(ramp, ramp, np.zeros(30, bool), 1000.0, 5000.0) == 0.0   # empty mask
    assert st.pearson_lag_us(flat, ramp, on, 1000.0, 5000.0) == 0.0                    # no variance
    lags, c = st.pearson_lag_curve(flat, ramp, on, 1000.0, 5000.0)
    assert lags.size == 0 and c.size == 0
    # a series shorter than the smoothing window still gives a lag, not an error
    assert np.isfinite(st.pearson_lag_us(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), np.ones(3, bool),
                                         1000.0, 5000.0))


def test_subsample_events():
    ev = _events()
    sub = subsample_events(ev, 4)
    assert (sub.width, sub.height) == (4, 4)
    assert len(sub) == 100 and (sub.x == 0).all()      # (12, 3): y=3 is not sampled


def test_consistency_exact_events_give_r2_one():
    # column x of the right half rises by m = 1 + x % 3 thresholds (0.2) per frame and
    # gets m ON events per frame interval
    k = np.arange(N_FR, dtype=np.float64)[:, None, None]
    m = np.zeros((1, H, W))
    m[..., W // 2:] = 1 + np.arange(W // 2, W) % 3
    img = (0.02 * np.exp(0.2 * m * k) - 0.01 * (m > 0) + 0.5 * (m == 0)).astype(np.float32)
    fr = Frames(img, np.arange(N_FR, dtype=np.int64) * STEP, np.zeros(N_FR, np.int64))
    ts, xs, ys = [], [], []
    for i in range(N_FR - 1):
        for x in range(W // 2, W):
            n = 1 + x % 3
            for y in range(H):
                ts += [i * STEP + 1000 * (j + 1) for j in range(n)]; xs += [x] * n; ys += [y] * n
    ts.append(N_FR * STEP); xs.append(0); ys.append(0)       # so the window covers the last frame
    ev = Events.from_columns(np.array(ts), np.array(xs), np.array(ys), np.ones(len(ts), np.uint8), W, H, sort=True)
    c = build_context(Recording(W, H, events=ev, frames=fr), CalibrateConfig(segments=2), 0.01, interpolate=NONE)
    out = consistency(c.real, c, 0.2, 0.2)
    assert out["active"] == (N_FR - 2) * H * W // 2      # the first interval starts before the events
    assert out["r2"] == pytest.approx(1.0, abs=1e-4)
    assert out["correlation"] == pytest.approx(1.0, abs=1e-6)
    assert out["slope"] == pytest.approx(1.0, abs=1e-4)
    # thresholds twice too large: slope 1/2, R^2 drops, correlation does not
    bad = consistency(c.real, c, 0.4, 0.4)
    assert bad["slope"] == pytest.approx(0.5, abs=1e-4) and bad["r2"] < 0.5
    assert bad["correlation"] == pytest.approx(1.0, abs=1e-6)


def test_bad_recordings_raise_clear_errors():
    fr, ev = _frames(), _events()
    cfg = CalibrateConfig(segments=2)
    with pytest.raises(FormatError, match="no frames"):
        build_context(Recording(W, H, events=ev), cfg, 0.01, interpolate=NONE)
    with pytest.raises(FormatError, match="no events"):
        build_context(Recording(W, H, frames=fr), cfg, 0.01, interpolate=NONE)
    late = ev.array.copy()
    late["t"] += 10_000_000
    with pytest.raises(FormatError, match="overlap"):
        build_context(Recording(W, H, events=Events(late, W, H), frames=fr), cfg, 0.01, interpolate=NONE)


def test_config_checks():
    with pytest.raises(ConfigError, match="calibrate.segments"):
        CalibrateConfig(segments=1)
    with pytest.raises(ConfigError, match="calibrate.seeds"):
        CalibrateConfig(seeds=1)
    with pytest.raises(ConfigError, match="calibrate.candidates"):
        CalibrateConfig(candidates=("gremlins",))
    with pytest.raises(ConfigError, match="calibrate.search_seeds"):
        CalibrateConfig(seeds=3, search_seeds=4)
    with pytest.raises(ConfigError, match="calibrate.max_fitted"):
        CalibrateConfig(max_fitted=0)


def test_iei_thresholds_equal_the_log10_bins():
    """The interval histogram bins a summary takes from integer thresholds are the bins of
    the definition (searchsorted of log10(dt) in IEI_EDGES, the kernel's own log10) for
    every interval up to a quarter decade beyond the last edge."""
    from numba import njit

    @njit
    def bins_by_log(d):
        out = np.empty(d.shape[0], np.int64)
        for i in range(d.shape[0]):
            out[i] = st._iei_bin(d[i])
        return out

    thr = st.iei_thresholds()
    assert thr[:9].tolist() == [1, 2, 4, 6, 10, 18, 32, 57, 100]
    assert thr[-1] == 3162278 and len(thr) == len(st.IEI_EDGES)
    d = np.arange(1, int(10 ** (st.IEI_EDGES[-1] + 0.25)), dtype=np.int64)
    assert np.array_equal(np.searchsorted(thr, d, side="right"), bins_by_log(d))


def test_aggregate_layout_is_computed_once_and_changes_nothing(ctx):
    """aggregate keeps per-context constants (cells, static pixels, time-bin masks) in the
    context's cache: the statistics are bit-identical with a cold and a warm cache, and the
    cached time-bin mask cannot be written through a result."""
    s = st.summarize(ctx.real, ctx)
    ctx._cache.pop("stats_layout", None)
    cold = [st.aggregate(s, ctx, segs) for segs in (ctx.fit, ctx.held, [0, 1])]
    lay = ctx._cache["stats_layout"]
    warm = [st.aggregate(s, ctx, segs) for segs in (ctx.fit, ctx.held, [0, 1])]
    assert ctx._cache["stats_layout"] is lay and len(lay.masks) == 3
    for a, b in zip(cold, warm):
        assert a.keys() == b.keys()
        assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)
    with pytest.raises(ValueError):
        warm[0]["time_mask"][0] = True


def test_peak_lag_refines_by_a_parabola_and_skips_missing_neighbours():
    lags = np.arange(-2, 3)
    # a parabola with its vertex at +0.25 bins
    c = -(lags - 0.25) ** 2
    assert st.peak_lag_us(c, lags, 1000.0) == pytest.approx(250.0)
    c2 = np.array([-np.inf, 0.0, 1.0, 0.5, 0.0])          # no parabola without both neighbours finite
    c2[1] = -np.inf
    assert st.peak_lag_us(c2, lags, 1000.0) == 0.0
