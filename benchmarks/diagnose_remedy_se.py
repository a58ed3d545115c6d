"""The path-space steps' reported increment se against their errors (6 % frequency random walk of
``bench_moderate_damage``, SMC and SEMC, seeds 0..K-1; the matrix's runs, bit for bit).

    OPENBLAS_NUM_THREADS=1 python benchmarks/diagnose_remedy_se.py 10

Prints, per step that some run took on the path space: the increment's error against the exact grid filter (mean and
sd over those runs), the RMS of the ``StepInfo.log_evidence_increment_se`` they reported, and the ratio of the two
(docs/jump_kernels.md, "The window's first prior").
"""

import os
import sys
import warnings
from concurrent.futures import ProcessPoolExecutor

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import bench_moderate_damage as B  # noqa: E402


def one(args):
    sampler, seed = args
    _, datasets = B.simulate(6.0, "frequency")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = B.SAMPLERS[sampler](B.prior(), B.kernels()["walk"], B.log_likelihood("frequency"), n_samples=1000,
                                     rng=np.random.default_rng(seed)).run(datasets)
    infos = [s.info for s in result.steps]
    return ([i.log_evidence_increment for i in infos], [i.log_evidence_increment_se for i in infos],
            [int(i.path_steps) for i in infos])


def main(n_seeds: int) -> None:
    reference = B.exact(6.0, "frequency", "walk")
    exact_increments = np.diff(np.concatenate([[0.0], reference["log_evidence"]]))
    jobs = [(sampler, seed) for sampler in ("SMC", "SEMC") for seed in range(n_seeds)]
    with ProcessPoolExecutor(2) as pool:
        runs = list(pool.map(one, jobs))
    for step in range(2, B.N_STEPS + 1):
        rows = np.array([(inc[step - 1] - exact_increments[step - 1], se[step - 1])
                         for inc, se, path in runs if path[step - 1]])
        if len(rows) > 1:
            spread, reported = rows[:, 0].std(ddof=1), np.sqrt(np.mean(rows[:, 1] ** 2))
            print(f"step {step}: {len(rows)} path-space runs, error mean {rows[:, 0].mean():+.3f} sd {spread:.3f}, "
                  f"reported se rms {reported:.3f}, ratio {reported / spread:.2f}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 10)
