"""The event simulator: frame interpolation, ideal sensor, degradations, paired
simulation with randomized settings, embedded scenes, GOPRO-style blur."""
