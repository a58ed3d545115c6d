"""Coulomb-friction model of Sec. 6: data, Den Hartog phase model, boundary, likelihood,
exact reference posterior."""

import math

import numpy as np
import pytest
from scipy import optimize, stats
from scipy.integrate import solve_ivp

from seqbayes.models import coulomb as cf

# Paper Table 1: r and phi (deg) per experiment q (rows) and step s (column pairs).
TABLE1 = np.array([
    [0.649, 46.464, 0.637, 27.217, 0.624, 16.622, 0.652, 6.496],
    [0.791, 41.492, 0.789, 26.269, 0.807, 16.900, 0.796, 4.292],
    [0.952, 41.864, 0.944, 29.936, 0.941, 14.934, 0.936, 5.839],
    [1.098, 132.661, 1.099, 147.498, 1.123, 162.318, 1.110, 174.223],
    [1.278, 137.022, 1.253, 150.104, 1.255, 160.757, 1.262, 174.832],
    [1.407, 129.795, 1.406, 152.246, 1.409, 156.074, 1.392, 171.955],
    [1.557, 136.944, 1.549, 152.011, 1.540, 161.960, 1.548, 173.666],
    [1.706, 131.314, 1.694, 152.008, 1.711, 157.884, 1.715, 171.698],
    [1.848, 134.294, 1.849, 153.251, 1.833, 161.017, 1.860, 169.833],
])
# Paper Table 2: omega_b (rad/s).
TABLE2 = np.array([
    [12.696, 12.462, 12.213, 12.751], [15.487, 15.444, 15.791, 15.576], [18.639, 18.478, 18.415, 18.318],
    [21.480, 21.500, 21.983, 21.729], [25.015, 24.514, 24.569, 24.694], [27.540, 27.522, 27.585, 27.239],
    [30.468, 30.321, 30.141, 30.296], [33.390, 33.149, 33.478, 33.558], [36.165, 36.195, 35.880, 36.398],
])


@pytest.fixture(scope="module")
def data():
    return cf.load_experiment()


# ------------------------------------------------------------------------------ data

def test_loader_matches_paper_tables(data):
    assert len(data) == 4 and [d.step for d in data] == [1, 2, 3, 4]
    np.testing.assert_allclose([d.coulomb_force for d in data], [1.435, 0.980, 0.662, 0.217], atol=6e-4)
    for s, d in enumerate(data):
        assert d.size == 9
        np.testing.assert_allclose(d.r_nom, np.arange(0.65, 1.86, 0.15), atol=1e-12)
        np.testing.assert_allclose(d.r_exp, TABLE1[:, 2 * s], atol=5.1e-4)        # 3 decimals
        np.testing.assert_allclose(d.phi, TABLE1[:, 2 * s + 1], atol=1.0e-3)  # one entry truncated
        np.testing.assert_allclose(d.beta, d.coulomb_force / cf.DRIVING_FORCE, atol=1e-4)
        np.testing.assert_allclose(d.omega_b, d.r_exp * cf.OMEGA_N, rtol=1e-6)
    omega_b = np.column_stack([d.omega_b for d in data])
    np.testing.assert_allclose(omega_b, TABLE2, atol=6e-4)   # Table 2 is r_exp * omega_n (3 decimals)


def test_dataset_is_frozen_and_validated(data):
    with pytest.raises(Exception):
        data[0].phi[0] = 0.0
    with pytest.raises(Exception):
        data[0].step = 7
    with pytest.raises(ValueError, match="phi"):
        cf.CoulombDataset(1, 1.0, 0.4, [0.6, 0.8], [0.6, 0.8], [12.0, 15.0], [10.0])


# --------------------------------------------------------------------- phase model

