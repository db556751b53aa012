"""The frame-pair restorer (task restore_frames, rdnet.nn.guide): its guide image has known
values, it trains and stores its guide, and ``rdnet restore`` cuts its windows at the
frames and hands each window its two frames, passing the events no pair brackets."""
import json

import numpy as np
import pytest
import torch

from rdnet.errors import ConfigError, FormatError, ModelNotFoundError, ValidationError
from rdnet.events import Events, Frames, Recording
from rdnet.nn.decision import decision_dict
from rdnet.nn.guide import FramePairGuide
from rdnet.restore.learned import load_restorer
from rdnet.restore.stream import windows
from rdnet.train.checkpoint import make_checkpoint, read_checkpoint, save_checkpoint
from rdnet.train.config import ModelConfig, TrainConfig
from rdnet.train.data import PairsDataset
from rdnet.train.loop import build_seeded, train
from rdnet.train.synthetic import write_synthetic_pairs

torch.set_num_threads(1)
GUIDE = FramePairGuide(log_eps=0.01, threshold=0.2)
W, H = 20, 12


def test_guide_image_is_the_first_frame_and_the_log_change_over_the_threshold():
    first = np.full((1, 2, 3), 0.5, np.float32)
    last = ((0.5 + 0.01) * np.exp(0.4) - 0.01) * np.ones((1, 2, 3), np.float32)   # log rise 0.4 = 2 thresholds
    im = GUIDE.image(first, last)
    assert im.shape == (2, 2, 3) and im.dtype == np.float32
    np.testing.assert_array_equal(im[0], first[0])
    np.testing.assert_allclose(im[1], 2.0, rtol=1e-5)
    np.testing.assert_allclose(GUIDE.image(last, first)[1], -2.0, rtol=1e-5)     # falling: OFF
    colour = GUIDE.image(np.repeat(first, 3, 0), np.repeat(last, 3, 0))          # change on the luminance
    assert colour.shape == (4, 2, 3)
    np.testing.assert_allclose(colour[3], 2.0, rtol=1e-5)
    with pytest.raises(ValidationError, match="frames"):
        GUIDE.image(first, last[:, :1])


def test_guide_round_trips_and_bad_guides_name_the_key():
    assert FramePairGuide.from_dict(GUIDE.to_dict()) == GUIDE
    assert FramePairGuide.from_dict(None) is None and FramePairGuide.from_dict({"kind": "blurry"}) is None
    with pytest.raises(ValidationError, match="guide.kind"):
        FramePairGuide.from_dict({"kind": "stereo"})
    with pytest.raises(ValidationError, match="guide.gamma"):
        FramePairGuide.from_dict({**GUIDE.to_dict(), "gamma": 2.2})
    with pytest.raises(ValidationError, match="guide.threshold"):
        FramePairGuide(0.01, 0.0)


def test_windows_end_at_the_cuts_inside_the_frames():
    t = np.array([0, 5, 10, 35, 45, 60, 79, 101, 130, 170])
    ev = Events.from_columns(t, np.zeros(10, int), np.zeros(10, int), np.ones(10, int), 4, 4)
    out = list(windows(iter([ev[:4], ev[4:]]), 20, cuts=[50, 75, 100]))
    bounds = [(a, b) for a, b, _ in out]
    # from the first event in steps of 20 up to the first cut, cut to cut, then steps of 20
    assert bounds == [(0, 20), (20, 40), (40, 50), (50, 75), (75, 100), (100, 120), (120, 140),
                      (140, 160), (160, 180)]
    assert sum(len(e) for _, _, e in out) == 10
    assert [e.t.tolist() for _, _, e in out][2:5] == [[45], [60], [79]]
    plain = [(a, b) for a, b, _ in windows(iter([ev]), 20)]
    assert plain == [(a, b) for a, b, _ in windows(iter([ev]), 20, cuts=[])] and plain[-1] == (160, 180)


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    return write_synthetic_pairs(tmp_path_factory.mktemp("p") / "train.h5", n=10, bins=3, height=24, width=24,
                                 seed=4)


