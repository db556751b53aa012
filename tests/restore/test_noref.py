import numpy as np
import pytest

from rdnet.errors import ValidationError
from rdnet.eval.noref import (EsrAccumulator, _median3, activity_mask, esr_packet, esr_score, mask_fractions,
                              pixel_mask)
from rdnet.events import Events


def test_esr_packet_hand_computed():
    # 10 x 10 sensor, a 5 x 5 block with 2 events per pixel (N = 50). The 3 x 3 median
    # (zeros outside) keeps the block except its 4 corners: 21 pixels of 2.
    c = np.zeros((10, 10)); c[2:7, 2:7] = 2
    ntss = 21 * 4 / 50 ** 2
    cover = (100 - (79 + 21 * 0.25)) / 100
    assert esr_packet(c, 50) == pytest.approx(1000 * np.sqrt(ntss * cover))
    assert np.isnan(esr_packet(c, 1))


def _events(x, y, t, W, H):
    o = np.argsort(t, kind="stable")
    return Events.from_columns(np.asarray(t)[o], np.asarray(x)[o], np.asarray(y)[o],
                               np.ones(len(t), np.uint8), W, H)


def test_structure_scores_higher_than_uniform_noise():
    rng = np.random.default_rng(0)
    W, H, n = 64, 48, 3000
    t = np.sort(rng.integers(0, 99_000, n))
    noise = _events(rng.integers(0, W, n), rng.integers(0, H, n), t, W, H)
    # the same number of events on two moving edges (thick lines)
    col = (t // 3000) % W
    edge = _events(np.clip(col + rng.integers(0, 2, n), 0, W - 1), rng.integers(0, H, n), t, W, H)
    assert esr_score(edge) > 2 * esr_score(noise)
    # adding noise to the structure lowers its score
    both = _events(np.r_[edge.x, noise.x], np.r_[edge.y, noise.y], np.r_[edge.t, noise.t], W, H)
    assert esr_score(both) < esr_score(edge)


def test_accumulator_chunked_equals_whole():
    rng = np.random.default_rng(1)
    W, H, n = 30, 20, 2000
    ev = _events(rng.integers(0, W, n), rng.integers(0, H, n), rng.integers(0, 200_000, n), W, H)
    acc = EsrAccumulator(W, H, 33_000)
    for i in range(0, n, 171):
        acc.add(ev[i:i + 171])
    assert acc.score() == pytest.approx(esr_score(ev))
    assert len(acc.values) == 200_000 // 33_000       # closed packets; the last is still open


def test_mask_fractions_and_activity_mask():
    W, H = 20, 10
    raw = _events([1, 1, 5, 5, 5, 18], [1, 1, 5, 5, 5, 9], [0, 1, 2, 3, 4, 5], W, H)
    kept = raw.select(np.array([True, False, True, True, True, False]))
    hot = pixel_mask(W, H, [(18, 9)])
    m = np.zeros((H, W), bool); m[4:7, 4:7] = True
    f = mask_fractions(raw, kept, {"region": m, "outside": ~m, "hot": hot})
    assert f["region"] == {"raw": 3, "kept": 3, "fraction": 1.0}
    assert f["outside"]["fraction"] == pytest.approx(1 / 3) and f["hot"]["fraction"] == 0.0
    # activity: a dense blob is in the mask, a single busy pixel far away is not
    rng = np.random.default_rng(2)
    bx, by = rng.integers(30, 40, 4000), rng.integers(10, 20, 4000)
    ev = _events(np.r_[bx, np.full(300, 55)], np.r_[by, np.full(300, 40)], np.arange(4300), 64, 48)
    am = activity_mask(ev, sigma_px=3, rel_threshold=0.25)
    assert am[15, 35] and not am[40, 55]


def _median3_ref(img):
    """The reference: scipy's 3 x 3 median filter, zero outside."""
    from scipy.ndimage import median_filter
    return median_filter(img, size=3, mode="constant", cval=0)


def _esr_ref(c, N):
    """ESR from the module docstring's formula on the dense scipy median (float64)."""
    n = _median3_ref(np.asarray(c, np.float64))
    miss = float(np.power(0.5, n).sum())
    return 1000.0 * float(np.sqrt(float((n * n).sum()) / float(N) ** 2 * ((c.size - miss) / c.size)))


def _sparse_counts(rng, H, W, n_hits, border=False):
    """(H, W) int64 count image: ``n_hits`` events on random pixels (clustered in a random
    box, so medians are often nonzero), optionally also along the four image borders."""
    c = np.zeros((H, W), np.int64)
    h, w = rng.integers(1, H + 1), rng.integers(1, W + 1)
    y0, x0 = rng.integers(0, H - h + 1), rng.integers(0, W - w + 1)
    np.add.at(c, (rng.integers(y0, y0 + h, n_hits), rng.integers(x0, x0 + w, n_hits)), 1)
    if border:
        for sl in ((0, slice(None)), (-1, slice(None)), (slice(None), 0), (slice(None), -1)):
            c[sl] += rng.integers(0, 3, c[sl].shape)
    return c


@pytest.mark.parametrize("H, W", [(1, 1), (1, 7), (5, 1), (2, 3), (30, 40), (72, 128)])
def test_median3_and_esr_equal_scipy_reference(H, W):
    rng = np.random.default_rng(H * 1000 + W)
    for trial in range(12):
        c = _sparse_counts(rng, H, W, int(rng.integers(0, 3 * H * W + 2)), border=trial % 3 == 0)
        # both candidate paths of _median3_sparse: sparse (np.unique) and dense (dilation)
        assert np.array_equal(_median3(c), _median3_ref(c))
        assert np.array_equal(_median3(c.astype(np.float64)), _median3_ref(c.astype(np.float64)))
        N = int(c.sum()) + 2
        got = esr_packet(c, N)
        assert (c.sum() == 0 and np.isnan(got)) or got == _esr_ref(c, N)       # bit-identical


def test_esr_sparse_path_border_events_equal_reference():
    # few events (the np.unique candidate path) on the corners and edges of a larger image
    rng = np.random.default_rng(7)
    H, W = 48, 64
    for _ in range(20):
        c = np.zeros((H, W), np.int64)
        ys = rng.choice([0, 1, H - 2, H - 1], 30)
        xs = rng.integers(0, W, 30)
        np.add.at(c, (np.r_[ys, rng.integers(0, H, 10)], np.r_[xs, rng.choice([0, W - 1], 10)]), rng.integers(1, 5))
        assert 9 * np.count_nonzero(c) < (H + 2) * (W + 2) // 8            # the sparse path
        assert np.array_equal(_median3(c), _median3_ref(c))
        assert esr_packet(c, int(c.sum())) == _esr_ref(c, int(c.sum()))


def test_accumulator_equals_dense_reference_per_packet():
    # the accumulator (chunks split inside packets) gives the reference ESR of every packet
    rng = np.random.default_rng(4)
    W, H, n = 50, 40, 6000
    x = np.r_[rng.integers(0, W, n // 2), np.clip(rng.normal(25, 3, n // 2), 0, W - 1).astype(int)]
    y = np.r_[rng.integers(0, H, n // 2), np.clip(rng.normal(0, 4, n // 2), 0, H - 1).astype(int)]
    ev = _events(x, y, rng.integers(0, 330_000, n), W, H)
    acc = EsrAccumulator(W, H, 33_000)
    for i in range(0, n, 777):
        acc.add(ev[i:i + 777])
    acc.add(ev[:0])
    k = ev.t // 33_000
    ref = []
    for p in np.unique(k):
        sel = k == p
        c = np.zeros((H, W), np.int64)
        np.add.at(c, (ev.y[sel], ev.x[sel]), 1)
        ref.append(_esr_ref(c, int(sel.sum())))
    assert acc.values == ref[:-1]                     # closed packets, bit-identical
    assert acc.score() == float(np.mean(ref))


def test_esr_packet_rejects_fractional_counts():
    c = np.zeros((4, 4)); c[1, 1] = 0.5
    with pytest.raises(ValidationError):
        esr_packet(c, 3)


def test_each_once_gives_the_distinct_indices():
    from rdnet.eval.noref import _each_once
    rng = np.random.default_rng(5)
    idx = rng.integers(0, 50, 300)
    scratch = np.full(50, -7, np.int64)
    got = _each_once(idx, scratch)
    assert sorted(got.tolist()) == np.unique(idx).tolist() and len(got) == len(np.unique(idx))
    assert idx.shape == (300,) and _each_once(idx[:0], scratch).size == 0
