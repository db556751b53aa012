"""Training: datasets, the loop, checkpoints, distributed set-up."""
