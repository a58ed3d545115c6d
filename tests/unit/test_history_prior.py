"""The exact history prior of static parameters (``predictive="history"``, chosen by ``"auto"``)
and IBIS's resample-move schedule (``move_every_stage=False``): exact values, evaluation
counts, reproducibility, resumption and input validation."""

import numpy as np
import pytest
from scipy import stats

from seqbayes.engine.settings import from_flat
from seqbayes import SEMC, SMC, Drift, JointPrior, MarkovKernel, Static, ZeroLikelihoodError
from seqbayes.predictive.history import HistoryPrior
from seqbayes.predictive.mixture import GaussianMixture
from seqbayes.models.linear_gaussian import LinearGaussianProblem
from seqbayes.predictive.particle import count_distinct
from seqbayes.predictive.base import resolve_predictive
from seqbayes.predictive.history import History
from seqbayes.predictive.transition import KernelDensity

PROBLEM = LinearGaussianProblem(drift_std=0.0)
STATIC = MarkovKernel([Static(), Static()])
DATA, _ = PROBLEM.simulate(4, rng=3)
IBIS = dict(n_moves=1, moved_fraction=0.0, move_every_stage=False, evidence="path", tempering=False)


def make(cls=SMC, n=300, seed=0, kernel=STATIC, **kw):
    return cls(PROBLEM.prior, kernel, PROBLEM.loglike, n_samples=n, rng=seed, **from_flat(cls.__name__, **kw))


def test_history_prior_is_the_prior_times_past_likelihoods():
    theta = np.random.default_rng(0).normal(size=(7, 2))
    prior = HistoryPrior(PROBLEM.prior, tuple(DATA[:3]), 1.25)
    expected = PROBLEM.prior.logpdf(theta) + sum(PROBLEM.loglike(theta, d) for d in DATA[:3]) - 1.25
    np.testing.assert_allclose(prior.logpdf(theta, PROBLEM.loglike), expected, rtol=1e-13)


def test_history_prior_skips_rows_already_at_zero():
    calls = []

    def loglike(theta, data):
        calls.append(theta.shape[0])
        return np.where(theta[:, 0] > data, -np.inf, 0.0)

    prior = HistoryPrior(JointPrior([stats.uniform(0, 1)]), (0.5, 0.2, 0.1), 0.0)
    values = prior.logpdf(np.array([[0.05], [0.3], [0.7], [1.5]]), loglike)
    np.testing.assert_array_equal(values, [0.0, -np.inf, -np.inf, -np.inf])
    assert calls == [3, 2, 1]  # 1.5 is outside the prior; 0.7 dies on 0.5, 0.3 on 0.2


def test_auto_chooses_history_for_static_kernels_only():
    assert resolve_predictive(None, STATIC).method == "history"
    assert resolve_predictive(None, PROBLEM.kernel).method == "smc2"  # a drifting and a static parameter
    assert resolve_predictive(None, MarkovKernel([Drift(0.0, noise_std=0.1), Drift(0.0, noise_std=0.1)])).method == \
        "transition"
    assert resolve_predictive(KernelDensity(), STATIC).method == "kde"
    with pytest.raises(ValueError, match="predictive: History .* needs a kernel whose every parameter is Static"):
        resolve_predictive(History(), PROBLEM.kernel)
    with pytest.raises(ValueError, match="predictive: History"):
        make(kernel=MarkovKernel([Drift(0.0, noise_std=0.1), Static()]), predictive="history")
    assert STATIC.is_static and not PROBLEM.kernel.is_static


def test_the_next_prior_is_the_posterior_itself():
    sampler = make()
    sampler.update(DATA[0])
    state, record = sampler.state, sampler.result.steps[0]
    assert isinstance(state.prior, HistoryPrior) and len(state.prior.datasets) == 1
    np.testing.assert_array_equal(record.predictive, record.posterior)  # no kernel density, no jitter
    assert state.prior.log_normaliser == record.info.log_evidence
    # the cached prior values at the particles are the history prior's own values
    np.testing.assert_allclose(state.log_prior, state.prior.logpdf(state.particles, PROBLEM.loglike), rtol=1e-12,
                               atol=1e-12)  # log-densities near 0 differ in the last bits of their sums
    transition = make(predictive="transition")
    transition.update(DATA[0])
    assert isinstance(transition.state.prior, GaussianMixture)


def test_stored_datasets_are_copies():
    data = DATA.copy()
    sampler = make()
    sampler.update(data[0])
    data[0] += 100.0  # the caller reuses its buffer
    np.testing.assert_array_equal(sampler.state.prior.datasets[0], DATA[0])