def test_dataset_builds_the_guide_after_the_flips(pairs, tmp_path, pairs_copier):
    import h5py
    with h5py.File(pairs) as f:
        first, last = f["frame_first"][3], f["frame_last"][3]
    plain = PairsDataset(pairs)[3]
    assert "guide" not in plain
    s = PairsDataset(pairs, guide=GUIDE)[3]
    np.testing.assert_allclose(s["guide"].numpy(), GUIDE.image(first, last), rtol=1e-6)
    flipped = PairsDataset(pairs, guide=GUIDE, augment=True, seed=0)
    for epoch in range(8):          # some draw flips: the guide flips with the voxels
        d = flipped[(3, epoch)]
        ref = GUIDE.image(first, last)
        ref = ref[:, :, ::-1] if torch.equal(d["blurry"], plain["blurry"].flip(-1)) else ref
        ref = ref[:, ::-1, :] if torch.equal(d["blurry"], plain["blurry"].flip(-2)) else ref
        ref = ref[:, ::-1, ::-1] if torch.equal(d["blurry"], plain["blurry"].flip(-1, -2)) else ref
        np.testing.assert_allclose(d["guide"].numpy(), ref, rtol=1e-6)
    import h5py
    old = pairs_copier(pairs, tmp_path / "old.h5")
    with h5py.File(old, "a") as f:        # written before the blur step kept the window frames
        del f["frame_first"], f["frame_last"]
    assert PairsDataset(old)[0]["blurry"].shape == (1, 24, 24)
    with pytest.raises(FormatError, match=r"old\.h5.*frame_first.*rerun the blur step"):
        PairsDataset(old, guide=GUIDE)


def test_restore_frames_trains_and_stores_its_guide(pairs, tmp_path):
    cfg = TrainConfig(iterations=4, batch_size=4, crop=16, device="cpu", log_every=2, ckpt_every=100,
                      dvclive=False, seed=1, restore_output="counts", val_sequences=2)
    tiny = ModelConfig(size="tiny", width=4)
    path = train("restore_frames", cfg, tiny, pairs, tmp_path / "f", progress=False, guide=GUIDE)
    ck = read_checkpoint(path)
    assert ck["model_args"]["image_channels"] == 2 and ck["extra"]["guide"] == GUIDE.to_dict()
    assert 0 < ck["extra"]["decision"]["threshold"] <= 1
    # scored as the restoration stage scores it: the guide read from the checkpoint, the same
    # restored voxels as the network run on the dataset's guide images
    from rdnet.eval.predict import predict
    from rdnet.train.checkpoint import load_model
    pr = predict("restore", path, pairs, events_out=True, batch_size=3)
    assert pr["restored_counts"].shape == (10, 2, 3, 24, 24)
    net = load_model(path, "restore")
    ds = PairsDataset(pairs, guide=GUIDE)
    with torch.no_grad():
        expected = net.signed(net(torch.stack([ds[i]["guide"] for i in range(10)]),
                                  torch.stack([ds[i]["counts_degraded"] for i in range(10)])))
    np.testing.assert_allclose(pr["restored"], expected.numpy(), rtol=1e-5, atol=1e-6)
    with pytest.raises(ConfigError, match="guide"):
        train("restore_frames", cfg, tiny, pairs, tmp_path / "g", progress=False)
    with pytest.raises(ConfigError, match="guide"):
        train("restore", cfg, tiny, pairs, tmp_path / "h", progress=False, guide=GUIDE)


def _identity_frames_checkpoint(path):
    """An untrained count RestoreNet (identity start, threshold 0.5) with the frame-pair guide."""
    args = {"kind": "restore", "size": "tiny", "image_channels": 2, "bins": 3, "width": 4,
            "restore_output": "counts"}
    extra = {"voxel": {"bins": 3, "mode": "hard", "normalize": None}, "window_us": 30000,
             "decision": decision_dict(0.5), "guide": GUIDE.to_dict()}
    save_checkpoint(path, make_checkpoint(build_seeded(args, 0), "restore", args, step=1, extra=extra,
                                          with_rng=False))
    return path


