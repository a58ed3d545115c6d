"""The predictive densities: exact mixture evaluation, chunking, Silverman, Liu-West moments."""

import numpy as np
import pytest
from scipy import stats
from scipy.integrate import trapezoid

from seqbayes.moves import proposals
from seqbayes.predictive import mixture as density_module
from seqbayes import Drift, MarkovKernel, Static
from seqbayes.predictive.mixture import GaussianMixture, predictive_density, silverman_bandwidth


def brute_force(mixture, x):
    w = np.exp(mixture.log_weights)
    pdf = np.prod(stats.norm.pdf(x[:, None, :], mixture.centres[None], mixture.bandwidth), axis=2)
    return np.log(pdf @ w)


def test_mixture_logpdf_exact_and_chunked(monkeypatch):
    rng = np.random.default_rng(0)
    centres = rng.normal([20.0, 0.01], [1.0, 0.003], size=(300, 2))
    mixture = GaussianMixture(centres, np.array([0.3, 0.001]), rng.normal(size=300))
    x = rng.normal([20.0, 0.01], [1.2, 0.004], size=(50, 2))
    # single-precision exponent block: ~1e-6 absolute error in the log density (documented)
    np.testing.assert_allclose(mixture.logpdf(x), brute_force(mixture, x), rtol=0, atol=2e-5)
    whole = mixture.logpdf(x)
    monkeypatch.setattr(proposals, "BLOCK_FLOATS", 301 * 3)  # 3 queries per block
    np.testing.assert_array_equal(mixture.logpdf(x), whole)


def test_mixture_integrates_to_one_in_1d():
    mixture = GaussianMixture(np.array([[0.0], [3.0]]), np.array([0.5]), np.log([0.3, 0.7]))
    grid = np.linspace(-6, 9, 20001)[:, None]
    # 1e-6: the single-precision exponent block (quadrature error is ~1e-12 here)
    assert trapezoid(np.exp(mixture.logpdf(grid)), grid[:, 0]) == pytest.approx(1.0, abs=1e-6)


def test_silverman_matches_eq_a10():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(1000, 3)) * [1.0, 2.0, 0.5]
    expected = x.std(axis=0) * (4 / (1000 * 5)) ** (1 / 7)
    np.testing.assert_allclose(silverman_bandwidth(x), expected, rtol=1e-12)
    collapsed = np.ones((10, 1))
    assert silverman_bandwidth(collapsed)[0] > 0  # floored, finite density


def test_transition_density_keeps_static_moments_and_uses_process_noise():
    # Liu-West shrinkage: the static dimension's mixture has the posterior's mean and variance;
    # the noisy one has variance var(posterior) + noise^2 around the drifted mean.
    rng = np.random.default_rng(2)
    post = rng.normal([1.0, 5.0], [0.2, 0.3], size=(4000, 2))
    kernel = MarkovKernel([Drift(-0.5, noise_std=0.1), Static()])
    mixture, samples = predictive_density(post, np.zeros(4000), kernel, rng, "transition", True)
    np.testing.assert_allclose(mixture.bandwidth[0], 0.1)
    mix_mean = mixture.centres.mean(axis=0)
    mix_var = mixture.centres.var(axis=0) + mixture.bandwidth**2
    np.testing.assert_allclose(mix_mean, post.mean(axis=0) + [-0.5, 0.0], rtol=1e-12)
    np.testing.assert_allclose(mix_var, post.var(axis=0) + [0.01, 0.0], rtol=1e-9)
    assert samples.shape == post.shape
    # the paper's KDE inflates the static variance by the bandwidth
    kde, _ = predictive_density(post, np.zeros(4000), kernel, rng, "kde")
    assert kde.centres.var(axis=0)[1] + kde.bandwidth[1] ** 2 > 1.05 * post.var(axis=0)[1]


