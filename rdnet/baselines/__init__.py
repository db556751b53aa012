"""Classical baselines: EDI deblurring, STCF and GEF event filtering."""
