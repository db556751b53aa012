"""Small concealed-effect recordings shared by the calibration tests (48x48, 0.6 s);
imported by name (pytest puts this folder on sys.path)."""
import numpy as np

from rdnet.calib.proof import ProofCase, make_recording
from rdnet.calib.scene import SceneSpec
from rdnet.calib.settings import CalibrateConfig
from rdnet.sim.interpolate import InterpolateConfig
from rdnet.sim.settings import SensorConfig

SPEC = SceneSpec(width=48, height=48, duration_us=600_000, fps_hz=100.0, period_s=0.3)
INTERP = InterpolateConfig(method="linear", max_upsample=8)
#: a cheaper search than the defaults (the tests must stay fast on 2 cores); linear blending
#: stays among the interpolation candidates here (the default dropped it): these recordings
#: are simulated from linearly blended frames, so the nuisance choice has a right answer
CFG = CalibrateConfig(seeds=3, search_points=5, refine_steps=4, max_effects=2,
                      interpolation=("flow", "linear", "selected"))
SENSOR = SensorConfig()

HOT = ProofCase("hot_pixels_in_noise", "hot_pixels", {"shot_noise_hz": 3.0},
                {"hot_pixel_fraction": 0.01, "hot_pixel_hz": 100.0, "shot_noise_hz": 2.0},
                compensate="shot_noise_hz")
NULL = ProofCase("null_thresholds", None, {"shot_noise_hz": 1.0}, {"shot_noise_hz": 1.0},
                 truth_threshold_scale=1.3, compensate=None)


def hot_recording():
    return make_recording(HOT, SPEC, SENSOR, np.random.default_rng(11), 1, INTERP)


def null_recording():
    return make_recording(NULL, SPEC, SENSOR, np.random.default_rng(12), 1, INTERP)
