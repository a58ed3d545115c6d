"""Filters: the batched Kalman filter against a dense Gaussian oracle, the EnKF
against the Kalman filter, EKF/UKF sanity, and input validation."""

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from seqbayes.structural.filters import (
    AugmentedModel, ekf, enkf_filter, ensemble_moments, kalman_filter, predictive_log_likelihood, ukf,
)
from seqbayes.structural.filters.kalman import kalman_log_likelihood
from seqbayes.structural.structures import ShearBuilding, add_measurement_noise, discretise, simulate

FRAME = ShearBuilding(np.array([15.51, 15.32, 14.66]) * 1e3, np.array([20.85, 9.23, 8.37]) * 1e6)
THETA = np.array([0.9079, 0.9197, 0.9424])


def _data(T=150, seed=0, sw_frac=0.05):
    rng = np.random.default_rng(seed)
    u = np.convolve(rng.standard_normal(T), np.ones(3) / 3, mode="same")
    sw = sw_frac * np.sqrt(np.mean(u**2))
    model = discretise(FRAME, THETA, 0.02)
    y = simulate(model, u, process_noise_std=sw, rng=rng)[0]
    noisy, std = add_measurement_noise(y, 0.05, rng)
    return model, u, noisy, std, sw


def test_kalman_log_likelihood_equals_dense_gaussian_oracle():
    # y_{0:T-1} is jointly Gaussian: build its mean and covariance by linearity and compare
    T = 12
    model, u, y, std, sw = _data(T)
    A, B0, B1, H = model.A[0], model.B0[0], model.B1[0], model.H[0]
    m, p = A.shape[0], H.shape[0]
    b = B0 + B1
    mean_x = np.zeros((T, m))
    for k in range(T - 1):
        mean_x[k + 1] = A @ mean_x[k] + B0 * u[k] + B1 * u[k + 1]
    # X_k = sum_{j<k} A^{k-1-j} b eta_j
    G = np.zeros((T, m, T))
    for k in range(1, T):
        for j in range(k):
            G[k, :, j] = np.linalg.matrix_power(A, k - 1 - j) @ b
    Gy = np.einsum("pm,kmj->kpj", H, G).reshape(T * p, T)
    cov = sw**2 * Gy @ Gy.T + np.kron(np.eye(T), np.diag(std**2))
    mean = (mean_x @ H.T).reshape(-1)
    oracle = multivariate_normal(mean, cov).logpdf(y.reshape(-1))
    assert kalman_filter(model, u, y, std, sw).log_likelihood[0] == pytest.approx(oracle, abs=1e-6)


def test_kalman_batched_equals_one_at_a_time():
    model, u, y, std, sw = _data(80)
    thetas = np.array([[0.8, 0.9, 1.0], [0.9, 0.9, 0.9], [0.7, 0.75, 0.95]])
    batch = kalman_filter(discretise(FRAME, thetas, 0.02), u, y, std, sw).log_likelihood
    single = [kalman_filter(discretise(FRAME, t, 0.02), u, y, std, sw).log_likelihood[0] for t in thetas]
    np.testing.assert_allclose(batch, single, rtol=1e-12)
    assert np.argmax(kalman_filter(discretise(FRAME, np.vstack([thetas, THETA]), 0.02), u, y, std,
                                   sw).log_likelihood) == 3


def test_fast_log_likelihood_equals_kalman_filter():
    # 600 steps: the covariance reaches its steady state (~200 steps here) and the frozen-gain
    # phase runs for the rest (two blocks of 256 steps); the difference is O(T * steady_tol) relative
    # (measured 1e-10)
    model, u, y, std, sw = _data(600)
    thetas = np.array([[0.8, 0.9, 1.0], [0.9, 0.9, 0.9], [0.7, 0.75, 0.95], THETA])
    batch = discretise(FRAME, thetas, 0.02)
    exact = kalman_filter(batch, u, y, std, sw).log_likelihood
    fast, steady = kalman_log_likelihood(batch, u, y, std, sw, return_steady_step=True)
    assert 0 < steady < 600
    np.testing.assert_allclose(fast, exact, rtol=1e-9, atol=1e-6)  # far-off theta: |ll| ~ 5e4
    # sequential processing alone (no steady state) is exact to round-off
    no_steady = kalman_log_likelihood(batch, u, y, std, sw, steady_tol=0)
    np.testing.assert_allclose(no_steady, exact, rtol=0, atol=1e-8)
    # a full (non-diagonal) R is whitened first
    R = np.diag(std**2) + 0.3 * np.sqrt(np.outer(std**2, std**2)) * (1 - np.eye(3))
    np.testing.assert_allclose(kalman_log_likelihood(batch, u, y, R, sw),
                               kalman_filter(batch, u, y, R, sw).log_likelihood, rtol=1e-9, atol=1e-6)


