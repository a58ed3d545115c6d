"""Exact grid references (``seqbayes.reference``): wall time, grid convergence, and the
bundled tables.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_reference.py [--coulomb] [--oscillator]
                                                                          [--write] [--runs 0 1 ...]

- ``--coulomb``: :func:`seqbayes.models.coulomb.exact_grid_reference` for T1 and T2 at three
  resolutions (half, default, double) and a thinner tail cut; prints the largest changes
  of the cumulative log-evidence [nats] and of the means [posterior sds] and stds [relative]
  between consecutive resolutions, and the time of the default one.
- ``--oscillator``: the same for runs/kernels 9/T2 (issue 11's case), 9/T3 and 8/T1 of the
  oscillator study (the two whose step-1 likelihood ridge matters most), and the time of
  every run and kernel of ``--runs`` at the defaults.
- ``--plain-grid``: an independent check of run 9, T2 on one fixed trapezoid grid.
- ``--sweep``: every bundled oscillator (run, kernel) recomputed at 3 points per sd (~3 min).
- ``--write``: write ``src/seqbayes/data/coulomb_exact_reference.csv`` (and, with
  ``--oscillator``, ``oscillator_exact_reference.csv`` for the ``--runs`` x T1..T6) at
  the defaults, with a comment header naming this command.
"""

import argparse
import time
from pathlib import Path

import numpy as np

from seqbayes import reference
from seqbayes.models import coulomb, oscillator

DATA = Path(__file__).resolve().parents[1] / "src" / "seqbayes" / "data"


def _compare(name, a, b):
    dz = np.max(np.abs(a.log_evidence - b.log_evidence))
    dm = np.max(np.abs(a.mean - b.mean) / b.std)
    ds = np.max(np.abs(a.std / b.std - 1.0))
    print(f"  {name}: |d log Z| {dz:.2e} nats, |d mean| {dm:.2e} sd, |d std| {ds:.2e} (relative)")
    return dz, dm, ds


def _print(ref):
    for s in range(ref.log_evidence.size):
        cells = "  ".join(f"{n} {m:.5g} +- {sd:.4g}" for n, m, sd in zip(ref.parameter_names, ref.mean[s], ref.std[s]))
        print(f"    s = {s + 1}: log Z {ref.log_evidence[s]:.4f}  {cells}")


def bench_coulomb(write: bool):
    refs = {}
    for kernel in ("T1", "T2"):
        print(f"Coulomb, kernel {kernel}")
        half = coulomb.exact_grid_reference(kernel, n_points=(151, 101), n_omega=10001)
        start = time.perf_counter()
        default = coulomb.exact_grid_reference(kernel)
        elapsed = time.perf_counter() - start
        double = coulomb.exact_grid_reference(kernel, n_points=(601, 401), n_omega=40001)
        thin = coulomb.exact_grid_reference(kernel, tail_mass=1e-80)
        _compare("half vs default", half, default)
        _compare("default vs double", default, double)
        _compare("tail 1e-40 vs 1e-80", default, thin)
        print(f"  default: {elapsed:.2f} s")
        _print(default)
        refs[(kernel,)] = default
    if write:
        header = ("# Exact grid reference of the Coulomb-friction experiment (Sec. 6, Table 3 prior), kernels T1 and T2:\n"
                  "# seqbayes.models.coulomb.exact_grid_reference(kernel) at its defaults; regenerate with\n"
                  "# OPENBLAS_NUM_THREADS=1 python benchmarks/bench_reference.py --coulomb --write\n")
        path = DATA / "coulomb_exact_reference.csv"
        path.write_text(header + reference.reference_table(refs, ("kernel",)))
        print(f"wrote {path}")


def bench_oscillator(write: bool, runs):
    for run, name in ((9, "T2"), (9, "T3"), (8, "T1")):
        problem = oscillator.study_problem(run)
        kern = problem.kernels[name].kernel
        print(f"Oscillator, run {run}, kernel {name}")
        start = time.perf_counter()
        default = oscillator.exact_grid_reference(problem.datasets, kern)
        elapsed = time.perf_counter() - start
        coarse = oscillator.exact_grid_reference(problem.datasets, kern, points_per_sd=3.0)
        fine = oscillator.exact_grid_reference(problem.datasets, kern, points_per_sd=8.0, n_points=301,
                                               max_points=3001)
        thick = oscillator.exact_grid_reference(problem.datasets, kern, tail_mass=1e-80)
        _compare("3 vs 5 points per sd (default)", coarse, default)
        _compare("default vs 8 points per sd (at least 301, at most 3001)", default, fine)
        _compare("tail 1e-80 vs 1e-100 (default)", thick, default)
        print(f"  default: {elapsed:.2f} s")
        _print(default)
    print("  issue 11 quotes k = 1.453 +- 0.066, 1.206, 1.052 at steps 3, 4, 6 for run 9, T2")
    start = time.perf_counter()
    refs = {}
    for run in runs:
        for name, ref in oscillator.study_grid_references([run]).items():
            refs[name] = ref
            print(f"  run {run} {name[1]}: log Z(6) {ref.log_evidence[-1]:.3f}, "
                  f"{time.perf_counter() - start:.1f} s so far", flush=True)
    print(f"runs {list(runs)} x 6 kernels: {time.perf_counter() - start:.1f} s")
    if write:
        header = ("# Exact grid reference of the damped-oscillator study (Sec. 5; seqbayes example oscillator, seed 0),\n"
                  f"# runs {' '.join(map(str, runs))}, kernels T1-T6: seqbayes.models.oscillator.study_grid_references(runs) at its\n"
                  "# defaults; regenerate with OPENBLAS_NUM_THREADS=1 python benchmarks/bench_reference.py --oscillator --write\n")
        path = DATA / "oscillator_exact_reference.csv"
        path.write_text(header + reference.reference_table(refs, ("run", "kernel")))
        print(f"wrote {path}")


