"""Bouc-Wen shear building: exact reduction to the linear model, energy and
hysteresis sanity, vectorisation, and the EnKF path of SG-EnMCMC."""

import numpy as np
import pytest

from seqbayes.structural.settings import sg_from_flat
from seqbayes import SGEnMCMC
from seqbayes.structural.filters.enkf import EnKFBank
from seqbayes.structural.structures import Sensors, ShearBuilding, discretise, simulate
from seqbayes.structural.structures.bouc_wen import (
    BoucWenBuilding,
    BoucWenExponential,
    BoucWenRK4,
    bouc_wen_transition,
    simulate_bouc_wen,
)

LINEAR = ShearBuilding([2.0e4, 2.0e4, 1.6e4], [3.0e7, 2.4e7, 1.6e7], (0.02, 0.04))
THETA = np.array([[0.9, 0.8, 1.0], [0.75, 0.95, 0.85]])
DT = 0.02


def _record(T=400, scale=1.0, seed=1):
    return np.random.default_rng(seed).standard_normal(T) * scale


def test_alpha_one_is_the_linear_building_exactly():
    bw = BoucWenBuilding(LINEAR, alpha=1.0, beta=100.0, gamma=100.0)
    u = _record(150)
    y_lin = simulate(discretise(LINEAR, THETA, DT), u)
    y_exp = simulate_bouc_wen(BoucWenExponential(bw, DT), THETA, u)
    # same matrices up to the augmented exponential's round-off
    assert np.abs(y_exp - y_lin).max() <= 1e-12 * np.abs(y_lin).max()
    for channels in ("absolute_acceleration", "drift", Sensors(accelerations=(1, 3), drifts=(2,))):
        H_bw = bw.observation_matrix(THETA, channels)
        H_lin = LINEAR.observation_matrix(THETA, channels)
        np.testing.assert_allclose(H_bw[:, :, :6], H_lin, rtol=1e-14, atol=0)
        assert np.all(H_bw[:, :, 6:] == 0)
    # RK4 converges to it at fourth order: 16 sub-steps to 2e-6 (measured 6e-7; 4 sub-steps 1.5e-4)
    y_rk4 = simulate_bouc_wen(BoucWenRK4(bw, DT, 16), THETA, u)
    assert np.abs(y_rk4 - y_lin).max() <= 2e-6 * np.abs(y_lin).max()
    y_rk4_coarse = simulate_bouc_wen(BoucWenRK4(bw, DT, 4), THETA, u)
    assert np.abs(y_rk4_coarse - y_lin).max() > 1e-5 * np.abs(y_lin).max()  # the check can fail


def test_hysteresis_loop_is_bounded_and_dissipative():
    """A storey driven through drift cycles ``a sin(w t)``: ``|z|`` stays below the
    yield drift ``(A / (beta + gamma))^(1/e)`` and the loop ``oint z d delta`` is
    positive (energy dissipated) and below the rigid-plastic bound ``4 a u_y``."""
    lin1 = ShearBuilding([1e3], [1e6])
    for exponent in (1.0, 2.0):
        uy, a = 0.004, 0.02
        bw = BoucWenBuilding.from_yield_drift(lin1, uy, alpha=0.2, exponent=exponent)
        t = np.linspace(0, 2.0, 4001)  # two cycles of 1 Hz, fine explicit steps
        w = 2 * np.pi
        rate = a * w * np.cos(w * t)
        z = np.zeros(1)
        zs = [0.0]
        for j in range(t.size - 1):  # loop over time only (a scalar ODE)
            h = t[j + 1] - t[j]
            rm = 0.5 * (rate[j] + rate[j + 1])
            k1 = bw.z_rate(z, rate[j:j + 1])
            k2 = bw.z_rate(z + 0.5 * h * k1, np.array([rm]))
            k3 = bw.z_rate(z + 0.5 * h * k2, np.array([rm]))
            k4 = bw.z_rate(z + h * k3, rate[j + 1:j + 2])
            z = z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            zs.append(float(z[0]))
        zs = np.array(zs)
        assert np.abs(zs).max() <= uy * (1 + 1e-9)
        assert np.abs(zs).max() > 0.9 * uy  # it does yield
        second = t >= 1.0
        drift = a * np.sin(w * t)
        area = np.trapezoid(zs[second], drift[second]) if hasattr(np, "trapezoid") else np.trapz(zs[second], drift[second])
        assert 0.5 * 4 * a * uy < area < 4 * a * uy


