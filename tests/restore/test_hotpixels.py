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
    assert med[0, 0] == np.median([1, 4, 5])                          # a corner has 3 neighbours
    assert med[0, 2] == np.median([1, 3, 5, 6, 7])                    # an edge pixel 5
    assert c[1, 1] == 5                                               # input untouched
    assert np.isnan(neighbour_median(np.array([[7]]))[0, 0])         # no neighbour at all


def test_a_uniformly_busy_sensor_has_no_hot_pixel_not_even_in_its_corners():
    assert not hot_pixels(np.full((10, 12), 500), 1_000_000, 20, 100).any()
    assert not hot_pixels(np.array([[900]]), 1_000_000, 20, 100).any()
    one = np.full((10, 12), 25)
    one[0, 0] = 900                                                   # a hot corner is still found
    assert np.argwhere(hot_pixels(one, 1_000_000, 20, 100)).tolist() == [[0, 0]]


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
    from rdnet.errors import ConfigError
    from rdnet.restore.settings import RestoreConfig
    with pytest.raises(ConfigError, match="hot_pixel_factor"):
        RestoreConfig(hot_pixel_factor=0.5)


def test_noise_free_edge_passes_unchanged():
    ev, lab = edge_noise_hot(seed=1, n_noise=0)
    ev = Events(ev.array[lab == 0], ev.width, ev.height)
    counts, dur = pixel_counts([ev], ev.width, ev.height)
    mask = hot_pixels(counts, dur, 20, 100)
    assert not mask.any()
    assert drop_pixels(ev, mask) is ev


def test_polarity_counts_and_model_known_values():
    from rdnet.restore.hotpixels import polarity_counts, polarity_model
    ev, _ = edge_noise_hot(seed=3, n_noise=200)
    counts, on, dur = polarity_counts((ev[i:i + 500] for i in range(0, len(ev), 500)), ev.width, ev.height)
    assert np.array_equal(counts, pixel_counts([ev], ev.width, ev.height)[0]) and on.sum() == int(ev.p.sum())
    assert dur == ev.t[-1] - ev.t[0]
    # two flagged pixels, one ON only and one OFF only: one polarity per pixel (k = 0), m = 0.5
    c = np.array([[100, 100, 3]])
    o = np.array([[100, 0, 1]])
    mask = np.array([[True, True, False]])
    got = polarity_model(c, o, mask)
    assert got["on_fraction"] == 0.5 and got["hot_pixel_on_fraction"] == 0.5
    assert got["hot_pixel_polarity_concentration"] == 0.0
    # alike pixels: concentration "inf"; nothing flagged: no share
    assert polarity_model(np.array([[1000, 1000]]), np.array([[700, 700]]), np.array([[True, True]]))[
        "hot_pixel_polarity_concentration"] == "inf"
    assert polarity_model(c, o, np.zeros_like(mask))["on_fraction"] is None
