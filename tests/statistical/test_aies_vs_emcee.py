"""The standalone ensemble sampler against emcee's stretch move and the exact answer.

Targets: a correlated 2-D Gaussian and a 5-D Rosenbrock-type "banana" (Haario et
al. 2001: x2 = z2 + b (z1^2 - 100)) whose moments are known in closed form because
it is an exact transform of a Gaussian. Monte Carlo error of each estimate comes
from batch means over 20 time batches of the chain (valid under autocorrelation);
every comparison uses a 4.5-sigma band of the combined standard error.
"""

import numpy as np
import pytest

import seqbayes
import seqbayes.aies

emcee = pytest.importorskip("emcee")

N_WALKERS, N_STEPS, BURN = 40, 3000, 500


def batch_stat(chain, stat, n_batches=20):
    """Statistic over the whole post-burn-in chain and its batch-means standard error."""
    batches = np.array_split(chain, n_batches, axis=0)
    values = np.array([stat(b.reshape(-1, b.shape[-1])) for b in batches])
    return stat(chain.reshape(-1, chain.shape[-1])), values.std(axis=0, ddof=1) / np.sqrt(n_batches)


def run_both(log_prob, dim, seed):
    rng = np.random.default_rng(seed)
    init = rng.normal(size=(N_WALKERS, dim))
    ours = seqbayes.aies.sample(log_prob, init, N_STEPS, rng=seed).chain[BURN:]
    sampler = emcee.EnsembleSampler(N_WALKERS, dim, log_prob, vectorize=True)
    np.random.seed(seed)  # emcee draws from numpy's global state
    sampler.run_mcmc(init, N_STEPS, progress=False)
    return ours, sampler.get_chain()[BURN:]


def check(ours, theirs, exact_mean, exact_cov):
    cov = lambda x: np.cov(x.T)  # noqa: E731
    for stat, exact in ((lambda x: x.mean(axis=0), exact_mean), (cov, exact_cov)):
        a, se_a = batch_stat(ours, stat)
        b, se_b = batch_stat(theirs, stat)
        assert np.all(np.abs(a - b) <= 4.5 * np.sqrt(se_a**2 + se_b**2)), (a, b)
        assert np.all(np.abs(a - exact) <= 4.5 * se_a + 1e-12), (a, exact)


def test_correlated_gaussian_2d():
    cov = np.array([[1.0, 0.9 * 2.0], [0.9 * 2.0, 4.0]])
    precision = np.linalg.inv(cov)
    mean = np.array([1.0, -2.0])

    def log_prob(x):
        z = x - mean
        return -0.5 * np.einsum("ij,jk,ik->i", z, precision, z)

    ours, theirs = run_both(log_prob, 2, seed=0)
    check(ours, theirs, mean, cov)


def test_banana_5d():
    b = 0.03
    scales = np.array([10.0, 1.0, 1.0, 1.0, 1.0])

    def log_prob(x):
        z = x.copy()
        z[:, 1] = x[:, 1] - b * (x[:, 0] ** 2 - 100.0)
        return -0.5 * np.sum((z / scales) ** 2, axis=1)

    exact_mean = np.zeros(5)
    exact_cov = np.diag([100.0, 1.0 + 2 * b**2 * 100.0**2, 1.0, 1.0, 1.0])
    ours, theirs = run_both(log_prob, 5, seed=1)
    check(ours, theirs, exact_mean, exact_cov)


def test_aies_reproducible_and_validates():
    lp = lambda x: -0.5 * np.sum(x**2, axis=1)  # noqa: E731
    init = np.random.default_rng(0).normal(size=(8, 2))
    a = seqbayes.aies.sample(lp, init, 50, rng=4)
    b = seqbayes.aies.sample(lp, init, 50, rng=4)
    np.testing.assert_array_equal(a.chain, b.chain)
    assert 0 < a.acceptance_rate < 1
    with pytest.raises(ValueError, match="initial: the stretch move needs at least 2 d = 4"):
        seqbayes.aies.sample(lp, init[:3], 10)
    with pytest.raises(ValueError, match="initial: every walker must have a finite log_prob"):
        seqbayes.aies.sample(lambda x: np.full(len(x), -np.inf), init, 10)
