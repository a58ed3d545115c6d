"""The path space's stopping rule (``scaled_rounds(..., kernel_density=True)``, docs/benchmarks.md, "Oscillator at
300,000 evaluations"): rounds stop once the particles' whitened travel amounts to an independent draw, and run to
their cap when nothing moves; the independence proposal is the kernel density above ``HIGH_DIMENSION`` too."""

import numpy as np
import pytest
from scipy import stats

from seqbayes.engine.settings import HIGH_DIMENSION, SamplerConfig
from seqbayes.moves import schedule

D = HIGH_DIMENSION + 2  # a path of six states of a two-parameter model


def gaussian_components(points):
    return stats.multivariate_normal(np.zeros(D)).logpdf(points).reshape(-1, 1)


def rounds(kernel_density, component_fn, seed=0, cap=12):
    rng = np.random.default_rng(seed)
    walkers = rng.standard_normal((1000, D))
    config = SamplerConfig(move="gaussian", scaled_moves=True, n_moves=1, max_moves=cap)
    return walkers, schedule.scaled_rounds(config, walkers, component_fn(walkers), component_fn, np.ones(1), None,
                                           rng, kernel_density)


def test_rounds_stop_once_the_particles_have_travelled_an_independent_draw():
    # exact draws of a 12-dimensional Gaussian: the kernel density's independence sweeps accept about half the
    # proposals, so a few rounds carry every particle an independent draw's whitened distance (2 d) on average
    walkers, (position, _, stats_, n_rounds) = rounds(True, gaussian_components)
    assert 1 <= n_rounds <= 4
    assert np.mean(np.any(position != walkers, axis=1)) >= 0.9
    # the moves leave the target invariant: moments of 1000 draws within 5 standard errors
    assert np.all(np.abs(position.mean(axis=0)) < 5 / np.sqrt(1000))
    assert np.all(np.abs(position.var(axis=0) - 1.0) < 5 * np.sqrt(2 / 1000))


def test_rounds_run_to_their_cap_when_nothing_moves():
    calls = []

    def nowhere(points):  # the particles' own values, then zero density at every proposal: nothing is accepted
        calls.append(points.shape[0])
        return gaussian_components(points) if len(calls) == 1 else np.full((points.shape[0], 1), -np.inf)

    walkers, (position, _, stats_, n_rounds) = rounds(True, nowhere, cap=5)
    assert n_rounds == 5 and stats_.n_accepted == 0
    np.testing.assert_array_equal(position, walkers)


@pytest.mark.parametrize("kernel_density, proposal", [(True, "DefensiveProposal"), (False, "FittedGaussian")])
def test_the_independence_proposal_above_high_dimension(monkeypatch, kernel_density, proposal):
    seen = []
    sweep = schedule.independence_sweep

    def recording(walkers, components, component_fn, coefficients, q, rng, support):
        seen.append(type(q).__name__)
        return sweep(walkers, components, component_fn, coefficients, q, rng, support)

    monkeypatch.setattr(schedule, "independence_sweep", recording)
    rounds(kernel_density, gaussian_components, cap=1)
    assert seen == [proposal]