def plain_grid_check(run: int = 9, kernel: str = "T2", k_range=(0.5, 13.0), c_range=(0.001, 4.0),
                     n_k: int = 2501, n_c: int = 801):
    """An independent check of the oscillator reference: one fixed trapezoid grid (no adaptive
    ranges, no Simpson), the same target written out directly. ~1 min, ~1 GB."""
    from scipy.special import logsumexp

    problem = oscillator.study_problem(run)
    kern = problem.kernels[kernel].kernel
    k, c = np.linspace(*k_range, n_k), np.linspace(*c_range, n_c)

    def trapezoid(axis):
        w = np.full(axis.size, axis[1] - axis[0])
        w[[0, -1]] /= 2
        return w

    wk, wc = trapezoid(k), trapezoid(c)
    log_w = np.log(wk)[:, None] + np.log(wc)[None, :]

    def transition(axis, component, q, w):
        z = (axis[:, None] - component.nominal(axis)[None, :]) / q
        return np.exp(-0.5 * z * z) / (q * np.sqrt(2 * np.pi)) * w[None, :]

    k_step = transition(k, kern.components[0], kern.noise_std[0], wk)
    c_step = transition(c, kern.components[1], kern.noise_std[1], wc)
    log_volume = sum(np.log(hi - lo) for lo, hi in oscillator.PRIOR_BOUNDS.values())
    total, log_post = 0.0, None
    print(f"Plain trapezoid grid, run {run}, {kernel}: k in {k_range} ({n_k}), c in {c_range} ({n_c})")
    for s, dataset in enumerate(problem.datasets):
        ll = oscillator._grid_log_likelihood((k, c), dataset)
        ll = np.where(np.isnan(ll), -np.inf, ll)
        if s == 0:
            log_prior = -log_volume
        else:
            shift = log_post.max()
            with np.errstate(divide="ignore"):
                log_prior = np.log(k_step @ np.exp(log_post - shift) @ c_step.T) + shift
        target = ll + log_prior
        log_z = logsumexp(target + log_w)
        total += log_z
        log_post = target - log_z
        mass = np.exp(log_post + log_w)
        mk, mc = mass.sum(1) @ k, mass.sum(0) @ c
        sk, sc = np.sqrt(mass.sum(1) @ (k - mk) ** 2), np.sqrt(mass.sum(0) @ (c - mc) ** 2)
        print(f"    s = {s + 1}: log Z {total:.4f}  k {mk:.5f} +- {sk:.4f}  c {mc:.5f} +- {sc:.4f}")


def sweep_oscillator(runs):
    """Every bundled (run, kernel) recomputed at 3 points per sd instead of 5: the largest
    change of the cumulative log-evidence [nats], the means [sd] and the sds [relative]."""
    bundled = oscillator.load_exact_references()
    print("Oscillator table: 3 against 5 (bundled) points per sd")
    for run in runs:
        problem = oscillator.study_problem(run)
        for name in problem.kernels:
            fresh = oscillator.exact_grid_reference(problem.datasets, problem.kernels[name].kernel, points_per_sd=3.0)
            _compare(f"run {run} {name}", fresh, bundled[(run, name)])


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--coulomb", action="store_true")
    parser.add_argument("--oscillator", action="store_true")
    parser.add_argument("--write", action="store_true")
    parser.add_argument("--runs", type=int, nargs="+", default=list(range(10)),
                        help="oscillator runs to tabulate (default: all ten of the study)")
    parser.add_argument("--plain-grid", action="store_true", help="the independent fixed-grid check (run 9, T2)")
    parser.add_argument("--sweep", action="store_true", help="recompute the bundled oscillator table at 3 points per sd")
    args = parser.parse_args()
    if args.plain_grid:
        plain_grid_check()
    if args.sweep:
        sweep_oscillator(args.runs)
    if not (args.coulomb or args.oscillator or args.plain_grid or args.sweep):
        args.coulomb = args.oscillator = True
    if args.coulomb:
        bench_coulomb(args.write)
    if args.oscillator:
        bench_oscillator(args.write, args.runs)


if __name__ == "__main__":
    main()