def test_mixture_bad_input():
    with pytest.raises(ValueError, match="bandwidth"):
        GaussianMixture(np.zeros((3, 2)), np.array([1.0, 0.0]))
    with pytest.raises(ValueError, match="predictive"):
        predictive_density(np.zeros((3, 1)), np.zeros(3), MarkovKernel([Static()]), np.random.default_rng(0), "bogus")


def _all_pairs_float64(centres, bandwidth, log_weights, x):
    """The mixture's log density by every pair in double precision (the reference of the k-d tree sum)."""
    z = (x[:, None, :] - centres[None]) / bandwidth
    terms = -0.5 * np.einsum("qij,qij->qi", z, z) + log_weights[None]
    peak = terms.max(axis=1)
    return (np.log(np.exp(terms - peak[:, None]).sum(axis=1)) + peak
            - np.sum(np.log(bandwidth)) - 0.5 * centres.shape[1] * np.log(2 * np.pi))


def test_tree_truncated_mixture_is_the_all_pairs_value_to_rounding(monkeypatch):
    # narrow bandwidth (1/50 of the spread, a slowly drifting parameter): the tree serves ~90 % of the
    # queries, summing only the centres within the radius beyond which the terms add up to < e^-40 of
    # the kept sum; measured max error 1e-13 (rounding of the sums), asserted at 1e-10
    rng = np.random.default_rng(5)
    n, d = 5000, 4
    centres = rng.normal(size=(n, d))
    log_w = rng.normal(size=n)
    mixture = GaussianMixture(centres, np.full(d, 0.02), log_w)
    x = np.concatenate([rng.normal(size=(300, d)) * 1.1, centres[:3], rng.normal(size=(5, d)) * 4])
    dense_rows = []
    real_dense = GaussianMixture._dense_logsum

    def counting_dense(self, xb):
        dense_rows.append(xb.shape[0])
        return real_dense(self, xb)

    monkeypatch.setattr(GaussianMixture, "_dense_logsum", counting_dense)
    got = mixture.logpdf(x)
    reference = _all_pairs_float64(mixture.centres, mixture.bandwidth, mixture.log_weights, x)
    served = sum(dense_rows) < x.shape[0]
    assert served and sum(dense_rows) <= 0.15 * x.shape[0]
    errors = np.abs(got - reference)
    # the queries the tree served (at least 85 %) are exact to rounding; the rest went to the dense sum,
    # whose single-precision block is ~1e-2 off at this narrow a bandwidth (the tree's other gain)
    assert np.sum(errors < 1e-10) >= 0.85 * x.shape[0]
    assert errors.max() < 0.05
    # a centre queried exactly (zero distance) is found
    np.testing.assert_allclose(got[300:303], reference[300:303], rtol=0, atol=1e-10)


def test_tree_is_skipped_where_it_saves_nothing():
    # bandwidth as wide as the spread: every term counts, the dense sum is used, bit for bit
    rng = np.random.default_rng(6)
    mixture = GaussianMixture(rng.normal(size=(5000, 3)), np.full(3, 0.5))
    x = rng.normal(size=(200, 3))
    scaled = (x - mixture._shift) / mixture.bandwidth
    np.testing.assert_array_equal(mixture.logpdf(x), mixture._dense_logsum(scaled) + mixture._const)


def test_tree_sum_with_zero_weights():
    # zero-weight centres (log w = -inf) never enter; the nearest centre of a query may be one of them
    rng = np.random.default_rng(7)
    centres = rng.normal(size=(6000, 2))
    log_w = rng.normal(size=6000)
    log_w[::2] = -np.inf
    mixture = GaussianMixture(centres, np.full(2, 0.01), log_w)
    x = np.concatenate([centres[:4], rng.normal(size=(100, 2))])
    reference = _all_pairs_float64(mixture.centres, mixture.bandwidth, mixture.log_weights, x)
    got = mixture.logpdf(x)
    assert np.all(np.isfinite(got))
    assert np.median(np.abs(got - reference)) < 1e-10
