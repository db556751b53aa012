"""PairsDataset: lazy reading, crops and flips consistent across images and voxels,
reproducible draws, step sampling and sharding."""
import pickle

import h5py
import numpy as np
import pytest
import torch

from rdnet.errors import ConfigError, FormatError
from rdnet.train.data import PairsDataset, StepSampler, check_finite, draw_augment, split_rows, step_indices
from rdnet.train.synthetic import write_synthetic_pairs


@pytest.fixture(scope="module")
def pairs(tmp_path_factory):
    return write_synthetic_pairs(tmp_path_factory.mktemp("pairs") / "train.h5", n=6, channels=3,
                                 bins=4, height=20, width=28, seed=1)


def full(path, i):
    with h5py.File(path, "r") as f:
        return {k: np.asarray(f[k][i]) for k in ("blurry", "sharp", "voxel_undegraded", "voxel_degraded")}


def test_full_frame_sample_equals_file(pairs):
    ds = PairsDataset(pairs, events="undegraded")
    s = ds[2]
    ref = full(pairs, 2)
    for k, v in ref.items():
        assert torch.equal(s[k], torch.from_numpy(v))
    assert torch.equal(s["voxel"], s["voxel_undegraded"])
    assert s["index"].item() == 2 and s["index"].dtype == torch.int64
    with h5py.File(pairs, "r") as f:
        assert s["level"].item() == float(f["level"][2])


def test_crop_and_flips_consistent_across_fields(pairs):
    ds = PairsDataset(pairs, events="degraded", crop=8, augment=True, seed=5)
    seen_flips = set()
    for epoch in range(12):
        key = (3, epoch)
        s = ds[key]
        y0, x0, ch, cw, fh, fv = draw_augment(5, epoch, 3, 20, 28, 8, True)
        seen_flips.add((fh, fv))
        ref = full(pairs, 3)
        for k, v in ref.items():
            w = v[:, y0:y0 + ch, x0:x0 + cw]
            if fh:
                w = w[:, :, ::-1]
            if fv:
                w = w[:, ::-1, :]
            # the same window and flips everywhere; flipping keeps polarity (no negation)
            assert np.array_equal(s[k].numpy(), w), k
            assert s[k].shape[-2:] == (8, 8)
        assert torch.equal(s["voxel"], s["voxel_degraded"])
    assert len(seen_flips) >= 3  # flips actually vary with the epoch


def test_draws_are_reproducible_and_depend_on_seed(pairs):
    a = PairsDataset(pairs, crop=8, augment=True, seed=0)
    b = PairsDataset(pairs, crop=8, augment=True, seed=0)
    c = PairsDataset(pairs, crop=8, augment=True, seed=1)
    assert all(torch.equal(a[(i, 2)]["blurry"], b[(i, 2)]["blurry"]) for i in range(6))
    assert any(not torch.equal(a[(i, 2)]["blurry"], c[(i, 2)]["blurry"]) for i in range(6))


def test_file_is_opened_lazily_and_dataset_pickles(pairs):
    ds = PairsDataset(pairs, crop=8)
    assert ds._file is None            # __init__ only checks the layout
    first = ds[1]["sharp"]
    assert ds._file is not None
    clone = pickle.loads(pickle.dumps(ds))  # what a spawned worker receives
    assert clone._file is None
    assert torch.equal(clone[1]["sharp"], first)
    ds.close()


def _samples(ds, keys):
    return [{k: v.clone() for k, v in ds[key].items()} for key in keys]


@pytest.mark.parametrize("rows", [None, [4, 1, 5]])
def test_preloaded_samples_equal_the_file_reads(pairs, monkeypatch, rows):
    """In memory (the default for a small file) or read from the file per sample, a
    dataset serves the same bytes: crops, flips, a subset of rows, per-polarity counts."""
    import rdnet.train.data as data
    keys = [(i, e) for i in range(3 if rows else 6) for e in range(3)]
    preloaded = PairsDataset(pairs, crop=8, augment=True, seed=3, rows=rows)
    a = _samples(preloaded, keys)
    assert isinstance(preloaded._arrays, dict)
    assert preloaded._arrays["blurry"].shape[0] == (3 if rows else 6)      # only its rows
    monkeypatch.setattr(data, "PRELOAD_MAX_BYTES", 0)
    from_file = PairsDataset(pairs, crop=8, augment=True, seed=3, rows=rows)
    b = _samples(from_file, keys)
    assert not isinstance(from_file._arrays, dict)
    assert a[0].keys() == b[0].keys() and "counts_degraded" in a[0]
    for x, y in zip(a, b):
        for k in x:
            assert torch.equal(x[k], y[k]), k