def test_ibis_schedule_evaluation_counts_are_exact():
    """Reweighting costs N evaluations; the deferred resample-move at the start of step s, one MH
    proposal per particle, costs N (s - 1) (the past datasets; the new one is evaluated after)."""
    n = 300
    sampler = make(SMC, n=n, seed=4, **IBIS)
    moved = 0
    for s, d in enumerate(DATA, start=1):
        info = sampler.update(d)
        expected = n + (n * (s - 1) if info.resampled else 0)
        assert info.n_loglike_evals == expected, (s, info)
        assert info.n_proposed == (n if info.resampled else 0)
        moved += info.resampled
        if not info.resampled:
            assert info.n_stages == 1 and info.n_move_evaluations == 0
    assert moved >= 1  # the data are informative enough that the schedule resampled at least once


def test_ibis_schedule_defers_resampling_of_the_last_step():
    sampler = make(SMC, seed=4, **IBIS)
    info = sampler.update(DATA[0])
    assert not info.resampled and info.ess < 0.5 * 300  # kept weighted: the move waits for the next dataset
    assert count_distinct(sampler.result.steps[0].posterior) == 300
    info = sampler.update(DATA[1])
    assert info.resampled


@pytest.mark.parametrize("cls", [SMC, SEMC])
@pytest.mark.parametrize("settings", [{}, IBIS], ids=["defaults", "ibis"])
def test_same_seed_same_numbers_and_snapshot_resumes_bit_for_bit(cls, settings):
    settings = dict(settings)
    if cls is SEMC:
        settings.pop("n_moves", None)
    full = make(cls, seed=8, **settings).run(DATA)
    again = make(cls, seed=8, **settings).run(DATA)
    first = make(cls, seed=8, **settings)
    first.update(DATA[0])
    first.update(DATA[1])
    resumed = make(cls, seed=99, **settings)
    resumed.restore(*first.snapshot())
    resumed.update(DATA[2])
    resumed.update(DATA[3])
    for a, b, c in zip(full.steps, again.steps, resumed.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.posterior, c.posterior)
        np.testing.assert_array_equal(a.log_weights, c.log_weights)
        assert a.info.log_evidence == b.info.log_evidence == c.info.log_evidence


def test_zero_likelihood_for_every_weighted_particle_names_the_step():
    def loglike(theta, data):  # a dataset that rules out every particle (e.g. a sensor limit exceeded)
        if isinstance(data, str):
            return np.full(theta.shape[0], -np.inf)
        return PROBLEM.loglike(theta, data)

    sampler = SMC(PROBLEM.prior, STATIC, loglike, n_samples=100, rng=0)
    sampler.update(DATA[0])
    with pytest.raises(ZeroLikelihoodError, match="step 2: every sample has zero likelihood"):
        sampler.update("out of range")


def test_count_distinct_matches_numpy_unique():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(500, 3))[rng.integers(0, 500, 500)]
    assert count_distinct(x) == np.unique(x, axis=0).shape[0]
    x[0, 1], x[1, 1] = 0.0, -0.0
    x[1, [0, 2]] = x[0, [0, 2]]
    assert count_distinct(x) == np.unique(x, axis=0).shape[0]
    one_column_apart = np.array([[1.0, 2.0], [1.0, np.nextafter(2.0, 3.0)], [1.0, 2.0]])
    assert count_distinct(one_column_apart) == 2


def test_only_zero_weight_particles_with_a_likelihood_is_a_zero_likelihood_error():
    """The IBIS schedule carries weights, some of them zero; a dataset whose likelihood is non-zero
    only at those particles has no weighted support: a clear error, not a crash in the bisection."""
    prior = JointPrior([stats.uniform(0, 1)])

    def loglike(theta, data):  # "low" rules out theta >= 0.5, "high" rules out theta < 0.5
        low = theta[:, 0] < 0.5
        return np.where(low if data == "low" else ~low, 0.0, -np.inf)

    sampler = SMC(prior, MarkovKernel([Static()]), loglike, n_samples=200, rng=0, **from_flat("SMC", **{k: v for k, v in IBIS.items() if k != "tempering"}, min_valid_fraction=0.0,
                                        ess_threshold=0.3))
    info = sampler.update("low")
    assert not info.resampled and np.isinf(sampler.state.log_weights).any()
    with pytest.raises(ZeroLikelihoodError, match="step 2: every sample with a non-zero weight has zero likelihood"):
        sampler.update("high")
