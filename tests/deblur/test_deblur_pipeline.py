"""Pieces of rdnet deblur: event windows, the size checks of the network call, and the
consistency comparison (same pixel-intervals for every stream)."""
import numpy as np
import pytest
import torch

from rdnet.calib.consistency import active_intervals, consistency
from rdnet.deblur.consistency import LogFrames, compare_consistency
from rdnet.deblur.pipeline import choose_windows, exposure_windows, interval_windows, run_rdnet
from rdnet.errors import FormatError, ValidationError
from rdnet.events import EVENT_DTYPE, Events, Frames
from rdnet.nn.models import build_model


def _frames(t, exposure):
    t = np.asarray(t, np.int64)
    return Frames(np.zeros((t.size, 4, 5), np.uint8), t, np.full(t.size, exposure, np.int64))


def test_windows():
    fr = _frames([1000, 2000, 4000], 100)
    e = exposure_windows(fr)
    assert e.start_us.tolist() == [950, 1950, 3950] and e.duration_us.tolist() == [100] * 3
    i = interval_windows(fr)
    assert i.start_us.tolist() == [500, 1500, 3000] and i.duration_us.tolist() == [1000, 1500, 2000]
    assert np.all(i.start_us[1:] == i.start_us[:-1] + i.duration_us[:-1])        # they tile
    assert choose_windows(fr, "auto").kind == "exposure"
    none = _frames([1000, 2000, 4000], 0)
    auto = choose_windows(none, "auto")
    assert auto.kind == "interval" and "fallback" in auto.note and auto.same_as(interval_windows(none))
    with pytest.raises(FormatError, match="exposure_us"):
        choose_windows(none, "exposure")
    with pytest.raises(FormatError, match="at least 2 frames"):
        interval_windows(_frames([1000], 0))


def test_run_rdnet_checks_sizes():
    net = build_model("rdnet", "tiny", 1, 3, width=4).eval()
    img, vox = np.random.default_rng(0).random((2, 1, 10, 13), np.float32), np.zeros((2, 3, 10, 13), np.float32)
    restored, sharp = run_rdnet(net, img, vox, torch.device("cpu"))
    np.testing.assert_array_equal(sharp, img)                    # fresh stages are the identity
    np.testing.assert_array_equal(restored, vox)
    for bad_img, bad_vox, word in [(img, vox[:, :, :8], "voxel size"), (img, vox[:1], "1 voxel grids"),
                                   (img, vox[:, :2], "2 bins"), (np.repeat(img, 3, 1), vox, "3 channels")]:
        with pytest.raises(ValidationError, match=word):
            run_rdnet(net, bad_img, bad_vox, torch.device("cpu"))


def test_consistency_scores_every_stream_on_the_same_intervals():
    W, H = 3, 1
    t = np.array([0, 100, 200], np.int64)
    logs = np.log(np.array([[[1, 1, 1]], [[np.e ** 0.4, 1, 1]], [[np.e ** 0.4, 1, np.e ** -0.2]]], np.float32))
    frames = Frames(np.exp(logs).astype(np.float32) / 10, t, np.zeros(3, np.int64))
    def ev(rows):
        a = np.array(rows, dtype=EVENT_DTYPE) if rows else np.empty(0, EVENT_DTYPE)
        return Events(a, W, H)
    exact = ev([(50, 0, 0, 1), (60, 0, 0, 1), (150, 2, 0, 0)])           # explains every change
    noisy = ev([(50, 0, 0, 1), (60, 0, 0, 1), (70, 1, 0, 1), (150, 2, 0, 0)])
    lf = LogFrames.of(frames, ev([(0, 0, 0, 1), (300, 0, 0, 1)]), log_eps=0.0)
    res = compare_consistency(lf, {"exact": exact, "noisy": noisy}, 0.2, 0.2)
    assert res["exact"]["active"] == res["noisy"]["active"] == 3          # the union of active intervals
    assert res["exact"]["r2_fitted"] == pytest.approx(1.0)
    assert res["noisy"]["r2_fitted"] < res["exact"]["r2_fitted"]
    # the default active set of the calibration measure is unchanged
    own = consistency(exact, lf, 0.2, 0.2)
    assert own["active"] == int(active_intervals(exact, lf, 0.2, 0.2).sum()) == 2


