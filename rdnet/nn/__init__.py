"""Networks: composable blocks, the dual-branch stage network, RDNet, DeblurNet, losses."""
from rdnet.nn.losses import count_restoration_loss, deblur_loss, restoration_loss
from rdnet.nn.models import (MODEL_KINDS, MODEL_SIZES, DeblurNet, RDNet, RestoreNet, build_model,
                             count_parameters, model_from_config)
from rdnet.nn.stage import StageNet

__all__ = ["MODEL_KINDS", "MODEL_SIZES", "DeblurNet", "RDNet", "RestoreNet", "StageNet",
           "build_model", "count_parameters", "count_restoration_loss", "deblur_loss", "model_from_config",
           "restoration_loss"]
