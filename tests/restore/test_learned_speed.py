"""The learned restorer's inference path (rdnet.restore.learned: prepare_for_inference,
channels_last inputs, the decision on logits and the sparse event conversion) gives the
events of the straightforward path: contiguous network, sigmoid probabilities against
the threshold, the dense per-window grid through voxel_events."""
import numpy as np
import pytest
import torch

from rdnet.events.select import select_events, signed_entries
from rdnet.events.voxel import voxel_events, voxel_grid
from rdnet.nn.decision import decision_dict, events_from_heads
from rdnet.restore.learned import load_restorer, prepare_for_inference
from rdnet.train.checkpoint import make_checkpoint, save_checkpoint
from rdnet.train.loop import build_seeded

from _streams import edge_noise_hot

PARAMS = {"voxel": {"bins": 4, "mode": "hard", "normalize": None}}
WINDOW = 15_000
#: events allowed to differ between the layouts: none on this stream (a voxel whose
#: probability is within float rounding of the threshold could flip; it would change 1-3 events)
MAX_LAYOUT_DIFF = 0


def _checkpoint(path, image_channels=1, threshold=0.45, output="counts"):
    args = {"kind": "restore", "size": "tiny", "image_channels": image_channels, "bins": 4, "width": 4}
    if output != "signed":
        args["restore_output"] = output
    net = build_seeded(args, 0)
    g = torch.Generator().manual_seed(5)
    with torch.no_grad():                        # a trained-looking net: not the identity it starts as
        for p in net.parameters():
            p.add_(0.15 * torch.randn(p.shape, generator=g))
    extra = {"voxel": {"bins": 4, "mode": "hard", "normalize": None}, "window_us": WINDOW,
             "decision": decision_dict(threshold if output == "counts" else None)}
    save_checkpoint(path, make_checkpoint(net, "restore", args, step=1, extra=extra, with_rng=False))
    return path


