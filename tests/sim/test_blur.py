"""GOPRO-style blur pairs and the pairs file (rdnet.sim.blur)."""
import pickle

import h5py
import numpy as np
import pytest

from rdnet.config import from_dict
from rdnet.errors import ConfigError, FormatError, ValidationError
from rdnet.events import Events, Frames
from rdnet.sim.blur import (DEGRADE_KEYS, POLARITY_KEYS, BlurConfig, PairsFile, blur_windows, make_samples,
                            read_pairs, write_pairs)
from rdnet.sim.settings import DegradeConfig

H, W, N = 12, 10, 60


def _data(color=False, seed=0):
    rng = np.random.default_rng(seed)
    shape = (N, H, W, 3) if color else (N, H, W)
    frames = Frames(rng.random(shape, dtype=np.float32), np.arange(N) * 4167, np.zeros(N, np.int64))
    def ev(n):
        t = np.sort(rng.integers(0, N * 4167, n))
        t[:5] = frames.t_us[[0, 7, 8, 12, 20]]       # events exactly on frame times (window edges)
        return Events.from_columns(t, rng.integers(0, W, n), rng.integers(0, H, n), rng.integers(0, 2, n),
                                   W, H, sort=True)
    return frames, ev(5000), ev(7000)


@pytest.mark.parametrize("color", [False, True])
def test_blurry_is_mean_of_window_and_sharp_is_middle(color):
    frames, ideal, degr = _data(color)
    s = make_samples(frames, ideal, degr, BlurConfig(), bins=5, rng=np.random.default_rng(1))
    c = 3 if color else 1
    n = s["blurry"].shape[0]
    assert n >= 4 and s["blurry"].shape == (n, c, H, W) and s["sharp"].shape == (n, c, H, W)
    assert s["voxel_degraded"].shape == (n, 5, H, W) and s["blurry"].dtype == np.float32
    prev_end = -1
    for j in range(n):
        i0 = int(np.searchsorted(frames.t_us, s["t0_us"][j]))
        i1 = int(np.searchsorted(frames.t_us, s["t0_us"][j] + s["duration_us"][j]))
        k = i1 - i0 + 1
        assert k % 2 == 1 and 7 <= k <= 13 and i0 == prev_end + 1       # back to back, odd count
        prev_end = i1
        chunk = frames.images[i0:i1 + 1]
        mean = chunk.mean(0) if not color else np.moveaxis(chunk.mean(0), -1, 0)
        mid = chunk[k // 2] if not color else np.moveaxis(chunk[k // 2], -1, 0)
        np.testing.assert_allclose(s["blurry"][j].reshape(mean.shape), mean, atol=1e-6)
        np.testing.assert_array_equal(s["sharp"][j].reshape(mid.shape), mid)


def test_voxel_sums_equal_signed_event_counts():
    frames, ideal, degr = _data()
    s = make_samples(frames, ideal, degr, BlurConfig(min_frames=7, max_frames=9), bins=10,
                     rng=np.random.default_rng(2))
    for j in range(len(s["t0_us"])):
        t0, t1 = s["t0_us"][j], s["t0_us"][j] + s["duration_us"][j]
        for key, ev in (("voxel_undegraded", ideal), ("voxel_degraded", degr)):
            keep = (ev.t >= t0) & (ev.t <= t1)                      # inclusive window
            expect = ev.select(keep).signed_count_per_pixel()
            np.testing.assert_array_equal(s[key][j].sum(0), expect)
    assert np.all(s["level"] > 0)                                     # ideal != degraded
    assert set(s["degrade"]) == set(DEGRADE_KEYS) and np.isnan(s["degrade"]["jitter_us"]).all()


def test_windows_gap_max_samples_and_config():
    rng = np.random.default_rng(0)
    w = blur_windows(100, BlurConfig(min_frames=3, max_frames=3, gap_frames=2, max_samples=5), rng)
    assert w == [(0, 3), (5, 3), (10, 3), (15, 3), (20, 3)]
    assert blur_windows(6, BlurConfig(), rng) == []
    with pytest.raises(ConfigError, match="blur.max_frames"):
        BlurConfig(min_frames=8, max_frames=8)
    with pytest.raises(ConfigError, match="blur.max_frames"):
        BlurConfig(min_frames=9, max_frames=7)
    with pytest.raises(ConfigError, match="blur.stride"):
        from_dict(BlurConfig, {"stride": 1}, "blur")


def test_pairs_file_round_trip(tmp_path):
    frames, ideal, degr = _data(color=True)
    dg = DegradeConfig(refractory_us=300.0, jitter_us=20.0)
    parts = [make_samples(frames, ideal, degr, BlurConfig(), 4, np.random.default_rng(i), sequence=i,
                          degrade=dg, level=0.5 * i) for i in range(2)]
    path = tmp_path / "pairs" / "train.h5"
    write_pairs(path, parts, {"bins": 4, "voxel_mode": "hard", "channels": 3, "split": "train"})
    assert sorted(p.name for p in path.parent.iterdir()) == ["train.h5"]     # no temp left
    with h5py.File(path) as f:      # DATA.md layout
        assert f["blurry"].dtype == np.float32 and f["sequence"].dtype == np.int32
        assert f["t0_us"].dtype == np.int64 and f["level"].dtype == np.float64
        assert f["degrade/refractory_us"].dtype == np.float64
        assert f.attrs["split"] == "train" and f.attrs["bins"] == 4
    ds = read_pairs(path)
    n0 = parts[0]["blurry"].shape[0]
    assert len(ds) == n0 + parts[1]["blurry"].shape[0]
    ds = pickle.loads(pickle.dumps(ds))       # as a DataLoader worker gets it
    for i, (p, r) in enumerate([(0, 0), (0, n0 - 1), (1, 0)]):
        row = ds[r + (n0 if p else 0)]
        for k in ("blurry", "sharp", "voxel_undegraded", "voxel_degraded", "t0_us", "duration_us"):
            np.testing.assert_array_equal(row[k], parts[p][k][r])
        assert row["sequence"] == p and row["level"] == 0.5 * p
        assert row["degrade"]["refractory_us"] == 300.0 and row["degrade"]["leak_hz"] == 0.0
    np.testing.assert_array_equal(ds.column("sequence"), np.repeat([0, 1], [n0, len(ds) - n0]))
    with pytest.raises(IndexError):
        ds[len(ds)]
    ds.close()


def test_pairs_errors(tmp_path):
    frames, ideal, degr = _data()
    s = make_samples(frames, ideal, degr, BlurConfig(), 4, np.random.default_rng(0))
    with pytest.raises(ValidationError, match="attrs"):
        write_pairs(tmp_path / "a.h5", [s], {"bins": 4})
    with pytest.raises(ValidationError, match="voxel_undegraded"):      # wrong bins
        write_pairs(tmp_path / "a.h5", [s], {"bins": 5, "voxel_mode": "hard", "channels": 1, "split": "x"})
    assert list(tmp_path.iterdir()) == []                               # nothing half-written
    with pytest.raises(FormatError, match="not found"):
        read_pairs(tmp_path / "missing.h5")
    bad = tmp_path / "bad.h5"
    with h5py.File(bad, "w") as f:
        f["blurry"] = np.zeros((1, 1, 2, 2), np.float32)
    with pytest.raises(FormatError, match="sharp"):
        read_pairs(bad)
    (tmp_path / "junk.h5").write_text("not hdf5")
    with pytest.raises(FormatError):
        PairsFile(tmp_path / "junk.h5")
    with pytest.raises(ValidationError):
        make_samples(frames, Events.empty(W + 1, H), degr, BlurConfig(), 4, np.random.default_rng(0))


def test_per_polarity_voxels_count_on_and_off_and_old_files_stay_readable(tmp_path):
    frames, ideal, degr = _data()
    s = make_samples(frames, ideal, degr, BlurConfig(min_frames=7, max_frames=9), bins=4,
                     rng=np.random.default_rng(3))
    for j in range(len(s["t0_us"])):
        t0, t1 = s["t0_us"][j], s["t0_us"][j] + s["duration_us"][j]
        for kind, ev in (("undegraded", ideal), ("degraded", degr)):
            inside = ev.select((ev.t >= t0) & (ev.t <= t1))
            np.testing.assert_array_equal(s[f"voxel_{kind}_on"][j].sum(0), inside.count_per_pixel(1))
            np.testing.assert_array_equal(s[f"voxel_{kind}_off"][j].sum(0), inside.count_per_pixel(0))
            np.testing.assert_array_equal(s[f"voxel_{kind}"][j],
                                          s[f"voxel_{kind}_on"][j] - s[f"voxel_{kind}_off"][j])
    attrs = {"bins": 4, "voxel_mode": "hard", "channels": 1, "split": "train"}
    ds = read_pairs(write_pairs(tmp_path / "new.h5", [s], attrs))
    np.testing.assert_array_equal(ds[1]["voxel_degraded_off"], s["voxel_degraded_off"][1])
    old = {k: v for k, v in s.items() if k not in POLARITY_KEYS}     # a file written before them
    ds = read_pairs(write_pairs(tmp_path / "old.h5", [old], attrs))
    assert "voxel_degraded_on" not in ds[0] and ds[0]["voxel_degraded"].shape == (4, H, W)
    part = dict(old, voxel_degraded_on=s["voxel_degraded_on"])
    with pytest.raises(ValidationError, match="incomplete"):
        write_pairs(tmp_path / "part.h5", [part], attrs)


def test_files_written_before_the_cutoff_floor_read_its_default(tmp_path):
    frames, ideal, degr = _data()
    s = make_samples(frames, ideal, degr, BlurConfig(), 4, np.random.default_rng(0),
                     degrade=DegradeConfig(cutoff_hz=50.0, cutoff_floor=0.02))
    attrs = {"bins": 4, "voxel_mode": "hard", "channels": 1, "split": "train"}
    path = write_pairs(tmp_path / "new.h5", [s], attrs)
    assert read_pairs(path)[0]["degrade"]["cutoff_floor"] == 0.02
    with h5py.File(path, "a") as f:                  # as a file from before the key existed
        del f["degrade/cutoff_floor"]
        del f["degrade/leak_hz"]
    with pytest.raises(FormatError, match="degrade/leak_hz"):     # other keys stay required
        read_pairs(path)
    path = write_pairs(tmp_path / "old.h5", [s], attrs)
    with h5py.File(path, "a") as f:
        del f["degrade/cutoff_floor"]
    row = read_pairs(path)[0]["degrade"]
    assert row["cutoff_floor"] == DegradeConfig().cutoff_floor and row["cutoff_hz"] == 50.0