@pytest.mark.slow
def test_enkf_reproduces_kalman_filter_with_large_ensemble():
    model, u, y, std, sw = _data(150)
    kf = kalman_filter(model, u, y, std, sw, store=True)
    en = enkf_filter(model, u, y, std, sw, n_members=20000, rng=1)
    # Monte Carlo error measured on the 40 s El Centro replica: N = 5000 -> max mean error
    # 4e-4 of peak, N = 50000 -> 1.2e-4 (falls like 1/sqrt(N)); log-likelihood within 0.6 at
    # N = 500 and 0.2 at N = 5000 over 500 steps. Tolerances here are several times that.
    peak = np.abs(kf.filtered_means[0]).max(axis=0)
    assert np.all(np.abs(en.filtered_means - kf.filtered_means[0]).max(axis=0) < 1e-3 * peak)
    assert en.log_likelihood == pytest.approx(kf.log_likelihood[0], abs=1.0)


def test_enkf_reproducible():
    model, u, y, std, sw = _data(40)
    a = enkf_filter(model, u, y, std, sw, n_members=50, rng=3)
    b = enkf_filter(model, u, y, std, sw, n_members=50, rng=3)
    assert a.log_likelihood == b.log_likelihood
    assert np.array_equal(a.final_ensemble, b.final_ensemble)


def test_conditional_moments_remove_the_covariate_effect():
    rng = np.random.default_rng(0)
    z = rng.standard_normal((5000, 1))
    X = 3 * z + 0.5 * rng.standard_normal((5000, 1))
    _, pooled = ensemble_moments(X)
    _, conditional = ensemble_moments(X, z)
    assert pooled[0, 0] == pytest.approx(9.25, rel=0.05)
    assert conditional[0, 0] == pytest.approx(0.25, rel=0.05)  # 5000 draws: rel. sd ~2 %


def test_predictive_log_likelihood_per_member_is_gaussian():
    Y = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    R = np.eye(2)
    ens, members = predictive_log_likelihood(np.array([0.5, 0.5]), Y, R)
    S = np.cov(Y.T) + R
    assert ens == pytest.approx(multivariate_normal([0.5, 0.5], S).logpdf([0.5, 0.5]))
    np.testing.assert_allclose(members, multivariate_normal([0, 0], S).logpdf(np.array([0.5, 0.5]) - Y))


@pytest.mark.parametrize("filt", [ekf, ukf])
def test_joint_filters_move_towards_the_truth(filt):
    model, u, y, std, sw = _data(400, seed=5)
    res = filt(AugmentedModel(FRAME, 0.02, sw, theta_walk_std=1e-5), u, y, std)
    prior_error = np.abs(0.85 - THETA).max()
    assert np.abs(res.theta_mean[-1] - THETA).max() < 0.3 * prior_error
    assert np.all(res.theta_var[-1] < 0.3**2 / 12)


def test_mismatched_channels_and_nan_are_rejected():
    model, u, y, std, sw = _data(20)
    with pytest.raises(ValueError, match="channels"):
        kalman_filter(model, u, y[:, :2], std[:2], sw)
    with pytest.raises(ValueError, match="measurements"):
        kalman_filter(model, u[:-1], y, std, sw)
    bad = u.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="ground_acceleration"):
        kalman_filter(model, bad, y, std, sw)
    with pytest.raises(ValueError, match="measurements"):
        ekf(AugmentedModel(FRAME, 0.02, sw), u, y[:, :2], std)


