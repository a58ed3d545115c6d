"""The alarm rule, its calibration on simulated healthy years, and the scoring of a monitored year (issue 40).

Every method of the misspecification matrix (the monitor and the baselines) gives, for each day of a year, a
:class:`DailyVerdict`: a score that grows with the evidence of damage (``P(damage)`` for the monitor, the
statistic of a baseline), the element it points to, and where it has them the 95 % intervals of the loss's size
and of its day. The alarm rule (:class:`AlarmRule`) is ``score > threshold`` on ``consecutive`` days in a row;
an alarm's time is the end of the day whose data completed it (``floor(day) + 1``, the convention of
docs/environment.md), so the delay counts the days of data the rule needed.

**False alarms.** An alarm *episode* is a run of days on which the rule holds; a false alarm is an episode that
starts at or before the damage day (every episode of a healthy year). The false-alarm rate is the number of
false alarms per monitored healthy year, ``c / E`` with ``E`` the monitored years before any damage; its Monte
Carlo error is Poisson: standard error ``sqrt(c) / E`` and the one-sided 95 % upper bound
``chi2.ppf(0.95, 2 (c + 1)) / (2 E)`` (3.0 / E with no false alarm), :func:`rate_interval`.

**Calibration** (:func:`calibrate`): for each number of days in a row ``k`` of ``consecutive``, the threshold is
the lowest at which the healthy calibration years' false alarms ``c`` keep the upper bound at or below the
user's ``target_rate`` (scanned down from the largest ``k``-day run minimum, so that no threshold above it breaks
the bound either), raised to the user's ``floor`` where it falls below it (0.5 for a probability of damage:
an alarm then always means damage is the more probable state); then the ``k`` whose rule detects the damaged calibration years soonest (the most detections
within ``within_days``, then the smallest median delay). The target is demonstrated only when ``E >= 3 /
target_rate`` (a zero count bounds the rate at ``3 / E``): at 0.1 false alarms a year, 30 healthy years.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

__all__ = ["AlarmRule", "DailyVerdict", "YearScore", "Calibration", "held_for", "alarm_times", "episode_starts",
           "score_year", "rate_interval", "false_alarm_rate", "calibrate"]


@dataclass(frozen=True)
class AlarmRule:
    """``score > threshold`` on ``consecutive`` days in a row."""

    threshold: float
    consecutive: int

    def __post_init__(self):
        if not np.isfinite(self.threshold):
            raise ValueError(f"threshold: expected a finite number, got {self.threshold}")
        if int(self.consecutive) != self.consecutive or self.consecutive < 1:
            raise ValueError(f"consecutive: expected a positive integer, got {self.consecutive}")


@dataclass(frozen=True)
class DailyVerdict:
    """A method's output on one year, one entry per whole day.

    Attributes
    ----------
    days : (D,) int array
        Whole days (``floor(day)``), ascending.
    score : (D,) array
        Grows with the evidence of damage (NaN: no verdict that day).
    element : (D,) int array
        The element (1-based) pointed to (0: none).
    size : (D, 3) array
        The loss's posterior mean and 95 % interval (NaN where the method has none).
    onset : (D, 3) array
        The damage day's mean and 95 % interval, in days (NaN where the method has none).
    first_day : float
        The first day the method monitors (after its training days; 0 for an on-line method).
    """

    days: np.ndarray
    score: np.ndarray
    element: np.ndarray
    size: np.ndarray
    onset: np.ndarray
    first_day: float = 0.0

    def __post_init__(self):
        days = np.asarray(self.days, int).reshape(-1)
        D = days.size
        object.__setattr__(self, "days", days)
        object.__setattr__(self, "score", np.asarray(self.score, float).reshape(D))
        object.__setattr__(self, "element", np.asarray(self.element, int).reshape(D))
        for name in ("size", "onset"):
            value = np.asarray(getattr(self, name), float)
            if value.shape != (D, 3):
                raise ValueError(f"{name}: expected shape ({D}, 3) (mean, low, high per day), got {value.shape}")
            object.__setattr__(self, name, value)
        if D and np.any(np.diff(days) <= 0):
            raise ValueError("days: expected increasing whole days")

    def to_json(self) -> dict:
        """Plain lists (NaN as None) for a JSON line."""
        def clean(a):
            return [None if not np.isfinite(v) else float(v) for v in np.asarray(a, float).ravel()]

        return {"days": self.days.tolist(), "score": clean(self.score), "element": self.element.tolist(),
                "size": clean(self.size), "onset": clean(self.onset), "first_day": float(self.first_day)}

    @classmethod
    def from_json(cls, record: dict) -> "DailyVerdict":
        def back(values, shape):
            return np.array([np.nan if v is None else v for v in values], float).reshape(shape)

        D = len(record["days"])
        return cls(np.asarray(record["days"], int), back(record["score"], (D,)), np.asarray(record["element"], int),
                   back(record["size"], (D, 3)), back(record["onset"], (D, 3)), float(record["first_day"]))


def held_for(above, consecutive: int) -> np.ndarray:
    """``(..., D)`` bool: ``above`` has held on the day and the ``consecutive - 1`` days before it (along the last
    axis; the rule's run length, vectorised over years).

    Examples
    --------
    >>> held_for(np.array([False, True, True, False, True, True, True]), 2).tolist()
    [False, False, True, False, False, True, True]
    """
    above = np.asarray(above, bool)
    held = above.copy()
    for lag in range(1, int(consecutive)):  # k - 1 shifted ANDs, each over the whole array
        held[..., lag:] &= above[..., :-lag]
        held[..., :lag] = False
    return held


def _alarm_state(verdict: DailyVerdict, rule: AlarmRule) -> np.ndarray:
    above = np.nan_to_num(verdict.score, nan=-np.inf) > rule.threshold
    return held_for(above, rule.consecutive) & (verdict.days >= verdict.first_day)


def alarm_times(verdict: DailyVerdict, rule: AlarmRule) -> np.ndarray:
    """The times ``floor(day) + 1`` of every day on which the rule holds (from ``first_day`` on)."""
    return (verdict.days[_alarm_state(verdict, rule)] + 1).astype(float)


def episode_starts(held: np.ndarray) -> np.ndarray:
    """``(..., D)`` bool: the days on which a run of ``held`` days starts."""
    held = np.asarray(held, bool)
    before = np.zeros_like(held)
    before[..., 1:] = held[..., :-1]
    return held & ~before


@dataclass(frozen=True)
class YearScore:
    """One method's year under one rule (see the module for the conventions; NaN or None where it does not apply).

    ``false_alarms`` counts episodes starting at or before the damage day, ``exposure_days`` the monitored days
    before it (the whole monitored year when healthy); ``delay`` is the first alarm time after the damage day
    minus that day, ``in_alarm_at_damage`` whether the rule already held the day before; ``element``, ``size``
    and ``onset`` are read at that first alarm, ``size_covered`` and ``onset_covered`` whether the 95 % intervals
    there hold the truth (None without an interval or a detection).
    """

    false_alarms: int
    false_alarm_days: int
    exposure_days: int
    delay: float | None
    in_alarm_at_damage: bool
    element: int | None
    size: tuple | None
    onset: tuple | None
    size_covered: bool | None
    onset_covered: bool | None
    first_alarm: float | None


def score_year(verdict: DailyVerdict, truth: dict, rule: AlarmRule) -> YearScore:
    """Score ``verdict`` against ``truth`` (``damage_day`` or None, ``damage_storey``, ``damage_size``)."""
    held = _alarm_state(verdict, rule)
    times = verdict.days + 1.0
    damage_day = truth.get("damage_day")
    before = times <= damage_day if damage_day is not None else np.ones(times.size, bool)
    starts = episode_starts(held)
    monitored = verdict.days >= verdict.first_day
    exposure = int(np.sum(monitored & (verdict.days < damage_day if damage_day is not None else True)))
    first = times[held][0] if held.any() else None
    delay = element = size = onset = size_covered = onset_covered = None
    in_alarm = False
    if damage_day is not None:
        after = np.flatnonzero(held & ~before)
        in_alarm = bool(np.any(held & (times == damage_day)))
        if after.size:
            i = after[0]
            delay = float(times[i] - damage_day)
            element = int(verdict.element[i]) or None
            size, onset = tuple(verdict.size[i].tolist()), tuple(verdict.onset[i].tolist())
            if np.all(np.isfinite(verdict.size[i, 1:])):
                size_covered = bool(verdict.size[i, 1] <= truth["damage_size"] <= verdict.size[i, 2])
            if np.all(np.isfinite(verdict.onset[i, 1:])):
                onset_covered = bool(verdict.onset[i, 1] <= damage_day <= verdict.onset[i, 2])
    return YearScore(int(np.sum(starts & before)), int(np.sum(held & before)), exposure, delay, in_alarm, element,
                     size, onset, size_covered, onset_covered, None if first is None else float(first))


def rate_interval(count: int, exposure_years: float, confidence: float = 0.95) -> tuple[float, float, float]:
    """``(rate, standard error, one-sided upper bound)`` of a Poisson count ``count`` over ``exposure_years``.

    Examples
    --------
    >>> [round(v, 4) for v in rate_interval(0, 30.0)]
    [0.0, 0.0, 0.0999]
    """
    from scipy.stats import chi2

    if exposure_years <= 0:
        raise ValueError(f"exposure_years: expected a positive exposure, got {exposure_years}")
    upper = chi2.ppf(confidence, 2 * (count + 1)) / 2 / exposure_years
    return count / exposure_years, np.sqrt(count) / exposure_years, float(upper)


def false_alarm_rate(verdicts, truths, rule: AlarmRule, days_per_year: float = 365.0) -> dict:
    """False alarms per monitored year over ``verdicts`` (with their ``truths``): count, exposure, rate, error."""
    scores = [score_year(v, t, rule) for v, t in zip(verdicts, truths)]
    count = sum(s.false_alarms for s in scores)
    exposure = sum(s.exposure_days for s in scores) / days_per_year
    rate, se, upper = rate_interval(count, exposure)
    return {"false_alarms": count, "exposure_years": exposure, "years": len(scores),
            "years_with_false_alarms": sum(s.false_alarms > 0 for s in scores), "rate": rate, "rate_se": se,
            "rate_upper": upper}


@dataclass(frozen=True)
class Calibration:
    """The calibrated rule and what it was measured to do on the calibration years (:func:`calibrate`).

    ``rule`` is None when no threshold meets the target for any ``k`` (every healthy year in alarm at its top);
    ``candidates`` holds one dict per ``k`` (its threshold, false alarms and delays).
    """

    rule: AlarmRule | None
    target_rate: float
    demonstrated: bool
    false_alarms: dict
    delays: dict
    candidates: list = field(default_factory=list)

    def to_json(self) -> dict:
        out = asdict(self)
        out["rule"] = None if self.rule is None else asdict(self.rule)
        return out


def _threshold_for(healthy, k: int, target_rate: float, days_per_year: float):
    """The lowest threshold of the ``k``-day rule whose false alarms on ``healthy`` keep the Poisson upper bound at
    or below ``target_rate`` (None when none does); scanned down over the ``k``-day run minima."""
    minima = []
    for v in healthy:
        above = np.nan_to_num(v.score, nan=-np.inf)
        run = above.copy()
        for lag in range(1, k):
            run[lag:] = np.minimum(run[lag:], above[:-lag])
            run[:lag] = -np.inf
        minima.append(run[v.days >= v.first_day])
    exposure = sum(m.size for m in minima) / days_per_year
    candidates = np.unique(np.concatenate(minima))[::-1]
    candidates = candidates[np.isfinite(candidates)]
    # too few years to show the target: the rule with no false alarm on them (flagged as not demonstrated)
    bound = max(target_rate, rate_interval(0, exposure)[2])
    chosen = None
    for threshold in candidates:  # from the top: stop at the first threshold whose count breaks the bound
        count = sum(int(episode_starts(m > threshold).sum()) for m in minima)
        if rate_interval(count, exposure)[2] > bound * (1 + 1e-12):
            break
        chosen = float(threshold)
    return chosen


def _delays(damaged, truths, rule: AlarmRule) -> dict:
    scores = [score_year(v, t, rule) for v, t in zip(damaged, truths)]
    delays = [s.delay for s in scores]
    return {"years": len(scores), "delays": delays,
            "median_delay": float(np.median([np.inf if d is None else d for d in delays])) if scores else None}


def calibrate(healthy, target_rate: float, *, damaged=(), damaged_truths=(), consecutive=(1, 2, 3),
              within_days: float = 30.0, days_per_year: float = 365.0, score_bounds=(-np.inf, np.inf),
              floor: float = -np.inf) -> Calibration:
    """The rule with the soonest detection among those whose false alarms on ``healthy`` meet ``target_rate``.

    Parameters
    ----------
    healthy : sequence of DailyVerdict
        The method on simulated healthy years (not the years it will be judged on).
    target_rate : float
        The false alarms per year the user accepts (the one-sided 95 % Poisson upper bound must stay below it).
    damaged, damaged_truths : sequences of DailyVerdict and of truth dicts
        The method on simulated damaged years, to choose ``k`` (without them, the first of ``consecutive``).
    consecutive : sequence of int
        The days in a row tried.
    within_days : float
        A detection counts when its delay is at most this.
    score_bounds : (2,) tuple
        Thresholds outside this open interval are not rules (``(0, 1)`` for a probability).
    floor : float
        The lowest threshold the user accepts (a calibrated threshold below it is raised to it): ``0.5`` for a
        posterior probability of damage, so that an alarm always means damage is the more probable state.

    Returns
    -------
    Calibration
    """
    if not target_rate > 0:
        raise ValueError(f"target_rate: expected a positive rate per year, got {target_rate}")
    if np.isnan(floor) or floor >= score_bounds[1]:
        raise ValueError(f"floor: expected a threshold below the scores' upper bound {score_bounds[1]}, got {floor}")
    healthy = list(healthy)
    if not healthy:
        raise ValueError("healthy: expected at least one healthy year")
    truths = [{"damage_day": None}] * len(healthy)
    damaged, damaged_truths = list(damaged), list(damaged_truths)
    if len(damaged) != len(damaged_truths):
        raise ValueError("damaged, damaged_truths: expected one truth per damaged year")
    candidates = []
    for k in consecutive:
        threshold = _threshold_for(healthy, int(k), target_rate, days_per_year)
        if threshold is not None:
            threshold = float(np.clip(max(threshold, floor), np.nextafter(score_bounds[0], np.inf),
                                      np.nextafter(score_bounds[1], -np.inf)))
        entry = {"consecutive": int(k), "threshold": threshold}
        if threshold is not None and threshold < score_bounds[1]:
            rule = AlarmRule(threshold, int(k))
            entry["false_alarms"] = false_alarm_rate(healthy, truths, rule, days_per_year)
            delays = _delays(damaged, damaged_truths, rule)
            entry["delays"] = delays
            entry["detected"] = sum(d is not None and d <= within_days for d in delays["delays"])
        candidates.append(entry)
    usable = [c for c in candidates if "false_alarms" in c
              and c["false_alarms"]["rate_upper"] <= target_rate * (1 + 1e-12)]
    if not usable:
        usable = [c for c in candidates if "false_alarms" in c]
    if not usable:
        return Calibration(None, float(target_rate), False, {}, {}, candidates)
    best = usable[0] if not damaged else min(usable, key=lambda c: (-c["detected"], c["delays"]["median_delay"]))
    rule = AlarmRule(best["threshold"], best["consecutive"])
    demonstrated = best["false_alarms"]["rate_upper"] <= target_rate * (1 + 1e-12)
    return Calibration(rule, float(target_rate), bool(demonstrated), best["false_alarms"], best.get("delays", {}),
                       candidates)
