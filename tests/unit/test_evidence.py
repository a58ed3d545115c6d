"""The importance-sampling evidence (seqbayes.predictive.evidence): its proposal at large N."""

import numpy as np
import pytest
from scipy import stats


from seqbayes.predictive.evidence import importance_step, pooled_start, step_standard_errors
from seqbayes.moves import proposals
from seqbayes.moves.proposals import defensive_parts, thinned_components


def test_thinned_keeps_small_sets_and_selects_systematically():
    rng = np.random.default_rng(0)
    points, log_w = rng.normal(size=(50, 2)), rng.normal(size=50)
    same_points, same_w = thinned_components(points, log_w, 50)
    assert same_points is points and same_w is log_w  # at most n_components: untouched (bit-identical runs)
    many, many_w = rng.normal(size=(20000, 2)), rng.normal(size=20000)
    centres, counts = thinned_components(many, many_w, 1000)
    assert centres.shape[0] <= 1000 and np.exp(counts).sum() == pytest.approx(1000)
    # the selection is a weighted sample: its mean differs from the weighted mean by ~ 1 / sqrt(K_eff);
    # log-normal weights (sd 1) keep K_eff = e^-1 1000 = 370 effective draws, sd 0.05; asserted at 4 sd
    w = np.exp(many_w - many_w.max())
    np.testing.assert_allclose(np.exp(counts) @ centres / 1000, w @ many / w.sum(), atol=0.2)
    again = thinned_components(many, many_w, 1000)  # deterministic: no random draw
    np.testing.assert_array_equal(again[0], centres)


def test_proposal_has_at_most_the_cap_of_components(monkeypatch):
    rng = np.random.default_rng(1)
    u = rng.normal(size=(3000, 3))
    kde, _ = defensive_parts(u, np.zeros(3000))
    assert kde.centres.shape[0] == proposals.MAX_PROPOSAL_COMPONENTS == 1000
    monkeypatch.setattr(proposals, "MAX_PROPOSAL_COMPONENTS", 10**9)
    assert defensive_parts(u, np.zeros(3000))[0].centres.shape[0] == 3000


def test_thinned_proposal_gives_the_exact_evidence():
    # Gaussian prior N(0, I_2), likelihood N(y; theta, 0.5^2 I): log Z in closed form. N = 6000 exact
    # posterior draws, proposal capped at 1000 components. Over seeds 0-19: error +0.0006 +- 0.0025 nats,
    # importance ESS >= 94 %; asserted within 0.015 (6 sd) of the closed form and ESS > 80 %
    d, y, s = 2, np.array([0.7, -0.3]), 0.5
    exact = stats.multivariate_normal(np.zeros(d), (1 + s**2) * np.eye(d)).logpdf(y)
    rng = np.random.default_rng(2)
    post_var = 1 / (1 + 1 / s**2)
    posterior = rng.normal(post_var * y / s**2, np.sqrt(post_var), size=(6000, d))
    prior = stats.multivariate_normal(np.zeros(d), np.eye(d))

    def loglike(theta):
        return stats.multivariate_normal(y, s**2 * np.eye(d)).logpdf(theta)

    components = np.column_stack([loglike(posterior), prior.logpdf(posterior)])
    support = np.array([[-np.inf, np.inf]] * d)
    log_z, ess, *_ = importance_step(posterior, np.zeros(6000), components, prior.logpdf, loglike, support, rng)
    assert log_z == pytest.approx(exact, abs=0.015)
    assert ess > 0.8 * 6000


def _replicated_gaussian_evidence(n_sweeps=1, pool_sweeps=False, replications=200, n=200, seed=0):
    """``(errors, reported)``: the importance step's log-evidence errors and reported se over ``replications`` of
    ``n`` exact posterior draws of a Gaussian prior N(0, I_2) and likelihood N(y; theta, 0.5^2 I) (closed form)."""
    d, y, s = 2, np.array([0.7, -0.3]), 0.5
    exact = stats.multivariate_normal(np.zeros(d), (1 + s**2) * np.eye(d)).logpdf(y)
    prior = stats.multivariate_normal(np.zeros(d), np.eye(d))
    likelihood = stats.multivariate_normal(y, s**2 * np.eye(d))
    post_var = 1 / (1 + 1 / s**2)
    rng = np.random.default_rng(seed)
    errors, reported = [], []
    for _ in range(replications):
        posterior = rng.normal(post_var * y / s**2, np.sqrt(post_var), size=(n, d))
        components = np.column_stack([likelihood.logpdf(posterior), prior.logpdf(posterior)])
        log_z, ess, *_ = importance_step(posterior, np.zeros(n), components, prior.logpdf, likelihood.logpdf,
                                         np.array([[-np.inf, np.inf]] * d), rng, n_sweeps, pool_sweeps=pool_sweeps)
        se, cumulative_se, variance = step_standard_errors(0.0, n, True, ess, None, None, 1, True, np.nan,
                                                           "transition")
        assert cumulative_se == se and variance == pytest.approx(se**2)
        errors.append(log_z - exact)
        reported.append(se)
    return np.array(errors), np.array(reported)


