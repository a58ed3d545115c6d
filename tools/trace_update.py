"""Which source files of seqbayes one ``update()`` runs through: the reader's path through an update.

Traces one SEMC update under a drifting kernel (the transition mixture of Eq. A3, the second step, so that the
mixture prior is in force) of a model defined here, as a user's would be, with :func:`sys.setprofile`, and counts the
distinct files of the ``seqbayes`` package whose functions the calls enter, and the switches between files::

    python tools/trace_update.py            # the count and the files
    python tools/trace_update.py --json     # the same as JSON

``tests/unit/test_trace_update.py`` asserts the bound (docs/architecture.md).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402


def traced_files(update, package_root: str) -> tuple[list[str], int, int]:
    """Run ``update()`` under :func:`sys.setprofile`: the files below ``package_root`` its calls enter (sorted,
    relative), the number of distinct functions and the switches between files."""
    files, functions, last, switches = set(), set(), [None], [0]

    def profile(frame, event, arg):
        if event != "call":
            return
        name = frame.f_code.co_filename
        if not name.startswith(package_root):
            return
        files.add(name)
        functions.add((name, frame.f_code.co_name, frame.f_code.co_firstlineno))
        if last[0] is not None and last[0] != name:
            switches[0] += 1
        last[0] = name

    sys.setprofile(profile)
    try:
        update()
    finally:
        sys.setprofile(None)
    return sorted(os.path.relpath(f, package_root) for f in files), len(functions), switches[0]


def semc_transition_update():
    """``(update, package_root)``: the second update of SEMC under a drifting kernel (the transition mixture prior,
    Eq. A3), on a user's model defined here (a damped sine with a bounded frequency and damping, uniform priors), so
    that only the library's files are counted."""
    from scipy import stats

    import seqbayes

    t = np.linspace(0.0, 4.0, 40)

    def loglike(theta, y):
        model = np.exp(-theta[:, 1:2] * t) * np.sin(theta[:, 0:1] * t)
        return -0.5 * np.sum((y - model) ** 2, axis=1) / 0.05**2

    truth = np.exp(-0.3 * t) * np.sin(2.0 * t)
    data = [truth + 0.05 * np.random.default_rng(s).standard_normal(t.size) for s in range(2)]
    prior = seqbayes.JointPrior({"omega": stats.uniform(1.0, 2.0), "zeta": stats.uniform(0.05, 0.9)})
    kernel = seqbayes.MarkovKernel([seqbayes.Drift(0.0, noise_std=0.02), seqbayes.Drift(0.0, noise_std=0.01)])
    sampler = seqbayes.SEMC(prior, kernel, loglike, n_samples=200, rng=1)
    sampler.update(data[0])
    root = str(Path(seqbayes.__file__).parent)
    return (lambda: sampler.update(data[1])), root


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    update, root = semc_transition_update()
    files, n_functions, switches = traced_files(update, root)
    if args.json:
        print(json.dumps({"files": files, "n_files": len(files), "n_functions": n_functions, "switches": switches}))
    else:
        print(f"{len(files)} files, {n_functions} functions, {switches} switches between files")
        for name in files:
            print("  ", name)
    return 0


if __name__ == "__main__":
    sys.exit(main())
