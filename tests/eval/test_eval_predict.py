"""evaluate_row / predict over a pairs file: known values from identity networks (fresh
residual stages output their input exactly), voxel transforms, breakdowns, errors."""
import h5py
import numpy as np
import pytest

from rdnet.errors import ConfigError, FormatError
from rdnet.eval.metrics import evaluate_images, restoration_metrics
from rdnet.eval.predict import evaluate_row, predict
from rdnet.nn.models import build_model
from rdnet.train.checkpoint import make_checkpoint, save_checkpoint
from rdnet.train.synthetic import write_synthetic_pairs


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    d = tmp_path_factory.mktemp("eval")
    pairs = write_synthetic_pairs(d / "test.h5", n=5, channels=3, bins=3, height=20, width=24, seed=7)
    ckpts = {}
    for kind in ("deblur", "rdnet", "restore", "image_only"):
        args = {"kind": kind, "size": "tiny", "image_channels": 3, "bins": 3, "width": 4}
        net = build_model(**args)          # fresh: exactly the identity on its receiving input
        ckpts[kind] = save_checkpoint(d / f"{kind}.pt", make_checkpoint(net, kind, args))
    with h5py.File(pairs, "r") as f:
        arrays = {k: np.asarray(f[k]) for k in ("blurry", "sharp", "voxel_undegraded", "voxel_degraded", "level")}
    return pairs, ckpts, arrays


def test_blurry_row_and_identity_networks_give_the_blurry_scores(setup):
    pairs, ckpts, a = setup
    ref = evaluate_images(a["blurry"], a["sharp"])
    blurry = evaluate_row("blurry", None, pairs, device="cpu")
    assert blurry["psnr"] == pytest.approx(ref["psnr"]) and blurry["ssim"] == pytest.approx(ref["ssim"])
    assert blurry["per_sample"]["psnr"] == pytest.approx(ref["psnr_per_image"])
    for kind in ("deblur", "image_only", "rdnet"):
        row = evaluate_row(kind, ckpts[kind], pairs, batch_size=2, device="cpu")
        assert row["psnr"] == blurry["psnr"] and row["ssim"] == blurry["ssim"], kind
        assert row["n"] == 5 and sum(b["n"] for b in row["by_level"]) == 5


def test_rdnet_restoration_scores_and_voxel_transform(setup):
    pairs, ckpts, a = setup
    row = evaluate_row("rdnet", ckpts["rdnet"], pairs, device="cpu", level_bins=2)
    ref = restoration_metrics(a["voxel_degraded"], a["voxel_undegraded"], a["voxel_degraded"])
    # identity stage 1: restored = degraded input
    assert row["restoration"]["voxel_l1"] == pytest.approx(ref["voxel_l1"])
    assert row["restoration_input"] == row["restoration"]
    assert {"psnr", "ssim", "voxel_l1", "voxel_psnr", "n", "level_bin"} <= set(row["by_level"][0])
    assert sum(r["n"] for r in row["by_degradation"]) == 5

    calls = []
    def zero(v, idx):
        calls.append((v.shape, idx.tolist()))
        return np.zeros_like(v)
    row = evaluate_row("restore", ckpts["restore"], pairs, events="degraded", voxel_transform=zero,
                       batch_size=2, device="cpu")
    assert [c[1] for c in calls] == [[0, 1], [2, 3], [4]] and calls[0][0] == (2, 3, 20, 24)
    zero_ref = restoration_metrics(np.zeros_like(a["voxel_degraded"]), a["voxel_undegraded"], a["voxel_degraded"])
    assert row["restoration"]["voxel_l1"] == pytest.approx(zero_ref["voxel_l1"])
    assert "psnr" not in row
    with pytest.raises(ValueError, match="voxel_transform returned shape"):
        evaluate_row("restore", ckpts["restore"], pairs, voxel_transform=lambda v, i: v[:, :1], device="cpu")


def test_predict_keeps_requested_order_and_full_frames(setup):
    pairs, ckpts, a = setup
    out = predict("deblur", ckpts["deblur"], pairs, events="undegraded", indices=[3, 0, 3], device="cpu")
    assert out["index"].tolist() == [3, 0, 3]
    assert out["pred"].shape == (3, 3, 20, 24)
    assert np.array_equal(out["pred"], a["blurry"][[3, 0, 3]])
    assert np.array_equal(out["voxel"], a["voxel_undegraded"][[3, 0, 3]])
    assert np.array_equal(out["level"], a["level"][[3, 0, 3]])


