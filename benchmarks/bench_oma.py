"""From raw accelerations to a monitoring data file by SSI-cov (issue 25, item 2; docs/oma.md).

A 4-storey shear building (``--masses``, ``--stiffness``; Rayleigh damping 2 % on modes 1 and 2)
is shaken by white-noise ground acceleration; every floor's absolute acceleration is recorded at
``1 / --dt`` Hz for ``--duration`` s with 5 % measurement noise
(:func:`seqbayes.structural.oma.ambient_record`) and identified by covariance-driven SSI with a
stabilisation diagram up to order 40 (:func:`seqbayes.structural.oma.ssi_cov`).

``--seeds N``: N records of the building at its reference stiffness (seeds 0 .. N-1); reports
each mode's largest relative frequency error and smallest MAC against the exact modes.

``--out FILE.csv``: ``--days`` days of ``--per-day`` records each, evenly spaced in time. The
temperature follows a seasonal and a daily cycle (``T(t) = 10 - 15 cos(2 pi t / 365) + 4 sin(2 pi
t)`` by default from -5 to 25 degrees C over a year), and every storey stiffness is scaled by the
issue's model ``1 + alpha (T - T_ref) + beta min(T, 0)`` (``--alpha -0.0015 --beta -0.015
--t-ref 10``, as the simulated years), with an optional stiffness loss (``--damage-day``, ``--damage-storey``, ``--damage-size``).
Each record becomes the row ``day, temperature, f1 .. f4``
(:func:`seqbayes.structural.oma.record_row`): the file that ``benchmarks/bench_environment.py
--data`` reads, with its truth sidecar ``FILE.json`` in the simulator's shape (damage day, storey,
size, seed, settings). The true frequencies and the errors go to ``--json`` (not ``FILE.json``).

Run::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oma.py --seeds 20
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_oma.py --out oma_days.csv --days 8 --per-day 4 \
        --damage-day 5 --damage-storey 2
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from seqbayes.structural.oma import ambient_record, record_row, ssi_cov
from seqbayes.structural.structures import ShearBuilding, mac

# the building of the simulated years (benchmarks/bench_environment.py simulate; f = 2.09 .. 10.34 Hz)
MASSES = (2.0e5, 2.0e5, 2.0e5, 1.6e5)
STIFFNESS = (3.0e8, 2.6e8, 2.2e8, 1.8e8)


def _floats(text: str) -> tuple:
    return tuple(float(v) for v in text.split(","))


def temperature(day: np.ndarray, mean: float = 10.0, seasonal: float = 15.0, daily: float = 4.0) -> np.ndarray:
    """Seasonal (coldest on day 0) and daily cycles [degrees C]."""
    return mean - seasonal * np.cos(2 * np.pi * day / 365.0) + daily * np.sin(2 * np.pi * day)


def stiffness_ratios(temp: float, day: float, args) -> np.ndarray:
    """The issue's environmental model on every storey, times the damage factor after the damage day."""
    theta = np.full(len(args.masses), 1 + args.alpha * (temp - args.t_ref) + args.beta * min(temp, 0.0))
    if args.damage_day is not None and day >= args.damage_day:
        theta[args.damage_storey - 1] *= 1 - args.damage_size
    return theta


def accuracy(building: ShearBuilding, args) -> dict:
    """Largest frequency error and smallest MAC per mode over ``args.seeds`` records."""
    theta = np.ones(building.n_storeys)
    frequencies, shapes = building.modes(theta)
    errors, macs, damping = [], [], []
    true_damping = building.modal_damping_ratios(theta)[0]
    for seed in range(args.seeds):
        y = ambient_record(building, theta, args.duration, args.dt, rng=np.random.default_rng([25, seed]))
        modes = ssi_cov(y, args.dt, n_modes=building.n_storeys)
        errors.append(modes.frequencies / frequencies[0] - 1)
        macs.append(np.diag(mac(modes.shapes, shapes[0])))
        damping.append(modes.damping_ratios / true_damping - 1)
    errors, macs, damping = np.array(errors), np.array(macs), np.array(damping)
    return {"true_frequencies": frequencies[0].tolist(), "seeds": args.seeds,
            "max_abs_error": np.abs(errors).max(axis=0).tolist(),
            "rms_error": np.sqrt(np.mean(errors**2, axis=0)).tolist(), "min_mac": macs.min(axis=0).tolist(),
            "true_damping": true_damping.tolist(), "damping_max_abs_error": np.abs(damping).max(axis=0).tolist(),
            "damping_rms_error": np.sqrt(np.mean(damping**2, axis=0)).tolist()}


