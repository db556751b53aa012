"""Deblurring real recordings with a trained RDNet (``rdnet deblur``).

- :mod:`~rdnet.deblur.config`: the ``deblur`` section of params.yaml;
- :mod:`~rdnet.deblur.network`: finding the study's checkpoint and checking it against
  the params (network kind and size, voxel bins, mode and normalisation);
- :mod:`~rdnet.deblur.pipeline`: event windows per frame, voxels, both stages in batches,
  restored voxels back to events;
- :mod:`~rdnet.deblur.consistency`: event-frame consistency of raw and restored events
  (the score that needs no ground truth), built on :mod:`rdnet.calib.consistency`;
- :mod:`~rdnet.deblur.run`: the whole command and its outputs, written atomically.
"""
