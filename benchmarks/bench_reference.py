"""Exact grid references (``seqbayes.reference``): wall time, grid convergence, and the
bundled tables.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_reference.py [--coulomb] [--oscillator]
                                                                          [--write] [--runs 10]

- ``--coulomb``: :func:`seqbayes.models.coulomb.exact_grid_reference` for T1 and T2 at three
  resolutions (half, default, double) and a thinner tail cut; prints the largest changes
  of the cumulative log-evidence [nats] and of the means [posterior sds] and stds [relative]
  between consecutive resolutions, and the time of the default one.
- ``--oscillator``: the same for run 9 of the oscillator study, kernel T2 (and the run-9
  numbers of issue 11), and the time of every run and kernel at the defaults.
- ``--write``: write ``src/seqbayes/data/coulomb_exact_reference.csv`` (and, with
  ``--oscillator``, ``oscillator_exact_reference.csv`` for ``--runs`` runs x T1..T6) at
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


def bench_oscillator(write: bool, runs: int):
    problem = oscillator.study_problem(9)
    kern = problem.kernels["T2"].kernel
    print("Oscillator, run 9, kernel T2")
    start = time.perf_counter()
    default = oscillator.exact_grid_reference(problem.datasets, kern)
    elapsed = time.perf_counter() - start
    coarse = oscillator.exact_grid_reference(problem.datasets, kern, n_points=201)
    fine = oscillator.exact_grid_reference(problem.datasets, kern, n_points=401)
    thin = oscillator.exact_grid_reference(problem.datasets, kern, tail_mass=1e-80)
    _compare("201 vs default (301)", coarse, default)
    _compare("default vs 401", default, fine)
    _compare("tail 1e-40 vs 1e-80", default, thin)
    print(f"  default: {elapsed:.2f} s; step-1 window {default.settings.get('first_window')}")
    _print(default)
    print("  issue 11 quotes k = 1.453 +- 0.066, 1.206, 1.052 at steps 3, 4, 6")
    start = time.perf_counter()
    refs = oscillator.study_grid_references(range(runs))
    print(f"all {runs} runs x 6 kernels: {time.perf_counter() - start:.1f} s")
    if write:
        header = ("# Exact grid reference of the damped-oscillator study (Sec. 5; seqbayes example oscillator, seed 0),\n"
                  "# every run and kernel: seqbayes.models.oscillator.study_grid_references() at its defaults;\n"
                  "# regenerate with OPENBLAS_NUM_THREADS=1 python benchmarks/bench_reference.py --oscillator --write\n")
        path = DATA / "oscillator_exact_reference.csv"
        path.write_text(header + reference.reference_table(refs, ("run", "kernel")))
        print(f"wrote {path}")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--coulomb", action="store_true")
    parser.add_argument("--oscillator", action="store_true")
    parser.add_argument("--write", action="store_true")
    parser.add_argument("--runs", type=int, default=10)
    args = parser.parse_args()
    if not (args.coulomb or args.oscillator):
        args.coulomb = args.oscillator = True
    if args.coulomb:
        bench_coulomb(args.write)
    if args.oscillator:
        bench_oscillator(args.write, args.runs)


if __name__ == "__main__":
    main()
