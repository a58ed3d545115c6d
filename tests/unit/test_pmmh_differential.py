"""SEMC's PMMH under ``strict_budget``: the differential-evolution move in place of the stretch move
(seqbayes.predictive.pmmh, issue 23; why and the measured jumps per re-run: docs/benchmarks.md, "Coulomb at 50,000
calls")."""

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
from seqbayes import SEMC
from seqbayes.core.likelihood import ValidatedLikelihood
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace
from seqbayes.predictive.pmmh import Budget, Refilter, Rejuvenation, outer_logpdf, rejuvenate, run_inner
from seqbayes.predictive.smc2 import KalmanInnerFilter, nested_split


@pytest.fixture(scope="module")
def mixed():
    problem = LinearGaussianStateSpace.mixed()
    data, _ = problem.simulate(12, rng=21)
    return problem, data


def _rejuvenate_exact_draws(problem, data, strict, n, seed):
    """Equal-weight draws of the exact (Kalman) posterior of the static parameters, moved by PMMH until 90 % have
    moved (the stages' rule), with the exact Kalman inner filter."""
    sampler = SEMC(problem.prior, problem.kernel, problem.loglike, n_samples=n, rng=0, **from_flat("SEMC", inner_filter=KalmanInnerFilter(problem.observe), strict_budget=strict))
    config, inner, split = sampler.config, sampler.problem.inner_filter, nested_split(problem.kernel)
    exact = problem.exact(data)[-1]
    mean, cov = exact.mean[split[0]], exact.cov[np.ix_(split[0], split[0])]
    rng = np.random.default_rng(seed)
    static = rng.multivariate_normal(mean, cov, size=n)
    likelihood = ValidatedLikelihood(problem.loglike, None, 1)
    past, last, cloud = run_inner(sampler.problem, inner, split, static, data, (None,) * len(data), likelihood, rng)
    components = np.column_stack([last, outer_logpdf(problem.prior, split[0], static), past])
    out = rejuvenate(Refilter(sampler.problem, inner, split, data, (None,) * len(data)), config, static,
                     np.full(n, -np.log(n)), cloud, components, 1.0, 2.0, Rejuvenation().restarted(30, n),
                     Budget(10**9), likelihood, rng)
    return static, out, mean, np.sqrt(np.diag(cov))


def test_a_strict_budget_moves_semc_by_differential_evolution_and_keeps_the_exact_posterior(mixed):
    """Started from exact draws, the moved cloud is still a sample of the exact posterior: its mean and sd within
    5 Monte Carlo standard errors (sd / sqrt(N)); the particles travelled (a wrong acceptance ratio would drift the
    cloud in the several sweeps it takes until 90 % have moved). The step size is the stretch move's and is left
    alone."""
    problem, data = mixed
    n = 2000
    before, out, mean, sd = _rejuvenate_exact_draws(problem, data, True, n, seed=5)
    moved, stats, step_size, left = out[0], out[3], out[4], out[6]
    assert step_size == 2.0
    assert stats.n_identical_partner == 0 and stats.n_accepted > 0.2 * stats.n_proposed
    assert left.moved.mean() >= 0.9 and stats.n_proposed >= 2 * n      # several sweeps
    got = moved.mean(axis=0)
    assert np.all(np.abs(got - mean) < 5 * sd / np.sqrt(n)), (got, mean, sd)
    got_sd = moved.std(axis=0)
    assert np.all(np.abs(got_sd / sd - 1) < 5 / np.sqrt(2 * n)), (got_sd, sd)
    assert np.mean(np.any(moved != before, axis=1)) >= 0.9


def test_without_a_strict_budget_semc_keeps_the_stretch_move(mixed):
    """The default path is unchanged: the stretch move, its step size adapted by Eq. (9) after each batch."""
    problem, data = mixed
    _, out, _, _ = _rejuvenate_exact_draws(problem, data, False, 400, seed=6)
    assert out[4] != 2.0