def _ode_phase(r, beta, cycles=15, eps=1e-3):
    """Phase lag [deg] from a direct stiff integration of Eq. (13), sgn regularised as
    tanh(v / eps), started at rest; the first harmonic is taken over the last 2 cycles."""
    def rhs(t, y):
        return [y[1], (math.cos(t) - y[0] - beta * math.tanh(y[1] / eps)) / r**2]

    def jac(t, y):
        z = min(abs(y[1]) / eps, 300.0)
        return [[0.0, 1.0], [-1.0 / r**2, -beta / eps * (1.0 - math.tanh(z) ** 2) / r**2]]

    end = 2 * math.pi * cycles
    sol = solve_ivp(rhs, (0.0, end), [0.0, 0.0], method="Radau", jac=jac, rtol=1e-6, atol=1e-9,
                    dense_output=True)
    t = np.linspace(end - 4 * math.pi, end, 2048, endpoint=False)
    c1 = np.mean(sol.sol(t)[0] * np.exp(-1j * t))
    return np.degrees(-np.angle(c1)) % 360.0


@pytest.mark.slow
@pytest.mark.parametrize("r, beta", [(0.65, 0.55), (0.55, 0.3), (1.8, 0.4)])
def test_phase_model_matches_direct_integration(r, beta):
    # continuous regime, away from resonance so that 15 cycles reach the steady state
    # (checked: 25 cycles change the ODE phase by < 0.01 deg at these points)
    assert beta < cf.beta_limit(r)
    assert abs(_ode_phase(r, beta) - float(cf.phase_lag(r, beta))) < 1.0
    # measured agreement is ~0.01 deg; 1 deg is the acceptance tolerance of issue 3


def test_fft_and_exact_coefficient_agree_on_grid():
    r = np.concatenate([np.linspace(0.3, 0.97, 25), np.linspace(1.03, 3.0, 25)])
    frac = np.linspace(0.0, 0.995, 21)
    beta = cf.beta_limit(r)[None, :] * frac[:, None]
    exact = cf.phase_lag(r[None, :], beta, method="exact")
    fft = cf.phase_lag(r[None, :], beta, method="fft", n_fft=1024)
    assert np.isfinite(exact).mean() > 0.99
    np.testing.assert_array_equal(np.isnan(exact), np.isnan(fft))
    assert np.nanmax(np.abs(exact - fft)) < 0.01


def test_phase_model_limits_and_range():
    # no friction: the linear undamped lag, 0 below and 180 above resonance
    np.testing.assert_allclose(cf.phase_lag([0.5, 0.8, 1.2, 2.0], 0.0), [0, 0, 180, 180], atol=1e-9)
    phi = cf.phase_model(np.linspace(0.05, 1.4, 30), np.array([0.7, 1.5]))
    assert np.all((phi[:, 0] > 0) & (phi[:, 0] < 90)) and np.all((phi[:, 1] > 90) & (phi[:, 1] < 180))
    assert np.all(np.diff(phi[:, 0]) > 0) and np.all(np.diff(phi[:, 1]) < 0)  # friction adds lag / lead


def test_phase_model_vectorised_shapes_and_values(data):
    forces = np.linspace(0.1, 1.5, 7)
    out = cf.phase_model(forces, data[0].r_exp)
    assert out.shape == (7, 9)
    single = np.array([[float(cf.phase_lag(r, f / cf.DRIVING_FORCE)) for r in data[0].r_exp] for f in forces])
    np.testing.assert_allclose(out, single, rtol=0, atol=1e-10, equal_nan=True)
    assert cf.phase_lag(np.ones((3, 1)) * 0.8, np.full((1, 5), 0.2)).shape == (3, 5)
    with pytest.raises(ValueError, match="F_mu"):
        cf.phase_model(np.ones((2, 2)), data[0].r_exp)
    with pytest.raises(ValueError, match="method"):
        cf.phase_model(forces, data[0].r_exp, method="ode")
    with pytest.raises(ValueError, match="boundary"):
        cf.beta_limit(0.8, boundary="x")