@pytest.mark.slow   # statistical (a spread over replications): make test, not make check
def test_importance_standard_error_matches_the_spread_over_replications():
    # 200 replications of the importance step from N = 200 exact posterior draws: sd of the log-evidence
    # error 0.0198, reported se (rms) 0.0202 (measured, seed 0). The sd of 200 replicates is known to 5 %,
    # so the ratio is asserted within [0.8, 1.25] (4 sd of that uncertainty)
    errors, reported = _replicated_gaussian_evidence()
    assert 0.8 < np.sqrt(np.mean(np.square(reported))) / np.std(errors, ddof=1) < 1.25


@pytest.mark.slow   # statistical (a spread over replications): make test, not make check
def test_pooled_sweeps_lower_the_evidence_error_and_report_it():
    # as above, with 4 sweeps whose draws all enter the estimate (pool_sweeps, the path-space remedy's): sd of the
    # error 0.0117 and 0.0120, reported se (rms) 0.0115 and 0.0116 (seeds 0 and 1), against 0.0198 from the first
    # sweep alone; mean error -0.0011 (1.3 of its sds). Asserted: the ratio within [0.8, 1.25] as above, the spread
    # below 0.015 (the single sweep's 0.0198 less 4 of its 200-replicate sds) and the mean within 4 of its sds
    errors, reported = _replicated_gaussian_evidence(n_sweeps=4, pool_sweeps=True)
    spread = np.std(errors, ddof=1)
    assert 0.8 < np.sqrt(np.mean(np.square(reported))) / spread < 1.25
    assert spread < 0.015
    assert abs(np.mean(errors)) < 4 * spread / np.sqrt(200)


@pytest.mark.parametrize("gaussian", [False, True])
def test_the_importance_sweeps_leave_the_target_invariant_sweep_after_sweep(gaussian):
    # exact draws of a 10-dimensional N(0, I) moved by 20 importance steps of one sweep each: a proposal fitted to
    # the very particles it moves put a kernel on each of them and the cloud drifted from the target (E|x|^2 / d
    # 1.224 +- 0.015, 2.5 % beyond the 1 % quantiles, kernel density, 4 seeds). Tolerances: 5 Monte Carlo sds of
    # 10,000 iid draws (sqrt(2 / 10000) = 0.014, sqrt(0.01 * 0.99 / 10000) = 0.001); over 4 seeds the fixed sweeps
    # gave 0.991 +- 0.003 and 0.0098 +- 0.0004 (kernel density), 0.995 +- 0.003 and 0.0101 +- 0.0004 (Gaussian)
    d, n = 10, 1000
    rng = np.random.default_rng(1)
    prior = stats.multivariate_normal(np.zeros(d), np.eye(d))

    def loglike(theta):
        return np.zeros(theta.shape[0])

    position = rng.standard_normal((n, d))
    components = np.column_stack([loglike(position), prior.logpdf(position)])
    support = np.array([[-50.0, 50.0]] * d)
    log_zs = []
    for _ in range(20):
        log_z, _, position, components, _ = importance_step(position, np.full(n, -np.log(n)), components,
                                                            prior.logpdf, loglike, support, rng, gaussian=gaussian)
        log_zs.append(log_z)
    np.testing.assert_allclose(components[:, 1], prior.logpdf(position))
    assert abs(np.mean(np.sum(position**2, axis=1)) / d - 1.0) < 5 * np.sqrt(2 / (n * d))
    assert abs(np.mean(np.abs(position) > stats.norm.ppf(0.995)) - 0.01) < 5 * np.sqrt(0.01 * 0.99 / (n * d))
    # every step's estimate of Z = 1 (sd 0.03 per step): their mean within 5 of its sds
    assert abs(np.mean(log_zs)) < 5 * 0.035 / np.sqrt(20)


