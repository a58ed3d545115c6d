"""SG-EnMCMC benchmarks (quoted in docs/benchmarks.md, section sgenmcmc).

1. SG-EnMCMC, 500 members, 3-storey WC1 replica, 2000 steps (40 s at 50 Hz).
2. One EnKF step (forecast + likelihood + perturbed-observation update) at 500
   members: seqbayes (vectorised) vs filterpy's EnsembleKalmanFilter.
3. Sparse-grid interpolation of the transition matrices at levels 3-6: max
   error against the exact discretisation and speed-up over one matrix
   exponential per member (scipy.linalg.expm) and over the batched exponential.
4. The exact Kalman log-likelihood of one AIES half-ensemble (16 thetas):
   the full batched filter vs the sequential/steady-state version.

Run: ``.venv/bin/python benchmarks/bench_sgenmcmc.py`` (the first benchmark also times the
SG-EnMCMC of git commit b2352ed, before profiling, interleaved with the current one).
"""

from __future__ import annotations

import os
import sys
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


def _load_previous(commit: str):
    """The SG-EnMCMC module as of ``commit`` (for a side-by-side timing), or None."""
    import importlib.util
    import subprocess
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    try:
        source = subprocess.run(["git", "show", f"{commit}:src/seqbayes/sgenmcmc.py"], cwd=root, check=True,
                                capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    name = f"seqbayes._sgenmcmc_{commit[:7]}"
    spec = importlib.util.spec_from_loader(name, loader=None)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = "seqbayes"
    sys.modules[name] = module  # dataclasses look their module up
    exec(compile(source, f"{commit[:7]}:sgenmcmc.py", "exec"), module.__dict__)
    return module


def bench_sgenmcmc(previous: str | None = "b2352ed"):
    data = make_data(CASES["wc1"], duration=40.0, rng=0)
    print(f"load average (1, 5, 15 min): {os.getloadavg()}")
    kwargs = dict(n_members=500, level=6)
    t0 = time.perf_counter()
    sg = SGEnMCMC(data["building"], 0.02, 0.7, 1.0, data["noise_std"], data["process_noise_std"], **kwargs)
    build = time.perf_counter() - t0
    variants = [("current", sg)]
    old = _load_previous(previous) if previous else None
    if old is not None:
        variants.append((f"commit {previous} (before profiling)",
                         old.SGEnMCMC(data["building"], 0.02, 0.7, 1.0, data["noise_std"],
                                      data["process_noise_std"], **kwargs)))
    times = {label: [] for label, _ in variants}
    for seed in range(2):  # interleaved, so both see the same load
        for label, identifier in variants:
            times[label].append(identifier.run(data["u"], data["y"], rng=seed).elapsed)
    for label, t in times.items():
        print(f"SG-EnMCMC 500 members x {data['u'].size} steps, {label}: best {min(t):.2f} s, "
              f"runs {np.round(t, 2).tolist()}")
    print(f"level-6 grid build {build:.2f} s; load average after: {os.getloadavg()}")
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


def bench_reference_likelihood(data, n=16):
    """Exact log-likelihood of one AIES half-ensemble (``n`` thetas, 2000 steps)."""
    from seqbayes.filters import kalman_filter
    from seqbayes.filters.kalman import kalman_log_likelihood

    theta = data["theta"] + 1e-3 * np.random.default_rng(2).standard_normal((n, 3))
    model = discretise(data["building"], theta, 0.02)
    args = (model, data["u"], data["y"], data["noise_std"], data["process_noise_std"])
    t_full = best_of(lambda: kalman_filter(*args), 2)
    t_fast = best_of(lambda: kalman_log_likelihood(*args), 3)
    diff = np.abs(kalman_filter(*args).log_likelihood - kalman_log_likelihood(*args)).max()
    print(f"exact KF log-likelihood, {n} thetas x {data['u'].size} steps: kalman_filter {t_full:.3f} s, "
          f"kalman_log_likelihood {t_fast:.3f} s ({t_full / t_fast:.1f}x), max difference {diff:.1e}")


if __name__ == "__main__":
    data = bench_sgenmcmc()
    bench_enkf_step(data)
    bench_sparse_grid(data)
    bench_reference_likelihood(data)