def test_stick_slip_gives_nan(data):
    r = data[0].r_exp
    lim = cf.beta_limit(r)
    inside = cf.phase_lag(r, 0.99 * lim)
    outside = cf.phase_lag(r, 1.01 * lim)
    assert np.all(np.isfinite(inside)) and np.all(np.isnan(outside))
    assert np.isnan(cf.phase_lag(1.0, 0.01))      # resonance: no continuous steady state
    assert np.isnan(cf.phase_lag(0.8, -0.1))


def test_boundaries_coincide_above_half_and_mc_is_never_looser():
    r_hi = np.linspace(0.5, 3.0, 200)
    r_hi = r_hi[np.abs(r_hi - 1) > 1e-3]
    np.testing.assert_allclose(cf.boundary_marino_cicirello(r_hi), cf.boundary_den_hartog(r_hi), rtol=1e-7)
    r_lo = np.linspace(0.26, 0.49, 47)
    assert np.all(cf.boundary_marino_cicirello(r_lo) <= cf.boundary_den_hartog(r_lo) * (1 + 1e-12))
    np.testing.assert_allclose(cf.boundary_marino_cicirello(0.35), 0.03831, atol=2e-5)
    np.testing.assert_allclose(cf.boundary_den_hartog(0.35), 0.07626, atol=2e-5)


def test_between_boundaries_the_closed_form_is_not_a_solution():
    # r = 0.35, beta = 0.06: inside Eq. (24), outside the Marino-Cicirello boundary.
    r, beta = 0.35, 0.06
    tau = np.linspace(1e-4, math.pi - 1e-4, 20001)
    dx = np.gradient(cf.steady_response(tau, r, beta), tau)
    assert dx.max() > 1e-3 and dx.min() < -1e-3        # velocity changes sign in the half period
    assert np.isnan(cf.phase_lag(r, beta)) and np.isfinite(cf.phase_lag(r, beta, boundary="den_hartog"))
    # just inside the exact boundary the velocity keeps one sign
    dx_ok = np.gradient(cf.steady_response(tau, r, 0.03), tau)
    assert dx_ok.max() <= 1e-9


# ------------------------------------------------------------------------ likelihood

def test_loglike_shape_and_edge_cases(data):
    d = data[0]
    theta = np.array([[1.41, 19.64, 4.0, 0.012],
                      [0.0, 19.64, 4.0, 0.012],      # F_mu <= 0
                      [1.41, 19.64, -1.0, 0.012],    # sigma_phi <= 0
                      [1.41, 19.64, 4.0, 0.0],       # sigma_r <= 0
                      [1.41, -2.0, 4.0, 0.012],      # omega_n <= 0
                      [1.60, 19.64, 4.0, 0.012]])    # stick-slip at r = 1.85
    out = cf.loglike(theta, d)
    assert out.shape == (6,)
    assert np.isfinite(out[0]) and np.all(out[1:5] == -np.inf) and np.isnan(out[5])
    # Eq. (23) by hand for the first row
    phi_hat = np.array([float(cf.phase_lag(r, 1.41 / 2.5)) for r in d.r_exp])
    by_hand = np.sum(stats.norm.logpdf(d.phi, phi_hat, 4.0) + stats.norm.logpdf(d.r_nom, d.omega_b / 19.64, 0.012))
    np.testing.assert_allclose(out[0], by_hand, rtol=1e-12)
    with pytest.raises(ValueError, match="theta"):
        cf.loglike(np.ones((3, 3)), d)
    with pytest.raises(TypeError, match="dataset"):
        cf.loglike(theta, {"phi": d.phi})