def test_frame_pair_restorer_needs_both_frames(tmp_path):
    params = {"voxel": {"bins": 3, "mode": "hard", "normalize": None}}
    path = _identity_frames_checkpoint(tmp_path / "f.pt")
    with pytest.raises(ConfigError, match=r"f\.pt.*image_channels.*needs frames"):
        load_restorer(path, has_frames=False, params=params)
    r = load_restorer(path, has_frames=True, params=params)
    assert (r.name, r.frame_pairs, r.info["guide"]["kind"]) == ("rdnet-frames", True, "frame_pair")
    rng = np.random.default_rng(0)
    ev = Events.from_columns(np.sort(rng.integers(0, 30000, 200)), rng.integers(0, W, 200), rng.integers(0, H, 200),
                             rng.integers(0, 2, 200), W, H, sort=True)
    frame = np.full((H, W), 100, np.uint8)
    np.testing.assert_array_equal(r.restore(ev, 0, 30000, (frame, frame)).array, ev.array)   # identity start
    np.testing.assert_array_equal(r.restore(ev, 0, 30000, None).array, ev.array)              # no pair: as is
    with pytest.raises(ValidationError, match="two frames"):
        r.restore(ev, 0, 30000, (frame,))


def test_rdnet_restore_cuts_windows_at_the_frames(tmp_path):
    from rdnet.events.io import save
    from rdnet.restore.run import restore_recording

    rng = np.random.default_rng(1)
    n = 3000
    ev = Events.from_columns(np.sort(rng.integers(0, 200_000, n)), rng.integers(0, W, n), rng.integers(0, H, n),
                             rng.integers(0, 2, n), W, H, sort=True)
    t = np.array([30_000, 70_000, 110_000, 150_000], np.int64)
    frames = Frames(rng.integers(20, 230, (4, H, W)).astype(np.uint8), t, np.full(4, 1000, np.int64))
    rec = tmp_path / "rec.h5"
    save(rec, Recording(W, H, events=ev, frames=frames, sensor="TEST"))
    params = {"voxel": {"bins": 3, "mode": "hard", "normalize": None}}
    ck = _identity_frames_checkpoint(tmp_path / "f.pt")
    res = restore_recording(rec, tmp_path / "out.h5", params, method="rdnet", checkpoint=ck, progress=False)
    outside = int(((ev.t < t[0]) | (ev.t >= t[-1])).sum())
    assert res["method"] == "rdnet-frames" and res["window_us"] == "frame intervals"
    assert res["events_outside_frame_pairs"] == outside > 0
    assert res["events_in"] == res["events_out"] == n and res["events_not_recorded"] == 0   # identity start
    assert any("passed unrestored" in note for note in res["notes"])
    model = json.loads((tmp_path / "out.json").read_text())["model"]
    assert model["guide"]["kind"] == "frame_pair" and model["window_us"] == "frame intervals"


