"""Shear building, discretisation and ground motions: exact checks and bad input."""

import numpy as np
import pytest
from scipy.linalg import expm

from seqbayes.structural.structures import (
    G, ShearBuilding, add_measurement_noise, band_limited_white_noise, discretise, kanai_tajimi,
    load_el_centro, read_at2, read_two_column, resample, scale_to_pga, simulate,
)
from seqbayes.structural.structures.shear_building import batched_expm

FRAME = ShearBuilding(np.array([15.51, 15.32, 14.66]) * 1e3, np.array([20.85, 9.23, 8.37]) * 1e6)


def test_fundamental_period_of_the_rc_frame_matches_the_paper():
    # the text's masses with Table 1's x stiffnesses give T1 = 0.48 s (paper: 0.47 s)
    f = FRAME.modes(np.ones(3))[0][0]
    assert abs(1 / f[0] - 0.47) < 0.02


def test_rayleigh_damping_gives_the_target_ratios_on_modes_1_and_2():
    z = FRAME.modal_damping_ratios(np.ones(3))[0]
    np.testing.assert_allclose(z[:2], [0.05, 0.05], rtol=1e-12)


def test_modes_are_mass_orthonormal_and_solve_the_eigenproblem():
    theta = np.array([[0.9, 0.8, 0.95]])
    f, phi = FRAME.modes(theta)
    M, K = FRAME.mass_matrix(), FRAME.stiffness_matrix(theta)[0]
    np.testing.assert_allclose(phi[0].T @ M @ phi[0], np.eye(3), atol=1e-10)
    np.testing.assert_allclose(K @ phi[0], M @ phi[0] * (2 * np.pi * f[0]) ** 2, rtol=1e-9, atol=1e-3)


def test_batched_expm_matches_scipy():
    M = np.random.default_rng(0).standard_normal((20, 8, 8)) * 2
    np.testing.assert_allclose(batched_expm(M), expm(M), rtol=1e-11, atol=1e-11)


def test_foh_is_exact_for_piecewise_linear_input_and_zoh_is_not():
    # a 1 ms FOH simulation of the linearly interpolated input equals the 20 ms FOH one
    rng = np.random.default_rng(1)
    u = rng.standard_normal(101)
    theta = np.array([0.9, 0.9, 0.9])
    coarse = simulate(discretise(FRAME, theta, 0.02, "foh"), u)[0]
    fine_u = np.interp(np.arange(0, 2.0 + 1e-9, 0.001), np.arange(101) * 0.02, u)
    fine = simulate(discretise(FRAME, theta, 0.001, "foh"), fine_u)[0][::20]
    np.testing.assert_allclose(coarse, fine, rtol=1e-8, atol=1e-10 * np.abs(fine).max())
    zoh = simulate(discretise(FRAME, theta, 0.02, "zoh"), u)[0]
    assert np.abs(zoh - fine).max() > 0.05 * np.abs(fine).max()


def test_batched_simulation_equals_one_at_a_time():
    thetas = np.array([[0.8, 0.9, 1.0], [0.75, 0.95, 0.85]])
    u = np.sin(np.arange(50) * 0.3)
    batch = simulate(discretise(FRAME, thetas, 0.02), u)
    for i in range(2):
        np.testing.assert_allclose(batch[i], simulate(discretise(FRAME, thetas[i], 0.02), u)[0], rtol=1e-12)


def test_absolute_acceleration_is_relative_plus_ground():
    # H X = x'' + a_g: check against a finite difference of the velocity at FOH
    theta = np.ones(3)
    u = np.sin(np.arange(400) * 0.05)
    model = discretise(FRAME, theta, 0.001)
    y, X = simulate(model, u, extra_observations=[model.H])[:2]
    vel = X[0, :, 3:]
    rel_acc = np.gradient(vel, 0.001, axis=0)
    np.testing.assert_allclose(y[0, 5:-5], rel_acc[5:-5] + u[5:-5, None], atol=2e-3 * np.abs(y).max())


def test_measurement_noise_is_a_fraction_of_channel_rms():
    y = np.column_stack([np.ones(20000), 10 * np.ones(20000)])
    noisy, std = add_measurement_noise(y, 0.05, rng=0)
    np.testing.assert_allclose(std, [0.05, 0.5])
    # sample std of 20000 normal draws has relative error ~ 1/sqrt(2*20000) = 0.5 %; allow 3 %
    np.testing.assert_allclose((noisy - y).std(axis=0), std, rtol=0.03)


def test_reproducible_noise():
    y = np.ones((10, 3))
    assert np.array_equal(add_measurement_noise(y, 0.1, rng=4)[0], add_measurement_noise(y, 0.1, rng=4)[0])


@pytest.mark.parametrize("masses, stiffnesses", [([1.0, -1.0], [1.0, 1.0]), ([1.0, 1.0], [0.0, 1.0]),
                                                 ([1.0, 1.0], [1.0])])
def test_bad_building(masses, stiffnesses):
    with pytest.raises(ValueError, match="masses|stiffnesses"):
        ShearBuilding(masses, stiffnesses)


def test_bad_theta_and_coarse_step():
    with pytest.raises(ValueError, match="theta"):
        FRAME.stiffness_matrix([1.0, -0.1, 1.0])
    with pytest.raises(ValueError, match="theta"):
        FRAME.stiffness_matrix([1.0, 1.0])
    with pytest.raises(ValueError, match="too coarse"):
        discretise(FRAME, np.ones(3), 0.1)  # 7.6 Hz mode, Nyquist 5 Hz


def test_ground_motion_with_nan_is_rejected():
    model = discretise(FRAME, np.ones(3), 0.02)
    with pytest.raises(ValueError, match="ground_acceleration"):
        simulate(model, np.array([0.0, np.nan, 1.0]))