def test_network_images_fit_the_channels_of_the_network():
    from rdnet.deblur.pipeline import network_images
    rng = np.random.default_rng(0)
    grey = Frames(rng.integers(0, 256, (2, 4, 5), dtype=np.uint8), [0, 10], [1, 1])
    colour = Frames(rng.integers(0, 256, (2, 4, 5, 3), dtype=np.uint8), [0, 10], [1, 1])
    np.testing.assert_array_equal(network_images(grey, 1)[:, 0], grey.grey())
    np.testing.assert_array_equal(network_images(grey, 3), np.repeat(grey.grey()[:, None], 3, 1))
    np.testing.assert_array_equal(network_images(colour, 1)[:, 0], colour.grey())
    np.testing.assert_array_equal(network_images(colour, 3), np.moveaxis(colour.linear(), -1, 1))
    with pytest.raises(FormatError, match="frames/images"):
        network_images(grey, 2)


def test_count_stage1_runs_once_per_window_and_gives_the_two_pass_events():
    """Exposure windows (not the interval ones): per batch stage 1 runs once on the deblur
    windows and once on the interval windows (the old code decided events in a second
    pass of each: 4 calls); voxels, events and frames equal the two-pass reference."""
    from rdnet.deblur.pipeline import _to_events, iter_deblur, window_voxels
    from rdnet.events.voxel_config import VoxelConfig
    from rdnet.nn.decision import decided_events, decision_dict
    rng = np.random.default_rng(4)
    W, H, n, bins = 16, 12, 3, 3
    net = build_model("rdnet", "tiny", 1, bins, restore_output="counts", width=4)
    g = torch.Generator().manual_seed(2)
    with torch.no_grad():
        for p in net.parameters():                     # random: a fresh stage 1 is the identity
            p.copy_(0.3 * torch.randn(p.shape, generator=g))
    net.eval()
    t = np.array([10_000, 20_000, 30_000], np.int64)
    a = np.empty(4000, EVENT_DTYPE)
    a["t"] = np.sort(rng.integers(5_000, 35_000, a.size))
    a["x"], a["y"], a["p"] = rng.integers(0, W, a.size), rng.integers(0, H, a.size), rng.integers(0, 2, a.size)
    events = Events(a, W, H)
    frames = Frames(rng.random((n, H, W)).astype(np.float32), t, np.full(n, 4_000, np.int64))
    images = frames.grey()[:, None]
    dw, ew = exposure_windows(frames), interval_windows(frames)
    voxel, decision = VoxelConfig(bins=bins), decision_dict(0.4)
    calls = []
    hook = net.restore.register_forward_hook(lambda *args: calls.append(1))
    batches = list(iter_deblur(net, images, events, dw, ew, voxel, batch_size=2, decision=decision))
    hook.remove()
    assert len(batches) == 2 and len(calls) == 4
    for b in batches:
        idx, img = b.index, torch.from_numpy(images[b.index])
        ref = {}
        for name, win in (("deblur", dw), ("events", ew)):
            grids, ones = window_voxels(events, win, idx, voxel, H, W, split=True)
            ref[name] = _to_events(decided_events(net.restore, img, torch.from_numpy(grids.astype(np.float32)),
                                                  decision), ones, win, idx, voxel.mode, events)
            if name == "events":
                g2 = grids.reshape(len(idx), 2, bins, H, W)
                np.testing.assert_array_equal(b.raw_voxel, g2[:, 0] - g2[:, 1])
                restored, _ = run_rdnet(net, images[idx], grids, torch.device("cpu"), restore_only=True)
                np.testing.assert_array_equal(b.restored_voxel, restored)
            else:
                _, sharp = run_rdnet(net, images[idx], grids, torch.device("cpu"))
                np.testing.assert_array_equal(b.deblurred, np.clip(sharp, 0.0, 1.0))
        assert len(b.events) > 0 and len(b.deblur_events) > 0
        np.testing.assert_array_equal(b.events.array, ref["events"].array)
        np.testing.assert_array_equal(b.deblur_events.array, ref["deblur"].array)
