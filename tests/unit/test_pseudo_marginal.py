"""The subsample estimate of the transition mixture (Eq. A3) and the pseudo-marginal moves built on it.

Tolerances are Monte Carlo ones: each check allows 4.5 standard errors (measured from the same
draws), so a correct implementation fails one of them with probability ~1e-5; the seeds are fixed.
"""

import numpy as np
import pytest
from scipy import stats

from seqbayes import SMC, Drift, JointPrior, MarkovKernel
from seqbayes.predictive import mixture as density_module
from seqbayes.predictive.mixture import GaussianMixture
from seqbayes.predictive.pseudo_marginal import SubsampledPrior
from seqbayes.moves import GaussianMove, gaussian_sweep
from seqbayes.engine.settings import from_flat


def mixture(n=3000, d=2, width=0.5, seed=0, zero_weights=True):
    rng = np.random.default_rng(seed)
    log_w = rng.normal(size=n)
    if zero_weights:
        log_w[:50] = -np.inf   # weightless components must never be drawn
    return GaussianMixture(rng.normal(size=(n, d)), np.full(d, width), log_w)


def test_estimate_is_unbiased_with_the_stated_variance():
    g = mixture()
    points = np.array([[0.0, 0.0], [1.0, -0.5], [-1.5, 0.3], [2.5, 2.5]])
    reps, n_terms = 20000, 4
    rng = np.random.default_rng(1)
    ratio = np.exp(g.subsample_logpdf(np.repeat(points, reps, axis=0), n_terms, rng)
                   - np.repeat(g.logpdf(points), reps)).reshape(len(points), reps)
    mean, se = ratio.mean(axis=1), ratio.std(axis=1) / np.sqrt(reps)
    assert np.all(np.abs(mean - 1.0) < 4.5 * se + 1e-4), (mean, se)   # 1e-4: single-precision exact value
    predicted = np.expm1(g.log_second_moment(points)) / n_terms
    measured = ratio.var(axis=1)
    # sd of a sample variance ~ var sqrt((kurtosis - 1) / reps): within 15 % at the three inner points
    np.testing.assert_allclose(measured[:3], predicted[:3], rtol=0.15)


def test_second_moment_against_brute_force():
    g = mixture(n=400, seed=2)
    points = np.array([[0.3, -0.2], [2.0, 1.0]])
    cache = g._ancestor_proposal()
    x = (points - g._shift) / g.bandwidth
    q = g._proposal(x)                                              # (m, K) cluster probabilities
    w = np.exp(g.log_weights)
    terms = np.exp(-0.5 * np.sum((x[:, None, :] - cache["scaled"][None]) ** 2, axis=2))   # T_j up to a constant
    p = terms @ w
    with np.errstate(divide="ignore", invalid="ignore"):
        proposal = np.where(w > 0, q[:, cache["cluster_of"]] * w / cache["cluster_weights"][cache["cluster_of"]], 0)
        second = np.nansum(np.where(w > 0, (w * terms) ** 2 / proposal, 0.0), axis=1)
    np.testing.assert_allclose(g.log_second_moment(points), np.log(second / p**2), rtol=1e-6)
    np.testing.assert_allclose(q.sum(axis=1), 1.0)


def test_start_values_are_draws_of_the_extended_target():
    """The start values (the draw's own component first) must follow the extended target, whose law of
    ``R = p_hat / p`` given ``theta`` is ``R`` times its law with every component drawn afresh: so
    ``E_start[f(R)] = E_fresh[R f(R)]`` for any ``f`` (here the bounded ``f(R) = 1 / (1 + R)``). The
    fresh draws' own ``E_fresh[f(R)]`` differs: the check can tell the two apart."""
    g = mixture(n=4000, d=2, width=0.3, seed=3, zero_weights=False)
    rng = np.random.default_rng(4)
    w = np.exp(g.log_weights)
    own, fresh = [], []
    for _ in range(5):
        theta = g.draw_one_per_component(rng)
        exact = g.logpdf(theta)
        own.append(np.exp(g.subsample_logpdf(theta, 2, rng, first=np.arange(theta.shape[0])) - exact))
        fresh.append(np.exp(g.subsample_logpdf(theta, 2, rng) - exact))
    own, fresh = np.concatenate(own), np.concatenate(fresh)
    weights = np.tile(w, 5) / 5

    def weighted(values):
        mean = weights @ values
        return mean, np.sqrt(np.sum(weights**2 * (values - mean) ** 2))

    start, start_se = weighted(1.0 / (1.0 + own))
    tilted, tilted_se = weighted(fresh / (1.0 + fresh))
    assert abs(start - tilted) < 4.5 * np.hypot(start_se, tilted_se), (start, tilted)
    untilted, untilted_se = weighted(1.0 / (1.0 + fresh))
    assert abs(untilted - start) > 5 * np.hypot(start_se, untilted_se), (start, untilted)


