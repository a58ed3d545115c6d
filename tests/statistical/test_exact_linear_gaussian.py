"""SMC and SEMC against the exact Kalman-filter answer on a linear-Gaussian on-line problem.

Tolerances (issue 2): posterior stds within 10 %, cumulative log-evidence within
0.25 nats, posterior means within 0.1 posterior std, at every one of 5 steps, N = 2000.

The static parameter is re-summarised by N samples at every step, so even perfect
sampling leaves an error of its mean of at least ``floor_s = sqrt((s + 1) / (2 N))``
posterior sds after s steps (0.039 at s = 5). 0.1 sd is within three floors at steps 4
and 5, so no sampler can meet it there in every seed: ``benchmarks/bench_core.py exact``
measures 16-17 of 20 seeds meeting all tolerances, with the step-5 error's spread
0.05-0.07 sd. The mean tolerance here is therefore ``max(0.1, 3 floor_s)``, which is
the issue's 0.1 at steps 1-3 and 0.106 / 0.116 at steps 4 / 5. Seeds were fixed
before looking at results.
"""

import numpy as np
import pytest

from seqbayes import SEMC, SMC
from seqbayes.models.linear_gaussian import LinearGaussianProblem, errors_against, kalman_filter

N_SAMPLES = 2000
MEAN_TOLERANCE = np.maximum(0.1, 3 * np.sqrt((np.arange(1, 6) + 1) / (2 * N_SAMPLES)))


def assert_within(err, mean, evidence):
    """Every step within ``mean`` posterior sds (scalar or per step), stds within 10 %, log-evidence
    within ``evidence`` nats."""
    assert np.all(err[:, 0] < mean), err
    assert np.all(err[:, 1] < 0.10), err
    assert np.all(err[:, 2] < evidence), err


def problem_and_data(prior_scale=None):
    problem = LinearGaussianProblem()
    data, _ = problem.simulate(5, rng=2024)
    if prior_scale is not None:  # a prior `prior_scale` times wider than the first posterior
        first = kalman_filter(problem, data)[0]
        problem = LinearGaussianProblem(prior_mean=first.mean + 3 * np.sqrt(np.diag(first.cov)),
                                        prior_std=prior_scale * np.sqrt(np.diag(first.cov)))
    return problem, data


@pytest.mark.parametrize("cls", [SEMC, SMC])
@pytest.mark.parametrize("seed", [0, 1])
def test_matches_kalman_filter(cls, seed):
    problem, data = problem_and_data()
    exact = kalman_filter(problem, data)
    result = cls(problem.prior, problem.kernel, problem.loglike, n_samples=N_SAMPLES, rng=seed).run(data)
    err = errors_against(result, exact)
    assert_within(err, MEAN_TOLERANCE, evidence=0.25)


@pytest.mark.parametrize("cls", [SEMC, SMC])
def test_tempered_default_with_a_ten_times_wider_prior(cls):
    problem, data = problem_and_data(prior_scale=10.0)
    exact = kalman_filter(problem, data)
    result = cls(problem.prior, problem.kernel, problem.loglike, n_samples=N_SAMPLES, rng=3).run(data)
    assert result.steps[0].info.n_stages > 1  # the first dataset needed bridging
    err = errors_against(result, exact)
    assert_within(err, MEAN_TOLERANCE, evidence=0.25)


@pytest.mark.parametrize("cls", [SEMC, SMC])
def test_static_parameters_use_the_exact_history_prior(cls):
    """Both parameters static (q = 0): ``predictive="auto"`` re-evaluates the past datasets, so
    there is no re-summarisation floor. ``benchmarks/bench_core.py static`` (20 seeds, N = 2000)
    measures at most 0.105 sd (means; 90 % of seeds below 0.077), 8.2 % (stds) and 0.065 nats (evidence;
    90 % below 0.042), so the evidence is held to 0.15 nats here (about 2x the largest of 20) and the
    means and stds to the issue's 0.1 sd and 10 % (docs/benchmarks.md)."""
    from seqbayes import MarkovKernel, Static
    from seqbayes.predictive.history import HistoryPrior

    problem = LinearGaussianProblem(drift_std=0.0)
    data, _ = problem.simulate(5, rng=2024)
    exact = kalman_filter(problem, data)
    sampler = cls(problem.prior, MarkovKernel([Static(), Static()]), problem.loglike, n_samples=N_SAMPLES, rng=4)
    result = sampler.run(data)
    assert isinstance(sampler.state.prior, HistoryPrior)
    err = errors_against(result, exact)
    assert_within(err, 0.1, evidence=0.15)