def test_priors_and_kernels():
    p = cf.prior()
    np.testing.assert_allclose(p.support, [[0.01, 100], [0.01, 100], [0.001, 10], [0.001, 1]])
    assert p.names == cf.PARAMETER_NAMES
    np.testing.assert_allclose(cf.prior("authors").support, [[0.01, 5], [0.01, 30], [0.001, 5], [0.001, 1]])
    with pytest.raises(ValueError, match="bounds"):
        cf.prior("wide")
    theta = np.array([[1.0, 19.6, 3.0, 0.01]])
    np.testing.assert_allclose(cf.kernel("T1").nominal(theta), [[0.625, 19.6, 3.0, 0.01]])
    np.testing.assert_allclose(cf.kernel("T2").nominal(theta), [[math.exp(-0.47), 19.6, 3.0, 0.01]])
    np.testing.assert_allclose(cf.kernel("T1").noise_std, [0.04, 0, 0, 0])
    np.testing.assert_allclose(cf.kernel("T2").noise_std, [0.09, 0, 0, 0])
    with pytest.raises(ValueError, match="name"):
        cf.kernel("T3")


# ------------------------------------------------------------------ exact reference

def test_reference_posterior_reproduces_issue_values(data):
    ref = cf.reference_posterior(data[0], n_grid=20001)
    # issue 3: -14.56, F 1.412 +- 0.036, omega 19.641 +- 0.064, sigma_phi 4.09 +- 1.22, sigma_r 0.0123 +- 0.0040
    assert abs(ref.log_evidence - (-14.56)) < 0.01
    assert np.all(np.abs(ref.mean - [1.412, 19.641, 4.09, 0.0123]) <= [5e-4, 5e-4, 5e-3, 1.5e-4]), ref.mean
    assert np.all(np.abs(ref.std - [0.036, 0.064, 1.22, 0.0040]) <= [5e-4, 5e-4, 5e-3, 1e-4]), ref.std
    # grid convergence: 10x finer grid moves nothing beyond 1e-4 (relative)
    fine = cf.reference_posterior(data[0], n_grid=200001)
    assert abs(fine.log_evidence - ref.log_evidence) < 1e-4
    np.testing.assert_allclose(fine.mean, ref.mean, rtol=1e-4)
    # the authors' narrower boxes: +log(volume ratio) = 4.895, less the part of the
    # sigma_phi posterior cut off at 5 deg
    auth = cf.reference_posterior(data[0], "authors", n_grid=20001)
    vol = sum(math.log((hi - lo) / (cf.AUTHORS_CODE_BOUNDS[k][1] - cf.AUTHORS_CODE_BOUNDS[k][0]))
              for k, (lo, hi) in cf.TABLE3_BOUNDS.items())
    assert abs(vol - 4.895) < 1e-3
    assert 4.5 < auth.log_evidence - ref.log_evidence < vol


def _adaptive_importance_sampling(dataset, n=100_000, rng=0):
    """Independent check of the quadrature: importance sampling over the 4 parameters in
    (F, omega, log sigma_phi, log sigma_r), Student-t proposal built from the mode and
    Hessian (one adaptation of mean and covariance from the weighted draws)."""
    rng = np.random.default_rng(rng)
    lo, hi = cf.prior().support.T
    log_volume = np.sum(np.log(hi - lo))

    def log_target(z):
        z = np.atleast_2d(z)
        theta = np.column_stack([z[:, 0], z[:, 1], np.exp(z[:, 2]), np.exp(z[:, 3])])
        inside = np.all((theta >= lo) & (theta <= hi), axis=1)
        ll = cf.loglike(theta, dataset)
        ll = np.where(inside & np.isfinite(ll), ll, -np.inf)
        return ll - log_volume + z[:, 2] + z[:, 3]          # Jacobian of sigma = exp(z)

    best = optimize.minimize(lambda z: -log_target(z)[0], [1.3, 19.8, math.log(3), math.log(0.03)],
                             method="Nelder-mead", options={"xatol": 1e-8, "fatol": 1e-10, "maxiter": 20000})
    mean = best.x
    # finite-difference Hessian for the proposal covariance
    h = np.array([1e-3, 1e-3, 1e-3, 1e-3])
    hess = np.empty((4, 4))
    for i in range(4):
        for j in range(4):
            ei, ej = np.eye(4)[i] * h[i], np.eye(4)[j] * h[j]
            hess[i, j] = (log_target(mean + ei + ej)[0] - log_target(mean + ei - ej)[0]
                          - log_target(mean - ei + ej)[0] + log_target(mean - ei - ej)[0]) / (4 * h[i] * h[j])
    cov = np.linalg.inv(-hess) * 1.5
    for n_draw in (20_000, n):
        prop = stats.multivariate_t(mean, cov, df=5)
        z = prop.rvs(n_draw, random_state=rng)
        logw = log_target(z) - prop.logpdf(z)
        w = np.exp(logw - logw.max())
        wn = w / w.sum()
        mean = wn @ z
        cov = 1.5 * ((z - mean).T * wn) @ (z - mean)
    log_z = logw.max() + math.log(w.mean())
    se_log_z = w.std() / w.mean() / math.sqrt(n)
    theta = np.column_stack([z[:, 0], z[:, 1], np.exp(z[:, 2]), np.exp(z[:, 3])])
    post_mean = wn @ theta
    post_sd = np.sqrt(wn @ (theta - post_mean) ** 2)
    ess = 1.0 / np.sum(wn**2)
    return log_z, se_log_z, post_mean, post_sd, ess


