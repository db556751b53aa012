import numpy as np
import pytest

from rdnet.eval.noref import (EsrAccumulator, activity_mask, esr_packet, esr_score, mask_fractions,
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


def test_esr_box_shortcut_equals_full_median():
    from scipy.ndimage import median_filter
    rng = np.random.default_rng(3)
    for _ in range(20):
        c = np.zeros((30, 40))
        h, w = rng.integers(1, 30), rng.integers(1, 40)
        y, x = rng.integers(0, 31 - h), rng.integers(0, 41 - w)
        c[y:y + h, x:x + w] = rng.integers(0, 4, (h, w)) * (rng.random((h, w)) < 0.5)
        N = int(c.sum()) + 2
        n = median_filter(c, size=3, mode="constant", cval=0)
        ref = 1000 * np.sqrt((n * n).sum() / N ** 2 * (c.size - np.power(0.5, n).sum()) / c.size)
        got = esr_packet(c, N)
        assert (c.sum() == 0 and np.isnan(got)) or got == pytest.approx(ref, rel=1e-12)
