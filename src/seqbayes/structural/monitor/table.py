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

__all__ = ["Monitor", "MonitorDay", "monitor_table", "table_days", "verdicts"]


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
    filter_updates : int
        The update's work: per-particle chunk updates of the filters (the new day's for every particle, and each
        move sweep's pass over the whole history).
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
    filter_updates: int
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
                          info.filter_updates, time.process_time() - started)


def table_days(table: dict) -> list:
    """The row indices of each calendar day of a table with a ``day`` column, in order."""
    day = np.floor(np.asarray(table["day"], dtype=float)).astype(int)
    breaks = np.flatnonzero(np.diff(day)) + 1
    return np.split(np.arange(day.size), breaks)


def _as_model(model) -> MonitorModel:
    if isinstance(model, MonitorModel):
        return model
    from ..structures import ShearBuilding
    from ..structures.linear import ShearBuildingModel

    if isinstance(model, ShearBuilding):
        return MonitorModel.linear(ShearBuildingModel(model))
    raise TypeError(f"model: expected a MonitorModel or a ShearBuilding, got {type(model).__name__}")


def monitor_table(table: dict, model, seed, settings: MonitorSettings | None = None) -> list:
    """Monitor a whole table day by day: one :class:`MonitorDay` per calendar day with sets.

    The stable entry point of the misspecification matrix (:mod:`seqbayes.studies.environment_matrix`) and of
    ``seqbayes environment`` (which runs the same updates through a monitor run store).

    Parameters
    ----------
    table : dict of str -> (S,) arrays
        The year CSV's columns (docs/environment.md): ``day`` (float days since the first monitored day,
        increasing), ``temperature`` (the air's, degC), the model's covariates by name, ``f1 .. fn`` [Hz] (NaN where
        a mode was not identified) and optionally ``sf1 .. sfn`` (the OMA's standard errors [Hz], NaN where not
        given). Other columns are not used.
    model : MonitorModel or ShearBuilding
        A shear building (:class:`~seqbayes.structural.structures.ShearBuilding`) becomes
        :meth:`MonitorModel.shear_building` (a loss located in a storey, named ``"1"`` .. ``"n"``, no further
        covariates).
    seed : int or numpy.random.Generator
        The seed reproduces the run bit for bit.
    settings : MonitorSettings, optional

    Returns
    -------
    list of MonitorDay
        Per day: ``p_damage``, ``alarm`` (the settings' rule), ``damage.location`` (the element's name; None
        without a structural model), ``damage.location_index`` (1-based, 0 for none), ``damage.size`` (the
        stiffness fraction lost: mean and 95 % interval), ``damage.day`` (the loss's first day: mean and 95 %
        interval), the learned ``environment``; :func:`verdicts` stacks them into arrays.
    """
    if isinstance(seed, np.random.Generator):
        rng = seed
    elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        rng = np.random.default_rng(int(seed))
    else:
        raise TypeError(f"seed: expected an integer or a numpy.random.Generator, got {type(seed).__name__}")
    model = _as_model(model)
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


def verdicts(days) -> dict:
    """The days of :func:`monitor_table` as arrays: ``day (D,)`` int, ``p_damage (D,)``, ``alarm (D,)`` bool,
    ``element (D,)`` (1-based, 0: none or no location), ``size (D, 3)`` (the stiffness fraction lost, or a mode's
    relative drop: mean, 2.5 % and 97.5 %; NaN where no loss is reported) and ``onset (D, 3)`` (the loss's first
    day: mean and 95 % interval)."""
    size = np.full((len(days), 3), np.nan)
    onset = np.full((len(days), 3), np.nan)
    for i, d in enumerate(days):
        if d.damage.size is not None:
            size[i] = (d.damage.size.mean, d.damage.size.lower, d.damage.size.upper)
        if d.damage.day is not None:
            onset[i] = (d.damage.day.mean, d.damage.day.lower, d.damage.day.upper)
    return {"day": np.array([d.day for d in days], dtype=int), "p_damage": np.array([d.p_damage for d in days]),
            "alarm": np.array([d.alarm for d in days], dtype=bool),
            "element": np.array([d.damage.location_index for d in days], dtype=int), "size": size, "onset": onset}
