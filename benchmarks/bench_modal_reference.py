"""Updating from identified modes against exact references (issue 38), and the cost of a likelihood evaluation.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_modal_reference.py --shear [--seeds 5]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_modal_reference.py --frame-reference [--draws 300000]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_modal_reference.py --frame [--seeds 3]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_modal_reference.py --cost

- ``--shear``: the 4-storey shear building cases of :data:`seqbayes.structural.modal_references.SHEAR_CASES`
  (3 static storey ratios; 2 drifting; 1 drifting with the frequency error learned, which the samplers run
  as SMC^2) by SEMC and SMC (N = 1000) against the grid filter at every step; the grid at two
  resolutions first. Prints, per case and sampler, the largest error over seeds and steps.
- ``--frame-reference``: the 750-DOF frame's importance-sampling reference (``--draws`` per step) written to
  ``src/seqbayes/data/modal_frame_reference.csv`` with its Monte Carlo errors.
- ``--frame``: SEMC and SMC (N = 1000) on the frame against that file, per step and seed.
- ``--cost``: the frame's cost per likelihood evaluation with each solver (sparse shift-invert eigsh, the
  batched dense eigh, the reduced basis), measured side by side in this process, and the reduced basis's
  error: frequencies and MAC against eigsh and the log-likelihood difference at posterior samples.

The bars (issue 38): posterior means within 0.3 sd, sds within 20 %, log-evidence within 0.5 nats.
"""

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

from seqbayes import SEMC, SMC
from seqbayes.structural.modal_references import (SHEAR_CASES, datasets_digest, frame_case, grid_reference,
                                                 importance_reference, read_importance_reference, shear_building_case)
from seqbayes.structural.structures.linear import DenseSolver, LinearModel, SparseSolver

FRAME_REFERENCE = Path(__file__).resolve().parents[1] / "src" / "seqbayes" / "data" / "modal_frame_reference.csv"
BARS = {"mean_sd": 0.3, "std_ratio": 0.2, "log_evidence": 0.5}


def _load():
    try:
        return f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        return "load unknown"


def _errors(ref, result):
    e = ref.errors(result.means(), result.stds(), result.log_evidence)
    return (np.abs(e["mean_sd"]).max(axis=1), np.abs(e["std_ratio"]).max(axis=1), np.abs(e["log_evidence"]))


def _run(cls, case, n_samples, seed):
    calls = [0]

    def like(theta, data):
        calls[0] += theta.shape[0]
        return case.likelihood(theta, data)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = cls(case.prior, case.kernel, like, n_samples=n_samples, rng=seed).run(case.datasets)
    return result, calls[0], time.perf_counter() - start


def _verdict(worst):
    ok = worst[0] <= BARS["mean_sd"] and worst[1] <= BARS["std_ratio"] and worst[2] <= BARS["log_evidence"]
    return "meets" if ok else "MISSES"


def bench_shear(seeds: int, n_samples: int):
    print(f"shear building, N = {n_samples}, seeds 0..{seeds - 1} ({_load()})")
    for name in SHEAR_CASES:
        case = shear_building_case(name)
        start = time.perf_counter()
        ref = grid_reference(case, n_points=61 if len(case.names) == 3 else 121)
        t_ref = time.perf_counter() - start
        fine = grid_reference(case, n_points=91 if len(case.names) == 3 else 181)
        print(f"  {name}: parameters {', '.join(case.names)}, {len(case.datasets)} records; grid {t_ref:.1f} s; "
              f"grid vs 1.5x finer: |d log Z| {np.abs(ref.log_evidence - fine.log_evidence).max():.1e} nats, "
              f"|d mean| {np.abs((ref.mean - fine.mean) / fine.std).max():.1e} sd, "
              f"|d sd| {np.abs(ref.std / fine.std - 1).max():.1e}")
        for cls in (SEMC, SMC):
            rows = []
            for seed in range(seeds):
                result, calls, seconds = _run(cls, case, n_samples, seed)
                rows.append(_errors(fine, result) + (calls, seconds))
            worst = [max(np.max(r[k]) for r in rows) for k in range(3)]
            calls = np.mean([r[3] for r in rows])
            print(f"    {cls.__name__}: worst over seeds and steps: mean {worst[0]:.3f} sd, sd {100 * worst[1]:.1f} %, "
                  f"log Z {worst[2]:.3f} nats ({_verdict(worst)} the bars); {calls:,.0f} likelihood evaluations, "
                  f"{np.mean([r[4] for r in rows]):.1f} s per run")


