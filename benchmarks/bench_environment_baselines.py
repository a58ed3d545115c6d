"""The baselines of issue 25 on years of monitoring data (docs/environment_baselines.md).

Three methods from :mod:`seqbayes.studies.environment_baselines`, each learning on the first
``--train-days`` days (90), with the threshold at the ``1 - --false-alarm-rate`` (0.99) quantile of
the training days' statistic and an alarm after ``--consecutive`` (2) days above it:

- ``regression``: log frequencies regressed on temperature and min(T, 0), daily Mahalanobis
  distance of the residuals (scikit-learn);
- ``pca``: the first principal component of the log frequencies removed, Mahalanobis distance in
  the others (scikit-learn);
- ``ekf``: the storey stiffness ratios tracked by an EKF with no environmental model; alarm when a
  ratio drops below its training mean by more than its training quantile.

One year::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_environment_baselines.py --data FILE.csv \\
        --masses m1,m2,m3,m4 --stiffness k1,k2,k3,k4 --json OUT.json

writes, per method, ``{"alarm_day", "storey", "false_alarm_days", "statistic" (one value per day),
"alarm_days", "detection_delay", "threshold"}`` with the conventions of
``benchmarks/bench_environment.py``: an alarm time is the end of the day whose data raised it
(``floor(day) + 1``); with a truth sidecar (``FILE.json``: ``damage_day``, ``damage_storey``), the
false-alarm days are the alarm times at or before the damage day (all of them in a year without
damage) and the delay is the first alarm time after the damage day minus that day.

A directory (``--data DIR``): every ``*.csv`` in it, and a markdown table (``--table OUT.md``) with a
row per year (its damage day and storey, and per method the delay, the storey at that alarm and
the number of false-alarm days; ``*`` when the alarm already held the day before the damage, so
that the "detection" is no news) and a summary per method: years alarmed within 7 days with the
storey right (and of those, the ones not already in alarm), the median delay, years with any false
alarm. The building defaults to that of the simulated years (``bench_environment.py simulate``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from seqbayes.structural.structures import ShearBuilding
from seqbayes.studies.environment import read_year_csv
from seqbayes.studies.environment_baselines import ekf_tracking, novelty_detection

MASSES = (2.0e5, 2.0e5, 2.0e5, 1.6e5)
STIFFNESS = (3.0e8, 2.6e8, 2.2e8, 1.8e8)
METHODS = ("regression", "pca", "ekf")
WITHIN_DAYS = 7


def read_year(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``day``, ``temperature`` and ``frequencies (R, n)`` of a ``day,temperature,f1,..,fn`` file, read as the
    monitor reads it (:func:`seqbayes.studies.environment.read_year_csv`)."""
    try:
        table = read_year_csv(path)
    except ValueError as error:
        raise SystemExit(f"--data: {error}") from None
    frequencies = np.column_stack([table[name] for name in table if name.startswith("f")])
    return table["day"], table["temperature"], frequencies


def read_truth(path: Path) -> dict | None:
    sidecar = path.with_suffix(".json")
    return json.loads(sidecar.read_text()) if sidecar.exists() else None


def run_year(path: Path, building: ShearBuilding, args) -> dict:
    """Every method on one file: the dict of the module docstring, per method, and the truth."""
    day, temperature, frequencies = read_year(path)
    truth = read_truth(path)
    damage_day = None if truth is None else truth.get("damage_day")
    settings = dict(train_days=args.train_days, false_alarm_rate=args.false_alarm_rate,
                    consecutive=args.consecutive)
    out = {"truth": truth}
    for method in METHODS:
        if method == "ekf":
            result = ekf_tracking(day, temperature, frequencies, building, **settings)
        else:
            result = novelty_detection(day, temperature, frequencies, building, method=method, **settings)
        false_alarms = [] if truth is None else [t for t in result.alarm_days if damage_day is None or t <= damage_day]
        after = [(t, s) for t, s in zip(result.alarm_days, result.storeys) if damage_day is not None and t > damage_day]
        out[method] = {"alarm_day": result.alarm_day, "storey": result.storey, "false_alarm_days": false_alarms,
                       "statistic": [None if not np.isfinite(v) else float(v) for v in result.statistic],
                       "alarm_days": result.alarm_days, "threshold": result.threshold,
                       "detection_delay": after[0][0] - damage_day if after else None,
                       "storey_after_damage": after[0][1] if after else None,
                       # the alarm already held at the end of the day before the damage: the "detection" is no news
                       "in_alarm_at_damage": damage_day is not None and damage_day in result.alarm_days}
    return out


