"""OMA with its defaults over a sweep of records, and the roving tower (issue 38; docs/oma.md).

``sweep``: a 3-storey 3-D shear building (principal axes 30 degrees from the sensors; first bending
frequencies 2.600 and 2.626 Hz, 1 % apart, with different shapes; torsion 3.600 Hz; second bending
7.285 and 7.358 Hz; 1 % damping; the modes below 8 Hz kept), driven by independent white floor
forces, seen at ``p`` accelerometers (X and Y at the corners of the floors, top floor first), with
5 % measurement noise (:func:`seqbayes.structural.oma.modal_record`). Each cell (sampling rate,
minutes, channels) runs ``--seeds`` records through ``ssi_cov(y, dt)`` with no option given and
reports per mode: how many seeds found it within 0.5 %, the largest error, the spread (sd over
seeds) and the typical reported standard error (root mean square and median over seeds), and per
cell the spurious modes (more than 2 % from every true mode) and the statuses.

``roving``: a 15-storey 3-D shear building (first frequencies 1.23, 1.29 and 1.45 Hz as the tower
of the issue; 1.5 % damping; modes below 16 Hz) tested in four setups of 6-8 channels, two
reference channels (X and Y at corner A of floor 15) in every setup, 328 s at 40 Hz each, forces
low-passed above 2 Hz like wind, sensor noise 5 % of the largest channel's RMS; each setup
identified with the defaults and merged through the references
(:func:`seqbayes.structural.oma.setups.ssi_cov_setups`).

Run::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oma_sweep.py sweep --seeds 20 --json sweep.json
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oma_sweep.py roving --seeds 10
    .venv/bin/python benchmarks/bench_oma_sweep.py tables sweep.json     # the tables of docs/oma.md
"""

from __future__ import annotations

import argparse
import json
import time
import warnings

import numpy as np

from seqbayes.structural.oma import building_3d, modal_record, ssi_cov
from seqbayes.structural.oma.setups import ssi_cov_setups

#: (sampling rate [Hz], minutes, channels): the corners of the issue's ranges and two inner points.
CELLS = [(20, 5, 2), (20, 5, 20), (20, 60, 2), (20, 60, 20), (200, 5, 2), (200, 5, 20), (200, 60, 2), (200, 60, 20),
         (50, 20, 6), (100, 10, 4)]
REFERENCES = ["15AX", "15AY"]
ROVING = [["15BX", "13AX", "13AY", "13BX"], ["11AX", "11AY", "11BX", "9AX", "9AY", "9BX"],
          ["7AX", "7AY", "7BX", "5AX", "5AY", "5BX"], ["3AX", "3AY", "3BX", "1AX", "1AY"]]


def sweep_model(channels: int):
    sensors = [(floor, corner, d) for floor in (3, 2, 1) for corner in "ABCD" for d in "XY"][:channels]
    return building_3d(3, (2.6, 2.626, 3.6), damping=0.01, max_frequency=8.0, sensors=sensors)


def tower_model():
    sensors = [(int(c[:-2]), c[-2], c[-1]) for c in REFERENCES + sum(ROVING, [])]
    return building_3d(15, (1.23, 1.29, 1.45), damping=0.015, max_frequency=16.0, sensors=sensors)


def score(found_f, found_sd, truth, tol=0.02):
    """Per true mode: relative error and relative reported sd of the nearest identified mode (NaN if none
    within ``tol``); and the number of identified modes more than ``tol`` from every true mode."""
    err, sd = np.full(truth.size, np.nan), np.full(truth.size, np.nan)
    for i, f in enumerate(truth):
        if found_f.size:
            j = int(np.argmin(np.abs(found_f - f)))
            if abs(found_f[j] / f - 1) < tol:
                err[i], sd[i] = found_f[j] / f - 1, found_sd[j] / f
    spurious = int(sum(np.min(np.abs(truth / f - 1)) >= tol for f in found_f))
    return err, sd, spurious


def summarise(errors, sds, truth) -> list[dict]:
    rows = []
    for i, f in enumerate(truth):
        e, s = errors[:, i], sds[:, i]
        ok = np.isfinite(e)
        spread = float(np.std(e[ok], ddof=1)) if ok.sum() > 2 else float("nan")
        rms = float(np.sqrt(np.nanmean(s[ok] ** 2))) if ok.any() else float("nan")
        median = float(np.nanmedian(s[ok])) if ok.any() else float("nan")
        rows.append({"frequency": float(f), "found": int(ok.sum()), "within_half_percent": int(np.sum(np.abs(e[ok]) < 0.005)),
                     "max_abs_error": float(np.max(np.abs(e[ok]))) if ok.any() else float("nan"), "spread": spread,
                     "rms_reported_sd": rms, "median_reported_sd": median, "ratio_rms": rms / spread,
                     "ratio_median": median / spread})
    return rows


def run_cell(fs, minutes, channels, seeds) -> dict:
    model = sweep_model(channels)
    errors, sds, spurious, statuses, seconds = [], [], [], [], 0.0
    for seed in range(seeds):
        y = modal_record(model, 60.0 * minutes, 1.0 / fs, rng=np.random.default_rng([38, fs, minutes, channels, seed]))
        start = time.process_time()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            modes = ssi_cov(y, 1.0 / fs)
        seconds += time.process_time() - start
        e, s, n = score(modes.frequencies, modes.std_frequencies, model.frequencies)
        errors.append(e), sds.append(s), spurious.append(n)
        statuses.append(modes.status + ("+warned" if caught else ""))
    return {"fs": fs, "minutes": minutes, "channels": channels, "seeds": seeds,
            "modes": summarise(np.array(errors), np.array(sds), model.frequencies),
            "spurious_per_seed": spurious, "statuses": {s: statuses.count(s) for s in sorted(set(statuses))},
            "cpu_seconds_per_record": seconds / seeds}


