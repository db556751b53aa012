"""One intra-op thread for torch: the test machine's 2 cores are shared with other jobs,
and OpenMP threads spinning on busy cores make the tiny networks several times slower."""
import torch

torch.set_num_threads(1)
