import numpy as np
import pytest

from rdnet.baselines import StcfState, baf_filter, baf_mask, baf_state, stcf_mask
from rdnet.errors import ValidationError
from rdnet.events import Events, concatenate

from test_baseline_stcf import edge_plus_noise


def _ev(t, x, y, p=None, W=30, H=20):
    p = np.ones(len(t), np.uint8) if p is None else np.array(p)
    return Events.from_columns(np.array(t), np.array(x), np.array(y), p, W, H)


def test_known_small_case():
    # (5,5) alone -> removed; (6,5) 100 us later -> neighbour fired -> kept;
    # (20,10) isolated -> removed; (6,6) 20 ms after (6,5) -> too late for dt 10 ms -> removed
    ev = _ev([0, 100, 200, 20_300], [5, 6, 20, 6], [5, 5, 10, 6])
    np.testing.assert_array_equal(baf_mask(ev, 10_000), [False, True, False, False])
    np.testing.assert_array_equal(baf_mask(ev, 30_000), [False, True, False, True])


def test_hot_pixel_removed_edge_kept():
    ev, sig = edge_plus_noise(n_noise=0)
    hot = _ev(np.arange(0, 60_000, 500), np.full(120, 30), np.full(120, 3), W=60, H=40)
    # the hot pixel fires every 0.5 ms; its neighbour columns x = 29, 31 fire at about
    # 29 and 31 ms (1 ms per column), which supports it until about 31 + 5 ms
    allev = concatenate([ev, hot], sort=True)
    keep = baf_mask(allev, 5000)
    is_hot = (allev.x == 30) & (allev.y == 3) & ((allev.t < 29_000) | (allev.t > 36_300))
    assert is_hot.sum() > 100 and not keep[is_hot].any()   # a pixel firing on its own is removed
    # the edge: every pixel except the first column (nothing before it) is kept
    edge = ~((allev.x == 30) & (allev.y == 3)) & (allev.x > 0)
    assert keep[edge].all()
    # include_self=True would keep the hot pixel (its own past supports it)
    assert baf_mask(allev, 5000, include_self=True)[is_hot].mean() > 0.9


def test_equals_stcf_k1_and_removes_isolated_noise():
    ev, sig = edge_plus_noise(seed=3)
    keep = baf_mask(ev, 5000)
    np.testing.assert_array_equal(keep, stcf_mask(ev, 5000, k=1, radius=1))
    assert keep[sig].mean() > 0.95 and keep[~sig].mean() < 0.25


@pytest.mark.parametrize("fn", ["baf", "stcf"])
def test_chunked_equals_whole(fn):
    ev, _ = edge_plus_noise(seed=1)
    call = ((lambda e, s: baf_mask(e, 3000, state=s)) if fn == "baf"
            else (lambda e, s: stcf_mask(e, 3000, k=2, radius=1, same_polarity=True, state=s)))
    whole = call(ev, None)
    state = baf_state(ev.width, ev.height) if fn == "baf" else StcfState(ev.width, ev.height, True)
    cuts = [0, 1, 700, 701, 1500, len(ev)]
    parts = [call(ev[a:b], state) for a, b in zip(cuts[:-1], cuts[1:])]
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    # without carried state the chunk borders lose support
    fresh = np.concatenate([call(ev[a:b], None) for a, b in zip(cuts[:-1], cuts[1:])])
    assert fresh.sum() < whole.sum()


def test_state_checks_and_input_unchanged():
    ev, _ = edge_plus_noise()
    before = ev.array.copy()
    out = baf_filter(ev, 5000)
    np.testing.assert_array_equal(ev.array, before)
    assert len(out) < len(ev)
    with pytest.raises(ValidationError):
        baf_mask(ev, 5000, state=baf_state(10, 10))
    with pytest.raises(ValidationError):
        baf_mask(ev, 0)
