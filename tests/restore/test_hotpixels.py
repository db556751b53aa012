"""The hot-pixel pass (rdnet.restore.hotpixels): known counts, a sweeping edge, a hot pixel."""
import numpy as np
import pytest

from rdnet.errors import ValidationError
from rdnet.events import Events
from rdnet.restore.hotpixels import drop_pixels, hot_pixels, neighbour_median, pixel_counts

from _streams import edge_noise_hot


def test_neighbour_median_known_values():
    c = np.arange(12).reshape(3, 4)
    med = neighbour_median(c)
    assert med[1, 1] == np.median([0, 1, 2, 4, 6, 8, 9, 10])        # the 8 neighbours, not itself
    assert med[0, 0] == np.median([0, 0, 0, 0, 0, 1, 4, 5])         # outside the sensor counts as 0
    assert c[1, 1] == 5                                               # input untouched


def test_edge_kept_hot_pixel_flagged_and_dropped():
    ev, lab = edge_noise_hot(seed=3, n_noise=200)          # hot pixel (7, 33) every 0.7 ms
    counts, dur = pixel_counts((ev[i:i + 500] for i in range(0, len(ev), 500)), ev.width, ev.height)
    assert counts.sum() == len(ev) and counts[33, 7] == ((ev.x == 7) & (ev.y == 33)).sum() > (lab == 2).sum() and dur == ev.t[-1] - ev.t[0]
    mask = hot_pixels(counts, dur, factor=20, min_rate_hz=100)
    assert np.argwhere(mask).tolist() == [[33, 7]]
    out = drop_pixels(ev, mask)
    assert len(out) == len(ev) - counts[33, 7] and not ((out.x == 7) & (out.y == 33)).any()
    # a pixel of the same count whose neighbours fire as often (structure) is not hot
    dense = counts.copy()
    dense[10:13, 20:23] = counts[33, 7]
    assert not hot_pixels(dense, dur, 20, 100)[11, 21]
    # too slow on average, or the pass off: nothing flagged
    assert not hot_pixels(counts, dur, 20, min_rate_hz=2000).any()
    assert not hot_pixels(counts, dur, 0, 100).any()
    assert not hot_pixels(counts, 0, 20, 100).any()
    with pytest.raises(ValidationError):
        hot_pixels(counts, dur, -1, 100)


def test_noise_free_edge_passes_unchanged():
    ev, lab = edge_noise_hot(seed=1, n_noise=0)
    ev = Events(ev.array[lab == 0], ev.width, ev.height)
    counts, dur = pixel_counts([ev], ev.width, ev.height)
    mask = hot_pixels(counts, dur, 20, 100)
    assert not mask.any()
    assert drop_pixels(ev, mask) is ev