def data_file(building: ShearBuilding, args) -> dict:
    """Write the CSV of identified frequencies; return the truth and the errors."""
    rng = np.random.default_rng(args.seed)
    days = np.arange(args.days * args.per_day) / args.per_day
    rows, truth = [], []
    for day in days:
        temp = float(temperature(day))
        theta = stiffness_ratios(temp, day, args)
        y = ambient_record(building, theta, args.duration, args.dt, rng=rng)
        rows.append(record_row(y, args.dt, day=day, temperature=temp, n_modes=building.n_storeys))
        truth.append(building.modes(theta)[0][0])
    rows, truth = np.array(rows), np.array(truth)
    header = "day,temperature," + ",".join(f"f{i + 1}" for i in range(building.n_storeys))
    np.savetxt(args.out, rows, delimiter=",", header=header, comments="", fmt="%.6f")
    errors = rows[:, 2:] / truth - 1
    report = {"out": args.out, "rows": len(rows), "max_abs_error": np.abs(errors).max(axis=0).tolist(),
              "true_frequencies": truth.tolist()}
    # the truth sidecar in the simulator's shape (studies/environment.py), so that bench_environment.py
    # can count false alarms and the delay on this file too
    sidecar = {"damage_day": args.damage_day, "damage_storey": None if args.damage_day is None else args.damage_storey,
               "damage_size": args.damage_size if args.damage_day is not None else 0.0, "seed": args.seed,
               "settings": {"masses": list(args.masses), "stiffnesses": list(args.stiffness), "alpha": args.alpha,
                            "beta": args.beta, "reference_temperature": args.t_ref, "record_seconds": args.duration,
                            "dt": args.dt, "identification": "SSI-cov (seqbayes.structural.oma)",
                            "max_abs_frequency_error": report["max_abs_error"]}}
    with open(Path(args.out).with_suffix(".json"), "w") as fh:
        json.dump(sidecar, fh, indent=1)
    return report


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--masses", type=_floats, default=MASSES)
    parser.add_argument("--stiffness", type=_floats, default=STIFFNESS)
    parser.add_argument("--dt", type=float, default=0.01)
    parser.add_argument("--duration", type=float, default=1200.0, help="record length [s]")
    parser.add_argument("--seeds", type=int, default=0)
    parser.add_argument("--out", default=None)
    parser.add_argument("--days", type=int, default=6)
    parser.add_argument("--per-day", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--alpha", type=float, default=-0.0015)
    parser.add_argument("--beta", type=float, default=-0.015)
    parser.add_argument("--t-ref", type=float, default=10.0)
    parser.add_argument("--damage-day", type=float, default=None)
    parser.add_argument("--damage-storey", type=int, default=1)
    parser.add_argument("--damage-size", type=float, default=0.05)
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    if not args.seeds and not args.out:
        parser.error("give --seeds N (accuracy) and/or --out FILE.csv (a data file)")
    if args.json and args.out and Path(args.json).resolve() == Path(args.out).with_suffix(".json").resolve():
        parser.error("--json: that path is the data file's truth sidecar; choose another")
    if not 1 <= args.damage_storey <= len(args.masses):
        parser.error(f"--damage-storey: expected 1..{len(args.masses)}")
    building = ShearBuilding(args.masses, args.stiffness, damping_ratios=(0.02, 0.02))
    report = {"duration_s": args.duration, "dt": args.dt}
    if args.seeds:
        report["accuracy"] = accuracy(building, args)
        acc = report["accuracy"]
        print(f"{args.seeds} records of {args.duration:g} s at {1 / args.dt:g} Hz")
        print("| mode | f [Hz] | max abs error % | rms error % | min MAC | damping | damping rms error % |")
        print("|---|---|---|---|---|---|---|")
        for j, f in enumerate(acc["true_frequencies"]):
            print(f"| {j + 1} | {f:.4f} | {100 * acc['max_abs_error'][j]:.3f} | {100 * acc['rms_error'][j]:.3f} "
                  f"| {acc['min_mac'][j]:.5f} | {acc['true_damping'][j]:.4f} | {100 * acc['damping_rms_error'][j]:.1f} |")
    if args.out:
        report["data_file"] = data_file(building, args)
        errs = report["data_file"]["max_abs_error"]
        print(f"wrote {args.out}: {report['data_file']['rows']} rows; largest |error| per mode (%): "
              + ", ".join(f"{100 * e:.3f}" for e in errs))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=1)
    return report


if __name__ == "__main__":
    main()
