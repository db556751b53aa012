"""Classical baselines: EDI deblurring, STCF and GEF event filtering."""
from rdnet.baselines.edi import edi_deblur, edi_from_counts, edi_from_voxel
from rdnet.baselines.gef import gef_voxel, guided_filter
from rdnet.baselines.stcf import stcf_filter, stcf_mask, stcf_voxel

__all__ = ["edi_deblur", "edi_from_counts", "edi_from_voxel", "gef_voxel", "guided_filter",
           "stcf_filter", "stcf_mask", "stcf_voxel"]
