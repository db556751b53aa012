"""One stage-1 pass gives what two gave (the restored voxel of RestoreNet.forward and the
events of rdnet.nn.decision.decided_events), exactly, on tiny random networks on CPU;
the forward calls and checkpoint reads of evaluation are counted."""
import h5py
import numpy as np
import pytest
import torch

import rdnet.train.checkpoint as ckpt_mod
from rdnet.errors import ValidationError
from rdnet.eval.predict import evaluate_row, iter_predictions, load_method, predict, stage1_decision
from rdnet.eval.stage1 import run_stage1, signed_counts
from rdnet.nn.decision import decided_events, decision_dict
from rdnet.nn.models import build_model
from rdnet.train.checkpoint import make_checkpoint, save_checkpoint
from rdnet.train.synthetic import write_synthetic_pairs

BINS, H, W = 3, 12, 16


def _random(net, seed):
    """Random weights everywhere (a fresh count stage 1 is the identity: no test)."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(0.3 * torch.randn(p.shape, generator=g))
    return net.eval()


def _inputs(output, image_channels=1, n=2, seed=0):
    rng = np.random.default_rng(seed)
    img = torch.from_numpy(rng.random((n, image_channels, H, W), np.float32)) if image_channels else None
    if output == "counts":
        x = rng.poisson(0.4, (n, 2 * BINS, H, W)).astype(np.float32)
    else:
        x = rng.integers(-2, 3, (n, BINS, H, W)).astype(np.float32)
    return img, torch.from_numpy(x)


class _Calls:
    """Counts forward calls of a module (a forward hook)."""

    def __init__(self, module):
        self.n = 0
        self.handle = module.register_forward_hook(self)

    def __call__(self, *args):
        self.n += 1


@pytest.mark.parametrize("output,image_channels", [("counts", 1), ("counts", 0), ("signed", 1)])
def test_one_pass_equals_forward_and_decided_events(output, image_channels):
    net = _random(build_model("restore", "tiny", image_channels, BINS, restore_output=output, width=4), 1)
    img, x = _inputs(output, image_channels)
    decision = decision_dict(0.4) if output == "counts" else decision_dict(None)
    calls = _Calls(net)
    restored, events = run_stage1(net, img, x, decision)
    assert calls.n == 1                                            # one pass for both
    with torch.inference_mode():
        want_restored = net.signed(net(img, x))
    want_events = decided_events(net, img, x, decision)
    assert torch.equal(restored, want_restored)
    np.testing.assert_array_equal(events, want_events)
    assert events.dtype == np.int64 and events.shape == (2, 2, BINS, H, W)
    assert 0 < events.sum() and restored.shape == (2, BINS, H, W)
    # without a decision: the voxel alone
    r2, none = run_stage1(net, img, x)
    assert none is None and torch.equal(r2, want_restored)
    if output == "counts":
        with pytest.raises(ValidationError, match="decision"):
            run_stage1(net, img, x, {"rule": "round"})


def test_signed_counts_is_on_minus_off():
    c = np.random.default_rng(3).integers(0, 4, (3, 2, BINS, H, W))
    s = signed_counts(c)
    np.testing.assert_array_equal(s, c[:, 0] - c[:, 1])
    assert s.dtype == c.dtype and s.shape == (3, BINS, H, W)
    np.testing.assert_array_equal(signed_counts(c[0]), c[0, 0] - c[0, 1])
    with pytest.raises(ValidationError, match="per-polarity"):
        signed_counts(c[:, :1])


@pytest.fixture(scope="module")
def counts_setup(tmp_path_factory):
    """A pairs file with per-polarity voxels and random count-output networks."""
    d = tmp_path_factory.mktemp("stage1")
    pairs = write_synthetic_pairs(d / "p.h5", n=5, bins=BINS, height=H, width=W, seed=2)
    ckpts = {}
    for kind, channels in (("rdnet", 1), ("restore", 0)):
        args = {"kind": kind, "size": "tiny", "image_channels": channels, "bins": BINS, "width": 4,
                "restore_output": "counts"}
        net = _random(build_model(**args), 5)
        ckpts[kind] = save_checkpoint(d / f"{kind}.pt", make_checkpoint(
            net, kind, args, extra={"decision": decision_dict(0.45)}, with_rng=False))
    return pairs, ckpts


@pytest.mark.parametrize("kind", ["rdnet", "restore"])
def test_predictions_run_stage1_once_per_batch_and_match_the_two_pass_result(counts_setup, kind):
    pairs, ckpts = counts_setup
    model = load_method(kind, ckpts[kind], pairs)
    stage1 = model.restore if kind == "rdnet" else model
    decision = stage1_decision(ckpts[kind])
    calls = _Calls(stage1)
    batches = list(iter_predictions(kind, model, pairs, batch_size=2, decision=decision))
    assert len(batches) == 3 and calls.n == 3                     # the old code ran stage 1 twice: 6
    calls.handle.remove()
    with h5py.File(pairs, "r") as f:
        on, off = np.asarray(f["voxel_degraded_on"]), np.asarray(f["voxel_degraded_off"])
        blurry = np.asarray(f["blurry"])
    for b in batches:                                              # the two-pass reference
        i = b["index"]
        x = torch.from_numpy(np.concatenate([on[i], off[i]], 1).round().astype(np.float32))
        img = torch.from_numpy(blurry[i]) if kind == "rdnet" else None
        with torch.inference_mode():
            out = model(img, x)
        if kind == "rdnet":
            np.testing.assert_array_equal(b["restored"], out[0].numpy())
            np.testing.assert_array_equal(b["pred"], out[1].numpy())
        else:
            np.testing.assert_array_equal(b["restored"], model.signed(out).numpy())
        np.testing.assert_array_equal(b["restored_counts"], decided_events(stage1, img, x, decision))
        assert b["restored_counts"].sum() > 0


def _count_loads(monkeypatch):
    loads = []
    real = ckpt_mod.torch.load

    def counting(path, *a, **k):
        loads.append(str(path))
        return real(path, *a, **k)
    monkeypatch.setattr(ckpt_mod.torch, "load", counting)
    return loads


def test_a_checkpoint_is_read_once_per_evaluation(counts_setup, monkeypatch):
    pairs, ckpts = counts_setup
    loads = _count_loads(monkeypatch)
    # an events-only restorer with its decision: was 3 reads (channels, model, decision)
    p = predict("restore", ckpts["restore"], pairs, batch_size=4, events_out=True)
    assert loads == [str(ckpts["restore"])] and p["restored_counts"].shape == (5, 2, BINS, H, W)
    loads.clear()
    row = evaluate_row("restore", ckpts["restore"], pairs, batch_size=4, device="cpu")
    assert loads == [str(ckpts["restore"])] and row["n"] == 5
    loads.clear()
    ck = ckpt_mod.read_checkpoint(ckpts["rdnet"])
    again = predict("rdnet", ckpts["rdnet"], pairs, batch_size=4, events_out=True, loaded=ck)
    assert loads == [str(ckpts["rdnet"])]                          # only the read above
    ref = predict("rdnet", ckpts["rdnet"], pairs, batch_size=4, events_out=True)
    for k in ref:
        np.testing.assert_array_equal(again[k], ref[k])


def test_restoration_table_reads_each_seed_checkpoint_once(counts_setup, monkeypatch):
    from rdnet.study.rows import AblationConfig, restoration_table
    pairs, ckpts = counts_setup
    loads = _count_loads(monkeypatch)
    res = restoration_table(AblationConfig(batch_size=4, device="cpu"), pairs, None, dict(ckpts), filters=())
    assert sorted(loads) == sorted(str(p) for p in ckpts.values())  # was 4 reads per checkpoint (restore)
    assert res["restore"]["events"]["restored"] > 0 and res["rdnet"]["seeds"] == [0]
