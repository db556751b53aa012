"""rdnet.restore.ednccn: causal FIFO time-surface features with known values, chunked ==
whole stream, labels and the fitted threshold follow rdnet.eval.events exactly, a tiny
training end to end, bad checkpoints give one ConfigError."""
import h5py
import numpy as np
import pytest
import torch

from rdnet.config import from_dict
from rdnet.errors import ConfigError, ModelNotFoundError
from rdnet.eval.events import match_metrics, polarity_counts
from rdnet.events import Events
from rdnet.events.recording import Recording
from rdnet.restore.ednccn import (EdnccnConfig, EdnccnNet, EdnccnRestorer, FeatureState, event_features,
                                  fit_f1_threshold, load_ednccn, parameter_count, train_ednccn, window_labels,
                                  window_voxels)
from rdnet.train.checkpoint import make_checkpoint, save_checkpoint

from _streams import edge_noise_hot

torch.set_num_threads(1)


def _ev(rows, W=5, H=4):
    t, x, y, p = np.array(rows).T
    return Events.from_columns(t, x, y, p, W, H)


def test_features_hold_the_decayed_time_differences_of_earlier_events_only():
    ev = _ev([(0, 1, 1, 1), (100, 2, 1, 1), (250, 1, 1, 1), (300, 1, 1, 0)])
    f = event_features(ev, radius=1, depth=2, tau_us=1000)
    assert f.shape == (4, 4, 3, 3) and f.dtype == np.float32
    assert not f[0].any()                                   # nothing before the first event
    np.testing.assert_allclose(f[1, 0, 1, 0], np.exp(-0.1), rtol=1e-6)  # ON at (1,1) 100 us before, left
    assert np.count_nonzero(f[1]) == 1
    # event 2 (ON at (1,1), t=250): same polarity, most recent: (1,1) at 0 and (2,1) at 100
    np.testing.assert_allclose(f[2, 0, 1, 1], np.exp(-0.25), rtol=1e-6)
    np.testing.assert_allclose(f[2, 0, 1, 2], np.exp(-0.15), rtol=1e-6)
    assert np.count_nonzero(f[2]) == 2
    # event 3 (OFF at (1,1), t=300): the ON events are the opposite polarity (channels 2, 3);
    # its pixel's FIFO holds 250 (most recent) then 0
    np.testing.assert_allclose(f[3, 2, 1, 1], np.exp(-0.05), rtol=1e-6)
    np.testing.assert_allclose(f[3, 3, 1, 1], np.exp(-0.3), rtol=1e-6)
    np.testing.assert_allclose(f[3, 2, 1, 2], np.exp(-0.2), rtol=1e-6)
    assert not f[3, :2].any()                               # no earlier OFF event


def test_features_are_zero_outside_the_sensor():
    ev = _ev([(0, 0, 0, 1), (10, 0, 0, 1)])
    f = event_features(ev, radius=2, depth=1, tau_us=100)
    assert np.count_nonzero(f[1]) == 1 and f[1, 0, 2, 2] == pytest.approx(np.exp(-0.1))


def _net(seed=0, **kw):
    torch.manual_seed(seed)
    return EdnccnNet(**{"radius": 2, "depth": 2, "conv_channels": (4,), "hidden": (8,), **kw})


def test_chunked_equals_whole_stream():
    ev, _ = edge_noise_hot(seed=1, W=30, H=20, T=30_000, n_noise=200, hot=(5, 9))
    whole = event_features(ev, 2, 2, 5000)
    state = FeatureState(ev.width, ev.height, 2)
    cuts = [0, 1, 137, 138, 900, len(ev)]
    parts = [event_features(ev[a:b], 2, 2, 5000, state) for a, b in zip(cuts[:-1], cuts[1:])]
    np.testing.assert_array_equal(np.concatenate(parts), whole)
    r = EdnccnRestorer(_net(), 5000, 0.5)
    prob_whole = r.keep_probability(ev, FeatureState(ev.width, ev.height, 2))
    r.threshold = float(np.median(prob_whole))              # a threshold that keeps about half
    kept_whole = r.filter_stream(ev)
    kept = [r.restore(ev[a:b]) for a, b in zip(cuts[:-1], cuts[1:])]
    np.testing.assert_array_equal(np.concatenate([k.array for k in kept]), kept_whole.array)
    assert 0 < len(kept_whole) < len(ev)