def _energy(bw, theta, X):
    n = bw.n_storeys
    k = theta * bw.linear.stiffnesses
    drift = np.diff(X[..., :n], axis=-1, prepend=0.0)
    kinetic = 0.5 * (bw.linear.masses * X[..., n:2 * n] ** 2).sum(-1)
    return kinetic + 0.5 * (k * (bw.alpha * drift**2 + (1 - bw.alpha) * X[..., 2 * n:] ** 2)).sum(-1)


def test_free_vibration_energy_never_increases():
    """Without viscous damping, ``E = 1/2 v'Mv + sum k (alpha d^2 + (1 - alpha) z^2) / 2``
    has ``dE/dt = -sum (1 - alpha) k (beta |d'| |z|^(e+1) + gamma d' z |z|^e) <= 0``
    for ``beta >= |gamma|``: conserved when linear, strictly lost when yielding."""
    undamped = ShearBuilding(LINEAR.masses, LINEAR.stiffnesses, (0.0, 0.0))
    theta = THETA[:1]
    x0 = np.zeros((1, 9))
    x0[0, :3] = [0.01, 0.02, 0.03]  # 2.5-10x the yield drift
    for alpha, lost in ((1.0, False), (0.3, True)):
        bw = BoucWenBuilding.from_yield_drift(undamped, 0.004, alpha=alpha)
        model = BoucWenRK4(bw, DT, 16)(theta)
        X = x0.copy()
        energies = [_energy(bw, theta, X)[0]]
        for _ in range(200):  # loop over time only
            X = model.propagate(X, 0.0, 0.0)
            energies.append(_energy(bw, theta, X)[0])
        e = np.array(energies)
        assert np.all(np.diff(e) <= 1e-7 * e[0])
        if lost:
            assert e[-1] < 0.5 * e[0]
        else:
            assert abs(e[-1] - e[0]) <= 1e-6 * e[0]