def sweep(args) -> dict:
    cells = CELLS if not args.cells else [tuple(int(v) for v in c.split(":")) for c in args.cells]
    out = []
    print("| fs [Hz] | min | p | mode f [Hz] | within 0.5 % | max err % | spread % | reported sd % (rms / median) "
          "| ratio (rms / median) | spurious | statuses |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for fs, minutes, channels in cells:
        cell = run_cell(fs, minutes, channels, args.seeds)
        out.append(cell)
        for j, m in enumerate(cell["modes"]):
            tail = (f" {sum(cell['spurious_per_seed'])} | {cell['statuses']} |" if j == 0 else " | |")
            print(f"| {fs} | {minutes} | {channels} | {m['frequency']:.3f} | {m['within_half_percent']}/{args.seeds} | "
                  f"{100 * m['max_abs_error']:.3f} | {100 * m['spread']:.3f} | {100 * m['rms_reported_sd']:.3f} / "
                  f"{100 * m['median_reported_sd']:.3f} | {m['ratio_rms']:.2f} / {m['ratio_median']:.2f} |{tail}",
                  flush=True)
    return {"cells": out}


def roving(args) -> dict:
    model = tower_model()
    truth = model.frequencies[:6]
    errors, sds, found_all, per_setup, spurious = [], [], [], [], []
    for seed in range(args.seeds):
        records, names = [], []
        for j, rover in enumerate(ROVING):
            channels = REFERENCES + rover
            records.append(modal_record(model.select(channels), 328.0, 1 / 40, rng=np.random.default_rng([42, seed, j]),
                                        force_corner_hz=2.0, noise="floor"))
            names.append(channels)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            merged = ssi_cov_setups(records, 1 / 40, names, REFERENCES)
        e, s, n = score(merged.frequencies, merged.std_frequencies, truth)
        errors.append(e), sds.append(s), spurious.append(n)
        per_setup.append([int(sum(np.isfinite(score(m.frequencies, m.std_frequencies, truth)[0]))) for m in merged.setups])
        found_all.append(bool(np.all(np.isfinite(e))))
    rows = summarise(np.array(errors), np.array(sds), truth)
    print(f"roving tower, {args.seeds} seeds: all six lowest modes in the merged result in {sum(found_all)} seeds; "
          f"per setup (of 6): {per_setup if args.seeds <= 5 else np.mean(per_setup, axis=0).round(2).tolist()}")
    print("| mode f [Hz] | found | within 0.5 % | max err % | spread % | reported sd % (rms / median) | ratio |")
    print("|---|---|---|---|---|---|---|")
    for m in rows:
        print(f"| {m['frequency']:.3f} | {m['found']} | {m['within_half_percent']} | {100 * m['max_abs_error']:.3f} | "
              f"{100 * m['spread']:.3f} | {100 * m['rms_reported_sd']:.3f} / {100 * m['median_reported_sd']:.3f} | "
              f"{m['ratio_rms']:.2f} / {m['ratio_median']:.2f} |")
    return {"modes": rows, "all_six": found_all, "per_setup": per_setup, "spurious": spurious}


def tables(report: dict) -> str:
    """The two tables of docs/oma.md (accuracy; calibration) from a saved ``sweep --json`` report."""
    lines = ["| fs [Hz] | minutes | channels | modes within 0.5 % (of 20 seeds; 2.600, 2.626, 3.600, 7.285, 7.358 Hz) "
             "| largest error % | spurious modes | results with a warning |", "|---|---|---|---|---|---|---|"]
    for c in report["cells"]:
        warned = sum(v for k, v in c["statuses"].items() if "warned" in k)
        lines.append(f"| {c['fs']} | {c['minutes']} | {c['channels']} | "
                     f"{', '.join(str(m['within_half_percent']) for m in c['modes'])} | "
                     f"{max(m['max_abs_error'] for m in c['modes']) * 100:.2f} | {sum(c['spurious_per_seed'])} | "
                     f"{warned} |")
    lines += ["", "| fs [Hz] | minutes | channels | spread % (per mode) | reported sd %, median | ratio median / spread "
              "| ratio rms / spread |", "|---|---|---|---|---|---|---|"]
    for c in report["cells"]:
        def row(key, scale=1.0, digits=3):
            return ", ".join(f"{scale * x[key]:.{digits}f}" for x in c["modes"])

        lines.append(f"| {c['fs']} | {c['minutes']} | {c['channels']} | {row('spread', 100)} | "
                     f"{row('median_reported_sd', 100)} | {row('ratio_median', 1, 2)} | {row('ratio_rms', 1, 2)} |")
    return "\n".join(lines)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("what", choices=["sweep", "roving", "tables"])
    parser.add_argument("report", nargs="?", help="tables: a saved sweep --json report")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--cells", nargs="*", help="FS:MINUTES:CHANNELS (default: the ten of the docs)")
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    if args.what == "tables":
        with open(args.report) as fh:
            print(tables(json.load(fh)))
        return {}
    report = sweep(args) if args.what == "sweep" else roving(args)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=1)
    return report


if __name__ == "__main__":
    main()
