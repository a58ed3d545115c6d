"""SG-EnMCMC against the exact Kalman-filter posterior on a reduced WC1 replica
(10 s = 500 steps, 300 members, level 5), and reproducibility."""

import numpy as np
import pytest

from seqbayes.filters import kalman_filter
from seqbayes.sgenmcmc import SGEnMCMC
from seqbayes.studies.shake_table import CASES, make_data
from seqbayes.structures import discretise


@pytest.fixture(scope="module")
def wc1():
    return make_data(CASES["wc1"], duration=10.0, rng=0)


@pytest.fixture(scope="module")
def run(wc1):
    sg = SGEnMCMC(wc1["building"], 0.02, 0.7, 1.0, wc1["noise_std"], wc1["process_noise_std"],
                  n_members=300, level=5)
    return sg.run(wc1["u"], wc1["y"], rng=1)


def _reference_moments(data):
    """Posterior mean/sd of each theta_j on a 1-D grid through the truth (exact KF likelihood);
    a cheap stand-in for the AIES reference of the CLI (the posterior is near Gaussian and
    nearly uncorrelated here, so conditional and marginal sds agree within ~30 %)."""
    truth = data["theta"]
    means, sds = [], []
    for j in range(3):
        grid = np.tile(truth, (121, 1))
        grid[:, j] = truth[j] + np.linspace(-0.015, 0.015, 121)
        ll = kalman_filter(discretise(data["building"], grid, 0.02), data["u"], data["y"],
                           data["noise_std"], data["process_noise_std"]).log_likelihood
        w = np.exp(ll - ll.max())
        w /= w.sum()
        mu = w @ grid[:, j]
        means.append(mu)
        sds.append(np.sqrt(w @ (grid[:, j] - mu) ** 2))
    return np.array(means), np.array(sds)


def test_final_mean_and_interval_against_truth_and_reference(run, wc1):
    truth = wc1["theta"]
    ref_mean, ref_sd = _reference_moments(wc1)
    mean, sd = run.theta_mean[-1], np.sqrt(run.theta_var[-1])
    # tolerance is the acceptance criterion itself (0.01); with this seed the error is a few 1e-3
    assert np.all(np.abs(mean - truth) < 0.01)
    # spread vs the exact conditional sd: acceptance asks for a factor 3 against the AIES marginal;
    # against the conditional sd (smaller than the marginal) we allow a factor 4. One seed measured.
    ratio = sd / ref_sd
    assert np.all((ratio > 0.25) & (ratio < 4)), ratio
    # the ensemble has moved far from the prior (sd of U(0.7, 1) is 0.087)
    assert np.all(sd < 0.01)


def test_outputs_have_consistent_shapes_and_values(run):
    T = run.theta_mean.shape[0]
    assert run.theta_quantiles.shape == (T, 3, 3)
    assert np.all(run.theta_quantiles[:, 0] <= run.theta_quantiles[:, 2])
    assert np.all((run.final_theta >= 0.7) & (run.final_theta <= 1.0))
    assert np.all((run.ess > 0) & (run.ess <= 300 + 1e-9))
    assert run.resampled.any()
    assert np.isfinite(run.log_evidence)


def test_reproducible(wc1):
    def once():
        sg = SGEnMCMC(wc1["building"], 0.02, 0.7, 1.0, wc1["noise_std"], wc1["process_noise_std"],
                      n_members=60, level=3)
        return sg.run(wc1["u"][:100], wc1["y"][:100], rng=7)

    a, b = once(), once()
    assert np.array_equal(a.theta_mean, b.theta_mean)
    assert np.array_equal(a.final_theta, b.final_theta)


def test_bad_arguments(wc1):
    with pytest.raises(ValueError, match="n_members"):
        SGEnMCMC(wc1["building"], 0.02, 0.7, 1.0, wc1["noise_std"], n_members=3, level=3)
    with pytest.raises(ValueError, match="lower, upper"):
        SGEnMCMC(wc1["building"], 0.02, 1.0, 0.7, wc1["noise_std"], level=3)
    sg = SGEnMCMC(wc1["building"], 0.02, 0.7, 1.0, wc1["noise_std"][:2], n_members=60, level=3)
    with pytest.raises(ValueError, match="channels"):
        sg.run(wc1["u"], wc1["y"][:, :2])
