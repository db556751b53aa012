import pytest
import torch
import torch.nn.functional as F

from rdnet.nn import build_model, deblur_loss, restoration_loss
from rdnet.nn.losses import masked_l1, restoration_loss_terms


def sparse_voxels(seed, shape=(2, 10, 16, 16), density=0.2):
    g = torch.Generator().manual_seed(seed)
    keep = torch.rand(shape, generator=g) < density
    return torch.randint(-2, 3, shape, generator=g).float() * keep


def test_masked_l1_known_value():
    diff = torch.tensor([1.0, -2.0, 3.0, 4.0])
    mask = torch.tensor([True, True, False, False])
    assert masked_l1(diff, mask).item() == pytest.approx(1.5)
    assert masked_l1(diff, torch.zeros(4, dtype=torch.bool)).item() == 0.0


def test_voxel_term_known_value():
    u = torch.zeros(1, 2, 1, 2)
    d = torch.zeros(1, 2, 1, 2)
    u[0, 0, 0, 0] = 1.0
    d[0, 1, 0, 1] = -1.0
    r = torch.full_like(u, 3.0)
    # mask covers 2 voxels: |3-1| and |3-0| -> mean 2.5; alpha scales it
    assert restoration_loss(r, u, d, alpha=0.5).item() == pytest.approx(1.25)
    # empty voxels: two with |3 - 0| = 3
    assert restoration_loss(r, u, d, alpha=0.5, empty_weight=2.0).item() == pytest.approx(1.25 + 6.0)


def test_empty_voxels_unconstrained_in_paper_loss():
    u, d = sparse_voxels(1), sparse_voxels(2)
    r = torch.randn(u.shape, generator=torch.Generator().manual_seed(3))
    empty = (u == 0) & (d == 0)
    assert empty.any()
    r2 = r.clone()
    r2[empty] += 5.0
    assert torch.equal(restoration_loss(r, u, d, 0.5), restoration_loss(r2, u, d, 0.5))
    # the extension term reacts to the empty voxels
    assert (restoration_loss(r2, u, d, 0.5, empty_weight=0.1)
            > restoration_loss(r, u, d, 0.5, empty_weight=0.1) + 0.1)


def local_features(x):
    """A pixel-local two-scale 'encoder' to test the feature mask exactly."""
    return [x, F.avg_pool2d(x, 2)]


def test_feature_mask_is_max_pooled_per_scale():
    u = torch.zeros(1, 10, 8, 8)
    d = torch.zeros(1, 10, 8, 8)
    u[0, 3, 0, 0] = 1.0           # the only event pixels: (0,0) and (1,1): 2x2 block (0,0)
    d[0, 5, 1, 1] = -1.0
    r = u.clone()
    base = restoration_loss_terms(r, u, d, local_features)["feature"]
    assert base.item() == 0.0
    far = r.clone()
    far[..., 4:, 4:] += 1.0       # pixels without events in any bin, whole 2x2 blocks
    assert restoration_loss(far, u, d, 0.5, local_features, 0.5).item() == 0.0
    near = r.clone()
    near[0, :, 0, 1] += 1.0       # no event at (0,1) but its 2x2 block has events
    t = restoration_loss_terms(near, u, d, local_features)
    assert t["voxel"].item() == 0.0
    # level 0: pixel (0,1) masked out -> 0; level 1: block (0,0) counted, 10 channels,
    # |diff| = 1/4 per channel -> masked mean 0.25; averaged over 2 scales -> 0.125
    assert t["feature"].item() == pytest.approx(0.125)


def test_feature_term_zero_at_target_and_positive_elsewhere():
    torch.manual_seed(0)
    deblur = build_model("deblur", "tiny", 1, 10)
    u, d = sparse_voxels(3), sparse_voxels(4)
    f = deblur.event_features
    assert restoration_loss(u.clone(), u, d, 0.5, f, 0.5).item() == 0.0
    t = restoration_loss_terms(u + 0.3 * torch.randn_like(u), u, d, f)
    assert t["feature"].item() > 0
    # the target side is detached: gradients reach only the restored input
    r = u.clone().requires_grad_(True)
    restoration_loss(r + 0.1, u, d, 0.5, f, 0.5).backward()
    assert r.grad is not None and r.grad.abs().sum() > 0


def test_deblur_loss_is_mean_abs():
    a = torch.tensor([[0.0, 1.0], [2.0, 3.0]])
    b = torch.zeros(2, 2)
    assert deblur_loss(a, b).item() == pytest.approx(1.5)
    with pytest.raises(ValueError):
        deblur_loss(a, b[:1])


def test_one_step_lowers_loss_on_fixed_batch():
    torch.manual_seed(0)
    rd = build_model("rdnet", "tiny", 1, 10)
    g = torch.Generator().manual_seed(5)
    img = torch.rand(2, 1, 32, 32, generator=g)
    sharp = (img + 0.1 * torch.rand(2, 1, 32, 32, generator=g)).clamp(0, 1)
    u, d = sparse_voxels(6, (2, 10, 32, 32)), sparse_voxels(7, (2, 10, 32, 32))
    opt = torch.optim.Adam(rd.parameters(), lr=1e-3)

    def loss():
        restored, pred = rd(img, d)
        return (restoration_loss(restored, u, d, 0.5, rd.deblur.event_features, 0.5)
                + deblur_loss(pred, sharp))

    before = loss()
    opt.zero_grad()
    before.backward()
    opt.step()
    with torch.no_grad():
        after = loss()
    assert after.item() < before.item()