def test_el_centro_record_and_resampling():
    gm = load_el_centro("180")
    assert gm.acceleration.size == 5372 and gm.dt == 0.01
    assert abs(gm.pga / G - 0.31) < 0.03  # El Centro NS PGA is about 0.31 g
    at50 = scale_to_pga(resample(gm, 0.02), 0.07)
    assert at50.dt == 0.02 and abs(at50.acceleration.size - 2686) <= 1
    assert abs(at50.pga - 0.07 * G) < 1e-12


def test_at2_and_two_column_readers(tmp_path):
    at2 = tmp_path / "x.AT2"
    at2.write_text("PEER\nrec\nACCELERATION IN G\nNPTS=    4, DT=   .0200 SEC\n 0.1 0.2 0.3\n 0.4\n")
    gm = read_at2(at2)
    np.testing.assert_allclose(gm.acceleration, np.array([0.1, 0.2, 0.3, 0.4]) * G)
    two = tmp_path / "x.txt"
    two.write_text("# t a\n0 0.1\n0.02 0.2\n0.04 0.3\n")
    gm2 = read_two_column(two, units="g")
    assert gm2.dt == pytest.approx(0.02)
    bad = tmp_path / "bad.txt"
    bad.write_text("0 0.1\n0.02 nan\n0.04 0.3\n")
    with pytest.raises(ValueError, match="NaN"):
        read_two_column(bad)


def test_synthetic_generators():
    kt = kanai_tajimi(10.0, 0.02, 0.07, rng=3)
    assert abs(kt.pga - 0.07 * G) < 1e-12 and kt.acceleration.size == 501
    assert np.array_equal(kt.acceleration, kanai_tajimi(10.0, 0.02, 0.07, rng=3).acceleration)
    wn = band_limited_white_noise(200.0, 0.02, rng=0)
    spec = np.abs(np.fft.rfft(wn.acceleration)) ** 2
    freq = np.fft.rfftfreq(wn.acceleration.size, 0.02)
    # almost no power below 0.25 Hz relative to the pass band
    assert spec[freq < 0.2].mean() < 0.01 * spec[(freq > 1) & (freq < 20)].mean()


def test_expm_and_derivatives_equal_scipy_frechet():
    from scipy.linalg import expm, expm_frechet

    from seqbayes.structural.structures.shear_building import expm_and_derivatives

    rng = np.random.default_rng(0)
    M = 3 * rng.standard_normal((6, 6))
    E = rng.standard_normal((2, 6, 6))
    R, L = expm_and_derivatives(M, E)
    np.testing.assert_allclose(R, expm(M), rtol=1e-11, atol=1e-11 * np.abs(R).max())
    for j in range(2):
        np.testing.assert_allclose(L[j], expm_frechet(M, E[j], compute_expm=False), rtol=1e-10,
                                   atol=1e-10 * np.abs(L[j]).max())


def test_sensor_layout_selects_rows_and_runs_through_the_filters():
    # only floors 1 and 3 of 3 carry accelerometers, storey 2 a drift sensor: H holds exactly those rows of the
    # full matrices, the exact Kalman likelihood equals the one of a model built from those rows, and the
    # EKF and the SG-EnMCMC identifier accept the layout
    from seqbayes.structural.filters import AugmentedModel, ekf, kalman_log_likelihood
    from seqbayes.structural.sgenmcmc import SGEnMCMC
    from seqbayes.structural.structures import DiscreteModel, Sensors, add_measurement_noise, kanai_tajimi

    b = ShearBuilding(np.array([30.0, 26.0, 20.0]) * 1e3, np.array([45.0, 34.0, 22.0]) * 1e6, (0.02, 0.05))
    theta = np.array([[0.88, 0.76, 0.95], [0.8, 0.9, 0.75]])
    layout = Sensors(accelerations=(1, 3), drifts=(2,))
    H = b.observation_matrix(theta, layout)
    np.testing.assert_array_equal(H[:, :2], b.observation_matrix(theta, "absolute_acceleration")[:, [0, 2]])
    np.testing.assert_array_equal(H[:, 2:], b.observation_matrix(theta, "drift")[:, [1]])
    model = discretise(b, theta, 0.02, channels=layout)
    full = discretise(b, theta, 0.02)
    assert model.H.shape == (2, 3, 6) and np.array_equal(model.A, full.A)
    u = kanai_tajimi(6.0, 0.02, 0.07, rng=0).acceleration
    y_clean = simulate(model.take([0]), u)[0]
    y, std = add_measurement_noise(y_clean, 0.03, rng=1)
    by_rows = DiscreteModel(full.A, full.B0, full.B1, np.concatenate(
        [full.H[:, [0, 2]], b.observation_matrix(theta, "drift")[:, [1]]], axis=1), 0.02, "foh")
    np.testing.assert_array_equal(kalman_log_likelihood(model, u, y, std, 0.01),
                                  kalman_log_likelihood(by_rows, u, y, std, 0.01))
    e = ekf(AugmentedModel(b, 0.02, 0.01, channels=layout), u, y, std)
    assert np.all(np.abs(e.theta_mean[-1] - theta[0]) < 0.05)
    run = SGEnMCMC(b, 0.02, 0.7, 1.0, std, 0.01, n_members=60, channels=layout).run(u, y, rng=2)
    assert np.all((run.theta_quantiles[-1, 0] < theta[0]) & (theta[0] < run.theta_quantiles[-1, 2]))
    with pytest.raises(ValueError, match="sensors"):
        b.observation_matrix(theta, Sensors(accelerations=(4,)))
    with pytest.raises(ValueError, match="accelerations"):
        Sensors(accelerations=(1, 1))
    with pytest.raises(ValueError, match="at least one"):
        Sensors()
