"""Networks: composable blocks, the dual-branch stage network, RDNet, DeblurNet, losses."""
