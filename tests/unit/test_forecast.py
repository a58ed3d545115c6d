"""Forecasts restricted to the parameter space (issue 11, item 4): ``seqbayes.engine.forecast.forecast``."""

import numpy as np
import pytest
from scipy import stats

import seqbayes
from seqbayes.engine.forecast import forecast

Q, START = 0.1, 0.9
KERNEL = seqbayes.MarkovKernel([seqbayes.Drift(0.0, noise_std=Q)])
BOX = np.array([[0.0, 1.0]])


def exact_restricted_moments(horizon):
    """Mean and sd of theta_h given theta_0 = START and theta_1..h in [0, 1], by recursion on a grid."""
    grid = np.linspace(0.0, 1.0, 4001)
    density = stats.norm.pdf(grid, START, Q)
    for _ in range(horizon - 1):
        density = np.trapezoid(density[None, :] * stats.norm.pdf(grid[:, None], grid[None, :], Q), grid, axis=1)
    density /= np.trapezoid(density, grid)
    mean = np.trapezoid(grid * density, grid)
    return mean, np.sqrt(np.trapezoid((grid - mean) ** 2 * density, grid))


@pytest.mark.slow
def test_forecasts_are_the_model_s_paths_conditioned_on_the_box():
    samples = np.full((20000, 1), START)
    draws = forecast(samples, KERNEL, BOX, 3, np.random.default_rng(0))
    assert draws.shape == (3, 20000, 1)
    assert np.all((draws >= 0.0) & (draws <= 1.0))
    for h in range(3):
        mean, sd = exact_restricted_moments(h + 1)
        # Monte Carlo error of a mean of 20,000 independent paths: sd / sqrt(20000) ~ 5e-4
        assert abs(draws[h, :, 0].mean() - mean) < 4 * sd / np.sqrt(20000)
        assert abs(draws[h, :, 0].std() / sd - 1) < 0.05
    # one step ahead it is the normal truncated to the box
    assert exact_restricted_moments(1)[0] == pytest.approx(
        stats.truncnorm.mean(-START / Q, (1 - START) / Q, loc=START, scale=Q), rel=1e-6)


def test_an_unbounded_space_gives_the_plain_propagation_draw_for_draw():
    samples = np.random.default_rng(1).normal(size=(50, 1))
    draws = forecast(samples, KERNEL, np.array([[-np.inf, np.inf]]), 4, np.random.default_rng(2))
    rng, current, plain = np.random.default_rng(2), samples, []
    for _ in range(4):
        current = KERNEL.propagate(current, rng)
        plain.append(current)
    np.testing.assert_array_equal(draws, np.stack(plain))


def test_a_kernel_that_leaves_the_box_for_good_is_refused():
    away = seqbayes.MarkovKernel([seqbayes.Drift(-5.0, noise_std=Q)])
    with pytest.raises(ValueError, match="stays inside the parameter space"):
        forecast(np.full((10, 1), 0.5), away, BOX, 1, np.random.default_rng(0), max_rounds=3)


def test_the_sampler_s_forecast_stays_in_the_prior_box():
    prior = seqbayes.JointPrior({"a": stats.uniform(0.0, 1.0)})
    loglike = lambda theta, y: stats.norm.logpdf(y, theta[:, 0], 0.05)  # noqa: E731
    sampler = seqbayes.SMC(prior, KERNEL, loglike, n_samples=500, rng=0)
    sampler.update(0.02)  # near the bound: unrestricted, a third of the next step's draws would fall below 0
    draws = sampler.predict(3)
    assert np.all((draws >= 0.0) & (draws <= 1.0))