def test_kalman_bank_steps_equal_the_batched_filter():
    from seqbayes.structural.filters.kalman import KalmanBank

    model, u, y, std, sw = _data(120)
    thetas = np.array([[0.8, 0.9, 1.0], [0.9, 0.9, 0.9], [0.7, 0.75, 0.95]])
    batch = discretise(FRAME, thetas, 0.02)
    ref = kalman_filter(batch, u, y, std, sw, store=True)
    bank = KalmanBank(batch, std, sw)
    mean, P = bank.initial_state()
    for k in range(u.size):  # loop over time only
        mean, P, inc = bank.step(mean, P, y[k], *((u[k - 1], u[k]) if k else (None, None)))
        np.testing.assert_allclose(inc, ref.log_likelihood_increments[:, k], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(mean, ref.filtered_means[:, -1], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(P, ref.filtered_covariances, rtol=1e-8, atol=1e-18)
    # a sub-bank is the bank of the sub-batch
    sub = bank.take([2, 0])
    m2, P2 = sub.initial_state()
    np.testing.assert_array_equal(sub.step(m2, P2, y[0])[2], bank.step(*bank.initial_state(), y[0])[2][[2, 0]])


@pytest.mark.parametrize("chandrasekhar", [True, False])
@pytest.mark.parametrize("T", [40, 300])
def test_fast_log_likelihood_returns_the_filtered_state(T, chandrasekhar):
    # T = 40 ends in the transient, T = 300 in the steady-state phase (steady from step 173)
    model, u, y, std, sw = _data(300)
    thetas = np.array([[0.8, 0.9, 1.0], [0.9, 0.9, 0.9]])
    batch = discretise(FRAME, thetas, 0.02)
    ref = kalman_filter(batch, u[:T], y[:T], std, sw, store=True)
    ll, steady, mean, P = kalman_log_likelihood(batch, u[:T], y[:T], std, sw, return_steady_step=True,
                                                return_state=True, chandrasekhar=chandrasekhar)
    assert (steady < T) == (T == 300)
    np.testing.assert_allclose(ll, ref.log_likelihood, rtol=0, atol=1e-6)
    scale = np.abs(ref.filtered_means[:, -1]).max()
    np.testing.assert_allclose(mean, ref.filtered_means[:, -1], rtol=0, atol=1e-8 * scale)
    np.testing.assert_allclose(P, ref.filtered_covariances, rtol=0, atol=1e-8 * np.abs(P).max())


def test_ekf_jacobian_is_the_derivative_of_the_exact_discretisation():
    # the exact Frechet-derivative Jacobian against central differences of discretise()
    model = AugmentedModel(FRAME, 0.02, 0.01)
    rng = np.random.default_rng(0)
    z = np.concatenate([1e-3 * rng.standard_normal(6), [0.85, 0.9, 0.95]])
    fz, F, b = model.linearise(z, 0.3, -0.2)

    def step(theta):
        m = discretise(FRAME, theta, 0.02)
        return m.A[0] @ z[:6] + m.B0[0] * 0.3 + m.B1[0] * -0.2

    np.testing.assert_allclose(fz[:6], step(z[6:]), rtol=1e-12, atol=1e-15)
    h = 1e-6
    fd = np.column_stack([(step(z[6:] + h * e) - step(z[6:] - h * e)) / (2 * h) for e in np.eye(3)])
    np.testing.assert_allclose(F[:6, 6:], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
    np.testing.assert_allclose(F[:6, :6], discretise(FRAME, z[6:], 0.02).A[0], rtol=1e-12, atol=1e-14)
    m = discretise(FRAME, z[6:], 0.02)
    np.testing.assert_allclose(b, m.B0[0] + m.B1[0], rtol=1e-12, atol=1e-18)


def test_enkf_bank_likelihood_approaches_the_kalman_likelihood():
    from seqbayes.structural.filters.enkf import enkf_log_likelihood

    model, u, y, std, sw = _data(60)
    batch = discretise(FRAME, THETA, 0.02)
    exact = kalman_log_likelihood(batch, u, y, std, sw)[0]
    # measured at 2,000 members per filter over 5 seeds: error -0.02 +- 0.20 (sd); bound 5 sd
    estimate, X, cov = enkf_log_likelihood(batch, u, y, std, sw, 2000, rng=0)
    assert abs(estimate[0] - exact) < 1.0
    assert X.shape == (1, 2000, 6) and cov.shape == (1, 6, 6)
    again = enkf_log_likelihood(batch, u, y, std, sw, 2000, rng=0)[0]
    assert np.array_equal(estimate, again)