def _frame(t_mid, W=60, H=40):
    """A linear grey frame: a bright band left of the sweeping edge."""
    x = np.arange(W)[None, :].repeat(H, 0)
    return np.where(x < t_mid // 1000, 0.8, 0.1).astype(np.float32)


def _restore_all(r, ev, frames=True):
    out = [r.restore(ev, t0, t0 + WINDOW, _frame(t0 + WINDOW // 2) if frames else None)
           for t0 in range(0, 60_000, WINDOW)]
    return np.concatenate([o.array for o in out])


def _reference(r, ev, frames=True):
    """The path before the speed-ups: contiguous inputs, sigmoid >= threshold, the dense grid
    to events (voxel_events, or select_events for ``event_times: input``)."""
    parts = []
    for t0 in range(0, 60_000, WINDOW):
        w = ev.slice_time(t0, t0 + WINDOW)
        x = torch.from_numpy(voxel_grid(w, r.bins, t0, WINDOW, polarity="split").reshape(1, -1, ev.height, ev.width))
        img = torch.from_numpy(_frame(t0 + WINDOW // 2)[None, None]) if frames else None
        with torch.inference_mode():
            mu, logit = r.net(img, x, return_heads=True)
        grid = events_from_heads(mu, torch.sigmoid(logit), r.decision)[0]
        if r.event_times == "input":      # the kept events are the window's own (rdnet.events.select)
            res = select_events(w, *signed_entries(grid), t0, WINDOW)
        else:
            res = voxel_events(grid, t0, WINDOW)
        parts.append(res.slice_time(t0, t0 + WINDOW).array)
    return np.concatenate(parts)


def _both_layouts(r, ev, frames: bool) -> dict:
    """Events of ``r`` with the contiguous (False) and the channels_last (True) network, at 2
    torch threads (the caller's thread count restored)."""
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        outs = {}
        for cl in (False, True):
            r.channels_last = prepare_for_inference(r.net, r.device, channels_last=cl)
            assert r.net.net.ending.weight.is_contiguous(memory_format=torch.channels_last) == cl
            outs[cl] = _restore_all(r, ev, frames)
    finally:
        torch.set_num_threads(threads)
    return outs


def _diff(a, b):
    """Events in one array and not the other (multiset difference, both ways)."""
    ka = np.sort(a, order=("t", "x", "y", "p"))
    kb = np.sort(b, order=("t", "x", "y", "p"))
    if ka.size == kb.size and np.array_equal(ka, kb):
        return 0
    u, ca = np.unique(ka, return_counts=True)
    v, cb = np.unique(kb, return_counts=True)
    both = np.union1d(u, v)
    na = np.zeros(both.size, int)
    nb = np.zeros(both.size, int)
    na[np.searchsorted(both, u)] = ca
    nb[np.searchsorted(both, v)] = cb
    return int(np.abs(na - nb).sum())


@pytest.mark.parametrize("image_channels", [1, 0])
def test_channels_last_and_contiguous_restore_the_same_events(tmp_path, image_channels):
    ev, _ = edge_noise_hot(seed=3)
    path = _checkpoint(tmp_path / "m.pt", image_channels)
    has_frames = bool(image_channels)
    r = load_restorer(path, has_frames=has_frames, params=PARAMS)
    outs = _both_layouts(r, ev, has_frames)
    r.channels_last = prepare_for_inference(r.net, r.device, channels_last=False)
    ref = _reference(r, ev, has_frames)
    assert 0 < len(ref) and len(ref) != len(ev)            # the net decides something
    np.testing.assert_array_equal(outs[False], ref)        # the logit/sparse path: exactly the old events
    assert _diff(outs[True], outs[False]) <= MAX_LAYOUT_DIFF
    assert np.all(np.diff(outs[True]["t"]) >= 0)


def test_prepare_for_inference_chooses_channels_last_on_cpu_with_two_threads(tmp_path):
    r = load_restorer(_checkpoint(tmp_path / "m.pt"), has_frames=True, params=PARAMS)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        assert prepare_for_inference(r.net, "cpu") is True and not r.net.training
        assert r.net.net.ending.weight.is_contiguous(memory_format=torch.channels_last)
        assert prepare_for_inference(r.net, "cuda") is False           # no GPU needed: only the choice
        assert r.net.net.ending.weight.is_contiguous()
        torch.set_num_threads(1)
        assert prepare_for_inference(r.net, "cpu") is False
        assert load_restorer(tmp_path / "m.pt", has_frames=True, params=PARAMS).channels_last is False
        torch.set_num_threads(2)
        assert load_restorer(tmp_path / "m.pt", has_frames=True, params=PARAMS).channels_last is True
    finally:
        torch.set_num_threads(threads)


def test_signed_output_restores_the_same_events_in_both_layouts(tmp_path):
    """The paper's signed output (rounded, no threshold) through the channels_last path."""
    ev, _ = edge_noise_hot(seed=4)
    r = load_restorer(_checkpoint(tmp_path / "s.pt", 0, output="signed"), has_frames=False, params=PARAMS)
    outs = _both_layouts(r, ev, frames=False)
    assert len(outs[False]) > 0 and _diff(outs[True], outs[False]) <= MAX_LAYOUT_DIFF


@pytest.mark.parametrize("image_channels,event_times", [(1, "input"), (0, "input"), (1, "bins")])
def test_sparse_and_dense_windows_restore_the_same_events(tmp_path, monkeypatch, image_channels, event_times):
    """LearnedRestorer.restore feeds a window's non-zero voxels (rdnet.nn.sparse) when at most
    SPARSE_MAX_DENSITY of them are non-zero, the dense grid otherwise: forced either way, the
    same events as the reference path (kept events with their own times, or spread over the bins)."""
    import rdnet.nn.sparse as sparse
    ev, _ = edge_noise_hot(seed=4)
    has_frames = bool(image_channels)
    r = load_restorer(_checkpoint(tmp_path / "m.pt", image_channels), has_frames=has_frames, params=PARAMS,
                      event_times=event_times)
    r.channels_last = prepare_for_inference(r.net, r.device, channels_last=False)
    ref = _reference(r, ev, has_frames)
    outs = {}
    for limit in (0.0, 1.0):                        # 0: every window dense; 1: every window sparse
        monkeypatch.setattr(sparse, "SPARSE_MAX_DENSITY", limit)
        outs[limit] = _restore_all(r, ev, has_frames)
    assert 0 < len(ref) and len(ref) != len(ev)
    np.testing.assert_array_equal(outs[0.0], ref)
    assert _diff(outs[1.0], ref) <= MAX_LAYOUT_DIFF


@pytest.mark.parametrize("threads", [1, 2])
def test_support_rule_removes_isolated_noise_on_the_restore_path(tmp_path, threads):
    """Known answer through LearnedRestorer.restore (sparse windows): a fresh count network is
    the identity at the event level, so with a decision that applies the support rule the
    output is the input without the events of pixels that have no input event among their 8
    neighbours in the window: the isolated noise goes, the edge stays, every window."""
    from rdnet.nn.decision import SUPPORT_RULE
    from rdnet.restore.learned import restorer_from_checkpoint
    args = {"kind": "restore", "size": "tiny", "image_channels": 0, "bins": 4, "width": 4,
            "restore_output": "counts"}
    net = build_seeded(args, 0)                          # zero output conv: the identity start
    extra = {"voxel": {"bins": 4, "mode": "hard", "normalize": None}, "window_us": WINDOW,
             "decision": decision_dict(0.5, support={"rule": SUPPORT_RULE, "drop": True})}
    path = tmp_path / "m.pt"
    save_checkpoint(path, make_checkpoint(net, "restore", args, step=1, extra=extra, with_rng=False))
    ev, lab = edge_noise_hot(seed=3, n_noise=120, hot=(50, 35))
    r = restorer_from_checkpoint(path, has_frames=False, params=PARAMS)
    prev = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        out = _restore_all(r, ev, frames=False)
    finally:
        torch.set_num_threads(prev)
    want = []
    for t0 in range(0, 60_000, WINDOW):
        w = ev.slice_time(t0, t0 + WINDOW)
        occ = np.zeros((ev.height + 2, ev.width + 2), int)
        np.add.at(occ, (w.y.astype(int) + 1, w.x.astype(int) + 1), 1)
        occ = occ > 0
        nb = sum(occ[1 + dy:1 + dy + ev.height, 1 + dx:1 + dx + ev.width]
                 for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0))
        want.append(nb[w.y, w.x] > 0)
    keep = np.concatenate(want)
    assert (lab == 1).sum() > 100 and 0 < (~keep & (lab == 1)).sum() and (~keep & (lab == 0)).sum() == 0
    # the output events are the kept input events (at voxel times: the pixels are compared)
    assert len(out) == int(keep.sum())
    kept = ev.array[keep]
    np.testing.assert_array_equal(np.sort(out["x"].astype(int) * 100 + out["y"]),
                                  np.sort(kept["x"].astype(int) * 100 + kept["y"]))


@pytest.mark.parametrize("image_channels", [1, 0])
def test_windows_restored_at_once_give_the_same_events_and_scores(tmp_path, image_channels):
    """``restore.workers``: the learned restorer takes several windows at once on the CPU
    (rdnet.restore.learned.LearnedRestorer.parallel); the output file, counts and scores equal
    those of one window at a time, and the caller's torch thread count is back afterwards."""
    import json

    from rdnet.cli import main
    from rdnet.events import Frames, Recording
    from rdnet.events.io import read_recording, write_recording
    ev, _ = edge_noise_hot(seed=3)
    frames = None
    if image_channels:
        t = 7_500 + WINDOW * np.arange(4)
        frames = Frames(np.stack([_frame(int(tt)) for tt in t]), t, np.full(4, 1000))
    write_recording(tmp_path / "in.h5", Recording(ev.width, ev.height, events=ev, frames=frames, sensor="SYN"))
    ck = _checkpoint(tmp_path / "m.pt", image_channels)
    threads = torch.get_num_threads()
    outs = {}
    try:
        torch.set_num_threads(2)
        for workers in (1, 2, 3):
            out = tmp_path / f"o{workers}.h5"
            assert main(["restore", str(tmp_path / "in.h5"), str(out), "--checkpoint", str(ck), "--no-progress",
                         "--set", f"restore.workers={workers}", "--set", "restore.device=cpu",
                         "--set", "voxel.bins=4"]) == 0
            assert torch.get_num_threads() == 2
            outs[workers] = (read_recording(out).events.array, json.loads(out.with_suffix(".json").read_text()))
    finally:
        torch.set_num_threads(threads)
    base, info1 = outs[1]
    assert info1["workers"] == 1 and info1["windows"] >= 4 and 0 < len(base) != len(ev)
    for workers in (2, 3):
        arr, info = outs[workers]
        assert info["workers"] == workers
        np.testing.assert_array_equal(arr, base)
        for key in ("events_in", "events_out", "events_not_recorded", "scores", "hot_pixels"):
            assert info[key] == info1[key], key


def test_ordered_map_keeps_the_order_and_bounds_what_it_takes_ahead():
    import threading
    import time

    from rdnet.restore.stream import ordered_map
    taken = []

    def items():
        for i in range(12):
            taken.append(i)
            yield i

    def slow_first(i):                     # later items finish first
        time.sleep(0.02 if i % 3 == 0 else 0.0)
        return i * i, threading.current_thread().name

    for workers in (1, 3):
        taken.clear()
        seen = []
        for i, (sq, name) in ordered_map(slow_first, items(), workers):
            assert len(taken) <= i + 1 + 2 * workers       # at most 2 x workers ahead
            seen.append((i, sq, name))
        assert [s[:2] for s in seen] == [(i, i * i) for i in range(12)]
        names = {s[2] for s in seen}
        assert (names == {threading.current_thread().name}) == (workers == 1)

    def boom(i):
        if i == 4:
            raise ValueError("window 4")
        return i
    with pytest.raises(ValueError, match="window 4"):
        list(ordered_map(boom, range(10), 2))


def test_workers_zero_takes_a_window_per_thread_on_small_sensors_only(tmp_path):
    from rdnet.restore.learned import WINDOW_PER_THREAD_MAX_PIXELS
    r = load_restorer(_checkpoint(tmp_path / "m.pt"), has_frames=True, params=PARAMS)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        for workers, pixels, want, inside in ((0, 346 * 260, 2, 1), (0, WINDOW_PER_THREAD_MAX_PIXELS + 1, 1, 2),
                                              (1, 346 * 260, 1, 2), (3, 1280 * 720, 3, 1)):
            with r.parallel(workers, pixels) as n:
                assert n == want and torch.get_num_threads() == inside
            assert torch.get_num_threads() == 2
        r.device = "cuda"                                   # only the choice: no GPU needed
        with r.parallel(2, 100) as n:
            assert n == 1
    finally:
        torch.set_num_threads(threads)


def test_an_error_in_a_window_thread_exits_2_with_no_output(tmp_path, monkeypatch, capsys):
    """A user error raised while windows run at once (here: the third window's restore call)
    reaches the CLI as one line and exit 2, neither output file is left, and torch's thread
    count is back."""
    from rdnet.cli import main
    from rdnet.errors import ValidationError
    from rdnet.events import Recording
    from rdnet.events.io import write_recording
    from rdnet.restore.learned import LearnedRestorer
    ev, _ = edge_noise_hot(seed=3)
    write_recording(tmp_path / "in.h5", Recording(ev.width, ev.height, events=ev, sensor="SYN"))
    ck = _checkpoint(tmp_path / "m.pt", 0)
    real = LearnedRestorer.restore
    calls = []

    def third_fails(self, events, t0_us, t1_us, frame):
        calls.append(t0_us)
        if len(calls) == 3:
            raise ValidationError("window", "a bad window")
        return real(self, events, t0_us, t1_us, frame)
    monkeypatch.setattr(LearnedRestorer, "restore", third_fails)
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        rc = main(["restore", str(tmp_path / "in.h5"), str(tmp_path / "o.h5"), "--checkpoint", str(ck),
                   "--no-progress", "--set", "restore.workers=2", "--set", "restore.device=cpu",
                   "--set", "voxel.bins=4"])
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(threads)
    err = capsys.readouterr().err
    assert rc == 2 and "a bad window" in err and "Traceback" not in err
    assert len(calls) >= 3
    assert not (tmp_path / "o.h5").exists() and not (tmp_path / "o.json").exists()
    assert not list(tmp_path.glob(".*.tmp")) and not list(tmp_path.glob("*.tmp"))