def test_labels_follow_the_event_metric_matching():
    # one window [0, 100], 2 bins, 3x2 sensor: voxel (ON, bin 0, (0,0)) has 3 degraded and
    # 1 reference event; (OFF, bin 1, (1,0)) 1 degraded, 2 reference; (ON, bin 1, (2,1)) 1, 0
    deg = Events.from_columns([5, 10, 20, 60, 100], [0, 0, 0, 1, 2], [0, 0, 0, 0, 1], [1, 1, 1, 0, 1], 3, 2)
    ref = Events.from_columns([7, 55, 70], [0, 1, 1], [0, 0, 0], [1, 0, 0], 3, 2)
    u = polarity_counts(ref, 2, 0, 100)
    i0, i1, v, lab = window_labels(deg, u, 2, 0, 100)
    assert (i0, i1) == (0, 5)
    np.testing.assert_allclose(lab, [1 / 3, 1 / 3, 1 / 3, 1.0, 0.0])
    assert lab.sum() == pytest.approx(match_metrics(polarity_counts(deg, 2, 0, 100), u)["matched"])


def test_labels_sum_to_matched_and_threshold_f1_is_exact():
    rng = np.random.default_rng(3)
    W, H, bins = 6, 5, 4

    def stream(n):
        return Events.from_columns(np.sort(rng.integers(0, 1000, n)), rng.integers(0, W, n),
                                   rng.integers(0, H, n), rng.integers(0, 2, n), W, H)
    deg, ref = stream(300), stream(250)
    deg = Events.from_columns(np.r_[deg.t, 250, 500, 1000], np.r_[deg.x, 1, 2, 3], np.r_[deg.y, 1, 1, 1],
                              np.r_[deg.p, 1, 0, 1], W, H, sort=True)        # events on bin boundaries
    u = polarity_counts(ref, bins, 0, 1000)
    i0, i1, v, lab = window_labels(deg, u, bins, 0, 1000)
    assert lab.sum() == pytest.approx(match_metrics(polarity_counts(deg, bins, 0, 1000), u)["matched"])
    prob = np.round(rng.random(i1 - i0), 2)                 # ties included
    thr, fit = fit_f1_threshold(prob, v, u)
    best = max(match_metrics(polarity_counts(deg[i0:i1].select(prob >= c), bins, 0, 1000), u)["f1"]
               for c in np.unique(prob))
    kept = deg[i0:i1].select(prob >= thr)
    assert fit["f1"] == pytest.approx(best)
    assert match_metrics(polarity_counts(kept, bins, 0, 1000), u)["f1"] == pytest.approx(best)


def _pairs(tmp_path, n_seq=3):
    """Sequences of an edge sweep + isolated noise + a hot pixel (degraded) whose reference
    (undegraded) is the edge alone, two windows each, as data/events + a pairs file."""
    from rdnet.events.io.hdf5 import write_recording
    ev_dir = tmp_path / "events"
    ev_dir.mkdir()
    bins, rows = 4, []
    for s in range(n_seq):
        ev, lab = edge_noise_hot(seed=s, W=24, H=16, T=24_000, n_noise=150, hot=(5, 9))
        write_recording(ev_dir / f"seq_{s:03d}.h5", Recording(ev.width, ev.height, events=ev))
        edge = ev.select(lab == 0)
        for t0 in (2_000, 13_000):
            on_off = polarity_counts(edge, bins, t0, 10_000)
            deg = polarity_counts(ev, bins, t0, 10_000)
            rows.append((s, t0, on_off, deg))
    n, H, W = len(rows), 16, 24
    with h5py.File(tmp_path / "pairs.h5", "w") as f:
        f.attrs["bins"] = bins
        f.attrs["voxel_mode"] = "hard"
        for k in ("blurry", "sharp"):
            f[k] = np.zeros((n, 1, H, W), np.float32)
        f["level"] = np.zeros(n)
        f["sequence"] = np.array([r[0] for r in rows], np.int32)
        f["t0_us"] = np.array([r[1] for r in rows], np.int64)
        f["duration_us"] = np.full(n, 10_000, np.int64)
        for kind, j in (("undegraded", 2), ("degraded", 3)):
            c = np.stack([r[j] for r in rows]).astype(np.float32)
            f[f"voxel_{kind}_on"], f[f"voxel_{kind}_off"] = c[:, 1], c[:, 0]
            f[f"voxel_{kind}"] = c[:, 1] - c[:, 0]
    return tmp_path / "pairs.h5", ev_dir


