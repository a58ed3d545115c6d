"""The importance-sampling evidence (seqbayes.evidence): its proposal at large N."""

import numpy as np
import pytest
from scipy import stats

from seqbayes import evidence
from seqbayes.evidence import _proposal, _thinned, importance_step, step_standard_errors


def test_thinned_keeps_small_sets_and_selects_systematically():
    rng = np.random.default_rng(0)
    points, log_w = rng.normal(size=(50, 2)), rng.normal(size=50)
    same_points, same_w = _thinned(points, log_w, 50)
    assert same_points is points and same_w is log_w  # at most n_components: untouched (bit-identical runs)
    many, many_w = rng.normal(size=(20000, 2)), rng.normal(size=20000)
    centres, counts = _thinned(many, many_w, 1000)
    assert centres.shape[0] <= 1000 and np.exp(counts).sum() == pytest.approx(1000)
    # the selection is a weighted sample: its mean differs from the weighted mean by ~ 1 / sqrt(K_eff);
    # log-normal weights (sd 1) keep K_eff = e^-1 1000 = 370 effective draws, sd 0.05; asserted at 4 sd
    w = np.exp(many_w - many_w.max())
    np.testing.assert_allclose(np.exp(counts) @ centres / 1000, w @ many / w.sum(), atol=0.2)
    again = _thinned(many, many_w, 1000)  # deterministic: no random draw
    np.testing.assert_array_equal(again[0], centres)


def test_proposal_has_at_most_the_cap_of_components(monkeypatch):
    rng = np.random.default_rng(1)
    u = rng.normal(size=(3000, 3))
    kde, _ = _proposal(u, np.zeros(3000))
    assert kde.centres.shape[0] == evidence.MAX_PROPOSAL_COMPONENTS == 1000
    monkeypatch.setattr(evidence, "MAX_PROPOSAL_COMPONENTS", 10**9)
    assert _proposal(u, np.zeros(3000))[0].centres.shape[0] == 3000


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


def test_importance_standard_error_matches_the_spread_over_replications():
    # 200 replications of the importance step from N = 200 exact posterior draws: sd of the log-evidence
    # error 0.0198, reported se (rms) 0.0202 (measured, seed 0). The sd of 200 replicates is known to 5 %,
    # so the ratio is asserted within [0.8, 1.25] (4 sd of that uncertainty)
    d, y, s = 2, np.array([0.7, -0.3]), 0.5
    exact = stats.multivariate_normal(np.zeros(d), (1 + s**2) * np.eye(d)).logpdf(y)
    prior = stats.multivariate_normal(np.zeros(d), np.eye(d))
    likelihood = stats.multivariate_normal(y, s**2 * np.eye(d))
    post_var = 1 / (1 + 1 / s**2)
    rng = np.random.default_rng(0)
    errors, reported = [], []
    for _ in range(200):
        posterior = rng.normal(post_var * y / s**2, np.sqrt(post_var), size=(200, d))
        components = np.column_stack([likelihood.logpdf(posterior), prior.logpdf(posterior)])
        log_z, ess, *_ = importance_step(posterior, np.zeros(200), components, prior.logpdf, likelihood.logpdf,
                                         np.array([[-np.inf, np.inf]] * d), rng)
        se, cumulative_se, variance = step_standard_errors(0.0, 200, True, ess, None, None, 1, True, np.nan,
                                                           "transition")
        assert cumulative_se == se and variance == pytest.approx(se**2)
        errors.append(log_z - exact)
        reported.append(se)
    ratio = np.sqrt(np.mean(np.square(reported))) / np.std(errors, ddof=1)
    assert 0.8 < ratio < 1.25


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