def test_weights_increment_variance_is_the_delta_method():
    # the carried-weights increment log sum_i W_i l_i: variance sum_i (W'_i - W_i)^2, W' = W l / sum W l;
    # with the history prior the cumulative one moves by 1/ESS' - 1/ESS and resets at an importance step
    rng = np.random.default_rng(3)
    before = rng.dirichlet(np.ones(50))
    l = rng.lognormal(size=50)
    after = before * l / (before @ l)
    se, cumulative_se, _ = step_standard_errors(0.01, 50, False, np.nan, before, np.log(after), 1, False, np.nan,
                                                "transition")
    assert se**2 == pytest.approx(np.sum((after - before) ** 2)) and se > 0
    assert cumulative_se**2 == pytest.approx(0.01 + np.sum((after - before) ** 2))
    _, history_se, _ = step_standard_errors(0.01, 50, False, np.nan, before, np.log(after), 1, False, np.nan,
                                            "history")
    assert history_se**2 == pytest.approx(0.01 + after @ after - before @ before)
    se, cumulative_se, variance = step_standard_errors(0.04, 50, True, 25.0, before, np.log(after), 1, True,
                                                       np.nan, "history")
    assert variance == pytest.approx(1 / 25 - 1 / 50) and se**2 == pytest.approx(0.04 + 1 / 25 - 1 / 50)
    # a multi-stage tempering path is not covered
    assert np.isnan(step_standard_errors(0.0, 50, False, np.nan, before, np.log(after), 3, True, np.nan,
                                         "transition")[0])


@pytest.mark.slow   # statistical (a spread over replications): make test, not make check
def test_sampler_reports_a_log_evidence_se_that_matches_the_spread_over_seeds():
    # drifting linear-Gaussian problem (transition mixture: importance + ancestor terms), N = 300, 10 seeds,
    # 3 datasets: reported 0.088 against an sd of 0.063 over the seeds (ratio 1.4, measured; at N = 1000
    # benchmarks/bench_evidence_se.py finds 0.90-1.09 over 100 seeds). The sd of 10 seeds is uncertain by
    # ~24 %, so the ratio is asserted within [0.5, 2.5] at the last step
    from seqbayes import SMC
    from seqbayes.models.linear_gaussian import LinearGaussianStateSpace

    design = np.column_stack([np.ones(10), np.random.default_rng(11).normal(size=10)])
    model = LinearGaussianStateSpace(design, ("drift", "drift"), (0.0, 0.0), (0.1, 0.1), (0.0, 0.0), (1.0, 1.0), 0.5)
    data, _ = model.simulate(3, rng=2024)
    exact = model.exact(data)[-1].log_evidence
    errors, reported = [], []
    for seed in range(10):
        result = SMC(model.prior, model.kernel, model.loglike, n_samples=300, rng=seed).run(data)
        errors.append(result.log_evidence[-1] - exact)
        reported.append(result.log_evidence_se[-1])
        assert np.all(np.isfinite(result.log_evidence_se))
        assert np.all(result.log_evidence_se > 0)  # (not increasing: consecutive increments' errors are correlated)
    ratio = np.sqrt(np.mean(np.square(reported))) / np.std(errors, ddof=1)
    assert 0.5 < ratio < 2.5


def _two_modes(seed):
    """Prior N(0, 9 I_2), likelihood 0.95 N(theta; (1, 0), 0.2^2 I) + 0.05 N(theta; (-1, 0), 0.2^2 I): a posterior
    with modes A and B of weights 0.95 and 0.05 and log Z in closed form. Returns the prior, the log-likelihood,
    log Z, 1000 exact draws of each mode's component of the posterior and the (unbounded) support."""
    a, b, s, w = np.array([1.0, 0.0]), np.array([-1.0, 0.0]), 0.2, 0.05
    prior = stats.multivariate_normal(np.zeros(2), 9 * np.eye(2))

    def loglike(theta):
        return np.logaddexp(np.log(1 - w) + stats.multivariate_normal(a, s**2 * np.eye(2)).logpdf(theta),
                            np.log(w) + stats.multivariate_normal(b, s**2 * np.eye(2)).logpdf(theta))

    marginal = stats.multivariate_normal(np.zeros(2), (9 + s**2) * np.eye(2))
    exact = np.logaddexp(np.log(1 - w) + marginal.logpdf(a), np.log(w) + marginal.logpdf(b))
    post_var = 1 / (1 / 9 + 1 / s**2)
    rng = np.random.default_rng(seed)
    mode_a = rng.normal(post_var * a / s**2, np.sqrt(post_var), size=(1000, 2))
    mode_b = rng.normal(post_var * b / s**2, np.sqrt(post_var), size=(1000, 2))
    return prior, loglike, exact, mode_a, mode_b, np.array([[-np.inf, np.inf]] * 2)