def write_frame_reference(draws: int):
    case = frame_case()
    start = time.perf_counter()
    ref, se = importance_reference(case, n_draws=draws, rng=2024)
    seconds = time.perf_counter() - start
    lines = [f"# The frame case (seqbayes.structural.modal_references.frame_case(seed=0)), exact reference by importance",
             f"# sampling: {draws} Student-t draws per step (seed 2024), {seconds:.0f} s ({_load()}). Written by",
             "# OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_modal_reference.py --frame-reference "
             f"--draws {draws}",
             f"# datasets sha256 {datasets_digest(case)}",
             "# importance ESS per step: " + ", ".join(f"{v:.0f}" for v in se["ess"]),
             "step,quantity,mean,std,se_mean,se_std"]
    for s in range(len(case.datasets)):
        lines.append(f"{s + 1},log_evidence,{ref.log_evidence[s]:.10g},,{se['log_evidence'][s]:.3g},")
        for j, name in enumerate(case.names):
            lines.append(f"{s + 1},{name},{ref.mean[s, j]:.10g},{ref.std[s, j]:.10g},{se['mean'][s, j]:.3g},"
                         f"{se['std'][s, j]:.3g}")
    FRAME_REFERENCE.write_text("\n".join(lines) + "\n")
    print(f"wrote {FRAME_REFERENCE} ({seconds:.0f} s); ESS per step {se['ess'].round()}; largest MC error: mean "
          f"{np.max(se['mean'] / ref.std):.4f} sd, sd {np.max(se['std'] / ref.std):.4f}, log Z "
          f"{np.max(se['log_evidence']):.4f} nats")


def read_frame_reference():
    return read_importance_reference(FRAME_REFERENCE.read_text())


def bench_frame(seeds: int, n_samples: int):
    case = frame_case()
    ref, se, digest = read_frame_reference()
    assert digest == datasets_digest(case), "the frame case changed since the reference was written; rerun --frame-reference"
    print(f"frame: 750 DOFs, 10 parameters, 5 modes with shapes at 10 floors, {len(case.datasets)} records; "
          f"N = {n_samples} ({_load()})")
    for cls in (SEMC, SMC):
        for seed in range(seeds):
            result, calls, seconds = _run(cls, case, n_samples, seed)
            m, s, z = _errors(ref, result)
            worst = (m.max(), s.max(), z.max())
            print(f"  {cls.__name__} seed {seed}: per step mean {np.round(m, 3).tolist()} sd, sd "
                  f"{np.round(100 * s, 1).tolist()} %, log Z {np.round(z, 3).tolist()} nats ({_verdict(worst)} the "
                  f"bars); {calls:,} likelihood evaluations in {seconds:.0f} s")


def bench_cost():
    case = frame_case()
    reduced = case.likelihood.model
    exact = LinearModel(reduced.mass, reduced.stiffness_terms[0], reduced.stiffness_terms[1:], reduced.n_modes,
                        reduced.observed, reduced.channels, solver=SparseSolver())
    dense = LinearModel(reduced.mass, reduced.stiffness_terms[0], reduced.stiffness_terms[1:], reduced.n_modes,
                        reduced.observed, reduced.channels, solver=DenseSolver(chunk=8))
    rng = np.random.default_rng(0)
    data = case.datasets[0]
    print(f"frame: {reduced.n_dofs} DOFs, {reduced.n_parameters} influence matrices, {reduced.n_modes} modes computed, "
          f"reduced basis of {reduced.solver.size} vectors ({_load()})")
    from seqbayes.structural.modal_likelihood import ModalLikelihood

    for label, model, n in (("reduced basis", reduced, 2000), ("sparse eigsh (shift-invert)", exact, 50),
                            ("dense eigh (batched)", dense, 16)):
        like = ModalLikelihood(model, frequency_error=case.likelihood.frequency_error,
                               shape_error=case.likelihood.shape_error)
        theta = rng.uniform(0.6, 1.4, (n, 10))
        like(theta[:2], data)                               # set-up (dense: the whitened matrices) not timed
        start = time.perf_counter()
        like(theta, data)
        per = (time.perf_counter() - start) / n
        print(f"  {label}: {1e3 * per:.3f} ms per likelihood evaluation (batch of {n})")
    ref, _, _ = read_frame_reference()
    post = ref.mean[-1] + ref.std[-1] * rng.standard_normal((200, 10))
    diff = np.concatenate([ModalLikelihood(m, frequency_error=case.likelihood.frequency_error,
                                           shape_error=case.likelihood.shape_error)(post, data)[None]
                           for m in (reduced, exact)])
    errors = reduced.solver.errors(rng.uniform(0.5, 1.5, (50, 10)))
    print(f"  reduced basis against eigsh on U(0.5, 1.5)^10 (50 draws): frequency error up to "
          f"{np.abs(errors['frequency'][:, :5]).max():.1e} (relative), 1 - MAC up to "
          f"{errors['one_minus_mac'][:, :5].max():.1e}; log-likelihood difference at 200 draws about the last "
          f"posterior: up to {np.abs(diff[0] - diff[1]).max():.1e} nats")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--shear", action="store_true")
    parser.add_argument("--frame-reference", action="store_true")
    parser.add_argument("--frame", action="store_true")
    parser.add_argument("--cost", action="store_true")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=300000)
    args = parser.parse_args(argv)
    if not (args.shear or args.frame_reference or args.frame or args.cost):
        args.shear = args.frame = args.cost = True
    if args.shear:
        bench_shear(args.seeds, args.samples)
    if args.frame_reference:
        write_frame_reference(args.draws)
    if args.frame:
        bench_frame(args.seeds, args.samples)
    if args.cost:
        bench_cost()


if __name__ == "__main__":
    main()
