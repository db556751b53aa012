"""Small synthetic streams for the restore tests."""
import numpy as np

from rdnet.events import Events


def edge_noise_hot(seed=0, W=60, H=40, T=60_000, n_noise=300, hot=(7, 33), hot_period_us=700):
    """A dense vertical edge sweeping left to right (each pixel fires once, 1 ms per
    column), ``n_noise`` uniformly random isolated events and a hot pixel firing every
    ``hot_period_us``. Returns events and the label per event (0 edge, 1 noise, 2 hot)."""
    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(W), np.arange(H))
    te = xs.ravel() * (T // W) + rng.integers(0, 200, H * W)
    th = np.arange(0, T, hot_period_us)
    t = np.concatenate([te, rng.integers(0, T, n_noise), th])
    x = np.concatenate([xs.ravel(), rng.integers(0, W, n_noise), np.full(th.size, hot[0])])
    y = np.concatenate([ys.ravel(), rng.integers(0, H, n_noise), np.full(th.size, hot[1])])
    p = np.concatenate([np.ones(H * W), rng.integers(0, 2, n_noise), np.ones(th.size)]).astype(np.uint8)
    lab = np.r_[np.zeros(H * W, int), np.ones(n_noise, int), np.full(th.size, 2)]
    o = np.argsort(t, kind="stable")
    return Events.from_columns(t[o], x[o], y[o], p[o], W, H), lab[o]


def prophesee_codec():
    """The test encoders of tests/events/prophesee_codec.py (known events -> RAW/DAT bytes)."""
    import importlib.util
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "events" / "prophesee_codec.py"
    spec = importlib.util.spec_from_file_location("prophesee_codec", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod
