"""The misspecification matrix of issue 40: every cell's years through the monitor and both baselines.

Steps (each resumable; ``all`` runs them in turn)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_environment_matrix.py all --out DIR [--reduced]
        [--methods monitor,regression,pca,ekf] [--workers 2] [--target-rate 0.1]

- ``run``: simulates every year of the plan (:data:`seqbayes.studies.environment_matrix.FULL_PLAN`, or the
  reduced one) once, cached as ``DIR/years/<purpose>/<cell>/<kind>_<i>.csv`` with its truth ``.json``
  (:func:`seqbayes.studies.environment_cells.cell_year`: the same seed gives the same file), then runs every
  method on every year, over at most ``--workers`` (2) processes, appending one JSON line per method to
  ``DIR/results/<purpose>/<cell>/<kind>_<i>.jsonl`` (a year's methods, its truth and each method's daily verdict:
  score, element, size and day intervals, CPU seconds). A year and method already there are skipped, so a killed
  run resumes where it stopped. ``purpose`` is ``calibration`` (the separate healthy and damaged years the alarm
  rule is chosen on) and ``matrix`` (the years the table judges).
- ``calibrate``: chooses each method's rule (threshold, days in a row) on the calibration years for
  ``--target-rate`` false alarms per year (:func:`seqbayes.studies.environment_alarms.calibrate`) and writes
  ``DIR/calibration.json`` (the rule, the false alarms per year with their Poisson error, the delays).
- ``table``: scores the matrix years under the calibrated rules (``--rule default``: each method's rule before
  calibration) and writes ``DIR/matrix.md`` (the one table of docs/environment.md) and ``DIR/matrix.json``.

``--reduced`` is the slow test's form (2 cells x 3 years of 90 days, 4 calibration years). ``DIR/plan.json`` holds
the plan; a directory made with another plan is refused.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path

import numpy as np

from seqbayes.structural.structures import ShearBuilding
from seqbayes.studies.environment import read_truth
from seqbayes.studies.environment_alarms import AlarmRule, DailyVerdict, calibrate
from seqbayes.studies.environment_cells import CELLS, KINDS, cell_year, read_cell_year, write_cell_year
from seqbayes.studies.environment_matrix import (DEFAULT_RULES, FULL_PLAN, METHODS, REDUCED_PLAN, MatrixPlan,
                                                 calibration_table, matrix_table, nominal_table, monitor_available, run_method,
                                                 summarise)

PURPOSES = {0: "matrix", 1: "calibration"}
BASELINES = ("regression", "pca", "ekf")
#: The lowest P(damage) threshold calibrated for a monitor: an alarm means damage is the more probable state.
PROBABILITY_FLOOR = 0.5


def year_paths(out: Path, cell: str, kind: str, index: int, purpose: int) -> tuple[Path, Path]:
    """The cached year CSV and its results file."""
    name = f"{kind}_{index:02d}"
    return (out / "years" / PURPOSES[purpose] / cell / f"{name}.csv",
            out / "results" / PURPOSES[purpose] / cell / f"{name}.jsonl")


def ensure_year(out: Path, plan: MatrixPlan, cell: str, kind: str, index: int, purpose: int) -> Path:
    """The year's CSV, simulated and written once (``write_cell_year`` renames a finished file into place)."""
    csv_path, _ = year_paths(out, cell, kind, index, purpose)
    if not csv_path.exists():
        csv_path.parent.mkdir(parents=True, exist_ok=True)
        table, truth = cell_year(cell, kind, index, seed=plan.seed, purpose=purpose, base=plan.base,
                                 damage_window=tuple(plan.damage_window))
        write_cell_year(csv_path, table, truth)
    return csv_path


def done_methods(results: Path) -> set:
    """Methods with a complete line in ``results`` (a line cut by a kill is ignored and redone)."""
    if not results.exists():
        return set()
    done = set()
    for line in results.read_text().splitlines():
        try:
            done.add(json.loads(line)["method"])
        except (json.JSONDecodeError, KeyError):
            continue
    return done


def _append(results: Path, record: dict) -> None:
    """One JSON line, under an exclusive lock: two runs of different methods may share a year's file."""
    import fcntl

    text = json.dumps(record) + "\n"
    with open(results, "a+b") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        handle.seek(0, os.SEEK_END)
        if handle.tell():
            handle.seek(-1, os.SEEK_END)
            if handle.read(1) != b"\n":  # a kill mid-line leaves no newline: start on a fresh line
                text = "\n" + text
        handle.write(text.encode())
        handle.flush()
        os.fsync(handle.fileno())
        fcntl.flock(handle, fcntl.LOCK_UN)


