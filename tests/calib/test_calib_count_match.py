"""The proof's count match (rdnet.calib.proof.match_count): the concealing parameter solved
so that the true event count equals the base count, in a few generator runs."""
import math

import pytest

from rdnet.calib.proof import COUNT_MATCH_TOL, match_count


def _counter(fn):
    runs = []

    def count_at(x):
        runs.append(x)
        return x, int(round(fn(x))), f"events at {x:.6f}"
    return count_at, runs


@pytest.mark.parametrize("beta, x_true", [(1.0, 0.0), (1.7, -0.4), (0.6, 0.9)])
def test_thresholds_solved_to_the_tolerance_in_a_few_runs(beta, x_true):
    """Count falling as a power of the threshold factor (the exponent unknown to the solver):
    the count lands within the tolerance, in far fewer runs than a 16-step bisection."""
    target = 70_000
    count_at, runs = _counter(lambda x: target * math.exp(-beta * (x - x_true)))
    start = count_at(0.3)
    x, n, payload = match_count(count_at, start, target, -1.0, 0.3 - 3.0, 0.3 + 3.0)
    assert abs(n - target) <= COUNT_MATCH_TOL * target
    assert abs(x - x_true) < 2 * COUNT_MATCH_TOL / beta
    assert payload == f"events at {x:.6f}"              # the returned run's own events
    assert len(runs) <= 7


def test_noise_rate_with_a_signal_floor():
    """Count = signal + noise rate x pixels (the shot-noise compensation): the log count is
    flat at low rates, and the solver still brackets and meets the target."""
    count_at, runs = _counter(lambda x: 50_000 + 8_000 * math.exp(x))
    target = 56_000                                      # rate 0.75
    x, n, _ = match_count(count_at, count_at(math.log(2.0)), target, 0.5, math.log(1e-4), math.log(2.0) + 3.0)
    assert abs(n - target) <= COUNT_MATCH_TOL * target
    assert math.exp(x) == pytest.approx(0.75, rel=0.02)
    assert len(runs) <= 8


def test_an_unreachable_target_returns_the_nearest_point_at_the_bound():
    """Below the signal floor no rate reaches the target: the solver walks the bracket down
    to the low bound and returns the nearest count, the floor, within its max_runs."""
    count_at, runs = _counter(lambda x: 50_000 + 8_000 * math.exp(x))
    lo = math.log(1e-4)
    x, n, _ = match_count(count_at, count_at(0.0), 40_000, 0.5, lo, 3.0)
    assert x < lo + 1.0 and n == 50_001               # the floor, rounded
    assert len(runs) <= 13


def test_a_count_that_moves_the_wrong_way_locally_still_converges():
    """Noise resets make the count non-monotone on a small scale (fewer noise events can
    give more signal events): a step that goes the wrong way is caught by the bracket, as in
    a bisection, and the solver still reaches the target."""
    count_at, runs = _counter(lambda x: 4_000 + 300 * math.exp(x) + 40 * math.sin(60 * x))
    target = 4_322                                       # rate near 1.07, wiggles of +-40
    x, n, _ = match_count(count_at, count_at(0.0), target, 0.5, math.log(1e-4), 3.0)
    assert abs(n - target) <= 0.02 * target
    assert len(runs) <= 13


def test_the_start_already_matching_runs_nothing_more():
    count_at, runs = _counter(lambda x: 70_000)
    assert match_count(count_at, count_at(0.0), 70_010, -1.0, -3.0, 3.0)[1] == 70_000
    assert len(runs) == 1
