"""The count output of RestoreNet: non-negative, an event-level identity when fresh, an
events-only variant, the occupancy loss on every voxel and the fitted decision."""
import numpy as np
import pytest
import torch

from rdnet.errors import ConfigError, ValidationError
from rdnet.events import Events
from rdnet.events.voxel import voxel_events, voxel_grid
from rdnet.nn.decision import decide_counts, fit_threshold, polarity_grid, read_decision, split_signed
from rdnet.nn.losses import count_loss_terms, restoration_loss
from rdnet.nn.models import RDNet, DeblurNet, RestoreNet, build_model

torch.set_num_threads(1)
ARCH = dict(width=4, enc_depths=(1, 1), middle_depth=1, dec_depths=(1, 1))


def _counts(seed=0, b=3, h=12, w=10):
    g = torch.Generator().manual_seed(seed)
    c = torch.poisson(torch.full((2, 2 * b, h, w), 0.4), generator=g)
    return c


def _perturb(net, seed=1, scale=0.5):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            p.add_(torch.randn(p.shape, generator=g) * scale)


@pytest.mark.parametrize("image_channels", [1, 0])
def test_counts_output_is_non_negative_and_fresh_net_is_event_identity(image_channels):
    net = RestoreNet(image_channels, 3, output="counts", **ARCH)
    x = _counts()
    img = torch.rand(2, 1, 12, 10) if image_channels else None
    mu, logit = net(img, x, return_heads=True)
    # fresh: p > 0.5 exactly where the input has events, mu = input there
    got = decide_counts(mu.detach().numpy(), torch.sigmoid(logit).detach().numpy(), 0.5)
    np.testing.assert_array_equal(got, x.numpy().astype(np.int64))
    _perturb(net)
    out = net(img, x)
    mu, logit = net(img, x, return_heads=True)
    assert out.shape == x.shape and (out >= 0).all() and (mu >= 1).all()
    assert not torch.equal(out, x)      # the perturbation changed it: the check above could fail


def test_events_only_net_has_no_image_branch_and_rdnet_reads_signed_counts():
    ev = build_model("restore", "tiny", image_channels=0, bins=3, restore_output="counts", width=4)
    assert ev.net.image_branch is None and ev.config["image_channels"] == 0
    with pytest.raises(ValueError, match="no image branch"):
        ev(torch.rand(1, 1, 8, 8), _counts(b=3, h=8, w=8)[:1])
    with pytest.raises(ConfigError, match="without images"):
        build_model("deblur", "tiny", image_channels=0, bins=3)
    r = RestoreNet(1, 3, output="counts", **ARCH)
    net = RDNet(r, DeblurNet(1, 3, **ARCH))
    x = _counts()
    restored, sharp = net(torch.rand(2, 1, 12, 10), x)
    assert restored.shape == (2, 3, 12, 10) and sharp.shape == (2, 1, 12, 10)
    exp = r(torch.rand(2, 1, 12, 10), x)
    np.testing.assert_allclose(r.signed(exp).detach().numpy(), (exp[:, :3] - exp[:, 3:]).detach().numpy())


def test_occupancy_term_constrains_empty_voxels_where_the_masked_loss_does_not():
    u = torch.zeros(1, 2, 4, 4)
    u[0, 0, 1, 1] = 2.0
    spurious = u.clone()
    spurious[0, 1, 3, 3] = 1.0                     # an event where neither stream has one
    # the paper's masked loss does not see it (signed voxels, E_d = E_u)
    su, ss = u[:, :1] - u[:, 1:], spurious[:, :1] - spurious[:, 1:]
    assert restoration_loss(ss, su, su).item() == 0.0
    logit = torch.where(spurious > 0, 5.0, -5.0)
    t = count_loss_terms(spurious.clamp_min(1), logit, u)
    clean = count_loss_terms(u.clamp_min(1), torch.where(u > 0, 5.0, -5.0), u)
    assert t["occupancy"].item() > clean["occupancy"].item() + 0.1
    # BCE(5, 0) on 1 of 32 voxels more: softplus(5) / 32 above the clean value
    assert t["occupancy"].item() - clean["occupancy"].item() == pytest.approx(
        (np.log1p(np.exp(5.0)) - np.log1p(np.exp(-5.0))) / 32, rel=1e-5)
    assert t["count"].item() == 0.0 and clean["count"].item() == 0.0