def test_pooled_proposal_moves_particles_into_the_mode_the_posterior_lacks():
    # The particles hold only mode A of _two_modes; another cloud holds only B (the path-space remedy's stored-path
    # start, seqbayes.predictive.transition.PathSpace). Measured over seeds 0-39 (scratch script, 3 sweeps as the samplers):
    # with the other cloud the fraction in B is 0.045 +- 0.007 (0.029-0.065) and the error of log Z
    # -0.005 +- 0.030 (ESS >= 486); without it the fraction is 0.0007 and the error's sd 0.16 (ESS down to 3).
    # Asserted: fraction in [0.02, 0.08] (4 sd), |error| < 0.15 (5 sd), and the fraction without it < 0.01
    prior, loglike, exact, mode_a, mode_b, support = _two_modes(7)
    components = np.column_stack([loglike(mode_a), prior.logpdf(mode_a)])
    log_z, ess, swept, swept_components, _ = importance_step(
        mode_a, np.zeros(1000), components, prior.logpdf, loglike, support, np.random.default_rng(8), 3,
        other=(mode_b, np.zeros(1000)))
    assert 0.02 <= np.mean(swept[:, 0] < 0) <= 0.08
    assert log_z == pytest.approx(exact, abs=0.15)
    np.testing.assert_allclose(swept_components[:, 0], loglike(swept))  # the components follow the moves
    alone = importance_step(mode_a, np.zeros(1000), components, prior.logpdf, loglike, support,
                            np.random.default_rng(8), 3)[2]
    assert np.mean(alone[:, 0] < 0) < 0.01


def test_pooled_proposal_is_the_average_of_its_parts():
    rng = np.random.default_rng(3)
    first, second = (proposals.DefensiveProposal(rng.normal(loc, 1.0, size=(200, 2)), np.zeros(200))
                     for loc in (-3.0, 3.0))
    pooled = proposals.PooledProposal([first, second], np.log([3.0, 1.0]))  # normalised to 0.75, 0.25
    points = rng.normal(size=(50, 2)) * 4
    np.testing.assert_allclose(np.exp(pooled.logpdf(points)),
                               0.75 * np.exp(first.logpdf(points)) + 0.25 * np.exp(second.logpdf(points)), rtol=1e-10)
    draws = pooled.sample(4000, np.random.default_rng(4))
    assert draws.shape == (4000, 2)
    assert abs(np.mean(draws[:, 0] > 0) - 0.25) < 0.03  # binomial sd 0.007


def test_pooled_start_gives_each_cloud_its_share_of_the_mass():
    # _two_modes (modes A, B with weights 0.95, 0.05), a cloud in each mode: over seeds 0-39 (scratch script) the
    # start's fraction drawn from B's cloud is 0.0495 +- 0.0028; asserted within [0.035, 0.065] (5 sd). A cloud
    # trapped where the target is ~e^-90 of its peak (a tempering caught in a minor mode), even as the preferred
    # first cloud, gets parts' shares of at most 0.0027 over those seeds: < 0.01.
    prior, loglike, _, mode_a, mode_b, support = _two_modes(11)
    trapped = np.random.default_rng(12).normal([0.0, 2.5], 0.05, size=(1000, 2))
    rng = np.random.default_rng(13)
    index, shares = pooled_start([(mode_a, np.zeros(1000)), (mode_b, np.zeros(1000))], prior.logpdf,
                                          loglike, support, rng)
    assert index.shape == (1000,) and shares.sum() == pytest.approx(1.0)
    assert 0.035 <= np.mean(index >= 1000) <= 0.065
    index, _ = pooled_start([(trapped, np.zeros(1000)), (mode_a, np.zeros(1000))], prior.logpdf, loglike,
                                     support, rng)
    assert np.mean(index < 1000) < 0.01


def test_pooled_start_draws_n_particles_from_two_half_clouds():
    # The path-space remedy pools two starts of N/2 each into N. Over seeds 0-39 (scratch script: the clouds' first
    # 500 draws, n = 1000) the fraction drawn from B's cloud is 0.0504 +- 0.0034 (0.045-0.058); asserted within
    # [0.035, 0.065] (4.4 sd)
    prior, loglike, _, mode_a, mode_b, support = _two_modes(21)
    index, shares = pooled_start([(mode_a[:500], np.zeros(500)), (mode_b[:500], np.zeros(500))], prior.logpdf,
                                 loglike, support, np.random.default_rng(22), n=1000)
    assert index.shape == (1000,) and index.max() < 1000 and shares.sum() == pytest.approx(1.0)
    assert 0.035 <= np.mean(index >= 500) <= 0.065


def test_clustered_parts_fit_one_part_per_mode():
    # a cloud with two modes 20 sds apart (weights 0.7, 0.3) is split at the gap, and each part keeps its mass
    rng = np.random.default_rng(5)
    u = np.concatenate([rng.normal(0.0, 1.0, size=(700, 3)), rng.normal(20.0, 1.0, size=(300, 3))])
    parts, log_weights, members = proposals.clustered_parts([(u, np.zeros(1000))], rng)
    assert len(parts) == 2
    masses = sorted(np.exp(log_weights))
    np.testing.assert_allclose(masses, [0.3, 0.7])
    for _, member in members:  # each part holds one mode whole
        assert len(np.unique(u[member, 0] > 10)) == 1