def posterior_mixture(g, y, noise):
    """The exact posterior of a Gaussian likelihood ``N(y; theta, noise^2 I)`` under ``g``: a mixture."""
    h2, s2 = g.bandwidth**2, noise**2
    log_w = g.log_weights + stats.norm.logpdf(y, g.centres, np.sqrt(h2 + s2)).sum(axis=1)
    log_w -= np.logaddexp.reduce(log_w)
    means = (g.centres * s2 + y * h2) / (h2 + s2)
    return np.exp(log_w), means, np.sqrt(h2 * s2 / (h2 + s2))


@pytest.mark.slow
def test_pseudo_marginal_moves_leave_the_exact_posterior_invariant():
    """Particles drawn exactly from ``L p`` with start values of the extended target, then 10 sweeps of
    pseudo-marginal random-walk MH (the sampler's Gaussian move, 2 terms: a noisy estimate): the mean,
    variance and distribution (KS) stay those of the exact posterior."""
    g = mixture(n=2000, d=2, width=0.4, seed=5, zero_weights=False)
    y, noise = np.array([0.8, -0.5]), 0.6
    w, means, sd = posterior_mixture(g, y, noise)
    rng = np.random.default_rng(6)
    n = 20000
    ancestor = rng.choice(w.size, size=n, p=w)
    theta = means[ancestor] + sd * rng.standard_normal((n, 2))
    n_terms = 2

    def loglike(points):
        return stats.norm.logpdf(y, points, noise).sum(axis=1)

    components = np.column_stack([loglike(theta), g.subsample_logpdf(theta, n_terms, rng, first=ancestor)])
    exact_mean = w @ means
    exact_var = w @ (means**2 + sd**2) - exact_mean**2
    move = GaussianMove(np.diag(exact_var), 1.0)
    accepted = 0
    for _ in range(10):
        theta, components, sweep = gaussian_sweep(
            theta, components, lambda p: np.column_stack([loglike(p), g.subsample_logpdf(p, n_terms, rng)]),
            np.array([1.0, 1.0]), move, rng, None)
        accepted += sweep.n_accepted
    assert accepted > 0.2 * 10 * n   # the chain does move
    mean_se = np.sqrt(exact_var / n)
    assert np.all(np.abs(theta.mean(axis=0) - exact_mean) < 4.5 * mean_se)
    assert np.all(np.abs(theta.var(axis=0) / exact_var - 1.0) < 4.5 * np.sqrt(2.0 / n) * 1.5)
    cdf = lambda x: w @ stats.norm.cdf((x[None, :] - means[:, :1]) / sd[0])   # noqa: E731
    assert stats.kstest(theta[:, 0], cdf).pvalue > 1e-4


@pytest.mark.slow
def test_start_chooses_the_subsample_in_the_bulk_and_exact_under_conflict():
    g = mixture(n=8000, d=2, width=0.3, seed=7, zero_weights=False)
    rng = np.random.default_rng(8)
    particles = g.draw_one_per_component(rng)
    prior = SubsampledPrior(g, rng)
    bulk = stats.norm.logpdf(0.2, particles, 0.5).sum(axis=1)
    values = prior.start(particles, g.log_weights, bulk)
    assert prior.n_terms is not None and prior.n_terms <= g.centres.shape[0] / 32
    assert np.all(np.isfinite(values)) and np.std(values - g.logpdf(particles)) < 1.5
    tail = stats.norm.logpdf(6.0, particles, 0.2).sum(axis=1)   # the data far in the mixture's tail
    values = prior.start(particles, g.log_weights, tail)
    assert prior.n_terms is None
    np.testing.assert_array_equal(values, g.logpdf(particles))
    # a restart from the restricted prior is not the mixture's per-component draws: exact
    prior.start(particles, g.log_weights, bulk, own_draws=False)
    assert prior.n_terms is None


def test_refreshed_falls_back_to_exact_values_when_particles_reach_the_tail():
    g = mixture(n=8000, d=2, width=0.3, seed=9, zero_weights=False)
    rng = np.random.default_rng(10)
    particles = g.draw_one_per_component(rng)
    prior = SubsampledPrior(g, rng)
    prior.start(particles, g.log_weights, np.zeros(particles.shape[0]))
    assert prior.n_terms is not None
    components = np.column_stack([np.zeros(8000), prior(particles)])
    assert prior.refreshed(particles, components) is components   # still accurate: unchanged
    far = particles * 0.2 + 4.0
    refreshed = prior.refreshed(far, components)
    assert prior.n_terms is None and prior.fell_back
    np.testing.assert_array_equal(refreshed[:, 1], g.logpdf(far))
    np.testing.assert_array_equal(prior(far[:5]), g.logpdf(far[:5]))


