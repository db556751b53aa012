"""The support rule of the voxel -> event decision (rdnet.nn.decision: neighbour_support,
input_support, fit_support, and the rule in every path that decides events): known answers on
hand-made grids, and the dense, sparse and probability paths keeping the same voxels."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from _nets import count_inputs, perturbed_count_net

from rdnet.errors import ValidationError
from rdnet.nn.decision import (SUPPORT_RULE, decide_counts, decided_entries, decided_events, decision_dict,
                               entry_support, events_from_heads, fit_support, input_support, neighbour_support,
                               read_decision, sparse_decided_entries, support_applies)
from rdnet.nn.sparse import SparseVoxels


def test_neighbour_support_known_answer():
    occ = np.zeros((5, 6), bool)
    occ[0, 0] = True                      # alone in its corner
    occ[3, 3] = occ[4, 4] = True          # diagonal neighbours of each other
    sup = neighbour_support(occ)
    assert not sup[0, 0]                  # the pixel itself does not count
    assert sup[3, 3] and sup[4, 4]
    assert sup[1, 1] and sup[0, 1] and sup[1, 0]        # next to the corner event
    assert not sup[2, 0] and not sup[0, 2]              # two pixels away
    assert sup.sum() == 3 + 11      # the corner event's 3 neighbours; rows 2-4 x cols 2-4 and (3, 5), (4, 5) around the pair
    np.testing.assert_array_equal(occ, neighbour_support(occ) & occ | occ)   # input untouched


def test_input_support_from_dense_and_sparse_inputs_agree():
    x, _ = count_inputs(0.05)             # sparse Poisson counts: isolated events exist
    dense = input_support(x)
    assert dense.shape == (1, 1, 13, 19) and dense.dtype == bool
    occ = (x[0] > 0).any(0).numpy()
    assert (occ & ~dense[0, 0]).any()     # some events have no neighbour
    idx = np.flatnonzero(x[0].numpy().ravel())
    sp = SparseVoxels.of(idx, x[0].numpy().ravel()[idx], tuple(x.shape[1:]))
    np.testing.assert_array_equal(input_support(sp), dense)
    np.testing.assert_array_equal(input_support(x.numpy()), dense)
    # the per-entry lookup of the sparse decision path: every voxel of the grid, borders included
    C, H, W = x.shape[1:]
    every = np.arange(C * H * W)
    np.testing.assert_array_equal(entry_support(every, (1, C, H, W), sp), np.tile(dense[0, 0].ravel(), C))
    empty = SparseVoxels.of(idx[:0], x[0].numpy().ravel()[idx[:0]], tuple(x.shape[1:]))
    assert not entry_support(every, (1, C, H, W), empty).any()
    # a dense batch of two samples (the decided_entries path): the same lookup per sample
    batch = torch.cat([x, torch.flip(x, dims=(3,))])
    both = np.arange(2 * C * H * W)
    np.testing.assert_array_equal(entry_support(both, (2, C, H, W), batch),
                                  np.concatenate([np.tile(m.ravel(), C) for m in input_support(batch)[:, 0]]))


def test_an_unknown_support_rule_is_refused_when_the_decision_is_read():
    with pytest.raises(ValidationError, match="support rule"):
        read_decision(decision_dict(0.5, support={"rule": "other", "drop": True}), "counts")


def test_an_isolated_event_is_dropped_and_a_supported_pair_kept():
    # one polarity channel pair, 1 bin: ON channel 0, OFF channel 1
    counts = np.zeros((1, 2, 6, 6), np.float32)
    counts[0, 0, 0, 0] = 1                # isolated
    counts[0, 0, 4, 4] = counts[0, 1, 4, 5] = 1   # neighbours (opposite polarities count)
    mu = np.ones_like(counts)
    prob = np.where(counts > 0, 0.9, 0.01).astype(np.float32)
    plain = decide_counts(mu, prob, 0.5)
    assert plain.sum() == 3
    kept = decide_counts(mu, prob, 0.5, input_support(counts))
    assert kept[0, 0, 0, 0] == 0 and kept[0, 0, 4, 4] == 1 and kept[0, 1, 4, 5] == 1 and kept.sum() == 2


def test_fit_support_drops_only_when_the_unsupported_voxels_are_rarely_real():
    rng = np.random.default_rng(0)
    n, C, H, W = 4, 2, 16, 16
    counts = (rng.random((n, C, H, W)) < 0.03).astype(np.float32)
    sup = input_support(counts)
    prob = np.where(counts > 0, 0.9, 0.0).astype(np.float32)
    mu = np.ones_like(counts)
    target_real_isolated = counts.copy()                     # every event real, isolated ones too
    t, info = fit_support(mu, prob, target_real_isolated, sup, 0.5)
    assert info["rule"] == SUPPORT_RULE and info["val_precision"] == 1.0 and not info["drop"] and t == 0.5
    target = counts * np.broadcast_to(sup, counts.shape)     # only supported events are real
    target[:, :, 0, 0] += 1                                  # one more real event elsewhere: count target
    t2, info2 = fit_support(mu, prob, target, sup, 0.5)
    assert info2["drop"] and info2["val_precision"] == 0.0 and info2["val_events"] > 0
    assert info2["threshold_before"] == 0.5 and 0 < t2 <= 0.9
    assert support_applies({"support": info2}) and not support_applies({"support": info}) and not support_applies({})
    with pytest.raises(ValidationError, match="support rule"):
        support_applies({"support": {"rule": "other", "drop": True}})


@pytest.mark.parametrize("channels_last", [False, True])
def test_every_decision_path_applies_the_support_rule_alike(channels_last):
    net = perturbed_count_net(5, 0.3)
    x, img = count_inputs(0.05)
    if channels_last:
        net.to(memory_format=torch.channels_last)
        x, img = (t.contiguous(memory_format=torch.channels_last) for t in (x, img))
    with torch.inference_mode():
        mu, logit = net(img, x, return_heads=True)
    t = float(torch.sigmoid(logit).flatten().sort().values[-60])
    plain = decision_dict(t)
    ruled = decision_dict(t, support={"rule": SUPPORT_RULE, "drop": True})
    want = events_from_heads(mu, torch.sigmoid(logit), ruled, x)          # the probability rule
    assert 0 < want.sum() < events_from_heads(mu, torch.sigmoid(logit), plain).sum()
    with torch.inference_mode():
        np.testing.assert_array_equal(decided_events(net, img, x, ruled), want)
        dense = decided_entries(mu, logit, ruled, x)
        got = sparse_decided_entries(net, img, x, ruled)
        idx = np.flatnonzero(x[0].contiguous().numpy().ravel())
        sp = SparseVoxels.of(idx, x[0].contiguous().numpy().ravel()[idx], tuple(x.shape[1:]), channels_last)
        got_sparse = sparse_decided_entries(net, img, sp, ruled)
    grid = np.zeros(mu.numel(), np.int64)
    grid[dense[0]] = dense[1]
    np.testing.assert_array_equal(grid.reshape(want.shape), want)
    for g in (got, got_sparse):
        np.testing.assert_array_equal(g[0], dense[0])
        np.testing.assert_array_equal(g[1], dense[1])
    with pytest.raises(ValidationError, match="inputs"):
        events_from_heads(mu, torch.sigmoid(logit), ruled)


def test_count_gain_scales_the_excess_and_is_fitted_where_the_head_undercounts():
    from rdnet.eval.events import match_metrics
    from rdnet.nn.decision import decision_gain, fit_count_gain, gained, polarity_grid
    mu = np.array([[[[1.0, 2.0, 3.0, 1.2]]]], np.float32)
    assert gained(mu, 1.0) is mu
    np.testing.assert_array_equal(decide_counts(mu, np.ones_like(mu), 0.5, gain=1.5)[0, 0, 0], [1, 2, 4, 1])
    assert decision_gain({}) == 1.0 and decision_gain({"count_gain": {"gain": 2.0}}) == 2.0
    # a count head that reports half the excess: the true counts are 1 + 2 (mu - 1)
    rng = np.random.default_rng(1)
    mu = (1.0 + rng.integers(0, 4, (2, 4, 8, 8))).astype(np.float32)   # integer excess: no two gains round alike
    prob = rng.uniform(0.2, 1.0, mu.shape).astype(np.float32)
    real = prob > 0.5                                           # the likelier voxels are the real ones
    target = np.where(real, 1 + 2 * (mu - 1), 0)
    ref = polarity_grid(np.rint(target).astype(np.int64))
    g, t, info = fit_count_gain(mu, prob, target, None, lambda c: match_metrics(polarity_grid(c), ref)["f1"])
    assert g == 2.0 and info["gain"] == 2.0 and set(info["val_f1"]) >= {"1", "2"}
    assert info["val_f1"]["2"] == 1.0 > info["val_f1"]["1"] and t == info["thresholds"]["2"]


def test_every_decision_path_applies_the_count_gain_alike():
    net = perturbed_count_net(5, 0.3)
    x, img = count_inputs(0.4)
    with torch.no_grad():
        net.net.ending.bias[:6] += 1.5                            # a count head above 1 somewhere
    with torch.inference_mode():
        mu, logit = net(img, x, return_heads=True)
    t = float(torch.sigmoid(logit).flatten().sort().values[-80])
    ruled = decision_dict(t, support={"rule": SUPPORT_RULE, "drop": True}, count_gain={"gain": 2.5})
    want = events_from_heads(mu, torch.sigmoid(logit), ruled, x)
    assert want.sum() > events_from_heads(mu, torch.sigmoid(logit), {**ruled, "count_gain": None}, x).sum()
    with torch.inference_mode():
        np.testing.assert_array_equal(decided_events(net, img, x, ruled), want)
        got = sparse_decided_entries(net, img, x, ruled)
    grid = np.zeros(mu.numel(), np.int64)
    grid[got[0]] = got[1]
    np.testing.assert_array_equal(grid.reshape(want.shape), want)


@pytest.mark.parametrize("channels_last", [False, True])
def test_logits_at_the_supported_pixels_alone_keep_the_dense_decision(channels_last, monkeypatch):
    import rdnet.nn.decision as decision_mod
    net = perturbed_count_net(5, 0.3)
    x, img = count_inputs(0.002)             # few events: 3 % of the pixels supported
    supported = input_support(x)[0, 0]
    assert 0 < supported.mean() <= decision_mod.GATED_MAX_SUPPORT
    if channels_last:
        net.to(memory_format=torch.channels_last)
        x, img = (t.contiguous(memory_format=torch.channels_last) for t in (x, img))
    idx = np.flatnonzero(x[0].contiguous().numpy().ravel())
    sp = SparseVoxels.of(idx, x[0].contiguous().numpy().ravel()[idx], tuple(x.shape[1:]), channels_last)
    with torch.inference_mode():
        mu, logit = net(img, x, return_heads=True)
    at = np.sort(torch.sigmoid(logit)[0][:, torch.from_numpy(supported)].flatten().numpy())
    calls = []
    real_heads = net.sparse_heads
    monkeypatch.setattr(net, "sparse_heads", lambda *a, **k: calls.append(k.get("pixels")) or real_heads(*a, **k))
    for q in (0.5, 0.9):                     # cuts between two supported probabilities: no ties
        i = int(q * at.size)
        ruled = decision_dict(float(at[i - 1] + at[i]) / 2, support={"rule": SUPPORT_RULE, "drop": True})
        want = decided_entries(mu, logit, ruled, x)
        assert want[0].size > 0
        with torch.inference_mode():
            for inputs in (x, sp):
                calls.clear()
                got = sparse_decided_entries(net, img, inputs, ruled)
                assert calls and calls[0] is not None          # the supported pixels alone were computed
                np.testing.assert_array_equal(got[0], want[0])
                np.testing.assert_array_equal(got[1], want[1])


def test_sparse_heads_at_pixels_gives_the_dense_logits_there():
    net = perturbed_count_net(3, 0.3)
    x, img = count_inputs(0.02)
    with torch.inference_mode():
        mu, logit = net(img, x, return_heads=True)
        y, xx = np.nonzero(np.ones((13, 19), bool))           # every pixel, borders included
        s = logit.flatten().sort().values
        cut = float(s[s.numel() // 2 - 1] + s[s.numel() // 2]) / 2      # between two logits: no tie
        where, mu_at = net.sparse_heads(img, x, cut, pixels=(y, xx))
        keep = logit >= cut
    np.testing.assert_array_equal(np.stack(where), np.stack(np.nonzero(keep.numpy())))
    torch.testing.assert_close(mu_at(*where), mu[keep], rtol=1e-5, atol=1e-5)
