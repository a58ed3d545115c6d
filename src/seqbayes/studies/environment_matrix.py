"""The misspecification matrix of issue 40: the methods on a year, the plan of years, the one table.

``benchmarks/bench_environment_matrix.py`` is the driver (simulation cache, parallel runs, resumable JSON lines,
calibration); this module holds what it composes, so that the tests can call it:

- :data:`METHODS` maps a method's name to a function ``(table, building, seed) -> (DailyVerdict, info)``:
  ``"monitor"`` (the new monitor's ``monitor_table``, when this code has it), ``"monitor_v1"`` (the old
  :func:`seqbayes.structural.environment.monitor_year`, which the cells are known to break), and the
  baselines ``"regression"``, ``"pca"`` and ``"ekf"`` (:mod:`seqbayes.studies.environment_baselines`, each
  with ``train_days`` of training; their score is the day's statistic over its training threshold);
- :class:`MatrixPlan` says which years (cells, kinds, counts, length, damage window, seeds), for the matrix and
  for the separate calibration set;
- :func:`summarise` scores a method's years of one cell under a rule against the issue's bars, and
  :func:`matrix_table` writes the one table.

The bars (issue 40, in every cell): no alarm in any healthy year; a 5 % loss found within 7 days at the right
element in at least 9 of 10 years; a 2 % loss found within 30 days in at least 8 of 10; the loss's size and its
day inside their 95 % intervals (read at that detection) in at least 9 of 10 years, for the 5 % and the 2 %
losses each. A detection counts only if the rule did not already hold the day before the damage.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from ..structural.structures import ShearBuilding
from .environment_alarms import AlarmRule, DailyVerdict, rate_interval, score_year
from .environment_baselines import ekf_tracking, novelty_detection
from .environment_cells import CELLS, KINDS, YearBase

__all__ = ["MatrixPlan", "FULL_PLAN", "REDUCED_PLAN", "METHODS", "DEFAULT_RULES", "BARS", "year_rows",
           "run_method", "summarise", "matrix_table", "monitor_available", "frequency_columns",
           "monitor_verdict", "calibration_table", "nominal_table"]


@dataclass(frozen=True)
class MatrixPlan:
    """Which years: ``years_per_kind`` of each kind of :data:`~seqbayes.studies.environment_cells.KINDS` in each
    of ``cells``, ``n_days`` long, the loss from a whole day in ``damage_window``; baselines train on
    ``train_days``; the calibration set has ``calibration_years`` of each kind per cell (its own seeds)."""

    cells: tuple = tuple(CELLS)
    years_per_kind: int = 10
    n_days: int = 365
    damage_window: tuple = (183, 335)
    train_days: float = 180.0
    seed: int = 0
    calibration_years: tuple = (("healthy", 4), ("loss5", 1), ("loss2", 1))

    def __post_init__(self):
        unknown = [c for c in self.cells if c not in CELLS]
        if unknown:
            raise ValueError(f"cells: unknown cell {unknown[0]!r}; expected some of {', '.join(CELLS)}")
        if not self.train_days < self.damage_window[0] <= self.damage_window[1] < self.n_days:
            raise ValueError("train_days, damage_window, n_days: expected train_days < first damage day <= last "
                             "damage day < n_days")

    @property
    def base(self) -> YearBase:
        return YearBase(n_days=int(self.n_days))

    def years(self, purpose: int = 0) -> list:
        """``(cell, kind, index, purpose)`` of every year (purpose 0: the matrix, 1: the calibration set)."""
        counts = ({kind: self.years_per_kind for kind in KINDS} if purpose == 0 else dict(self.calibration_years))
        return [(cell, kind, i, purpose) for cell in self.cells for kind in KINDS for i in range(counts.get(kind, 0))]


#: The issue's matrix: 8 cells x 30 years (10 healthy, 10 with each loss of KINDS), and 48
#: calibration years (4 healthy, one of each loss per cell).
FULL_PLAN = MatrixPlan()
#: The reduced form the slow test runs: 2 cells x 3 years of 90 days, the loss on a day in 60..75, and 2
#: calibration years per cell.
REDUCED_PLAN = MatrixPlan(cells=("lag0", "lag6"), years_per_kind=1, n_days=90, damage_window=(60, 75),
                          train_days=45.0, calibration_years=(("healthy", 1), ("loss2", 1)))

#: Each method's rule before calibration: the old monitor's 0.95 on 2 days; a baseline's training threshold.
DEFAULT_RULES = {"monitor": AlarmRule(0.95, 2), "monitor_v1": AlarmRule(0.95, 2), "regression": AlarmRule(1.0, 2),
                 "pca": AlarmRule(1.0, 2), "ekf": AlarmRule(1.0, 2)}


def frequency_columns(table: dict) -> tuple[np.ndarray, np.ndarray | None]:
    """``f1..fn (S, n)`` and ``sf1..sfn (S, n)`` (None when absent) of a year table."""
    n = sum(1 for k in table if k.startswith("f") and k[1:].isdigit())
    frequencies = np.column_stack([table[f"f{r + 1}"] for r in range(n)])
    std = np.column_stack([table[f"sf{r + 1}"] for r in range(n)]) if "sf1" in table else None
    return frequencies, std


def _baseline_verdict(result, train_days) -> DailyVerdict:
    D = result.days.size
    nan = np.full((D, 3), np.nan)
    return DailyVerdict(result.days, result.statistic / result.threshold, result.elements, nan, nan,
                        float(result.days[0]) + float(train_days))


def _regression(table, building, seed, *, train_days):
    frequencies, _ = frequency_columns(table)
    result = novelty_detection(table["day"], table["temperature"], frequencies, building, method="regression",
                               train_days=train_days)
    return _baseline_verdict(result, train_days), {"threshold": result.threshold}


def _pca(table, building, seed, *, train_days):
    frequencies, _ = frequency_columns(table)
    result = novelty_detection(table["day"], table["temperature"], frequencies, building, method="pca",
                               train_days=train_days)
    return _baseline_verdict(result, train_days), {"threshold": result.threshold}


#: The EKF's random walk per set for the matrix (with the temperature law in its state).
EKF_PROCESS_STD = 1e-4


def _ekf(table, building, seed, *, train_days):
    frequencies, std = frequency_columns(table)
    result = ekf_tracking(table["day"], table["temperature"], frequencies, building, train_days=train_days,
                          temperature_law=True, process_std=EKF_PROCESS_STD, std_frequencies=std)
    return _baseline_verdict(result, train_days), {"process_std": EKF_PROCESS_STD}


def _monitor_v1(table, building, seed, *, train_days):
    """The old monitor (structural/environment.py): it takes complete sets only, and temperature only; the day of
    the loss has a posterior mean but no interval (the onset interval is NaN), the size a normal 95 % interval."""
    from ..structural.environment import monitor_year

    frequencies, _ = frequency_columns(table)
    complete = ~np.isnan(frequencies).any(axis=1)
    old = {"day": table["day"][complete], "temperature": table["temperature"][complete]}
    old.update({f"f{r + 1}": frequencies[complete, r] for r in range(frequencies.shape[1])})
    summary, monitor, days, records = monitor_year(building, old, rng=np.random.default_rng(seed))
    D = len(days)
    size, onset = np.full((D, 3), np.nan), np.full((D, 3), np.nan)
    element = np.zeros(D, int)
    for i, record in enumerate(records):
        if record.storey is None:
            continue
        model = record.models[record.storey]
        element[i] = record.storey
        mean, sd = float(model.mean[-1]), float(model.sd[-1])
        size[i] = (mean, mean - 1.959964 * sd, mean + 1.959964 * sd)
        onset[i, 0] = model.damage_day
    verdict = DailyVerdict(np.asarray(days, int), np.array([r.p_damage for r in records]), element, size, onset, 0.0)
    return verdict, {"environment": summary["environment"], "sets_used": int(complete.sum()),
                     "n_particle_evaluations": summary["n_particle_evaluations"]}


def monitor_available() -> bool:
    """Whether the new monitor (``seqbayes.structural.monitor.table.monitor_table``) imports in this code."""
    try:
        _monitor_entry()
    except ImportError:
        return False
    return True


def _monitor_entry():
    from ..structural.monitor.table import monitor_table, verdicts

    return monitor_table, verdicts


def monitor_code() -> str:
    """A digest of the monitor's source files (``structural/monitor/*.py``): which monitor a result came from."""
    import hashlib
    from pathlib import Path

    from ..structural import monitor

    digest = hashlib.sha256()
    for path in sorted(Path(monitor.__file__).parent.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def monitor_verdict(stacked: dict) -> DailyVerdict:
    """The monitor's days stacked by ``seqbayes.structural.monitor.table.verdicts`` (``day``, ``p_damage``,
    ``element``, ``size (D, 3)``, ``onset (D, 3)``) as a :class:`DailyVerdict`: the score is ``P(damage)``, the
    element the most probable storey, the size the stiffness fraction lost and the onset the loss's first day, each
    with its posterior mean and central 95 % interval."""
    return DailyVerdict(stacked["day"], stacked["p_damage"], stacked["element"], stacked["size"], stacked["onset"],
                        0.0)


def _monitor(table, building, seed, *, train_days):
    """The new monitor: on-line from day 0, told the nominal building and the air temperature only (no humidity,
    no lag, no knee: it learns them), with its default settings and ``seed``."""
    monitor_table, verdicts = _monitor_entry()
    days = monitor_table(table, building, int(seed))
    last = days[-1]
    return monitor_verdict(verdicts(days)), {
        "environment": {k: [v.mean, v.lower, v.upper] for k, v in last.environment.static.items()},
        "coefficients": {k: [v.mean, v.lower, v.upper] for k, v in last.environment.coefficients.items()},
        "p_lag": last.environment.p_lag, "n_sweeps": int(sum(d.n_sweeps for d in days)),
        "log_evidence": last.log_evidence, "monitor_code": monitor_code()}


METHODS = {"monitor": _monitor, "monitor_v1": _monitor_v1, "regression": _regression, "pca": _pca, "ekf": _ekf}


def run_method(name: str, table: dict, building: ShearBuilding, *, seed: int, train_days: float) -> dict:
    """One method on one year: ``{"verdict": DailyVerdict.to_json(), "info", "cpu_seconds", "wall_seconds"}``."""
    if name not in METHODS:
        raise ValueError(f"name: unknown method {name!r}; expected one of {', '.join(METHODS)}")
    start, cpu = time.perf_counter(), time.process_time()
    verdict, info = METHODS[name](table, building, seed, train_days=train_days)
    return {"verdict": verdict.to_json(), "info": info, "cpu_seconds": time.process_time() - cpu,
            "wall_seconds": time.perf_counter() - start}


#: The issue's bars: (kind, what, at least how many of 10).
BARS = {"healthy": 10, "loss5": 9, "loss2": 8, "intervals": 9}


def summarise(records: list, rule: AlarmRule | None) -> dict:
    """Score one method's year records of one cell (dicts with ``kind``, ``truth``, ``verdict``, ``cpu_seconds``)
    under ``rule`` (None: no rule, every year counts as failed) against the bars (:data:`BARS`)."""
    by_kind = {kind: [r for r in records if r["kind"] == kind] for kind in KINDS}
    out = {"years": {kind: len(rs) for kind, rs in by_kind.items()}, "rule": None if rule is None else asdict(rule)}
    scores = {kind: [score_year(DailyVerdict.from_json(r["verdict"]), r["truth"], rule) for r in rs] if rule else []
              for kind, rs in by_kind.items()}
    out["healthy_with_alarm"] = sum(s.false_alarms > 0 for s in scores["healthy"]) if rule else len(by_kind["healthy"])
    all_scores = [s for kind in KINDS for s in scores[kind]]
    count = sum(s.false_alarms for s in all_scores)
    exposure = sum(s.exposure_days for s in all_scores) / 365.0
    out["false_alarms"] = count
    out["exposure_years"] = exposure
    if exposure > 0:
        out["rate"], out["rate_se"], out["rate_upper"] = (float(v) for v in rate_interval(count, exposure))
    for kind, window in (("loss5", 7), ("loss2", 30)):
        ss, rs = scores[kind], by_kind[kind]
        news = [s for s in ss if s.delay is not None and not s.in_alarm_at_damage]
        found = [s for s, r in zip(ss, rs) if s.delay is not None and not s.in_alarm_at_damage and s.delay <= window
                 and (kind != "loss5" or s.element == r["truth"]["damage_storey"])]
        delays = [s.delay for s in news]
        out[kind] = {"found": len(found), "window": window, "median_delay": float(np.median(delays)) if delays else None,
                     "size_covered": sum(bool(s.size_covered) for s in news),
                     "onset_covered": sum(bool(s.onset_covered) for s in news),
                     "both_covered": sum(bool(s.size_covered and s.onset_covered) for s in news),
                     "has_intervals": any(s.size_covered is not None for s in news)}
    # the baselines' default threshold is the 1 - rate quantile of their training days: this share, over the
    # healthy years' monitored days, is what that rate becomes on days the training did not see
    monitored = [(v.score[v.days >= v.first_day]) for v in (DailyVerdict.from_json(r["verdict"])
                                                              for r in by_kind["healthy"])]
    days = sum(m.size for m in monitored)
    out["healthy_days"] = int(days)
    out["share_above_one"] = float(sum(np.sum(m > 1.0) for m in monitored) / days) if days else None
    out["cpu_seconds"] = float(np.mean([r["cpu_seconds"] for r in records])) if records else None
    n = {kind: len(rs) for kind, rs in by_kind.items()}
    bars = {"healthy": None if not n["healthy"] else out["healthy_with_alarm"] == 0,
            "loss5": None if not n["loss5"] else out["loss5"]["found"] >= np.ceil(BARS["loss5"] / 10 * n["loss5"]),
            "loss2": None if not n["loss2"] else out["loss2"]["found"] >= np.ceil(BARS["loss2"] / 10 * n["loss2"]),
            "intervals": (None if not (n["loss5"] or n["loss2"]) else
                          all(out[k]["both_covered"] >= np.ceil(BARS["intervals"] / 10 * n[k])
                              for k in ("loss5", "loss2") if n[k]))}
    # None: no year of that kind has run yet (the bar is not judged, neither met nor failed)
    out["bars"] = {k: None if v is None else bool(v) for k, v in bars.items()}
    return out


def year_rows(plan: MatrixPlan, purpose: int = 0) -> list:
    """The year identifiers of ``plan`` as dicts (``cell``, ``kind``, ``index``, ``purpose``)."""
    return [dict(zip(("cell", "kind", "index", "purpose"), y)) for y in plan.years(purpose)]


def _fmt(value, spec=".0f", missing="-"):
    return missing if value is None else format(value, spec)


def matrix_table(summaries: dict, methods) -> list:
    """Markdown lines: one row per cell and method (``summaries[cell][method]`` from :func:`summarise`)."""
    rows = ["| cell | method | rule (threshold, days) | healthy years with an alarm | false alarms per year "
            "(95 % upper) | 5 %: found in 7 days at the element | 5 %: median delay [d] | 2 %: found in 30 days "
            "| 2 %: median delay [d] | size and day in their 95 % intervals (5 % / 2 %) | CPU s per year | bars met |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for cell, by_method in summaries.items():
        for method in methods:
            s = by_method.get(method)
            if s is None:
                continue
            n = s["years"]
            rule = "none" if s["rule"] is None else f"{s['rule']['threshold']:.4g}, {s['rule']['consecutive']}"
            if s.get("rule_source") == "default":
                rule += " (not calibrated)"
            rate = ("-" if "rate" not in s else
                    f"{s['rate']:.2f} +- {s['rate_se']:.2f} ({s['rate_upper']:.2f})")
            coverage = " / ".join(
                (f"{s[k]['both_covered']} of {n[k]}" if s[k]["has_intervals"] else "no interval")
                for k in ("loss5", "loss2"))
            met = sum(v is True for v in s["bars"].values())
            judged = sum(v is not None for v in s["bars"].values())
            failing = [k for k, v in s["bars"].items() if v is False]
            unjudged = [k for k, v in s["bars"].items() if v is None]
            verdict = f"{met} of {judged}" + ("" if not failing else " (not: " + ", ".join(failing) + ")")
            if unjudged:
                verdict += "; no years yet: " + ", ".join(unjudged)
            rows.append(f"| {cell} | {method} | {rule} | {s['healthy_with_alarm']} of {n['healthy']} | {rate} "
                        f"| {s['loss5']['found']} of {n['loss5']} | {_fmt(s['loss5']['median_delay'])} "
                        f"| {s['loss2']['found']} of {n['loss2']} | {_fmt(s['loss2']['median_delay'])} "
                        f"| {coverage} | {_fmt(s['cpu_seconds'], '.1f')} | {verdict} |")
    return rows


def calibration_table(report: dict, methods) -> list:
    """Markdown lines: each method's calibrated rule and what it did on the calibration years (``report`` as the
    benchmark's ``calibration.json``: :meth:`~seqbayes.studies.environment_alarms.Calibration.to_json` per method)."""
    rows = ["| method | rule (threshold, days) | healthy calibration years | false alarms | per year +- se (95 % "
            "upper) | target shown | damaged calibration years found in 30 days | their median delay [d] |",
            "|---|---|---|---|---|---|---|---|"]
    for method in methods:
        c = report.get(method)
        if c is None:
            continue
        rule = "none" if c["rule"] is None else f"{c['rule']['threshold']:.4g}, {c['rule']['consecutive']}"
        fa, delays = c["false_alarms"], c["delays"]
        found = sum(d is not None and d <= 30 for d in delays.get("delays", []))
        rows.append(f"| {method} | {rule} | {fa.get('years', 0)} ({fa.get('exposure_years', 0):.1f} monitored years) "
                    f"| {fa.get('false_alarms', '-')} | {fa.get('rate', 0):.2f} +- {fa.get('rate_se', 0):.2f} "
                    f"({fa.get('rate_upper', float('nan')):.2f}) | {'yes' if c['demonstrated'] else 'no'} "
                    f"| {found} of {delays.get('years', 0)} | {_fmt(delays.get('median_delay'))} |")
    return rows


def nominal_table(summaries: dict, methods, nominal: float = 0.01) -> list:
    """Markdown lines: each baseline's share of healthy monitored days above its training threshold, per cell and
    pooled, against the ``nominal`` rate that threshold was set for (binomial standard error over days, which
    understates the error of correlated days)."""
    rows = ["| method | " + " | ".join(summaries) + " | pooled (+- se) |", "|---|" + "---|" * (len(summaries) + 1)]
    for method in methods:
        cells = [summaries[c].get(method) for c in summaries]
        if all(c is None or c.get("share_above_one") is None for c in cells):
            continue
        above = sum(round(c["share_above_one"] * c["healthy_days"]) for c in cells if c and c["healthy_days"])
        days = sum(c["healthy_days"] for c in cells if c)
        share = above / days
        se = float(np.sqrt(nominal * (1 - nominal) / days))
        rows.append(f"| {method} | " + " | ".join("-" if c is None or c["share_above_one"] is None
                                                   else f"{c['share_above_one']:.3f}" for c in cells)
                    + f" | {share:.4f} +- {se:.4f} (nominal {nominal}) |")
    return rows