def test_a_sample_edited_in_place_leaves_the_preloaded_rows_alone(pairs):
    ds = PairsDataset(pairs, crop=None)                 # a full frame: the row itself, if not copied
    s = ds[1]
    before = s["voxel_degraded"].clone()
    for v in s.values():
        v.zero_()
    assert torch.equal(ds[1]["voxel_degraded"], before) and before.abs().sum() > 0
    state = pickle.loads(pickle.dumps(ds)).__dict__     # workers get no copy of the arrays
    assert state["_arrays"] is None and state["_at"] is None


def test_layout_errors_name_file_and_field(tmp_path, pairs):
    bad = tmp_path / "bad.h5"
    with h5py.File(pairs, "r") as src, h5py.File(bad, "w") as dst:
        for k in ("blurry", "sharp", "voxel_undegraded", "level"):
            src.copy(k, dst)
    with pytest.raises(FormatError, match="voxel_degraded.*missing"):
        PairsDataset(bad)
    with pytest.raises(FormatError, match="not found"):
        PairsDataset(tmp_path / "nope.h5")
    (tmp_path / "junk.h5").write_bytes(b"not hdf5")
    with pytest.raises(FormatError, match="HDF5"):
        PairsDataset(tmp_path / "junk.h5")
    with pytest.raises(ConfigError, match="train.crop"):
        PairsDataset(pairs, crop=21)
    with pytest.raises(ConfigError, match="events"):
        PairsDataset(pairs, events="ideal")


@pytest.mark.parametrize("name", ["blurry", "level", "voxel_degraded_on", "sequence"])
def test_a_dataset_that_is_a_group_names_file_and_dataset(tmp_path, pairs, name, pairs_copier):
    bad = pairs_copier(pairs, tmp_path / "group.h5", replace=[name])
    with pytest.raises(FormatError) as e:
        split_rows(bad, 1)              # the layout check, then the held-out sequences
    assert str(e.value) == f"{bad}: field '{name}': is an HDF5 group, expected a dataset"


@pytest.mark.parametrize("chunk_bytes", [None, 1])   # one read per dataset / one row per read
def test_check_finite_names_the_dataset_and_first_bad_index(tmp_path, pairs, chunk_bytes, pairs_copier):
    check_finite(pairs, chunk_bytes=chunk_bytes)     # a clean file passes
    for name, idx, value in [("voxel_degraded", (4, 1, 2, 5), np.nan), ("sharp", (2, 2, 19, 27), -np.inf),
                             ("level", (3,), np.inf)]:
        bad = pairs_copier(pairs, tmp_path / f"{name}.h5")
        with h5py.File(bad, "r+") as f:
            f[name][idx] = value
            if name != "level":                  # a later bad value is not the one reported
                f[name][5, 0, 0, 0] = np.nan
        where = idx[0] if len(idx) == 1 else idx
        with pytest.raises(FormatError) as e:
            check_finite(bad, chunk_bytes=chunk_bytes)
        assert str(e.value) == f"{bad}: field '{name}': holds NaN or inf values (first at index {where})"


def test_step_indices_visit_every_row_once_per_epoch():
    n, b = 7, 3
    keys = [k for s in range(7) for k in step_indices(11, s, b, n)]  # 21 draws = 3 epochs
    for e in range(3):
        rows = sorted(i for i, ep in keys if ep == e)
        assert rows == list(range(n))
    assert step_indices(11, 4, b, n) == step_indices(11, 4, b, n)
    assert step_indices(11, 0, b, n) != step_indices(12, 0, b, n)


def test_step_sampler_shards_union_is_the_global_batch():
    single = list(StepSampler(10, 4, 3, start_step=2, stop_step=5))
    r0 = list(StepSampler(10, 4, 3, 2, 5, rank=0, world_size=2))
    r1 = list(StepSampler(10, 4, 3, 2, 5, rank=1, world_size=2))
    assert len(single) == 12 and len(r0) == len(r1) == 6
    for s in range(3):
        assert single[4 * s:4 * s + 4] == r0[2 * s:2 * s + 2] + r1[2 * s:2 * s + 2]
    # resuming at step 3 gives the tail of the uninterrupted sequence
    assert list(StepSampler(10, 4, 3, 3, 5)) == single[4:]
    with pytest.raises(ConfigError, match="batch_size"):
        StepSampler(10, 5, 0, 0, 1, rank=0, world_size=2)
