import numpy as np
import pytest

from rdnet.errors import ValidationError
from rdnet.eval.events import event_metrics, match_metrics, polarity_counts
from rdnet.events import Events
from rdnet.events.voxel import voxel_grid


def _ev(t, x, y, p, W=4, H=3):
    return Events.from_columns(np.array(t), np.array(x), np.array(y), np.array(p), W, H)


def test_polarity_counts_binning_matches_voxel_grid():
    # window [0, 100], 2 bins: [0, 50) and [50, 100] (last bin closed)
    ev = _ev([0, 10, 49, 50, 100, 101], [0, 0, 1, 1, 2, 3], [0, 0, 1, 1, 2, 2], [1, 1, 0, 1, 0, 1])
    c = polarity_counts(ev, 2, 0, 100)
    assert c.shape == (2, 2, 3, 4) and c.dtype == np.int32
    assert c[1, 0, 0, 0] == 2              # two ON at (0, 0), bin 0
    assert c[0, 0, 1, 1] == 1 and c[1, 1, 1, 1] == 1
    assert c[0, 1, 2, 2] == 1              # t = 100 lands in the last bin
    assert c.sum() == 5                    # t = 101 is outside the window
    np.testing.assert_array_equal(c[1] - c[0], voxel_grid(ev, 2, 0, 100))


def test_match_metrics_hand_computed():
    u = np.zeros((2, 1, 1, 3), np.int32)
    r = np.zeros_like(u)
    u[1, 0, 0, 0] = 3; u[0, 0, 0, 1] = 1            # reference: 3 ON at px0, 1 OFF at px1
    r[1, 0, 0, 0] = 2; r[1, 0, 0, 1] = 1; r[0, 0, 0, 2] = 1   # restored: 2 ON px0, 1 ON px1, 1 OFF px2
    m = match_metrics(r, u)
    # matched = min(2,3) = 2; restored 4, reference 4
    assert m["matched"] == 2 and m["restored"] == 4 and m["reference"] == 4
    assert m["precision"] == pytest.approx(0.5) and m["recall"] == pytest.approx(0.5)
    assert m["f1"] == pytest.approx(0.5) and m["count_ratio"] == pytest.approx(1.0)
    # signed: u = [3, -1, 0], r = [2, 1, -1] -> |diff| = [1, 2, 1], 3 voxels, all event voxels
    assert m["voxel_l1_all"] == pytest.approx(4 / 3)
    assert m["voxel_l1_event"] == pytest.approx(4 / 3) and m["event_voxels"] == 3
    # per polarity: OFF |0-0|+|0-1|+|1-0| = 2, ON |2-3|+|1-0|+0 = 2 -> 4 over 6 entries
    assert m["polarity_l1_all"] == pytest.approx(4 / 6)


def test_event_voxels_exclude_empty_ones():
    u = np.zeros((2, 2, 2, 2), np.int32); r = np.zeros_like(u)
    u[1, 0, 0, 0] = 1
    m = match_metrics(r, u)
    assert m["voxel_l1_all"] == pytest.approx(1 / 8) and m["voxel_l1_event"] == pytest.approx(1.0)
    assert m["precision"] == 1.0 and m["recall"] == 0.0 and m["f1"] == 0.0 and m["count_ratio"] == 0.0


def test_edge_cases_and_identity():
    z = np.zeros((2, 1, 2, 2), np.int32)
    m = match_metrics(z, z)
    assert (m["precision"], m["recall"], m["f1"], m["count_ratio"]) == (1.0, 1.0, 1.0, 1.0)
    assert m["voxel_l1_event"] == 0.0
    one = z.copy(); one[0, 0, 1, 1] = 2
    assert match_metrics(one, z)["count_ratio"] == np.inf
    assert match_metrics(one, z)["precision"] == 0.0 and match_metrics(one, z)["recall"] == 1.0
    ident = match_metrics(one, one)
    assert ident["f1"] == 1.0 and ident["voxel_l1_all"] == 0.0


def test_batched_pooled_and_per_sample():
    rng = np.random.default_rng(0)
    r = rng.integers(0, 3, (3, 2, 2, 4, 5)).astype(np.int32)
    u = rng.integers(0, 3, (3, 2, 2, 4, 5)).astype(np.int32)
    pooled = match_metrics(r, u)
    per = match_metrics(r, u, per_sample=True)
    assert per["f1"].shape == (3,)
    for i in range(3):
        one = match_metrics(r[i], u[i])
        assert per["precision"][i] == pytest.approx(one["precision"])
        assert per["voxel_l1_all"][i] == pytest.approx(one["voxel_l1_all"])
    assert pooled["matched"] == int(np.minimum(r, u).sum())
    assert pooled["voxel_l1_all"] == pytest.approx(np.mean(per["voxel_l1_all"]))  # equal voxel counts


def test_bad_shapes_rejected():
    with pytest.raises(ValidationError):
        match_metrics(np.zeros((2, 1, 2, 2)), np.zeros((2, 1, 2, 3)))
    with pytest.raises(ValidationError):
        match_metrics(np.zeros((3, 1, 2, 2)), np.zeros((3, 1, 2, 2)))


def test_event_metrics_of_streams():
    ref = _ev([0, 10, 60], [0, 1, 2], [0, 0, 0], [1, 0, 1])
    out = _ev([0, 60, 70], [0, 2, 3], [0, 0, 0], [1, 1, 1])
    m = event_metrics(out, ref, 2, 0, 100)
    assert m["matched"] == 2 and m["precision"] == pytest.approx(2 / 3) and m["recall"] == pytest.approx(2 / 3)
