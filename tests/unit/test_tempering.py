"""The one tempering rule (seqbayes.core.tempering): exact ESS at the chosen exponent, the whole remainder
when it fits, and both end conventions."""

import numpy as np
import pytest

from seqbayes.core.tempering import bisect_increment, next_exponent, next_increment, tempered_ess


def _ess(log_weights):
    w = np.exp(log_weights - log_weights.max())
    return w.sum() ** 2 / (w @ w)


def test_exponent_keeps_the_target_ess():
    rng = np.random.default_rng(0)
    logw = 0.1 * rng.standard_normal(300)
    inc = 50 * rng.standard_normal(300)
    phi = next_exponent(logw, inc, 0.2, 150.0)
    assert 0.2 < phi < 1
    assert _ess(logw + (phi - 0.2) * inc) == pytest.approx(150.0, rel=1e-6)
    assert next_exponent(logw, 1e-3 * inc, 0.2, 150.0) == 1.0  # the whole remainder fits


def test_increment_keeps_a_fraction_of_the_ess_of_the_particles_with_a_likelihood():
    rng = np.random.default_rng(1)
    loglike = 30 * rng.standard_normal(500)
    loglike[:100] = -np.inf  # zero likelihood: out of ESS(0+)
    logw = np.zeros(500)
    delta = next_increment(logw, loglike, 1.0, 0.5, 0.5)
    assert 0 < delta < 1
    assert _ess(delta * loglike[100:]) == pytest.approx(0.5 * 400, rel=1e-6)
    assert next_increment(logw, 1e-6 * np.nan_to_num(loglike, neginf=0.0), 1.0, 0.5, 0.5) == 1.0
    assert next_increment(logw, np.full(500, -np.inf), 0.7, 0.5, 0.5) == 0.7  # nothing to weigh: the caller reports it


def test_bisection_bracket_and_ess_of_equal_weights():
    logw, inc = np.zeros(4), np.array([0.0, -1.0, -2.0, -3.0])
    assert tempered_ess(logw, inc, 0.0) == pytest.approx(4.0)
    lo, hi = bisect_increment(logw, inc, 1.0, 3.0, 1e-12)
    assert hi - lo <= 1e-12 and tempered_ess(logw, inc, lo) >= 3.0 > tempered_ess(logw, inc, hi)