def test_reference_agrees_with_adaptive_importance_sampling(data):
    ref = cf.reference_posterior(data[0], n_grid=20001)
    log_z, se, mean, sd, ess = _adaptive_importance_sampling(data[0])
    assert ess > 10_000
    # 5 standard errors of the IS estimate (se measured from the weights)
    assert abs(log_z - ref.log_evidence) < 5 * se + 1e-3
    assert np.all(np.abs(mean - ref.mean) <= 5 * ref.std / math.sqrt(ess)), (mean, ref.mean)
    np.testing.assert_allclose(sd, ref.std, rtol=0.05)


def test_loglike_matches_eq23_term_by_term_on_random_parameters(data):
    # The likelihood's cached constants (boundary, completed square of the frequency term,
    # one-arctan phase) against Eq. (23) written out with phase_lag per element.
    rng = np.random.default_rng(3)
    n = 400
    theta = np.column_stack([rng.uniform(-0.1, 1.7, n), rng.uniform(-1.0, 40.0, n),
                             rng.uniform(-0.5, 10.0, n), rng.uniform(-0.01, 0.5, n)])
    for d in data:
        out = cf.loglike(theta, d)
        valid = np.all(theta > 0, axis=1)
        with np.errstate(divide="ignore"):
            phi_hat = cf.phase_lag(d.r_exp[None, :], np.where(valid, theta[:, 0], 1.0)[:, None] / cf.DRIVING_FORCE)
        sp, sr = (np.where(valid[:, None], theta[:, j:j + 1], 1.0) for j in (2, 3))
        w = np.where(theta[:, 1:2] > 0, theta[:, 1:2], 1.0)
        by_hand = np.sum(stats.norm.logpdf(d.phi, phi_hat, sp) + stats.norm.logpdf(d.r_nom, d.omega_b / w, sr), axis=1)
        assert np.all(out[~valid] == -np.inf)
        stick = valid & np.isnan(by_hand)
        assert stick.sum() > 10 and np.all(np.isnan(out[stick]))
        ok = valid & ~stick
        assert ok.sum() > 10
        np.testing.assert_allclose(out[ok], by_hand[ok], rtol=1e-10)
    # the FFT path of Algorithm 3 gives the same likelihood up to its 1e-3 degree phase error
    d = data[1]
    sub = np.array([[0.95, 19.6, 3.0, 0.012], [0.5, 19.6, 2.0, 0.02], [0.2, 19.5, 5.0, 0.01]])
    np.testing.assert_allclose(cf.loglike(sub, d, method="fft"), cf.loglike(sub, d), atol=0.01)
