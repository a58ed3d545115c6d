"""The monitor's driver and its table-level entry point.

:class:`Monitor` holds one monitoring run in memory: the sampler's state (:mod:`~seqbayes.structural.monitor.
sampler`), the history, the generator and the alarm rule's count. :meth:`Monitor.update` takes one dataset (the
sets of a day, or of a record) and returns the day's :class:`MonitorDay`. :func:`monitor_table` runs a whole table
(the year CSV's columns) day by day; the run store (:mod:`seqbayes.store.monitor`) runs the same
:meth:`Monitor.update` on each dataset and keeps the state between processes.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from .history import History, prepare_sets
from .model import MonitorModel, MonitorSettings
from .sampler import MonitorState, assimilate, prior_state
from .summary import DamageSummary, EnvironmentSummary, damage_summary, environment_summary

__all__ = ["Monitor", "MonitorDay", "monitor_table", "table_days"]


@dataclass(frozen=True)
class MonitorDay:
    """The monitor after a dataset (a day's sets, or a record of a day).

    Attributes
    ----------
    day : int
        The calendar day of its last set (0: the first monitored day).
    time : float
        Its last set's time [days].
    n_sets : int
        Sets in the dataset.
    p_damage : float
        ``P(a loss by now | data)``.
    days_above : int
        Days in a row (ending with this one) whose last ``p_damage`` exceeded the alarm's threshold.
    alarm : bool
        Whether the alarm rule holds (:class:`~seqbayes.structural.monitor.model.AlarmRule`).
    damage : DamageSummary
    environment : EnvironmentSummary
    log_evidence : float
        ``log p(data so far)``.
    ess : float
    n_stages, n_sweeps : int
        Tempering stages with a resample-move, and their sweeps (passes over the history).
    acceptance : float
        Of the sweeps' proposals (NaN without sweeps).
    cpu_seconds : float
        Process CPU time of the update.
    """

    day: int
    time: float
    n_sets: int
    p_damage: float
    days_above: int
    alarm: bool
    damage: DamageSummary
    environment: EnvironmentSummary
    log_evidence: float
    ess: float
    n_stages: int
    n_sweeps: int
    acceptance: float
    cpu_seconds: float

    def to_dict(self) -> dict:
        """Plain JSON values (NaN as None)."""
        return _plain(asdict(self))


def _plain(value):
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return _plain(value.item())
    return value


class Monitor:
    """One monitoring run in memory (module docstring).

    Parameters
    ----------
    model : MonitorModel
    settings : MonitorSettings
    rng : numpy.random.Generator
        Draws the prior particles now and every resampling and move later.
    """

    def __init__(self, model: MonitorModel, settings: MonitorSettings, rng: np.random.Generator):
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
        self.model, self.settings, self.rng = model, settings, rng
        self.state: MonitorState = prior_state(model, settings, rng)
        self.history = History.empty(model.n_modes, len(model.covariates))
        self.days_above = 0
        self.last_day: int | None = None
        self.last_p_damage = 0.0

    @classmethod
    def restored(cls, model, settings, rng, state, history, days_above: int, last_day, last_p_damage: float):
        """A monitor continuing from a stored state (:mod:`seqbayes.store.monitor`)."""
        monitor = cls.__new__(cls)
        monitor.model, monitor.settings, monitor.rng = model, settings, rng
        monitor.state, monitor.history = state, history
        monitor.days_above, monitor.last_day, monitor.last_p_damage = int(days_above), last_day, float(last_p_damage)
        return monitor

    def update(self, times, temperature, frequencies, std_frequencies=None, covariates=None) -> MonitorDay:
        """Take one dataset's sets (times [days] increasing past the last set so far, air temperatures [degC],
        frequencies ``(S, n)`` [Hz] with NaN where missing, optional OMA standard errors [Hz] and covariates
        ``(S, r)`` in the model's order) and return the day after it."""
        started = time.process_time()
        arrays = prepare_sets(self.model, times, temperature, frequencies, std_frequencies, covariates)
        history = self.history.extended(*arrays)
        first = self.history.n_chunks
        state, info = assimilate(self.state, self.model, self.settings, history, first, self.rng)
        day = int(history.chunk_day[-1])
        damage = damage_summary(state, self.model, self.settings, day)
        rule = self.settings.alarm
        # the rule counts days: a dataset later on the same day replaces that day's value
        above = (self.days_above - (self.last_p_damage > rule.threshold) if day == self.last_day
                 else self.days_above)
        days_above = rule.next(above, damage.p_damage)
        self.state, self.history = state, history
        self.days_above, self.last_day, self.last_p_damage = days_above, day, damage.p_damage
        return MonitorDay(day, float(history.times[-1]), int(arrays[0].size), damage.p_damage, days_above,
                          rule.raised(days_above), damage, environment_summary(state, self.model),
                          state.log_evidence, info.ess, info.n_stages, info.n_sweeps, info.acceptance,
                          time.process_time() - started)


def table_days(table: dict) -> list:
    """The row indices of each calendar day of a table with a ``day`` column, in order."""
    day = np.floor(np.asarray(table["day"], dtype=float)).astype(int)
    breaks = np.flatnonzero(np.diff(day)) + 1
    return np.split(np.arange(day.size), breaks)


def monitor_table(table: dict, model: MonitorModel, settings: MonitorSettings | None = None,
                  rng: np.random.Generator | None = None) -> list:
    """Monitor a whole table day by day: one :class:`MonitorDay` per calendar day with sets.

    Parameters
    ----------
    table : dict of str -> (S,) arrays
        The year CSV's columns (docs/environment.md): ``day`` (float days since the first monitored day,
        increasing), ``temperature`` (the air's, degC), the model's covariates by name, ``f1 .. fn`` [Hz] (NaN where
        a mode was not identified) and optionally ``sf1 .. sfn`` (the OMA's standard errors [Hz], NaN where not
        given).
    model : MonitorModel
    settings : MonitorSettings, optional
    rng : numpy.random.Generator
        Required: the seed reproduces the run bit for bit.

    Returns
    -------
    list of MonitorDay
    """
    if rng is None:
        raise TypeError("rng: monitor_table needs a numpy.random.Generator (its seed reproduces the run)")
    settings = MonitorSettings() if settings is None else settings
    n = model.n_modes
    missing = [c for c in ["day", "temperature", *model.covariates, *(f"f{i + 1}" for i in range(n))]
               if c not in table]
    if missing:
        raise ValueError(f"table: missing column(s) {', '.join(missing)} (the year CSV has day, temperature, the "
                         f"model's covariates and f1..f{n})")
    f = np.column_stack([np.asarray(table[f"f{i + 1}"], dtype=float) for i in range(n)])
    sf = (np.column_stack([np.asarray(table[f"sf{i + 1}"], dtype=float) for i in range(n)])
          if all(f"sf{i + 1}" in table for i in range(n)) else None)
    z = (np.column_stack([np.asarray(table[c], dtype=float) for c in model.covariates]) if model.covariates
         else None)
    monitor = Monitor(model, settings, rng)
    days = []
    for rows in table_days(table):
        days.append(monitor.update(np.asarray(table["day"], dtype=float)[rows],
                                   np.asarray(table["temperature"], dtype=float)[rows], f[rows],
                                   None if sf is None else sf[rows], None if z is None else z[rows]))
    return days
