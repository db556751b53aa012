"""A small count-output RestoreNet with perturbed weights (not the identity a fresh one
starts as), and inputs for it, for the decision and layout tests of this folder."""
import torch

from rdnet.nn.models import RestoreNet


def perturbed_count_net(seed: int, scale: float) -> RestoreNet:
    """RestoreNet(1 image channel, 3 bins, width 4, two levels), counts output, weights
    plus ``scale`` x N(0, 1) drawn from torch seed ``seed`` (torch's global RNG restored),
    in eval mode."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        net = RestoreNet(1, 3, width=4, enc_depths=(1, 1), middle_depth=1, dec_depths=(1, 1), output="counts")
        with torch.no_grad():
            for p in net.parameters():
                p.add_(scale * torch.randn(p.shape))
    return net.eval()


def count_inputs(rate: float, seed: int = 6) -> tuple[torch.Tensor, torch.Tensor]:
    """(counts, image) for :func:`perturbed_count_net`: Poisson(``rate``) ON/OFF counts of
    3 bins and a uniform image, 13 x 19 (an odd size, padded inside the network)."""
    g = torch.Generator().manual_seed(seed)
    counts = torch.poisson(torch.full((1, 6, 13, 19), rate), generator=g)
    return counts, torch.rand(1, 1, 13, 19, generator=g)
