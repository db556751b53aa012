"""The study's steps as library functions (each DVC stage in ``stages/`` is a thin
wrapper around one of them, so the study also runs without DVC)."""
