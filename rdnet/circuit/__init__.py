"""An independent DVS event generator: a continuous-time pixel circuit (photoreceptor with
intensity-dependent bandwidth, source follower, comparators with reset hold), written from
a different model than :mod:`rdnet.sim.sensor` and sharing none of its code; used by the
calibration proof (:mod:`rdnet.calib.proof`) as a second source of "real" events."""
from rdnet.circuit.generate import DEGRADE_EQUIVALENT, CircuitParams, from_degrade, generate, pixel_parameters

__all__ = ["CircuitParams", "DEGRADE_EQUIVALENT", "from_degrade", "generate", "pixel_parameters"]