def test_restore_guide_picks_the_frame_pair_restorer_for_recordings_with_frames(tmp_path, monkeypatch):
    """restore.guide (no --checkpoint): frame_pair takes the study's models/restore_frames on a
    recording with frames, the events-only restorer without frames; auto takes it when
    restore.guide_threshold is set, the blurry-frame one otherwise; a bad value names the key."""
    from rdnet.restore import learned
    from rdnet.restore.base import get_restorer
    from rdnet.restore.learned import export_restorer
    from rdnet.restore.settings import RestoreConfig
    params = {"voxel": {"bins": 3, "mode": "hard", "normalize": None}}
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(learned, "_package_file", lambda name: None)       # no packaged models
    _identity_frames_checkpoint((tmp_path / "models" / "restore_frames" / "seed0").mkdir(parents=True)
                                or tmp_path / "models" / "restore_frames" / "seed0" / "model.pt")
    r = get_restorer("rdnet", {**params, "restore": {"guide": "frame_pair"}}, None, has_frames=True)
    assert r.name == "rdnet-frames" and r.source.startswith("study model models/restore_frames")
    with pytest.raises(ModelNotFoundError, match="restore_image"):   # auto, no threshold: the blurry-frame model
        get_restorer("rdnet", params, None, has_frames=True)
    with pytest.raises(ModelNotFoundError, match="restore_image"):   # frame: the same, absent here
        get_restorer("rdnet", {**params, "restore": {"guide": "frame", "guide_threshold": 0.4}}, None,
                     has_frames=True)
    # auto with the camera's threshold known (as --calibration sets it): the frame-pair one at that threshold
    r = get_restorer("rdnet", {**params, "restore": {"guide_threshold": 0.4}}, None, has_frames=True)
    assert r.name == "rdnet-frames" and r.guide.threshold == 0.4 and r.trained_threshold == 0.2
    with pytest.raises(ModelNotFoundError, match="restore_events"):  # no frames: events-only, absent here
        get_restorer("rdnet", {**params, "restore": {"guide": "frame_pair"}}, None, has_frames=False)
    with pytest.raises(ConfigError, match="restore.guide"):
        RestoreConfig(guide="stereo")
    out = export_restorer(tmp_path / "models" / "restore_frames", tmp_path / "pkg", kind="frame_pair")
    assert out.name == "restore_frames.pt"
    with pytest.raises(ConfigError, match="extra.guide"):
        export_restorer(tmp_path / "models" / "restore_frames", tmp_path / "pkg", kind="frame")


def test_guide_threshold_sets_the_cameras_threshold_and_calibration_sets_the_fitted_one(tmp_path):
    """restore.guide_threshold replaces the threshold a frame-pair guide divides by (the change
    channel scales by trained / camera threshold, the frame channel stays); OUT.json says both;
    the blurry-frame and events-only restorers ignore it; --calibration sets the mean of the
    fitted ON and OFF thresholds."""
    from rdnet.restore.settings import RestoreConfig, calibrated_restore
    from rdnet.sim.settings import DegradeConfig, SensorConfig
    params = {"voxel": {"bins": 3, "mode": "hard", "normalize": None}}
    path = _identity_frames_checkpoint(tmp_path / "f.pt")
    trained = load_restorer(path, has_frames=True, params=params)
    camera = load_restorer(path, has_frames=True, params=params, guide_threshold=0.5)
    assert trained.guide.threshold == 0.2 and camera.guide.threshold == 0.5
    assert camera.info["guide"] == {**GUIDE.to_dict(), "threshold": 0.5, "threshold_trained": 0.2}
    assert trained.info["guide"]["threshold_trained"] == 0.2
    rng = np.random.default_rng(3)
    f0, f1 = (rng.integers(10, 250, (H, W)).astype(np.uint8) for _ in range(2))
    a, b = trained._image((f0, f1), H, W), camera._image((f0, f1), H, W)
    np.testing.assert_array_equal(a[0, 0], b[0, 0])
    np.testing.assert_allclose(b[0, 1], a[0, 1] * 0.2 / 0.5, rtol=1e-5, atol=1e-6)
    assert np.abs(a[0, 1]).max() > 1              # the frames do change
    same = load_restorer(path, has_frames=True, params=params, guide_threshold=0.2)
    assert same.trained_threshold is None and same.info["guide"]["threshold"] == 0.2
    for bad in (0.0, -0.3, 1e-4, 20.0):
        with pytest.raises(ConfigError, match="restore.guide_threshold"):
            RestoreConfig(guide_threshold=bad)
    fitted = calibrated_restore(SensorConfig(threshold_on=0.4, threshold_off=0.3), DegradeConfig(latency_us=7000.0))
    assert fitted == {"latency_us": 7000.0, "guide_threshold": pytest.approx(0.35)}
