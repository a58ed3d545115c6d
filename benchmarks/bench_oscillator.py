"""Benchmark of the damped-oscillator study (Lye et al. 2023, Sec. 5).

1. The likelihood: Eq. (12) evaluated on the 501-point grid for N = 1000 samples
   (``response``, then the sum of squares) against the closed-form sum of squares
   (``sum_squared_residuals``: geometric series plus a blocked matrix product),
   medians of ``--repeat`` interleaved pairs, and their largest relative difference.
2. The whole study (10 runs x 6 kernels x {SEMC, SMC}, N = 1000) end to end, as
   ``seqbayes example oscillator`` runs it, with the wall time of each sampler.
3. ``--compare-settings``: SEMC against SMC on kernel T1 of every run, in one
   process (no competition between workers), with the library defaults and with
   the paper's settings (one move per tempering stage or virtual iteration, no
   "90% moved" rule, moves in the parameters' own coordinates, the tempering
   path's evidence): wall time, likelihood evaluations, and the posterior error
   against the truth in posterior stds, so that speed is compared at known accuracy.

Run: ``.venv/bin/python benchmarks/bench_oscillator.py [--runs 10] [--samples 1000] [--workers 2]
[--compare-settings] [--skip-study]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from seqbayes.models import oscillator as osc
from seqbayes.studies import oscillator as study


def bench_likelihood(n: int = 1000, repeat: int = 20) -> dict:
    problem = osc.make_problem(0)
    data = problem.datasets[0].displacement
    rng = np.random.default_rng(1)
    theta = np.column_stack([rng.uniform(0.5, 3.5, n), rng.uniform(0.01, 0.7, n)])

    def direct():
        return np.sum((osc.response(theta) - data) ** 2, axis=1)

    def closed():
        return osc.sum_squared_residuals(theta, data)

    samples = {"direct Eq. 12": [], "closed form": []}
    for _ in range(repeat):   # interleaved pairs: both see the same load
        for name, fn in (("direct Eq. 12", direct), ("closed form", closed)):
            start = time.perf_counter()
            fn()
            samples[name].append(time.perf_counter() - start)
    timings = {name: float(np.median(t)) for name, t in samples.items()}
    ratio = float(np.median(np.array(samples["direct Eq. 12"]) / np.array(samples["closed form"])))
    diff = np.max(np.abs(closed() - direct()) / direct())
    return {"timings": timings, "ratio": ratio, "max_rel_diff": float(diff)}


PAPER_LIKE = {"SEMC": {"step_size": 10.0, "transform": False, "moved_fraction": 0.0, "n_moves": 1,
                       "evidence": "path"},
              "SMC": {"transform": False, "moved_fraction": 0.0, "n_moves": 1, "evidence": "path"}}


def compare_settings(runs: int = 10, n_samples: int = 1000, kernel: str = "T1") -> list[dict]:
    """SEMC vs SMC per settings: CPU and wall time and evaluations per run, error of the posterior mean.

    The two samplers alternate run by run, so that a change of machine load hits both alike;
    CPU time (``time.process_time``, this process only) is the load-independent figure.
    """
    rows = []
    for label, options in (("library defaults", study.DEFAULT_OPTIONS), ("paper-like", PAPER_LIKE)):
        acc = {s: {"cpu": [], "time": [], "evals": [], "z": [], "cover": []} for s in study.SAMPLERS}
        for run in range(runs):
            truth = osc.make_problem(np.random.default_rng(study.problem_seed(0, run))).truth
            for sampler in study.SAMPLERS:
                cpu = time.process_time()
                res = study.run_task(0, run, kernel, sampler, n_samples, options[sampler])
                a = acc[sampler]
                a["cpu"].append(time.process_time() - cpu)
                a["time"].append(res["wall_time"])
                a["evals"].append(np.nansum(res["n_loglike_evals"]))
                a["z"].append(np.abs(res["mean"] - truth) / res["std"])
                q = list(study.QUANTILES)
                lo, hi = res["quantile"][:, q.index(0.025)], res["quantile"][:, q.index(0.975)]
                a["cover"].append((truth >= lo) & (truth <= hi))
        for sampler in study.SAMPLERS:
            a = acc[sampler]
            rows.append({"settings": label, "sampler": sampler, "cpu": float(np.mean(a["cpu"])),
                         "time": float(np.mean(a["time"])), "evals": float(np.mean(a["evals"])),
                         "median_z": float(np.nanmedian(a["z"])), "coverage": float(np.mean(a["cover"]))})
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--compare-settings", action="store_true")
    parser.add_argument("--skip-study", action="store_true")
    args = parser.parse_args(argv)
    if args.compare_settings:
        print(f"SEMC vs SMC, kernel T1, {args.runs} runs, N = {args.samples}, one process")
        print("| settings | sampler | CPU time per run [s] | wall time per run [s] | likelihood evaluations "
              "per run | median abs(mean - truth) / std | truth in 95% interval |")
        print("|:---|:---|---:|---:|---:|---:|---:|")
        for row in compare_settings(args.runs, args.samples):
            print(f"| {row['settings']} | {row['sampler']} | {row['cpu']:.2f} | {row['time']:.2f} | {row['evals']:.0f} "
                  f"| {row['median_z']:.2f} | {100 * row['coverage']:.0f}% |")
        if args.skip_study:
            return 0

    lik = bench_likelihood(args.samples, args.repeat)
    print(f"likelihood at N = {args.samples}, 501 points (medians of {args.repeat} interleaved pairs):")
    for name, t in lik["timings"].items():
        print(f"  {name:14s} {1e3 * t:7.2f} ms")
    print(f"  speed-up (median of the pairs' ratios) {lik['ratio']:.1f}x, "
          f"max relative difference {lik['max_rel_diff']:.1e}")
    if args.skip_study:
        return 0

    start = time.perf_counter()
    ds = study.run_study(args.runs, args.samples, 0, workers=args.workers)
    total = time.perf_counter() - start
    summary = study.summarise(ds)
    print(f"study: {args.runs} runs x 6 kernels x 2 samplers, N = {args.samples}, "
          f"{ds.attrs['workers']} worker(s): {total:.1f} s wall")
    evals = ds["n_loglike_evals"].sum("step")
    for sampler, (mean, lo, hi) in summary.wall_time.items():
        print(f"  {sampler}: {mean:.2f} s per (run, kernel) [min {lo:.2f}, max {hi:.2f}], "
              f"{float(evals.sel(sampler=sampler).mean()):.0f} likelihood evaluations")
    print("  against the exact grid reference (selected kernels): "
          + ", ".join(f"{s} means within {summary.mean_error[s]:.2f} sd, log-evidence within "
                      f"{summary.log_evidence_error[s]:.2f} nats" for s in summary.selected)
          + f"; SEMC acceptance in [0.15, 0.50]: {summary.semc_acceptance_in_bounds:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
