"""SG-EnMCMC benchmarks (quoted in docs/benchmarks.md, section sgenmcmc).

1. SG-EnMCMC, 500 members, 3-storey WC1 replica, 2000 steps (40 s at 50 Hz).
2. One EnKF step (forecast + likelihood + perturbed-observation update) at 500
   members: seqbayes (vectorised) vs filterpy's EnsembleKalmanFilter.
3. Sparse-grid interpolation of the transition matrices at levels 3-6: max
   error against the exact discretisation and speed-up over one matrix
   exponential per member (scipy.linalg.expm) and over the batched exponential.

Run: ``PYTHONPATH=src .venv/bin/python benchmarks/bench_sgenmcmc.py``
"""

from __future__ import annotations

import time

import numpy as np
from scipy.linalg import expm

from seqbayes.filters.enkf import forecast, perturbed_observation_update, predictive_log_likelihood
from seqbayes.sgenmcmc import SGEnMCMC, SparseGridTransition
from seqbayes.studies.shake_table import CASES, make_data
from seqbayes.structures import discretise


def best_of(fn, repeat=5):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_sgenmcmc():
    data = make_data(CASES["wc1"], duration=40.0, rng=0)
    t0 = time.perf_counter()
    sg = SGEnMCMC(data["building"], 0.02, 0.7, 1.0, data["noise_std"], data["process_noise_std"],
                  n_members=500, level=6)
    build = time.perf_counter() - t0
    runs = [sg.run(data["u"], data["y"], rng=s) for s in range(2)]
    r = min(runs, key=lambda r: r.elapsed)
    print(f"SG-EnMCMC 500 members x {data['u'].size} steps: run {r.elapsed:.2f} s (best of 2), "
          f"grid build {build:.2f} s, resampled at {int(r.resampled.sum())} steps; "
          f"final mean {np.round(r.theta_mean[-1], 4)}, truth {data['theta']}")
    return data


def bench_enkf_step(data, n=500):
    from filterpy.kalman import EnsembleKalmanFilter

    model = discretise(data["building"], data["theta"], 0.02)
    A, B0, B1, H = model.A[0], model.B0[0], model.B1[0], model.H[0]
    R = np.diag(data["noise_std"] ** 2)
    rng = np.random.default_rng(0)
    X = rng.standard_normal((n, 6)) * 1e-3
    y = data["y"][100]
    u0, u1 = data["u"][99], data["u"][100]

    def ours():
        Xf = forecast(model, X, u0, u1, data["process_noise_std"], rng)
        Y = Xf @ H.T
        predictive_log_likelihood(y, Y, R)
        perturbed_observation_update(Xf, Y, y, R, rng)

    b = B0 + B1
    Q = data["process_noise_std"] ** 2 * np.outer(b, b) + 1e-30 * np.eye(6)
    fx = lambda x, dt: A @ x + B0 * u0 + B1 * u1  # noqa: E731
    hx = lambda x: H @ x  # noqa: E731
    f = EnsembleKalmanFilter(x=np.zeros(6), P=np.eye(6) * 1e-6, dim_z=3, dt=0.02, N=n, hx=hx, fx=fx)
    f.Q, f.R = Q, R
    np.random.seed(0)

    def theirs():
        f.predict()
        f.update(y)

    t_ours = best_of(ours, 20)
    t_theirs = best_of(theirs, 5)
    print(f"EnKF step, {n} members: seqbayes {1e3 * t_ours:.2f} ms, filterpy {1e3 * t_theirs:.2f} ms, "
          f"speed-up {t_theirs / t_ours:.0f}x")


def bench_sparse_grid(data, n=500):
    building = data["building"]
    theta = 0.7 + 0.3 * np.random.default_rng(1).random((n, 3))
    exact = discretise(building, theta, 0.02)
    t_batched = best_of(lambda: discretise(building, theta, 0.02), 3)
    # one scipy expm per member (what an un-interpolated ensemble would do)
    A_c, b_c = building.continuous_state_space(theta)
    aug = np.zeros((n, 8, 8))
    aug[:, :6, :6] = A_c * 0.02
    aug[:, :6, 6] = b_c * 0.02
    aug[:, 6, 7] = 1.0
    t_loop = best_of(lambda: [expm(a) for a in aug], 2)
    print(f"exact discretisation of {n} members: scipy expm per member {1e3 * t_loop:.1f} ms, "
          f"batched Taylor expm {1e3 * t_batched:.1f} ms")
    print("| level | points (Eq. 17) | build [s] | eval 500 members [ms] | max abs error A | max abs error B0 "
          "| speed-up vs per-member expm | vs batched expm |")
    print("|---|---|---|---|---|---|---|---|")
    for level in (3, 4, 5, 6):
        t0 = time.perf_counter()
        tr = SparseGridTransition(building, 0.02, [0.7] * 3, [1.0] * 3, level)
        build = time.perf_counter() - t0
        t_eval = best_of(lambda: tr(theta), 10)
        approx = tr(theta)
        err_a = np.abs(approx.A - exact.A).max()
        err_b = np.abs(approx.B0 - exact.B0).max() / np.abs(exact.B0).max()
        print(f"| {level} | {tr.n_points} | {build:.2f} | {1e3 * t_eval:.2f} | {err_a:.1e} | {err_b:.1e} (rel) "
              f"| {t_loop / t_eval:.0f}x | {t_batched / t_eval:.1f}x |")


if __name__ == "__main__":
    data = bench_sgenmcmc()
    bench_enkf_step(data)
    bench_sparse_grid(data)
