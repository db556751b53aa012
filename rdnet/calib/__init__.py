"""Sim-to-real calibration: statistics, mismatch localisation, effect fits, report."""