@pytest.mark.parametrize("integrator", ["rk4", "exponential", "grid"])
def test_propagate_vectorised_matches_member_loop(integrator):
    bw = BoucWenBuilding.from_yield_drift(LINEAR, 0.004, alpha=0.2)
    if integrator == "grid":
        transition = bouc_wen_transition(bw, DT, "exponential", level=3, lower=0.7, upper=1.0)
    else:
        transition = bouc_wen_transition(bw, DT, integrator)
    rng = np.random.default_rng(5)
    theta = 0.7 + 0.3 * rng.random((4, 3))
    X = rng.standard_normal((4, 6, 9)) * 0.01  # (N, M, m)
    eta = rng.standard_normal((4, 6))
    model = transition(theta)
    batched = model.propagate(X, 0.3, -0.2, eta)
    for i in range(4):  # the reference loop
        one = transition(theta[i:i + 1])
        for j in range(6):
            single = one.propagate(X[i:i + 1, j], 0.3, -0.2, eta[i:i + 1, j])
            np.testing.assert_allclose(batched[i, j], single[0], rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(model.take([2, 0]).theta, theta[[2, 0]])


def test_sparse_grid_interpolates_the_exponential_matrices():
    bw = BoucWenBuilding.from_yield_drift(LINEAR, 0.004, alpha=0.2)
    theta = 0.7 + 0.3 * np.random.default_rng(2).random((50, 3))
    exact = bw.exponential_matrices(theta, DT)
    errors = []
    for level in (3, 5):
        grid = BoucWenExponential(bw, DT, level=level, lower=0.7, upper=1.0)
        errors.append(np.abs(grid.matrices(theta) - exact).max() / np.abs(exact).max())
    assert errors[1] < 1e-4 and errors[1] < 0.3 * errors[0]


def test_exponential_integrator_converges_to_rk4_under_yielding():
    bw = BoucWenBuilding.from_yield_drift(LINEAR, 0.004, alpha=0.2)
    u = _record(150, 2.0)
    ref = simulate_bouc_wen(BoucWenRK4(bw, DT, 32), THETA, u)
    errs = [np.abs(simulate_bouc_wen(BoucWenExponential(bw, DT, substeps=s), THETA, u) - ref).max()
            / np.abs(ref).max() for s in (1, 4)]
    assert errs[1] < 0.25 * errs[0]  # second order (measured ratio ~ 1/16 per factor 4)
    err_rk4 = np.abs(simulate_bouc_wen(BoucWenRK4(bw, DT, 4), THETA, u) - ref).max() / np.abs(ref).max()
    assert err_rk4 < 5e-3


def test_inputs_are_validated():
    with pytest.raises(ValueError, match="alpha"):
        BoucWenBuilding(LINEAR, alpha=1.5)
    with pytest.raises(ValueError, match="beta, gamma"):
        BoucWenBuilding(LINEAR, beta=-1.0, gamma=0.0)
    with pytest.raises(TypeError, match="linear"):
        BoucWenBuilding("building")
    bw = BoucWenBuilding.from_yield_drift(LINEAR, 0.004)
    with pytest.raises(ValueError, match="likelihood='enkf'"):
        SGEnMCMC(bw, DT, 0.7, 1.0, np.ones(3))
    with pytest.raises(ValueError, match="level"):
        bouc_wen_transition(bw, DT, "rk4", level=3)
    with pytest.raises(ValueError, match="integrator"):
        bouc_wen_transition(bw, DT, "euler")


def test_enkf_bank_runs_the_nonlinear_model_reproducibly():
    bw = BoucWenBuilding.from_yield_drift(LINEAR, 0.004, alpha=0.2)
    model = BoucWenRK4(bw, DT, 2)(THETA)
    u = _record(30)
    y = simulate_bouc_wen(BoucWenRK4(bw, DT, 2), THETA[0], u)[0] + 0.01

    def run(seed):
        bank = EnKFBank(model, 0.05 * np.ones(3), 0.05, 8, np.random.default_rng(seed))
        X, cov = bank.initial_state()
        total = np.zeros(2)
        for k in range(u.size):
            X, cov, inc = bank.step(X, cov, y[k], *((u[k - 1], u[k]) if k else (None, None)))
            total += inc
        return total, X

    a, b = run(3), run(3)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1].shape == (2, 8, 9) and np.all(np.isfinite(a[0]))
    assert a[0][0] > a[0][1]  # the data come from the first theta


def test_sgenmcmc_runs_on_the_grid_surrogate_of_bouc_wen():
    linear = ShearBuilding([2e4, 1.6e4], [3e7, 2.0e7], (0.02, 0.04))
    bw = BoucWenBuilding.from_yield_drift(linear, 0.004, alpha=0.3)
    u = _record(40, 2.0)
    y = simulate_bouc_wen(BoucWenRK4(bw, DT, 8), [0.85, 0.78], u)[0]
    sg = SGEnMCMC(bw, DT, 0.7, 1.0, 0.05 * y.std(axis=0), 0.05, n_members=16, **sg_from_flat(likelihood="enkf",
                                                                                             enkf_members=8, level=3))
    assert isinstance(sg.transition, BoucWenExponential) and sg.transition.substeps == 4
    assert sg.transition.n_points == 17
    run = sg.run(u, y, rng=0)
    again = SGEnMCMC(bw, DT, 0.7, 1.0, 0.05 * y.std(axis=0), 0.05, n_members=16,
                     **sg_from_flat(likelihood="enkf", enkf_members=8, level=3)).run(u, y, rng=0)
    np.testing.assert_array_equal(run.theta_mean, again.theta_mean)  # bit-reproducible by seed
    assert np.all(np.isfinite(run.theta_mean)) and np.all(run.theta_var[-1] < run.theta_var[0])