def run_year(out: str, plan_record: dict, year: tuple, methods: list) -> list:
    """Simulate (or read) one year and run the methods it lacks; returns the methods run."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    out = Path(out)
    plan = _plan_from(plan_record)
    cell, kind, index, purpose = year
    csv_path = ensure_year(out, plan, cell, kind, index, purpose)
    _, results = year_paths(out, cell, kind, index, purpose)
    todo = [m for m in methods if m not in done_methods(results)]
    if not todo:
        return []
    results.parent.mkdir(parents=True, exist_ok=True)
    table, truth = read_cell_year(csv_path), read_truth(csv_path)
    nominal = truth.settings["nominal"]
    building = ShearBuilding(nominal["masses"], nominal["stiffnesses"])
    seed = int(np.random.SeedSequence([plan.seed, purpose, list(CELLS).index(cell), list(KINDS).index(kind),
                                       index]).generate_state(1)[0])  # the methods' own seed, fixed per year
    for method in todo:
        result = run_method(method, table, building, seed=seed, train_days=plan.train_days)
        record = {"method": method, "cell": cell, "kind": kind, "index": index, "purpose": purpose,
                  "truth": {"damage_day": truth.damage_day, "damage_storey": truth.damage_storey,
                            "damage_size": truth.damage_size}, "seed": seed, **result}
        _append(results, record)
    return todo


def _plan_from(record: dict) -> MatrixPlan:
    record = dict(record)
    record["cells"] = tuple(record["cells"])
    record["damage_window"] = tuple(record["damage_window"])
    record["calibration_years"] = tuple(tuple(kv) for kv in record["calibration_years"])
    return MatrixPlan(**record)


def check_plan(out: Path, plan: MatrixPlan) -> dict:
    """Write ``plan.json`` or refuse a directory that holds another plan (the cells may differ: a cell's years do
    not depend on the others)."""
    record = json.loads(json.dumps(asdict(plan)))
    path = out / "plan.json"
    if path.exists():
        held = json.loads(path.read_text())
        if {**held, "cells": None} != {**record, "cells": None}:
            raise SystemExit(f"--out {out}: holds the years of another plan ({path}); use another directory")
    else:
        out.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record, indent=1) + "\n")
    return record


#: Within a round, kinds in this order: the healthy years (the false alarms a law the model lacks can raise),
#: then the smaller loss, then the larger.
KIND_ORDER = ("healthy", "loss2", "loss5")


def priority(plan: MatrixPlan, year: tuple) -> tuple:
    """The order years run in, so that a run stopped early has balanced cells: round ``i`` holds the ``i``-th matrix
    year of every cell and kind (every cell's healthy year first, then every cell's year of each loss), then the
    ``i``-th healthy calibration year of every cell; the damaged calibration years join round 1 (they only choose
    the days in a row)."""
    cell, kind, index, purpose = year
    round_ = index if purpose == 0 or kind == "healthy" else 1
    return (round_, purpose == 1, KIND_ORDER.index(kind), plan.cells.index(cell))


def run(out: Path, plan: MatrixPlan, methods: list, workers: int, purposes=(1, 0)) -> int:
    """Every year of ``purposes`` through ``methods`` (skipping what is done); returns the number of method runs."""
    record = check_plan(out, plan)
    years = sorted((y for p in purposes for y in plan.years(p)), key=lambda y: priority(plan, y))
    pending = [y for y in years if set(methods) - done_methods(year_paths(out, *y)[1])]
    print(f"{len(years)} years, {len(pending)} with methods to run ({', '.join(methods)})", flush=True)
    count = 0
    if workers <= 1:
        for y in pending:
            count += len(run_year(str(out), record, y, methods))
            print(*y, flush=True)
        return count
    with ProcessPoolExecutor(max_workers=min(workers, 2)) as pool:  # the machine is shared: 2 processes at most
        futures = {pool.submit(run_year, str(out), record, y, methods): y for y in pending}
        for future in as_completed(futures):
            ran = future.result()
            count += len(ran)
            print(*futures[future], ",".join(ran), flush=True)
    return count


def load_records(out: Path, plan: MatrixPlan, purpose: int) -> list:
    records = []
    for y in plan.years(purpose):
        results = year_paths(out, *y)[1]
        if not results.exists():
            continue
        for line in results.read_text().splitlines():
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return records


def calibrate_step(out: Path, plan: MatrixPlan, methods: list, target_rate: float) -> dict:
    """Each method's rule from the calibration years; written to ``DIR/calibration.json``."""
    records = load_records(out, plan, 1)
    report = {"target_rate": target_rate}
    for method in methods:
        mine = [r for r in records if r["method"] == method]
        healthy = [DailyVerdict.from_json(r["verdict"]) for r in mine if r["truth"]["damage_day"] is None]
        damaged = [r for r in mine if r["truth"]["damage_day"] is not None]
        if not healthy:
            continue
        probability = method.startswith("monitor")
        result = calibrate(healthy, target_rate, damaged=[DailyVerdict.from_json(r["verdict"]) for r in damaged],
                           damaged_truths=[r["truth"] for r in damaged],
                           score_bounds=(0.0, 1.0) if probability else (-np.inf, np.inf),
                           floor=PROBABILITY_FLOOR if probability else -np.inf)
        report[method] = result.to_json()
        report[method]["damaged_kinds"] = [r["kind"] for r in damaged]
        rule = result.rule
        print(f"{method}: rule {None if rule is None else (rule.threshold, rule.consecutive)}, "
              f"demonstrated {result.demonstrated}, false alarms {result.false_alarms}", flush=True)
    (out / "calibration.json").write_text(json.dumps(report, indent=1) + "\n")
    lines = calibration_table(report, methods)
    (out / "calibration.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return report


def table_step(out: Path, plan: MatrixPlan, methods: list, rule_source: str = "calibrated") -> list:
    """The one table (``DIR/matrix.md``) and the summaries behind it (``DIR/matrix.json``)."""
    records = load_records(out, plan, 0)
    calibration = {}
    if rule_source == "calibrated":
        path = out / "calibration.json"
        if not path.exists():
            raise SystemExit(f"--rule calibrated: no {path}; run the calibrate step first (or --rule default)")
        calibration = json.loads(path.read_text())
    summaries = {}
    for cell in plan.cells:
        summaries[cell] = {}
        for method in methods:
            mine = [r for r in records if r["method"] == method and r["cell"] == cell]
            if not mine:
                continue
            source = rule_source if method in calibration or rule_source == "default" else "default"
            if source == "calibrated":  # a calibration that found no rule stays None: every bar fails
                held = calibration[method].get("rule")
                rule = None if held is None else AlarmRule(**held)
            else:  # no calibration years of this method yet: its rule before calibration, flagged in the table
                rule = DEFAULT_RULES[method]
            summaries[cell][method] = {**summarise(mine, rule), "rule_source": source}
    lines = matrix_table(summaries, methods)
    baselines = [m for m in methods if not m.startswith("monitor")]
    lines += ["", "Baselines: share of healthy monitored days above the training threshold (set for 1 % of days)",
              "", *nominal_table(summaries, baselines)]
    (out / "matrix.md").write_text("\n".join(lines) + "\n")
    (out / "matrix.json").write_text(json.dumps(summaries, indent=1) + "\n")
    print("\n".join(lines))
    return lines


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("step", choices=("run", "calibrate", "table", "all"))
    parser.add_argument("--out", required=True, help="the matrix's directory (years, results, tables)")
    parser.add_argument("--reduced", action="store_true", help="the slow test's form: 2 cells x 3 short years")
    parser.add_argument("--cells", help="comma-separated cells (default: the plan's)")
    parser.add_argument("--methods", help="comma-separated, of " + ", ".join(METHODS)
                        + " (default: monitor if this code has it, else monitor_v1, and the baselines)")
    parser.add_argument("--workers", type=int, default=2, help="processes (at most 2)")
    parser.add_argument("--target-rate", type=float, default=0.1, help="false alarms per year the rule may make")
    parser.add_argument("--rule", choices=("calibrated", "default"), default="calibrated")
    parser.add_argument("--only", choices=("matrix", "calibration"), help="run: only these years")
    args = parser.parse_args(argv)
    plan = REDUCED_PLAN if args.reduced else FULL_PLAN
    if args.cells:
        plan = MatrixPlan(**{**asdict(plan), "cells": tuple(args.cells.split(","))})
    methods = (args.methods.split(",") if args.methods
               else ["monitor" if monitor_available() else "monitor_v1", *BASELINES])
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        parser.error(f"--methods: unknown method {unknown[0]!r}; expected some of {', '.join(METHODS)}")
    if not 1 <= args.workers <= 2:
        parser.error("--workers: expected 1 or 2 (the machine is shared)")
    out = Path(args.out)
    if args.step in ("run", "all"):
        purposes = {"matrix": (0,), "calibration": (1,), None: (1, 0)}[args.only]
        run(out, plan, methods, args.workers, purposes)
    if args.step in ("calibrate", "all"):
        calibrate_step(out, plan, methods, args.target_rate)
    if args.step in ("table", "all"):
        table_step(out, plan, methods, args.rule)


if __name__ == "__main__":
    sys.exit(main())
