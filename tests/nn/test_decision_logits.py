"""The occupancy decision on logits (rdnet.nn.decision.logit_threshold, decided_entries,
decided_events) keeps exactly the voxels the stored rule on probabilities keeps
(decide_counts / events_from_heads: float32 sigmoid >= float32 threshold), at the
boundary too, and for any memory format of the heads."""
import numpy as np
import pytest
import torch
from _nets import perturbed_count_net

from rdnet.errors import ValidationError
from rdnet.nn.decision import (_float_to_ordered, _ordered_to_float, decide_counts, decided_entries,
                               decided_events, decision_dict, events_from_heads, logit_threshold)

torch.set_num_threads(1)
#: the packaged image-guided model's fitted threshold, two round ones, extremes
THRESHOLDS = [0.3654939532279968, 0.5, 0.45, 1e-6, 0.01, 0.999, 0.9999999, 1.0]


def _sigmoid_passes(x: np.ndarray, t: float) -> np.ndarray:
    """The stored rule on float32 logits ``x``, with every element in torch's vectorised loop
    (a length that is a multiple of 64; see logit_threshold)."""
    assert x.size % 64 == 0
    return torch.sigmoid(torch.from_numpy(x.astype(np.float32))).numpy() >= t


def test_ordered_float_keys_round_trip_and_keep_the_order():
    x = np.array([-np.inf, -3.4e38, -1.5, -1e-45, -0.0, 0.0, 1e-45, 2.5, 3.4e38, np.inf], np.float32)
    k = _float_to_ordered(x)
    assert np.all(np.diff(k) > 0)
    assert k[4] == -1 and k[5] == 0 and k[6] == 1                 # -0.0, +0.0, the smallest subnormal
    back = _ordered_to_float(k)
    np.testing.assert_array_equal(back.view(np.int32), x.view(np.int32))      # bit for bit (-0.0 too)


@pytest.mark.parametrize("t", THRESHOLDS)
def test_logit_threshold_is_the_exact_boundary_of_the_sigmoid_rule(t):
    lt = logit_threshold(t)
    t32 = float(np.float32(t))
    # every float32 within 4,096 steps either side of the answer: same decision both ways
    k0 = int(_float_to_ordered(np.float32(lt)))
    x = _ordered_to_float(np.arange(k0 - 4096, k0 + 4096))
    np.testing.assert_array_equal(x >= lt, _sigmoid_passes(x, t32))
    # and on a wide sample of logits
    x = np.r_[np.linspace(-30, 30, 100_000), -np.inf, np.inf, 0.0, -0.0].astype(np.float32)
    x = np.r_[x, np.zeros(-x.size % 64, np.float32)]
    np.testing.assert_array_equal(x >= lt, _sigmoid_passes(x, t32))
    if 0 < t < 1:     # near the analytic logit, but not equal to it in general
        assert lt == pytest.approx(np.log(t / (1 - t)), abs=0.02 + 1e-6 / (t * (1 - t)))


def test_logit_threshold_known_values_and_edges():
    assert logit_threshold(0.5) < 0 and logit_threshold(0.5) > -1e-6     # sigmoid rounds up to 0.5 below 0
    assert logit_threshold(0.0) == -np.inf and logit_threshold(-1.0) == -np.inf
    assert logit_threshold(1.0 + 1e-6) == np.inf                           # above 1 in float32: none passes
    assert logit_threshold(1.0 + 1e-12) == logit_threshold(1.0) < 20      # 1.0 in float32: finite
    assert logit_threshold(0.3654939532279968) == pytest.approx(-0.55159718, abs=1e-6)


def _heads(seed, shape=(2, 6, 9, 13)):
    g = torch.Generator().manual_seed(seed)
    mu = 1.0 + 3.0 * torch.rand(shape, generator=g)
    logit = 2.0 * torch.randn(shape, generator=g)
    return mu, logit


@pytest.mark.parametrize("t", [0.3654939532279968, 0.5, 0.45])
@pytest.mark.parametrize("channels_last", [False, True])
def test_decided_entries_equal_the_probability_rule(t, channels_last):
    mu, logit = _heads(1)
    lt = logit_threshold(t)
    k = int(_float_to_ordered(np.float32(lt)))
    flat = logit.view(-1)
    flat[:5] = torch.from_numpy(_ordered_to_float(np.arange(k - 2, k + 3)))   # on the boundary
    flat[5:7] = torch.tensor([float("inf"), float("-inf")])
    decision = decision_dict(t)
    want = events_from_heads(mu, torch.sigmoid(logit), decision)              # (n, 2, bins, H, W)
    rounded = np.rint(mu.view(-1)[:7].numpy()).astype(int)
    assert want.reshape(-1)[:7].tolist() == [0, 0, *rounded[2:6], 0]          # 2 below, 3 at or above; +-inf
    if channels_last:
        mu, logit = (v.contiguous(memory_format=torch.channels_last) for v in (mu, logit))
    index, counts = decided_entries(mu, logit, decision)
    assert np.all(np.diff(index) > 0) and index.dtype == np.int64 and counts.dtype == np.int64
    np.testing.assert_array_equal(index, np.flatnonzero(want))
    np.testing.assert_array_equal(counts, want.reshape(-1)[index])


def test_decided_entries_rounding_none_kept_and_checks():
    mu = torch.tensor([[[[0.2, 1.5, 2.5, 3.49]]]])                        # decide_counts: max(mu, 1), half to even
    logit = torch.tensor([[[[5.0, 5.0, 5.0, -5.0]]]])
    index, counts = decided_entries(mu, logit, decision_dict(0.5))
    assert index.tolist() == [0, 1, 2] and counts.tolist() == [1, 2, 2]
    assert counts.tolist() == decide_counts(mu.numpy(), torch.sigmoid(logit).numpy(), 0.5).ravel()[:3].tolist()
    index, counts = decided_entries(mu, torch.full_like(logit, float("inf")), decision_dict(1.0 + 1e-6))
    assert index.size == 0 and counts.size == 0
    with pytest.raises(ValidationError, match="decision"):
        decided_entries(mu, logit, None)
    with pytest.raises(ValidationError, match="differ"):
        decided_entries(mu, logit[..., :2], decision_dict(0.5))


def test_decided_events_equals_the_probability_rule_on_a_network():
    net = perturbed_count_net(3, 0.5)
    g = torch.Generator().manual_seed(4)
    x = torch.poisson(torch.full((2, 6, 12, 16), 0.4), generator=g)
    img = torch.rand(2, 1, 12, 16, generator=g)
    decision = decision_dict(0.45)
    with torch.inference_mode():
        mu, logit = net(img, x, return_heads=True)
    want = events_from_heads(mu, torch.sigmoid(logit), decision)
    got = decided_events(net, img, x, decision)
    assert got.shape == (2, 2, 3, 12, 16) and got.dtype == np.int64 and got.sum() > 0
    np.testing.assert_array_equal(got, want)
