"""The oscillator study's remedied runs (0, 3 and 9: the ones that take path-space steps) against the exact grid.

The other seven runs of ``seqbayes example oscillator`` never take a path-space step, so a change to the path space
leaves them bit for bit as they were: the study's mean evaluations per run are (this script's sum of runs 0, 3
and 9 + the other seven's sum) / 10, the other seven's sum read from a full study (0.850 M on the code of
docs/benchmarks.md, "Suffix moves on the path space"). Every kernel and sampler, N = 1000, the study's seeds
(``--replicates 2`` adds a second sampler seed per task, as ``run_task(..., replicate=1)``).

Printed: the mean evaluations per run of runs 0, 3 and 9 (over kernels, samplers and replicates) and their sum,
the study's estimate, and per sampler the largest ``|mean - exact| / exact sd`` and ``|log p(D^1:s) - exact|`` over
every (run, kernel, step), the number of path-space steps and the errors' root mean square over them alone (the
steps a change to the path space changes; the largest error over 36 tasks moves by a few hundredths of an sd
between seeds).

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oscillator_remedied.py [--replicates 2]
[--workers 2] [--others 850000]``
"""

from __future__ import annotations

import argparse
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from seqbayes.models import oscillator as osc  # noqa: E402
from seqbayes.studies import oscillator as study  # noqa: E402

RUNS = (0, 3, 9)


def _task(args):
    run, kernel, sampler, replicate = args
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the remedy's conflict warnings, expected here
        return args, study.run_task(0, run, kernel, sampler, replicate=replicate)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--replicates", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--others", type=float, default=850_000.0,
                        help="the sum of runs 1, 2, 4-8's mean evaluations per run (from a full study)")
    args = parser.parse_args(argv)
    refs = osc.load_exact_references()
    jobs = [(r, k, s, rep) for rep in range(args.replicates) for r in RUNS for k in study.KERNELS
            for s in study.SAMPLERS]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(_task, jobs))
    evals = {r: [] for r in RUNS}
    worst = {s: [0.0, 0.0] for s in study.SAMPLERS}
    remedied = {s: ([], []) for s in study.SAMPLERS}
    for (run, kernel, sampler, _), out in results:
        ref = refs[(run, kernel)]
        evals[run].append(float(np.nansum(out["n_loglike_evals"])))
        mean_sd = (out["mean"] - ref.mean) / ref.std                      # (steps, 2)
        log_z = out["log_evidence"] - ref.log_evidence                    # (steps,)
        worst[sampler] = [max(worst[sampler][0], float(np.nanmax(np.abs(mean_sd)))),
                          max(worst[sampler][1], float(np.nanmax(np.abs(log_z))))]
        path = np.nan_to_num(out["path_steps"]) > 0
        remedied[sampler][0].append(mean_sd[path].ravel())
        remedied[sampler][1].append(log_z[path])
    per_run = {r: float(np.mean(v)) for r, v in evals.items()}
    total = sum(per_run.values())
    print(f"evaluations per run, mean over kernels, samplers and {args.replicates} replicate(s): "
          + ", ".join(f"run {r} {v:,.0f}" for r, v in per_run.items())
          + f"; runs 0 + 3 + 9 {total / 1e6:.3f} M; the study's estimate {(total + args.others) / 10:,.0f} per run "
          f"({time.perf_counter() - start:.0f} s wall)")
    for s in study.SAMPLERS:
        mean_sd, log_z = (np.concatenate(x) for x in remedied[s])
        print(f"{s}: largest error {worst[s][0]:.3f} sd, {worst[s][1]:.3f} nats; on the {log_z.size} path-space "
              f"steps rms {np.sqrt(np.mean(mean_sd**2)):.4f} sd, {np.sqrt(np.mean(log_z**2)):.4f} nats")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
