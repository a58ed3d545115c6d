"""The predictive densities: exact mixture evaluation, chunking, Silverman, Liu-West moments."""

import numpy as np
import pytest
from scipy import stats
from scipy.integrate import trapezoid

from seqbayes import density as density_module
from seqbayes import Drift, MarkovKernel, Static
from seqbayes.density import GaussianMixture, predictive_density, silverman_bandwidth


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
    monkeypatch.setattr(density_module, "_BLOCK_FLOATS", 301 * 3)  # 3 queries per block
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
