"""Exact checks of priors and Markov kernels, and their input validation."""

import numpy as np
import pytest
from scipy import stats

from seqbayes import Custom, Decay, Drift, JointPrior, MarkovKernel, Static
from seqbayes.rng import as_generator, generator_from_state, generator_state


def test_joint_prior_logpdf_and_sample():
    prior = JointPrior({"k": stats.uniform(1.0, 2.0), "c": stats.norm(0.5, 0.2)})
    theta = np.array([[1.5, 0.5], [2.5, 0.1], [3.5, 0.0]])
    expected = stats.uniform(1, 2).logpdf(theta[:, 0]) + stats.norm(0.5, 0.2).logpdf(theta[:, 1])
    np.testing.assert_allclose(prior.logpdf(theta), expected)
    assert prior.logpdf(theta)[2] == -np.inf
    draws = prior.sample(4000, rng=3)
    assert draws.shape == (4000, 2)
    assert np.all((draws[:, 0] >= 1) & (draws[:, 0] <= 3))
    np.testing.assert_array_equal(draws, prior.sample(4000, rng=3))
    np.testing.assert_allclose(prior.support, [[1, 3], [-np.inf, np.inf]])
    assert prior.names == ("k", "c")


def test_joint_prior_bad_input():
    prior = JointPrior([stats.norm(), stats.norm()])
    with pytest.raises(ValueError, match=r"theta: expected 2 columns"):
        prior.logpdf(np.zeros((3, 3)))
    with pytest.raises(ValueError, match=r"theta: expected shape \(N, d\)"):
        prior.logpdf(np.zeros(3))
    with pytest.raises(TypeError, match="distributions"):
        JointPrior({"a": 3.0})
    with pytest.raises(ValueError, match="names"):
        JointPrior([stats.norm()], names=["a", "b"])


def test_kernel_components():
    theta = np.array([[1.0, 2.0, 3.0, 4.0]])
    kernel = MarkovKernel([Drift(-0.375, noise_std=0.04), Decay(0.47, noise_std=0.09), Static(),
                           Custom(lambda x: 2 * x, noise_std=0.1)])
    np.testing.assert_allclose(kernel.nominal(theta), [[0.625, 2 * np.exp(-0.47), 3.0, 8.0]])
    np.testing.assert_array_equal(kernel.static_mask, [False, False, True, False])
    rng = np.random.default_rng(0)
    many = kernel.propagate(np.repeat(theta, 20000, axis=0), rng)
    # std of the sample mean is noise/sqrt(20000); 5 sigma
    np.testing.assert_allclose(many.mean(axis=0), kernel.nominal(theta)[0], atol=5 * 0.1 / np.sqrt(20000))
    np.testing.assert_allclose(many.std(axis=0), [0.04, 0.09, 0.0, 0.1], rtol=0.03)
    assert np.all(many[:, 2] == 3.0)
    # logpdf: Gaussian over noisy dims, -inf if a static one changed
    new = kernel.nominal(theta)
    expected = sum(stats.norm.logpdf(0.0, 0.0, s) for s in (0.04, 0.09, 0.1))
    assert kernel.logpdf(new, theta)[0] == pytest.approx(expected)
    moved = new.copy()
    moved[0, 2] += 1e-3
    assert kernel.logpdf(moved, theta)[0] == -np.inf


def test_kernel_from_function_and_validation():
    kernel = MarkovKernel(nominal_function=lambda t: t * 0.5, noise_std=[0.1, 0.0])
    np.testing.assert_allclose(kernel.nominal(np.array([[2.0, 4.0]])), [[1.0, 2.0]])
    with pytest.raises(TypeError, match="either components or nominal_function"):
        MarkovKernel()
    with pytest.raises(ValueError, match="noise_std"):
        Drift(0.1, noise_std=-1)
    with pytest.raises(TypeError, match=r"components\[0\]"):
        MarkovKernel([object()])
    bad = MarkovKernel(nominal_function=lambda t: t[:, :1], noise_std=[0.1, 0.0])
    with pytest.raises(ValueError, match="nominal_function: returned shape"):
        bad.nominal(np.zeros((3, 2)))


def test_rng_conversion_and_state_round_trip():
    rng = as_generator(7)
    state = generator_state(rng)
    a = rng.normal(size=5)
    b = generator_from_state(state).normal(size=5)
    np.testing.assert_array_equal(a, b)
    g = np.random.default_rng(1)
    assert as_generator(g) is g
    with pytest.raises(TypeError, match="rng"):
        as_generator("seed")
    with pytest.raises(ValueError, match="rng"):
        as_generator(-1)


@pytest.mark.parametrize("dist", [stats.norm(0.3, 2.0), stats.norm(loc=-5, scale=1e-3), stats.norm(),
                                  stats.uniform(-1, 3), stats.uniform(scale=7.1, loc=0.3), stats.uniform(0.01, 99.99),
                                  stats.lognorm(0.5, scale=2.0)])
def test_joint_prior_fast_paths_agree_with_scipy(dist):
    """norm and uniform are evaluated and drawn without scipy's per-call overhead: the draws
    are scipy's bit for bit, the log-densities agree to rounding, the support exactly."""
    prior = JointPrior([dist])
    draws = prior.sample(500, np.random.default_rng(4))[:, 0]
    np.testing.assert_array_equal(draws, dist.rvs(size=500, random_state=np.random.default_rng(4)))
    x = np.concatenate([draws, dist.support(), [dist.mean() + 30 * dist.std(), dist.mean() - 30 * dist.std()]])
    expected = dist.logpdf(x)
    expected[np.isnan(expected)] = -np.inf
    got = prior.logpdf(x[:, None])
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(expected))
    finite = np.isfinite(expected)
    np.testing.assert_allclose(got[finite], expected[finite], rtol=1e-13, atol=1e-13)