def test_tiny_training_writes_a_checkpoint_that_restores(tmp_path):
    pairs, ev_dir = _pairs(tmp_path)
    cfg = from_dict(EdnccnConfig, {"radius": 2, "conv_channels": [4], "hidden": [16], "max_train_events": 3000,
                                   "epochs": 8, "batch_size": 256, "val_sequences": 1, "tau_us": 3000,
                                   "device": "cpu"}, "ednccn")
    res = train_ednccn(cfg, pairs, ev_dir, tmp_path / "model", progress=False)
    d = res["decision"]
    assert d["val_metrics"]["f1"] > d["val_metrics_raw"]["f1"]      # held out: better than keeping every event
    r = load_ednccn(tmp_path / "model", device="cpu")
    assert r.threshold == d["threshold"] and parameter_count(r.net) == res["parameters"]
    ev, lab = edge_noise_hot(seed=2, W=24, H=16, T=24_000, n_noise=150, hot=(5, 9))  # held out
    p = r.keep_probability(ev, FeatureState(ev.width, ev.height, cfg.depth))
    assert p[lab == 1].mean() < p[lab == 0].mean()           # isolated noise scores below the edge
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(EdnccnConfig, {"radius": 2, "epoch": 1}, "ednccn")


def test_bad_checkpoints_give_one_config_error(tmp_path):
    with pytest.raises(ModelNotFoundError, match="no EDnCNN model.pt"):      # absent: restore_real skips it
        load_ednccn(tmp_path / "missing")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="not a readable checkpoint") as err:
        load_ednccn(tmp_path / "junk.pt")
    assert not isinstance(err.value, ModelNotFoundError)                    # broken: the stage fails
    net = _net()
    args = {"kind": "ednccn", **net.config}
    other = make_checkpoint(net, "restore", {**args, "kind": "restore"}, with_rng=False)
    save_checkpoint(tmp_path / "other.pt", other)
    with pytest.raises(ConfigError, match="not an EDnCNN classifier"):
        load_ednccn(tmp_path / "other.pt")
    no_thr = make_checkpoint(net, "ednccn", args, extra={"tau_us": 1000}, with_rng=False)
    save_checkpoint(tmp_path / "nothr.pt", no_thr)
    with pytest.raises(ConfigError, match="threshold"):
        load_ednccn(tmp_path / "nothr.pt")
    wrong = make_checkpoint(net, "ednccn", args, extra={"tau_us": 1000, "decision": {"threshold": 0.5}},
                            with_rng=False)
    wrong["model_config"] = {**wrong["model_config"], "hidden": [9]}           # weights of another size
    save_checkpoint(tmp_path / "wrong.pt", wrong)
    with pytest.raises(ConfigError, match="state_dict"):
        load_ednccn(tmp_path / "wrong.pt")


def test_rdnet_restore_method_ednccn_streams_like_the_whole_stream(tmp_path):
    from rdnet.events.io import read_events
    from rdnet.events.io.hdf5 import write_recording
    from rdnet.restore.run import restore_recording
    ev, _ = edge_noise_hot(seed=4, W=30, H=20, T=30_000, n_noise=200, hot=(5, 9))
    write_recording(tmp_path / "rec.h5", Recording(ev.width, ev.height, events=ev))
    net = _net()
    r = EdnccnRestorer(net, 5000, 0.5)
    thr = float(np.median(r.keep_probability(ev, FeatureState(ev.width, ev.height, 2))))
    save_checkpoint(tmp_path / "m.pt", make_checkpoint(net, "ednccn", {"kind": "ednccn", **net.config},
                                                       extra={"tau_us": 5000, "decision": {"threshold": thr}},
                                                       with_rng=False))
    params = {"restore": {"scores": False, "window_us": 7000, "device": "cpu", "hot_pixel_factor": 0}}
    res = restore_recording(tmp_path / "rec.h5", tmp_path / "out.h5", params, method="ednccn",
                            checkpoint=tmp_path / "m.pt", progress=False)
    expected = load_ednccn(tmp_path / "m.pt").filter_stream(ev)
    assert res["method"] == "ednccn" and res["windows"] == 5
    np.testing.assert_array_equal(read_events(tmp_path / "out.h5").array, expected.array)


@pytest.mark.parametrize("bins,t0,dur", [(5, 0, 1000), (10, 137, 2500), (3, 900, 100)])
def test_window_voxels_bin_as_polarity_counts(bins, t0, dur):
    """The label voxels are the metric's voxels: every window's bincount equals
    rdnet.eval.events.polarity_counts, events on both window edges included."""
    rng = np.random.default_rng(bins)
    n = 3000
    t = np.sort(np.r_[rng.integers(0, 4000, n - 2), t0, t0 + dur])
    ev = Events.from_columns(t, rng.integers(0, 9, n), rng.integers(0, 7, n), rng.integers(0, 2, n).astype(np.uint8),
                             9, 7)
    i0, i1, v = window_voxels(ev, bins, t0, dur)
    counts = polarity_counts(ev, bins, t0, dur)
    assert i1 - i0 == counts.sum() > 0
    np.testing.assert_array_equal(np.bincount(v, minlength=counts.size), counts.ravel())
