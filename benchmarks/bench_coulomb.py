"""Wall time of the Coulomb-friction study (issue 3) and of one sampler run.

    .venv/bin/python benchmarks/bench_coulomb.py [--runs 10] [--workers 2]

Prints: full-study wall time (runs x {SEMC, SMC} x {T1, T2}, N = 1000, 4 steps), the
per-sampler-run times, the likelihood cost per call at N = 1000, and the s = 1 accuracy
against the exact reference. Targets of issue 3: study < 60 s, one run < 1.5 s.
"""

import argparse
import time
import timeit

import numpy as np

from seqbayes.models import coulomb as cf
from seqbayes.studies import coulomb as study_mod


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    data = cf.load_experiment()
    rng = np.random.default_rng(0)
    theta = np.column_stack([rng.uniform(0.01, 1.5, 1000), rng.uniform(19, 20, 1000),
                             rng.uniform(1, 8, 1000), rng.uniform(0.005, 0.05, 1000)])
    cf.loglike(theta, data[0])
    t_ll = min(timeit.repeat(lambda: cf.loglike(theta, data[0]), number=50, repeat=5)) / 50
    t_fft = min(timeit.repeat(lambda: cf.phase_model(theta[:, 0], data[0].r_exp, method="fft"),
                              number=1, repeat=3))
    t_exact = min(timeit.repeat(lambda: cf.phase_model(theta[:, 0], data[0].r_exp), number=50, repeat=5)) / 50
    print(f"loglike, N = 1000 x 9 ratios: {t_ll * 1e3:.2f} ms per call")
    print(f"phase model N = 1000 x 9: exact coefficient {t_exact * 1e3:.2f} ms, FFT (1024 points) {t_fft * 1e3:.0f} ms")
    start = time.perf_counter()
    study = study_mod.run_study(n_runs=args.runs, out_dir=None, progress=True, workers=args.workers)
    wall = time.perf_counter() - start
    print(f"full study ({args.runs} runs x 2 samplers x 2 kernels, N = 1000, 4 steps, "
          f"{args.workers} processes): {wall:.1f} s")
    for key, times in study.run_times.items():
        evals = np.mean([sum(i.n_loglike_evals for i in r.infos) for r in study.results[key]])
        print(f"  {key[0]:4s} {key[1]}: per run {times.mean():.2f} s mean, {times.min():.2f}-{times.max():.2f} s; "
              f"{evals:.0f} likelihood evaluations (samples) per run")
    ref = study.reference
    for s in ("SEMC", "SMC"):
        z = np.array([r.log_evidence[0] for r in study.results[(s, "T1")]])
        z4 = np.array([r.log_evidence[-1] for r in study.results[(s, "T1")]])
        lnb = study.log_bayes_factor(s)
        print(f"  {s}: s=1 log-evidence {z.mean():.2f} +- {z.std(ddof=1):.2f} (exact {ref.log_evidence:.2f}); "
              f"s=4 std {z4.std(ddof=1):.2f}; log B(T1:T2) {lnb.mean():.2f} +- {lnb.std(ddof=1):.2f}")


if __name__ == "__main__":
    main()
