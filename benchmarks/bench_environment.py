"""A year of monitoring under temperature (issue 25): simulate years, run the workflow on them.

Simulate (the files of docs/environment.md)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_environment.py simulate --out DIR --years 20 --seed 0

writes ``damaged_00.csv`` ... (5 % loss of a random storey from the start of a random day in
183..350) and ``healthy_00.csv`` ..., each with a ``.json`` truth sidecar
(:func:`seqbayes.studies.environment.simulate_years`).

Run the workflow on one year::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_environment.py --data FILE.csv \\
        --masses m1,m2,m3,m4 --stiffness k1,k2,k3,k4 --json OUT.json

:class:`seqbayes.structural.environment.EnvironmentMonitor` at its defaults (128 particles per
model, alarm when P(damage) > 0.95 on 2 days in a row), one update per whole day
(``floor(day)``). ``OUT.json`` holds:

- ``p_damage``: P(damage by the end of the day), one value per day with data;
- ``alarm_days``: the times at which the alarm rule holds, each the end of the day whose update
  raised it (``floor(day) + 1``, in the CSV's day units);
- ``alarm_day``: the first of them, or null; ``storey``: the monitor's storey (1-based) at that day, or null;
- ``false_alarm_days``: with a truth sidecar (``FILE.json``, as the simulator writes), the alarm
  days at or before the true damage day (every alarm day if the year has no damage); with no
  sidecar there is no truth to judge by and the list is empty (``truth`` is then null);
- ``detection_delay``: the first alarm day after the true damage day minus that day (null if none);
- ``wall_seconds``, ``n_particle_evaluations`` (particle likelihood calls, each over one day or a
  whole history) and ``n_set_evaluations`` (particle x frequency-set terms).

Every year of a directory (the table of docs/environment.md)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_environment.py --dir DIR [--json OUT.json]

with the simulator's building unless ``--masses``/``--stiffness`` are given.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from seqbayes import plotting
from seqbayes.store.environment_report import environment_figure
from seqbayes.structural.environment import monitor_year
from seqbayes.structural.structures import ShearBuilding
from seqbayes.studies.environment import MASSES, STIFFNESSES, ThermalLaw, read_truth, read_year_csv, simulate_years


def run_year(path, masses, stiffnesses, *, n_particles: int = 128, seed: int = 0, threshold: float = 0.95,
             consecutive: int = 2, figure=None) -> dict:
    """The workflow on one CSV year; the dict written as ``OUT.json`` (see the module); ``figure``: a PNG path."""
    table = read_year_csv(path)
    building = ShearBuilding(masses, stiffnesses)
    truth = read_truth(path)
    result, monitor, days, records = monitor_year(building, table, rng=np.random.default_rng(seed),
                                            damage_day=None if truth is None else truth.damage_day,
                                            truth_known=truth is not None, n_particles=n_particles,
                                            threshold=threshold, consecutive=consecutive)
    result["truth"] = None if truth is None else {"damage_day": truth.damage_day,
                                                  "damage_storey": truth.damage_storey,
                                                  "damage_size": truth.damage_size}
    if figure is not None:
        fig = environment_figure(monitor, table, days, records, result["alarm_days"],
                                 *(() if truth is None else (truth.damage_day, truth.damage_storey)))
        plotting.save(fig, figure, dpi=110)
    return result


def _floats(text: str, name: str) -> list:
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        raise SystemExit(f"{name}: expected comma-separated numbers, got {text!r}") from None


def table_rows(results: dict) -> list:
    """Markdown rows: file, truth, alarm, delay, storey right, false alarms, wall seconds, evaluations."""
    rows = ["| year | damage day (storey) | first alarm after it | delay [days] | storey found | false alarm days "
            "| max P(damage) before damage | wall [s] | CPU [s] | particle evaluations |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in results.items():
        truth = r["truth"] or {}
        damage_day = truth.get("damage_day")
        p = np.asarray(r["p_damage"])
        before = p[: int(damage_day)] if damage_day is not None else p
        found = r.get("storey_at_detection", None if r["false_alarm_days"] else r["storey"])
        delay = r["detection_delay"]
        truth_text = "-" if damage_day is None else f"{damage_day:.0f} ({truth.get('damage_storey')})"
        alarm_text = "-" if delay is None else f"{damage_day + delay:.0f}"
        delay_text = "-" if delay is None else f"{delay:.0f}"
        worst = before.max() if before.size else float("nan")
        rows.append(f"| {name} | {truth_text} | {alarm_text} | {delay_text} | {'-' if found is None else found} "
                    f"| {len(r['false_alarm_days'])} | {worst:.2g} | {r['wall_seconds']:.0f} "
                    f"| {r.get('cpu_seconds', float('nan')):.0f} "
                    f"| {r['n_particle_evaluations']:,} |")
    return rows


def acceptance_lines(results: dict) -> list:
    """The issue's acceptance counts over the years of ``results``."""
    damaged = {k: r for k, r in results.items() if r["truth"] and r["truth"]["damage_day"] is not None}
    healthy = {k: r for k, r in results.items() if r["truth"] and r["truth"]["damage_day"] is None}
    in_time = sum(r["detection_delay"] is not None and r["detection_delay"] <= 7 for r in damaged.values())
    storey = sum(r.get("storey_at_detection", r["storey"]) == r["truth"]["damage_storey"] for r in damaged.values())
    clean = sum(not r["false_alarm_days"] for r in healthy.values())
    clean_damaged = sum(not r["false_alarm_days"] for r in damaged.values())
    walls = [r["wall_seconds"] for r in results.values()]
    cpus = [r.get("cpu_seconds", float("nan")) for r in results.values()]
    delays = [r["detection_delay"] for r in damaged.values() if r["detection_delay"] is not None]
    return [f"- alarm within 7 days of the damage: {in_time} of {len(damaged)} damaged years "
            f"(delays {min(delays, default=float('nan')):.0f} to {max(delays, default=float('nan')):.0f} days)",
            f"- storey right at the alarm: {storey} of {len(damaged)}",
            f"- no false alarm: {clean} of {len(healthy)} healthy years "
            f"(and {clean_damaged} of {len(damaged)} damaged years before their damage)",
            f"- time per year: wall {min(walls):.0f} to {max(walls):.0f} s, CPU {np.nanmin(cpus):.0f} to "
            f"{np.nanmax(cpus):.0f} s; particle likelihood evaluations "
            f"{min(r['n_particle_evaluations'] for r in results.values()):,} to "
            f"{max(r['n_particle_evaluations'] for r in results.values()):,}"]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", help="one year: CSV with the header day,temperature,f1,...,fn")
    parser.add_argument("--dir", help="every *.csv of a directory (the simulator's files)")
    parser.add_argument("--masses", help="floor masses [kg], bottom to top, comma-separated")
    parser.add_argument("--stiffness", help="nominal storey stiffnesses [N/m], comma-separated")
    parser.add_argument("--json", help="write the result (or all results) here")
    parser.add_argument("--figure", help="with --data: write the year's figure (PNG) here")
    parser.add_argument("--pattern", default="*.csv", help="with --dir: the files to run (glob)")
    parser.add_argument("--table", nargs="+", help="print the table of --dir runs' JSON files and stop")
    parser.add_argument("--particles", type=int, default=128, help="particles per model")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threshold", type=float, default=0.95)
    parser.add_argument("--consecutive", type=int, default=2)
    args = parser.parse_args(argv)
    if args.table:
        results = {}
        for path in args.table:
            results.update(json.loads(Path(path).read_text()))
        print("\n".join(table_rows(results) + [""] + acceptance_lines(results)))
        return
    if (args.data is None) == (args.dir is None):
        parser.error("give one of --data FILE.csv or --dir DIR")
    if args.data is not None and (args.masses is None or args.stiffness is None):
        parser.error("--data needs --masses and --stiffness")
    masses = _floats(args.masses, "--masses") if args.masses else list(MASSES)
    stiffnesses = _floats(args.stiffness, "--stiffness") if args.stiffness else list(STIFFNESSES)
    options = dict(n_particles=args.particles, seed=args.seed, threshold=args.threshold,
                   consecutive=args.consecutive)
    if args.data is not None:
        result = run_year(args.data, masses, stiffnesses, figure=args.figure, **options)
        print(json.dumps({k: result[k] for k in ("alarm_day", "storey", "false_alarm_days", "detection_delay",
                                                  "wall_seconds", "n_particle_evaluations")}))
        if args.json:
            Path(args.json).write_text(json.dumps(result, indent=1) + "\n")
        return
    results = {}
    for path in sorted(Path(args.dir).glob(args.pattern)):
        result = run_year(path, masses, stiffnesses, **options)
        results[path.stem] = result
        print(path.stem, {k: result[k] for k in ("alarm_day", "storey", "detection_delay", "false_alarm_days",
                                                 "wall_seconds", "cpu_seconds")}, flush=True)
        if args.json:  # after every year, so that a long run keeps what it has done
            Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    print("\n".join(table_rows(results) + [""] + acceptance_lines(results)))


def simulate_main(argv) -> None:
    parser = argparse.ArgumentParser(prog="bench_environment.py simulate", description="Write simulated years.")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--years", type=int, default=20, help="number of years (half damaged, half healthy)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--damage-size", type=float, default=0.05)
    parser.add_argument("--alpha-spread", type=float, default=0.0,
                        help="a law the monitor lacks: storey alphas alpha (1 + spread s_i), s from -1 to 1")
    parser.add_argument("--thermal-lag-hours", type=float, default=0.0,
                        help="a law the monitor lacks: the structure lags the recorded air temperature")
    args = parser.parse_args(argv)
    for path in simulate_years(args.out, args.years, args.seed, damage_size=args.damage_size,
                               law=ThermalLaw(alpha_spread=args.alpha_spread,
                                                                         thermal_lag_hours=args.thermal_lag_hours)):
        print(path)


if __name__ == "__main__":
    if sys.argv[1:2] == ["simulate"]:
        simulate_main(sys.argv[2:])
    else:
        main()