def test_count_loss_l1_aims_at_the_median_poisson_at_the_mean():
    """The count term's optimum for a shared mu over occupied voxels with counts 1, 1, 1, 2, 5:
    the L1's is the median (1), the Poisson half-deviance's the mean (2); voxels with no
    undegraded event do not enter either; an unknown loss is refused."""
    u = torch.tensor([1.0, 1.0, 1.0, 2.0, 5.0, 0.0, 0.0]).view(1, 1, 1, 7)
    logit = torch.zeros_like(u)
    grid = torch.linspace(1.0, 4.0, 301)

    def best(loss):
        vals = [count_loss_terms(torch.full_like(u, float(m)), logit, u, loss)["count"].item() for m in grid]
        return grid[int(np.argmin(vals))].item()
    assert best("l1") == pytest.approx(1.0)
    assert best("poisson") == pytest.approx(2.0, abs=0.011)
    t = count_loss_terms(torch.where(u > 0, u, 7.0), logit, u, "poisson")   # mu = u where occupied
    assert t["count"].item() == pytest.approx(0.0, abs=1e-6)
    # known value: mean over the 5 occupied voxels of mu - u + u log(u / mu) at mu = 2
    expect = np.mean([2 - k + k * np.log(k / 2) for k in (1, 1, 1, 2, 5)])
    assert count_loss_terms(torch.full_like(u, 2.0), logit, u, "poisson")["count"].item() == pytest.approx(expect, rel=1e-6)
    with pytest.raises(ValueError, match="count_loss"):
        count_loss_terms(u, logit, u, "l2")


def test_train_count_loss_is_checked():
    from rdnet.train.config import TrainConfig
    assert TrainConfig(count_loss="poisson").count_loss == "poisson"
    with pytest.raises(ConfigError, match="train.count_loss"):
        TrainConfig(count_loss="mse")


def test_fit_threshold_known_answers_and_decision_checks():
    p = np.array([0.9, 0.8, 0.8, 0.1])
    mu = np.array([1.0, 2.0, 1.0, 1.0])
    assert fit_threshold(mu, p, 4) == 0.8          # ties at 0.8 kept together: 1 + 2 + 1
    assert fit_threshold(mu, p, 3) == 0.9          # 4 would overshoot: keep only the 0.9 voxel
    assert fit_threshold(mu, p, 0) > 0.9
    assert decide_counts(mu, p, 0.8).tolist() == [1, 2, 1, 0]
    flat = np.arange(2 * 6 * 2 * 2).reshape(2, 6, 2, 2)        # (N, 2 * bins, H, W), bins 3
    g = polarity_grid(flat)
    assert g.shape == (2, 2, 3, 2, 2) and g[1, 1, 0, 0, 1] == flat[1, 3, 0, 1]    # OFF bin 0 = channel bins
    with pytest.raises(ValidationError, match="counts"):
        polarity_grid(np.zeros((1, 5, 2, 2)))
    np.testing.assert_array_equal(split_signed(np.array([[[2.0]], [[-1.0]]])), [[[2.0]], [[0.0]], [[0.0]], [[1.0]]])
    with pytest.raises(ValidationError, match="decision"):
        read_decision(None, "counts")
    assert read_decision(None, "signed")["rule"] == "round"


def test_split_voxels_keep_on_and_off_of_one_voxel_and_round_trip():
    t = np.array([0, 10, 20, 55, 90, 99])
    x = np.array([1, 1, 1, 0, 2, 2])
    y = np.array([0, 0, 0, 1, 1, 1])
    p = np.array([1, 0, 1, 0, 1, 1])
    ev = Events.from_columns(t, x, y, p, 3, 2)
    split = voxel_grid(ev, 4, 0, 100, polarity="split")
    assert split.shape == (2, 4, 2, 3)
    assert split[0, 0, 0, 1] == 2 and split[1, 0, 0, 1] == 1   # 2 ON + 1 OFF in one voxel
    signed = voxel_grid(ev, 4, 0, 100)
    np.testing.assert_array_equal(signed, split[0] - split[1])
    back = voxel_events(split, 0, 100)
    assert len(back) == 6 and back.p.sum() == 4
    np.testing.assert_array_equal(voxel_grid(back, 4, 0, 100, polarity="split"), split)
    with pytest.raises(ValidationError, match="negative"):
        voxel_events(-split, 0, 100)
    with pytest.raises(ValidationError, match="polarity"):
        voxel_grid(ev, 4, 0, 100, polarity="on")