def test_method_and_checkpoint_errors(setup, tmp_path):
    pairs, ckpts, _ = setup
    with pytest.raises(FormatError, match=r"restore\.pt.*model_kind"):
        evaluate_row("deblur", ckpts["restore"], pairs, device="cpu")
    with pytest.raises(ConfigError, match="needs a checkpoint"):
        evaluate_row("rdnet", None, pairs, device="cpu")
    with pytest.raises(ConfigError, match="takes no checkpoint"):
        evaluate_row("blurry", ckpts["deblur"], pairs, device="cpu")
    with pytest.raises(ConfigError, match="unknown method"):
        evaluate_row("stcf", None, pairs, device="cpu")
    grey = write_synthetic_pairs(tmp_path / "grey.h5", n=2, channels=1, bins=3, height=16, width=16)
    with pytest.raises(FormatError, match="image_channels"):
        evaluate_row("deblur", ckpts["deblur"], grey, device="cpu")
    other_bins = write_synthetic_pairs(tmp_path / "b5.h5", n=2, channels=3, bins=5, height=16, width=16)
    with pytest.raises(FormatError, match="voxel bins"):
        evaluate_row("deblur", ckpts["deblur"], other_bins, device="cpu")


def test_a_sample_without_motion_is_left_out_of_every_rows_image_means(tmp_path, setup):
    _, ckpts, _ = setup
    pairs = write_synthetic_pairs(tmp_path / "still.h5", n=4, channels=3, bins=3, height=20, width=24, seed=8)
    with h5py.File(pairs, "r+") as f:
        f["blurry"][1] = f["sharp"][1]                   # nothing moves in sample 1
        a = {k: np.asarray(f[k]) for k in ("blurry", "sharp")}
    keep = [0, 2, 3]
    ref = evaluate_images(a["blurry"][keep], a["sharp"][keep])
    for kind, ck in (("blurry", None), ("deblur", ckpts["deblur"])):
        row = evaluate_row(kind, ck, pairs, batch_size=3, device="cpu")
        assert row["n"] == 4 and row["n_images"] == 3 and row["still_excluded"] == 1
        assert row["psnr"] == pytest.approx(ref["psnr"]) and np.isfinite(row["psnr"])
        assert row["per_sample"]["moving"] == [True, False, True, True]
        assert row["per_sample"]["psnr"][1] == np.inf    # the per-sample values keep it
        assert sum(b["n"] for b in row["by_level"]) == 4


def test_pairs_held_in_memory_give_the_file_rows_and_follow_a_rewritten_file(tmp_path, monkeypatch):
    """The rows read from memory (a small file, read whole once) equal those read from the
    file, in any order and with repeats; a file rewritten in place is read again."""
    import rdnet.eval.predict as P
    import rdnet.train.data as D
    from rdnet.eval.predict import iter_predictions
    pairs = write_synthetic_pairs(tmp_path / "p.h5", n=6, channels=1, bins=3, height=12, width=16, seed=3)
    rows = [5, 0, 3, 3, 1]

    def batches():
        return list(iter_predictions("blurry", None, pairs, indices=rows, batch_size=3, decision=None))

    in_memory = batches()
    assert len(P._PAIRS_IN_MEMORY) == 1
    monkeypatch.setattr(D, "PRELOAD_MAX_BYTES", 0)
    P._PAIRS_IN_MEMORY.clear()
    from_file = batches()
    assert not P._PAIRS_IN_MEMORY
    for a, b in zip(in_memory, from_file, strict=True):
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    monkeypatch.undo()
    first = batches()[0]["sharp"]
    write_synthetic_pairs(pairs, n=6, channels=1, bins=3, height=12, width=16, seed=4)    # same path, new rows
    with h5py.File(pairs, "r") as f:
        want = np.asarray(f["sharp"][5])
    again = batches()[0]["sharp"]
    np.testing.assert_array_equal(again[0], want)
    assert not np.array_equal(again, first)