def test_ancestor_ess_from_a_subsample_of_rows(monkeypatch):
    g = mixture(n=6000, d=2, width=0.3, seed=11, zero_weights=False)
    rng = np.random.default_rng(12)
    theta = g.draw_one_per_component(rng)[:5000] * 0.7 + 0.3   # a posterior: a part of the mixture
    log_w = rng.normal(size=5000) * 0.5
    estimate = g.ancestor_ess(theta, log_w)
    monkeypatch.setattr(density_module, "TREE_MIN_CENTRES", 10**9)   # every row
    exact = g.ancestor_ess(theta, log_w)
    assert abs(estimate / exact - 1.0) < 0.05, (estimate, exact)


def test_config_rejects_a_negative_threshold():
    with pytest.raises(ValueError, match="pseudo_marginal_from"):
        from_flat("SMC", pseudo_marginal_from=-1)


def drifting_sampler(n, seed, **settings):
    prior = JointPrior({"a": stats.norm(0, 1), "b": stats.norm(0, 1)})
    kernel = MarkovKernel([Drift(0.0, noise_std=0.1), Drift(0.0, noise_std=0.1)])

    def loglike(theta, y):
        return -0.5 * np.sum((y[None] - theta[:, None]) ** 2, axis=(1, 2)) / 0.25

    return SMC(prior, kernel, loglike, n_samples=n, rng=seed, **from_flat("SMC", **settings))


def test_pseudo_marginal_run_is_reproducible_and_resumes_bit_for_bit(monkeypatch):
    used = []
    original = SubsampledPrior.start

    def start(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        used.append(self.n_terms)
        return out

    monkeypatch.setattr(SubsampledPrior, "start", start)
    rng = np.random.default_rng(13)
    data = [rng.normal(0.3, 0.5, size=(5, 2)) for _ in range(4)]
    first = drifting_sampler(600, 1, pseudo_marginal_from=500)
    for y in data:
        first.update(y)
    assert any(m is not None for m in used)   # the pseudo-marginal path ran
    second = drifting_sampler(600, 1, pseudo_marginal_from=500)
    for y in data[:2]:
        second.update(y)
    state, records, rng_state = second.snapshot()
    resumed = drifting_sampler(600, 99, pseudo_marginal_from=500)
    resumed.restore(state, records, rng_state)
    for y in data[2:]:
        resumed.update(y)
    for a, b in zip(first.result.steps, resumed.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        assert a.info.log_evidence == b.info.log_evidence
    # below the threshold the moves evaluate the mixture exactly: the same numbers as without the option
    plain, off = drifting_sampler(600, 1), drifting_sampler(600, 1, pseudo_marginal_from=0)
    for y in data[:3]:
        plain.update(y)
        off.update(y)
    np.testing.assert_array_equal(plain.result.steps[-1].posterior, off.result.steps[-1].posterior)


def test_a_step_in_the_mixtures_tail_evaluates_exactly(monkeypatch):
    """Prior-data conflict end to end: a dataset far in the predictive mixture's tail makes that step evaluate
    the mixture exactly (and the steps before it run pseudo-marginal). Either check may switch: the pilot at the
    step's start, from the relative variance at the tail draws it happens to select, or the check before a move,
    at the particles the data have pulled into the tail (seeds 0-11 of this sampler: the pilot in 4, the move's
    check in 6, neither in 2, whose subsample stayed within SUBSAMPLE_MAX_VARIANCE at 21 and 31 terms)."""
    chosen, subsamplers = [], []
    original = SubsampledPrior.start

    def start(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        chosen.append(self.n_terms)
        subsamplers.append(self)
        return out

    monkeypatch.setattr(SubsampledPrior, "start", start)
    rng = np.random.default_rng(14)
    sampler = drifting_sampler(1000, 2, pseudo_marginal_from=500, conflict_remedy=False)
    for _ in range(3):
        sampler.update(rng.normal(0.3, 0.5, size=(5, 2)))
    sampler.update(rng.normal(2.5, 0.5, size=(5, 2)))   # ~10 posterior sds away
    assert all(m is not None for m in chosen[:2]), chosen
    assert chosen[-1] is None or subsamplers[-1].fell_back, chosen
    assert subsamplers[-1].n_terms is None