def _cell(truth: dict, m: dict) -> str:
    """``delay / storey found / false-alarm days`` of one method on one year."""
    delay, found = m["detection_delay"], m["storey_after_damage"]
    if truth.get("damage_day") is None:
        return f"- / - / {len(m['false_alarm_days'])}"
    star = "*" if m["in_alarm_at_damage"] else ""
    return (f"{'-' if delay is None else f'{delay:.0f}'}{star} / {'-' if found is None else found} "
            f"/ {len(m['false_alarm_days'])}")


def summary(results: dict, method: str) -> dict:
    """Years detected within ``WITHIN_DAYS`` days, with the storey right, years with a false alarm."""
    damaged = detected = right = with_false = news = 0
    delays = []
    for r in results.values():
        truth, m = r["truth"] or {}, r[method]
        if truth.get("damage_day") is not None:
            damaged += 1
            delay = m["detection_delay"]
            hit = delay is not None and delay <= WITHIN_DAYS
            detected += hit
            right += hit and m["storey_after_damage"] == truth.get("damage_storey")
            news += hit and m["storey_after_damage"] == truth.get("damage_storey") and not m["in_alarm_at_damage"]
            if delay is not None:
                delays.append(delay)
        with_false += bool(m["false_alarm_days"])
    return {"damaged": damaged, "detected": detected, "storey_right": right, "not_already_alarming": news,
            "years": len(results),
            "years_with_false_alarms": with_false,
            "false_alarm_days": sum(len(r[method]["false_alarm_days"]) for r in results.values()),
            "median_delay": float(np.median(delays)) if delays else None}


def table(results: dict) -> list:
    """Markdown: one row per year (``delay / storey found / false-alarm days`` per method), then the summary."""
    rows = ["| year | damage day (storey) | " + " | ".join(METHODS) + " |", "|---|---|" + "---|" * len(METHODS)]
    for name, r in results.items():
        truth = r["truth"] or {}
        truth_text = "-" if truth.get("damage_day") is None else f"{truth['damage_day']:.0f} ({truth.get('damage_storey')})"
        rows.append(f"| {name} | {truth_text} | " + " | ".join(_cell(truth, r[m]) for m in METHODS) + " |")
    rows += ["", "`*`: the alarm already held at the end of the day before the damage.", "",
             f"| method | alarm within {WITHIN_DAYS} days, storey right | of which not already in alarm "
             f"| alarm within {WITHIN_DAYS} days | median delay [days] | years with false alarms "
             "| false-alarm days in all |", "|---|---|---|---|---|---|---|"]
    for method in METHODS:
        s = summary(results, method)
        median = "-" if s["median_delay"] is None else f"{s['median_delay']:.0f}"
        rows.append(f"| {method} | {s['storey_right']} of {s['damaged']} | {s['not_already_alarming']} of {s['damaged']} "
                    f"| {s['detected']} of {s['damaged']} | {median} "
                    f"| {s['years_with_false_alarms']} of {s['years']} | {s['false_alarm_days']} |")
    return rows


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--data", required=True, help="a CSV day,temperature,f1,..,fn or a directory of them")
    parser.add_argument("--masses", default=",".join(map(str, MASSES)), help="floor masses [kg], comma-separated")
    parser.add_argument("--stiffness", default=",".join(map(str, STIFFNESS)), help="storey stiffnesses [N/m]")
    parser.add_argument("--train-days", type=float, default=90.0)
    parser.add_argument("--false-alarm-rate", type=float, default=0.01)
    parser.add_argument("--consecutive", type=int, default=2)
    parser.add_argument("--json", default=None)
    parser.add_argument("--table", default=None, help="write the markdown tables here (a directory)")
    args = parser.parse_args(argv)
    try:
        building = ShearBuilding([float(v) for v in args.masses.split(",")],
                                 [float(v) for v in args.stiffness.split(",")])
    except ValueError as error:
        raise SystemExit(f"--masses/--stiffness: {error}") from None
    data = Path(args.data)
    if data.is_dir():
        files = sorted(data.glob("*.csv"))
        if not files:
            raise SystemExit(f"--data: no *.csv in {data}")
        results = {path.stem: run_year(path, building, args) for path in files}
        text = "\n".join(table(results))
        print(text)
        if args.table:
            Path(args.table).write_text(text + "\n")
        report = results
    elif data.is_file():
        report = run_year(data, building, args)
        for method in METHODS:
            m = report[method]
            print(f"{method}: alarm_day {m['alarm_day']}, storey {m['storey']}, "
                  f"false-alarm days {len(m['false_alarm_days'])}, delay {m['detection_delay']}")
    else:
        raise SystemExit(f"--data: {data} is neither a file nor a directory")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
    return report


if __name__ == "__main__":
    main()
