"""Exact checks of log-domain weights, and unbiasedness of every resampling scheme."""

import numpy as np
import pytest
from scipy import special

from seqbayes import weights as resampling
from seqbayes.weights import ess, log_evidence_increment, log_mean_exp, logsumexp, normalise


def test_logsumexp_matches_scipy_and_handles_minus_inf():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(7, 5)) * 300
    np.testing.assert_allclose(logsumexp(x, axis=1), special.logsumexp(x, axis=1), rtol=1e-12)
    assert logsumexp(np.array([-np.inf, -np.inf])) == -np.inf
    assert logsumexp(np.array([-np.inf, 0.0])) == 0.0


def test_normalise_ess_and_evidence_increment():
    with np.errstate(divide="ignore"):
        log_w = np.log(np.array([1.0, 1.0, 2.0, 0.0]))
    np.testing.assert_allclose(np.exp(normalise(log_w)), [0.25, 0.25, 0.5, 0.0])
    assert ess(log_w) == pytest.approx(1.0 / (0.25**2 * 2 + 0.5**2))
    assert ess(np.zeros(10)) == pytest.approx(10.0)
    # Eq. (1): equal previous weights -> log mean of the new weights
    increments = np.log(np.array([0.1, 0.2, 0.3, 0.4]))
    assert log_evidence_increment(np.zeros(4), increments) == pytest.approx(np.log(0.25))
    assert log_mean_exp(increments) == pytest.approx(np.log(0.25))


@pytest.mark.parametrize("bad", [np.array([-np.inf, -np.inf]), np.array([np.nan, 0.0]), np.array([np.inf, 0.0])])
def test_normalise_rejects_degenerate_weights(bad):
    with pytest.raises(ValueError, match="log_weights"):
        normalise(bad)


@pytest.mark.parametrize("scheme", sorted(resampling.SCHEMES))
def test_resampling_is_unbiased(scheme):
    # Expected offspring count of particle i is N w_i. Over R repetitions the mean count has
    # std <= sqrt(N w_i (1 - w_i) / R) (the multinomial's; the other schemes have less), so a
    # 5-sigma band fails by chance with probability < 1e-6 per particle.
    rng = np.random.default_rng(42)
    n, reps = 50, 4000
    w = rng.dirichlet(np.full(n, 0.5))
    counts = np.zeros(n)
    for _ in range(reps):
        counts += np.bincount(resampling.resample(scheme, w, rng), minlength=n)
    mean_counts = counts / reps
    sigma = np.sqrt(n * w * (1 - w) / reps)
    assert np.all(np.abs(mean_counts - n * w) <= 5 * sigma + 1e-12)


@pytest.mark.parametrize("scheme", sorted(resampling.SCHEMES))
def test_resampling_shapes_and_low_variance_property(scheme):
    rng = np.random.default_rng(1)
    w = np.array([0.5, 0.25, 0.25])
    idx = resampling.resample(scheme, w, rng, n=8)
    assert idx.shape == (8,) and idx.min() >= 0 and idx.max() <= 2
    if scheme in ("systematic", "residual", "stratified"):
        # floor(n w_i) copies are guaranteed for systematic and residual
        counts = np.bincount(idx, minlength=3)
        if scheme != "stratified":
            assert np.all(counts >= np.floor(8 * w))


def test_resampling_bad_input():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="weights"):
        resampling.systematic(np.array([]), rng)
    with pytest.raises(ValueError, match="weights"):
        resampling.systematic(np.array([0.0, 0.0]), rng)
    with pytest.raises(ValueError, match="weights"):
        resampling.multinomial(np.array([0.5, -0.1]), rng)
    with pytest.raises(ValueError, match="unknown scheme"):
        resampling.resample("bogus", np.ones(3), rng)
