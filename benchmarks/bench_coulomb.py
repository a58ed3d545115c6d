"""Wall time of the Coulomb-friction study (issue 3) and of one sampler run.

    .venv/bin/python benchmarks/bench_coulomb.py [--runs 10] [--workers 2] [--single 4]
                                                 [--blas-threads] [--skip-study] [--profile]
                                                 [--threshold-scan 40]

Prints the load average, then:

- the likelihood (Eq. 23) per call at N = 1000 and the phase model (closed form / FFT);
- ``--single K``: K sampler runs per sampler (4 steps, N = 1000, kernel T1, the study's
  sampler settings) in this process, one BLAS thread (as the study runs them), wall and
  CPU time; with
  ``--blas-threads`` also with the BLAS library's default thread count;
- ``--profile``: where the time of one SEMC and one SMC run goes (cProfile, grouped into
  the likelihood, the core's mixture density, the prior, the rest);
- ``--threshold-scan K``: step 1 only, K seeds per sampler, with the core's default
  ``tempering_threshold`` (0.1, which the study uses) and 0.5 (the study's former override,
  removed when the core's importance-density refits, commit 8231e8b, fixed the seed it was
  for): log-evidence and the largest error of the posterior means (in exact posterior stds)
  against the exact reference;
- the full study (runs x {SEMC, SMC} x {T1, T2}, N = 1000, 4 steps, ``--workers``
  processes) with the per-run times and the s = 1 accuracy against the exact reference.

Targets of issue 3: study < 60 s, one run < 1.5 s.
"""

import argparse
import cProfile
import os
import pstats
import resource
import time
import timeit

import numpy as np

from seqbayes.engine.settings import from_flat
import seqbayes
from seqbayes.models import coulomb as cf
from seqbayes.studies import coulomb as study_mod


def _cpu():
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def _one(name, seed, data):
    """One run with the study's settings (``study_mod.SAMPLER_SETTINGS``)."""
    cls = getattr(seqbayes, name)
    return cls(cf.prior(), cf.kernel("T1"), cf.loglike, n_samples=1000, rng=np.random.default_rng(seed),
               **study_mod.SAMPLER_SETTINGS[name]).run(data)


def single_runs(k, data, limit):
    for name in ("SEMC", "SMC"):
        walls, cpus = [], []
        for seed in range(k):
            ctx = study_mod.single_blas_thread() if limit else _Null()
            with ctx:
                w, c = time.perf_counter(), _cpu()
                _one(name, 100 + seed, data)
                walls.append(time.perf_counter() - w)
                cpus.append(_cpu() - c)
        label = "1 BLAS thread" if limit else "default BLAS threads"
        print(f"  {name:4s} one run (4 steps, N = 1000, T1), {label}: wall {np.median(walls):.2f} s median "
              f"({min(walls):.2f}-{max(walls):.2f}), CPU {np.median(cpus):.2f} s median; "
              f"load {os.getloadavg()[0]:.1f}")


class _Null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


# Disjoint leaves of the call tree (none calls another), by cumulative time.
_LEAVES = {
    "likelihood": ("models/coulomb.py", "loglike"),
    "mixture density (core)": ("predictive/mixture.py", "logpdf"),
    "prior logpdf (core + scipy.stats)": ("priors.py", "logpdf"),
}
_SWEEPS = (("moves/stretch.py", "stretch_sweep"), ("moves/gaussian.py", "gaussian_sweep"))


def profile(data):
    for name in ("SEMC", "SMC"):
        with study_mod.single_blas_thread():
            _one(name, 7, data)
            pr = cProfile.Profile()
            pr.enable()
            _one(name, 8, data)
            pr.disable()
        stats = pstats.Stats(pr).stats

        def cum(file_part, func):
            return sum(v[3] for (f, _, fn), v in stats.items() if file_part in f and fn == func)

        total = cum("engine/drivers.py", "run")
        leaves = {label: cum(*key) for label, key in _LEAVES.items()}
        sweeps = sum(cum(*key) for key in _SWEEPS)
        print(f"  {name} one run under cProfile {total:.2f} s: "
              + ", ".join(f"{label} {t:.2f} s ({t / total:.0%})" for label, t in leaves.items())
              + f", rest (move, tempering, evidence and resampling code) {total - sum(leaves.values()):.2f} s"
              f" ({(total - sum(leaves.values())) / total:.0%}); the MCMC sweeps including their density and"
              f" likelihood calls {sweeps:.2f} s ({sweeps / total:.0%})")


def threshold_scan(k, data):
    import warnings

    d = data[0]
    ref = cf.reference_posterior(d, n_grid=20001)
    seeds = np.random.SeedSequence(2023).spawn(k)
    with warnings.catch_warnings(), study_mod.single_blas_thread():
        warnings.simplefilter("ignore", RuntimeWarning)   # the core's path-evidence fallback warning
        for threshold in (0.1, 0.5):
            for name in ("SEMC", "SMC"):
                z, err, ess = [], [], []
                for seed in seeds:
                    smp = getattr(seqbayes, name)(cf.prior(), cf.kernel("T1"), cf.loglike, n_samples=1000, rng=np.random.default_rng(seed), **from_flat(name, tempering_threshold=threshold))
                    info = smp.update(d)
                    z.append(info.log_evidence)
                    ess.append(info.evidence_ess)
                    err.append(np.max(np.abs(smp.result.steps[-1].mean() - ref.mean) / ref.std))
                z, err, ess = map(np.array, (z, err, ess))
                low = np.flatnonzero(ess < 100)
                print(f"  tempering_threshold {threshold}, {name:4s}, {k} seeds at s = 1: log-evidence "
                      f"{z.mean():.3f} +- {z.std(ddof=1):.3f} (exact {ref.log_evidence:.3f}, largest error "
                      f"{np.max(np.abs(z - ref.log_evidence)):.2f}); largest mean error {err.max():.2f} sd "
                      f"(median {np.median(err):.2f}); importance ESS < 100 in seeds {low.tolist()}")


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--single", type=int, default=4, help="single sampler runs per sampler (0: skip)")
    parser.add_argument("--blas-threads", action="store_true", help="also time single runs with default BLAS threads")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--skip-study", action="store_true")
    parser.add_argument("--threshold-scan", type=int, default=0, help="step 1 only: seeds per sampler for a scan of tempering_threshold 0.1 (the core's "
                        "default, used by the study) against 0.5 (the study's former override) (0: skip)")
    args = parser.parse_args()
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
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
    if args.single > 0:
        single_runs(args.single, data, limit=True)
        if args.blas_threads:
            single_runs(args.single, data, limit=False)
    if args.profile:
        profile(data)
    if args.threshold_scan > 0:
        threshold_scan(args.threshold_scan, data)
    if args.skip_study:
        return
    load0 = os.getloadavg()[0]
    start = time.perf_counter()
    study = study_mod.run_study(n_runs=args.runs, out_dir=None, progress=True, workers=args.workers)
    wall = time.perf_counter() - start
    print(f"full study ({args.runs} runs x 2 samplers x 2 kernels, N = 1000, 4 steps, "
          f"{args.workers} processes, no output files): {wall:.1f} s; load {load0:.1f} -> {os.getloadavg()[0]:.1f}")
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
