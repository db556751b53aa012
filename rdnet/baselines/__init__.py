"""Classical baselines: EDI deblurring, STCF, BAF and GEF event filtering."""
from rdnet.baselines.baf import baf_filter, baf_mask, baf_state
from rdnet.baselines.edi import edi_deblur, edi_from_counts, edi_from_voxel
from rdnet.baselines.gef import gef_voxel, guided_filter
from rdnet.baselines.stcf import StcfState, stcf_filter, stcf_mask, stcf_voxel

__all__ = ["StcfState", "baf_filter", "baf_mask", "baf_state", "edi_deblur", "edi_from_counts",
           "edi_from_voxel", "gef_voxel", "guided_filter", "stcf_filter", "stcf_mask", "stcf_voxel"]
