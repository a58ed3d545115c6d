"""seqbayes' automated OMA against pyoma-2 on the same simulated records (issue 38; docs/oma.md, "pyoma-2").

Every record of a cell (``bench_oma_sweep.py``'s building, seeds and noise) goes through

- ``seqbayes``: ``ssi_cov(y, dt)`` with its defaults;
- ``pyoma-2`` (1.4.3, MIT): ``SSI(method="cov", br=20, ordmax=min(80, 19 p), calc_unc=False)`` on a
  ``SingleSetup`` (its default of 20 block rows; orders up to 80, or as many as its fast SSI takes from 20
  block rows of ``p`` channels: with more, e.g. 80 for 2 channels, it raises a LinAlgError), its automated
  clustering preset "Magalhaes" (hierarchical clustering on frequency and MAC, distance 0.02;
  ``Clustering(quick=...)``), and no decimation (a user would have to choose it). Its own uncertainty
  (``calc_unc=True``) is left out: with it, the five records of a 20-channel cell had not finished after
  10 minutes of wall time on the shared machine (load about 11 on 2 cores); the frequencies compared here
  do not depend on it.

The 20-channel cells are left out: pyoma-2's clustering of their ~3000 poles had not finished one cell
after 18 minutes of wall time on the shared machine (load about 14 on 2 cores).

Reported per cell and mode: seeds with the mode within 0.5 %, largest error, spurious modes, and CPU
seconds per record of each (the two run side by side in one process, so the ratio is fair under any load).

Run (needs the bench extra: ``pip install -c requirements.lock -e ".[bench]"``)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oma_pyoma.py --seeds 3
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oma_pyoma.py --seeds 1 --cells     # the tower only
"""

from __future__ import annotations

import argparse
import json
import os
import logging
import time
import warnings

import numpy as np

from seqbayes.structural.oma import modal_record, ssi_cov

from bench_oma_sweep import ROVING, REFERENCES, score, sweep_model, tower_model

CELLS = [(20, 5, 2), (200, 5, 2), (50, 20, 6)]


def pyoma(y: np.ndarray, fs: float, preset: str = "Magalhaes"):
    """Frequencies and their standard errors from pyoma-2's SSI-cov and automated clustering."""
    from pyoma2.algorithms import SSI
    from pyoma2.algorithms.data.run_params import Clustering
    from pyoma2.setup import SingleSetup

    setup = SingleSetup(y, fs=fs)
    algorithm = SSI(name="ssi", method="cov", br=20, ordmax=min(80, 19 * y.shape[1]), calc_unc=False)
    setup.add_algorithms(algorithm)
    setup.run_by_name("ssi")
    algorithm.add_clustering(Clustering(name=preset, quick=preset))
    algorithm.run_clustering(preset)
    result = algorithm.result.clustering_results[preset]
    f = np.asarray(result.Fn, dtype=float).ravel()
    sd = np.asarray(result.Fn_std, dtype=float).ravel() if result.Fn_std is not None else np.full(f.size, np.nan)
    order = np.argsort(f)
    return f[order], sd[order]


def compare(records, truth):
    rows = {"seqbayes": [], "pyoma-2": []}
    seconds = {"seqbayes": 0.0, "pyoma-2": 0.0}
    failures = {"seqbayes": 0, "pyoma-2": 0}
    for y, fs in records:
        for name in rows:
            start = time.process_time()
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    if name == "seqbayes":
                        m = ssi_cov(y, 1 / fs)
                        f, sd = m.frequencies, m.std_frequencies
                    else:
                        f, sd = pyoma(y, fs)
                rows[name].append(score(f, sd, truth))
            except Exception:  # a failed run counts as finding nothing
                failures[name] += 1
                rows[name].append((np.full(truth.size, np.nan), np.full(truth.size, np.nan), 0))
            seconds[name] += time.process_time() - start
    out = {}
    for name, results in rows.items():
        errors = np.array([r[0] for r in results])
        out[name] = {"within_half_percent": np.sum(np.abs(errors) < 0.005, axis=0).tolist(),
                     "max_abs_error": np.nanmax(np.abs(np.where(np.isfinite(errors), errors, np.nan)), axis=0).tolist()
                     if np.isfinite(errors).any() else [float("nan")] * truth.size,
                     "spurious": int(sum(r[2] for r in results)), "failures": failures[name],
                     "cpu_seconds_per_record": seconds[name] / len(records)}
    return out


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--json")
    parser.add_argument("--cells", nargs="*", help="FS:MINUTES:CHANNELS (default the four above; none: the tower only)")
    args = parser.parse_args(argv)
    logging.disable(logging.CRITICAL)
    os.environ["TQDM_DISABLE"] = "1"  # pyoma-2 draws a progress bar per run
    report = {"cells": [], "roving": None}
    print("| case | mode f [Hz] | seqbayes within 0.5 % | pyoma-2 within 0.5 % | seqbayes max err % | pyoma-2 max err % |")
    print("|---|---|---|---|---|---|")
    cells = CELLS if args.cells is None else [tuple(int(v) for v in c.split(":")) for c in args.cells]
    for fs, minutes, channels in cells:
        model = sweep_model(channels)
        records = [(modal_record(model, 60.0 * minutes, 1.0 / fs,
                                 rng=np.random.default_rng([38, fs, minutes, channels, seed])), fs)
                   for seed in range(args.seeds)]
        result = compare(records, model.frequencies)
        report["cells"].append({"fs": fs, "minutes": minutes, "channels": channels, **result})
        _print(f"{fs} Hz, {minutes} min, {channels} ch", model.frequencies, result, args.seeds)
    tower = tower_model()
    records = []
    for seed in range(args.seeds):
        for j, rover in enumerate(ROVING):
            names = REFERENCES + rover
            records.append((modal_record(tower.select(names), 328.0, 1 / 40, rng=np.random.default_rng([42, seed, j]),
                                         force_corner_hz=2.0, noise="floor"), 40))
    result = compare(records, tower.frequencies[:6])
    report["roving"] = result
    _print("tower setups (328 s, 40 Hz)", tower.frequencies[:6], result, len(records))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=1)
    return report


def _print(case, truth, result, n):
    s, q = result["seqbayes"], result["pyoma-2"]
    for j, f in enumerate(truth):
        tail = (f" (spurious {s['spurious']} / {q['spurious']}; failed runs {s['failures']} / {q['failures']}; CPU s per "
                f"record {s['cpu_seconds_per_record']:.2f} / {q['cpu_seconds_per_record']:.2f})") if j == 0 else ""
        print(f"| {case if j == 0 else ''} | {f:.3f} | {s['within_half_percent'][j]}/{n} | {q['within_half_percent'][j]}/{n} | "
              f"{100 * s['max_abs_error'][j]:.3f} | {100 * q['max_abs_error'][j]:.3f} |{tail}", flush=True)


if __name__ == "__main__":
    main()
