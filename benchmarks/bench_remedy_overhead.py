"""What the conflict remedy costs a healthy run: CPU time with ``conflict_remedy=True`` over ``False``.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_remedy_overhead.py [--pairs 4] [--run 0] [--kernel T1]

Default: run 0 of the oscillator study under T1 (no step triggers the remedy: asserted), SMC,
N = 1000, six steps. ``--run 9 --kernel T2``: the issue's conflict, where the remedy runs (what it
costs there). The two settings alternate in one process (interleaved pairs, process CPU time) and
the median ratio is printed, since the machine is shared.
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from seqbayes.engine.settings import from_flat
from seqbayes.models import oscillator as osc  # noqa: E402
from seqbayes import SMC  # noqa: E402


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", type=int, default=4)
    parser.add_argument("--run", type=int, default=0)
    parser.add_argument("--kernel", default="T1")
    args = parser.parse_args()
    problem = osc.study_problem(args.run)
    kernel = problem.kernels[args.kernel].kernel
    times = {True: [], False: []}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for pair in range(args.pairs):
            for remedy in (True, False):
                start = time.process_time()
                result = SMC(osc.prior(), kernel, osc.log_likelihood, n_samples=1000, rng=pair, **from_flat("SMC", conflict_remedy=remedy)).run(problem.datasets)
                times[remedy].append(time.process_time() - start)
                if args.run == 0 and args.kernel == "T1":
                    assert all(r.info.path_steps == 0 for r in result.steps)
    on, off = np.array(times[True]), np.array(times[False])
    print(f"CPU s per run, remedy on: {np.round(on, 2)}, off: {np.round(off, 2)}; "
          f"median ratio on/off {np.median(on / off):.2f}")


if __name__ == "__main__":
    main()
