"""The monitor run store: a structure watched day by day for damage under a learned environment
(docs/environment.md, "The monitor run store").

A :class:`MonitorRunStore` keeps one :class:`~seqbayes.structural.monitor.table.Monitor` in one NetCDF-4 file
(configuration: :mod:`seqbayes.store.monitor_config`). Each ``update`` takes one dataset, the sets of one calendar
day (or of a record of it), as either

- **year-CSV rows**: ``day, temperature, [covariates], f1 .. fn, [sf1 .. sfn]`` (docs/environment.md; an empty
  cell is a mode not identified in that set), or
- a **tracked modes table** (docs/modal.md, ``seqbayes track``): one row per tracked mode of a set, with the
  columns ``day, mode, frequency_hz``, optionally ``std_frequency_hz``, and ``temperature`` (and the run's
  covariates) on every row; the rows of one set share its ``day``.

Both go through the store's strict reader (:func:`seqbayes.store.datasets.read_datafile`: a regular file of
bounded size, our own one-line messages) with bounds on days, temperatures, covariates and frequencies; the sets
must come after the last one stored, and a dataset holds one calendar day.

Layout (``seqbayes_store_format = 5``, ``run_kind = "monitor"``): ``dataset_values (set, column)`` with
``dataset_rows (step)`` (the sets of every step, the history a move of the static parameters re-weighs), the text
records of every step (``step_info``: the day's :class:`~seqbayes.structural.monitor.table.MonitorDay` as JSON),
and the sampler's state after the last step, kept whole: ``monitor_u (particle, parameter)``,
``monitor_log_weights``, ``monitor_loglike``, the per-mode filters (``monitor_filter_mean``, ``monitor_filter_cov``),
the lagged structure temperature, the change bank (``monitor_bank_A``, ``_B``, ``_delta``, ``_days``) and the
no-damage log-likelihood. A new process restores the monitor from these and the generator's state and continues
bit for bit as an uninterrupted run (tested, with kills: benchmarks/bench_monitor_kills.py). Every write replaces
the whole file atomically (temporary file, fsync, rename: :mod:`seqbayes.store.base`), since the state's shape
grows with the candidate days.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..rng import generator_from_state, generator_state
from .base import BaseStore, Provenance, json_value, json_values
from .datasets import DataError, TableSpec, dataset_digest, printable, read_datafile, read_regular
from .errors import StoreError
from .monitor_config import RUN_KIND, MonitorRunConfig
from .registry import register

__all__ = ["MonitorRunStore", "MONITOR_FORMAT_VERSION", "DAY_RANGE", "TEMPERATURE_RANGE", "FREQUENCY_RANGE",
           "COVARIATE_RANGE", "MAX_FREQUENCY_RATIO"]

MONITOR_FORMAT_VERSION = 5
#: Bounds of a dataset's columns: days since the first monitored day (at most 100 years), air temperatures
#: [degC], covariates (any unit), frequencies [Hz]; and how far a mode's median may lie from its reference.
DAY_RANGE = (0.0, 36525.0)
TEMPERATURE_RANGE = (-80.0, 80.0)
COVARIATE_RANGE = (-1e6, 1e6)
FREQUENCY_RANGE = (0.01, 1000.0)
MAX_FREQUENCY_RATIO = 10.0
#: The sampler's state as the file keeps it: name -> (attribute path, dims).
_STATE = {"u": ("particle", "parameter"), "log_weights": ("particle",), "loglike_previous": ("particle",),
          "loglike": ("particle",), "filter_mean": ("particle", "mode", "state"),
          "filter_cov": ("particle", "mode", "state", "state_"), "structure_temperature": ("particle",),
          "bank_A": ("particle", "mode", "candidate"), "bank_B": ("particle", "mode", "candidate"),
          "bank_delta": ("particle", "mode", "state", "candidate"), "bank_days": ("candidate",),
          "loglike0": ("particle",), "log_evidence": ()}
_PREFIX = "monitor_"


def _snapshot(state) -> dict:
    parts = state.particles
    cache = parts.cache
    return {"u": parts.u, "log_weights": state.log_weights, "loglike_previous": parts.loglike_previous,
            "loglike": parts.loglike, "filter_mean": cache.filters.mean, "filter_cov": cache.filters.cov,
            "structure_temperature": cache.structure_temperature, "bank_A": cache.bank.A, "bank_B": cache.bank.B,
            "bank_delta": cache.bank.delta, "bank_days": cache.bank.days, "loglike0": cache.loglike0,
            "log_evidence": np.array(state.log_evidence)}


def _restore(arrays: dict):
    from ..structural.monitor.change import Bank
    from ..structural.monitor.daily_filter import FilterState
    from ..structural.monitor.sampler import Cache, MonitorState, Particles

    a = {k: np.asarray(v) for k, v in arrays.items()}
    cache = Cache(FilterState(a["filter_mean"], a["filter_cov"]), a["structure_temperature"],
                  Bank(a["bank_A"], a["bank_B"], a["bank_delta"], a["bank_days"].astype(int)), a["loglike0"])
    return MonitorState(Particles(a["u"], cache, a["loglike_previous"], a["loglike"]), a["log_weights"],
                        float(a["log_evidence"]))


@register(RUN_KIND)
class MonitorRunStore(BaseStore):
    """An on-line monitor kept in one NetCDF-4 file (module docstring)."""

    title = "monitor"
    format_version = MONITOR_FORMAT_VERSION
    readable_versions = (MONITOR_FORMAT_VERSION,)
    growing = {"step": 8, "rng_index": 8, "set": 256}
    unit = "dataset"

    def __init__(self, path, config: MonitorRunConfig, provenance: Provenance, *, tables=(), infos=(), state=None):
        super().__init__(path, config, provenance)
        self.tables = list(tables)
        self.infos = list(infos)
        self.state = state

    @classmethod
    def _new(cls, path: Path, config: MonitorRunConfig) -> "MonitorRunStore":
        return cls(path, config, Provenance([generator_state(np.random.default_rng(config.seed))]))

    @classmethod
    def _from_file(cls, path: Path, attrs: dict, variables: dict, config, version: int) -> "MonitorRunStore":
        n_steps = int(attrs["n_steps"])
        text, record_hashes = cls._read_records(path, attrs, variables, version)
        stored = MonitorRunConfig.from_dict(json_value(attrs["config"], path, "config"))
        cls._check_config(path, attrs, stored, config)
        rng_states = json_values(text["rng_state"], path, "rng_state")
        infos = json_values(text["step_info"], path, "step_info")
        tables, state = [], None
        if n_steps:
            rows = np.asarray(variables["dataset_rows"]).astype(int)
            values = np.asarray(variables["dataset_values"], dtype=float)
            if (rows.shape != (n_steps,) or int(rows.sum()) != values.shape[0]
                    or values.shape[1:] != (len(stored.columns),)):
                raise StoreError(f"{path}: inconsistent store (dataset_rows {rows.tolist()[:5]}... for data of "
                                 f"shape {values.shape})")
            tables = np.split(values, np.cumsum(rows)[:-1])
            missing = [_PREFIX + k for k in _STATE if _PREFIX + k not in variables]
            if missing:
                raise StoreError(f"{path}: damaged run store: missing variable(s) {', '.join(missing)}")
            arrays = {k: np.asarray(variables[_PREFIX + k]) for k in _STATE}
            n = stored.n_particles
            if arrays["u"].shape != (n, len(stored.names)) or arrays["filter_mean"].shape[:2] != (n, stored.n_modes):
                raise StoreError(f"{path}: inconsistent store (monitor_u of shape {arrays['u'].shape} for "
                                 f"{n} particles)")
            finite = [k for k in ("u", "filter_mean", "filter_cov", "bank_A", "bank_B", "bank_delta")
                      if not np.all(np.isfinite(arrays[k]))]
            if finite:
                raise StoreError(f"{path}: damaged run store: non-finite values in {_PREFIX + finite[0]}")
            state = _restore(arrays)
        provenance = Provenance(rng_states, text["dataset_sha256"], text["dataset_source"], attrs.get("created"),
                                record_hashes)
        return cls(path, config or stored, provenance, tables=tables, infos=infos, state=state)

    # ------------------------------------------------------------------ the monitor
    def monitor(self):
        """The :class:`~seqbayes.structural.monitor.table.Monitor` after the last step (from the prior before
        the first), with the generator where the last step left it."""
        from ..structural.monitor.history import History, prepare_sets
        from ..structural.monitor.table import Monitor

        model, settings = self.config.build_model(), self.config.build_settings()
        rng = generator_from_state(self.rng_states[-1])
        if not self.n_steps:
            return Monitor(model, settings, rng)
        history = History.empty(model.n_modes, len(model.covariates))
        for table in self.tables:
            history = history.extended(*prepare_sets(model, *self._arguments(table)))
        last = self.infos[-1]
        return Monitor.restored(model, settings, rng, self.state, history, int(last["days_above"]), int(last["day"]),
                                float(last["p_damage"]))

    def _arguments(self, table) -> tuple:
        """``(times, temperature, frequencies, std_frequencies, covariates)`` of a stored table."""
        c = self.config
        r, n = len(c.covariates), c.n_modes
        z = table[:, 2:2 + r] if r else None
        return table[:, 0], table[:, 1], table[:, 2 + r:2 + r + n], table[:, 2 + r + n:], z

    # ------------------------------------------------------------------ datasets
    def read_datafile(self, datafile) -> np.ndarray:
        """One dataset as the run's ``(S, c)`` table (columns ``config.columns``): year-CSV rows or a tracked
        modes table (module docstring).

        Raises
        ------
        DataError
            One line naming the file: not a regular file or too large, a header of neither kind, a column
            missing or extra, a value that is not a number or out of its bounds, sets out of time order, a mode
            id outside 1..n or given twice in a set, several calendar days, frequencies far from the modes'.
        """
        path = Path(datafile)
        if path.suffix.lower() not in (".csv", ".txt", ""):
            raise DataError(f"{path}: a monitor dataset is a CSV file (year-CSV rows or a tracked modes table)")
        head = read_regular(path).split(b"\n", 1)[0]
        try:
            header = [h.strip() for h in head.decode("utf-8-sig").split(",")]
        except UnicodeDecodeError:
            raise DataError(f"{path}: not a UTF-8 text CSV file") from None
        if "frequency_hz" in header:
            table = self._from_modes_table(path, header)
        elif "f1" in header:
            table = self._from_year_rows(path, header)
        else:
            raise DataError(f"{path}: neither year-CSV rows (a header day,temperature,f1,...) nor a tracked modes "
                            f"table (day,mode,frequency_hz,...,temperature); the header has "
                            f"'{printable(','.join(header), 80)}'")
        return self._checked(table, str(path))

    def _bounds(self) -> dict:
        return {"temperature": TEMPERATURE_RANGE, **{c: COVARIATE_RANGE for c in self.config.covariates}}

    def _from_year_rows(self, path: Path, header: list) -> np.ndarray:
        c = self.config
        n = c.n_modes
        with_sf = "sf1" in header
        sf = [f"sf{i + 1}" for i in range(n)] if with_sf else []
        columns = ["day", "temperature", *c.covariates, *c.frequency_columns, *sf]
        spec = TableSpec(tuple(columns), time="day", time_range=DAY_RANGE, time_order="increasing",
                         ranges={**self._bounds(), **{f: FREQUENCY_RANGE for f in c.frequency_columns},
                                 **{s: (0.0, FREQUENCY_RANGE[1]) for s in sf}},
                         positive=c.frequency_columns, extra="refuse", missing=(*c.frequency_columns, *sf),
                         describe=f"the header {','.join(columns)}",
                         hints={"extra": f" (this run has {n} modes and the covariates "
                                         f"{', '.join(c.covariates) or '(none)'})"})
        values = read_datafile(path, spec)
        out = np.full((values.shape[0], len(c.columns)), np.nan)
        out[:, :values.shape[1]] = values
        return out

    def _from_modes_table(self, path: Path, header: list) -> np.ndarray:
        c = self.config
        n = c.n_modes
        if "mode" not in header:
            raise DataError(f"{path}: a modes table without a mode column (untracked); track the records first "
                            f"(seqbayes track), or give year-CSV rows")
        with_sf = "std_frequency_hz" in header
        columns = ["day", "mode", "frequency_hz", *(["std_frequency_hz"] if with_sf else []), "temperature",
                   *c.covariates]
        spec = TableSpec(tuple(columns), time="day", time_range=DAY_RANGE, time_order="grouped",
                         ranges={**self._bounds(), "frequency_hz": FREQUENCY_RANGE, "mode": (1, n),
                                 **({"std_frequency_hz": (0.0, FREQUENCY_RANGE[1])} if with_sf else {})},
                         positive=("frequency_hz",), missing=("std_frequency_hz",) if with_sf else (),
                         hints={"mode": f" (tracked mode ids 1..{n} of this run)"})
        values = read_datafile(path, spec)
        mode = values[:, 1]
        if np.any(mode != np.round(mode)):
            raise DataError(f"{path}: column 'mode' holds {mode[mode != np.round(mode)][0]:.6g}; tracked mode ids "
                            f"are integers 1..{n}")
        sets, index = np.unique(values[:, 0], return_inverse=True)
        out = np.full((sets.size, len(c.columns)), np.nan)
        out[:, 0] = sets
        seen = np.zeros((sets.size, n), dtype=bool)
        k = 4 if with_sf else 3                       # the first of temperature and the covariates
        r = len(c.covariates)
        for row, s in enumerate(index):
            m = int(mode[row]) - 1
            if seen[s, m]:
                raise DataError(f"{path}: data row {row + 1}: mode {m + 1} appears twice in the set of day "
                                f"{sets[s]:.10g}")
            seen[s, m] = True
            out[s, 2 + r + m] = values[row, 2]
            if with_sf:
                out[s, 2 + r + n + m] = values[row, 3]
            covariates = values[row, k:]
            first = np.flatnonzero(index == s)[0]
            if row != first and not np.array_equal(covariates, values[first, k:]):
                raise DataError(f"{path}: data row {row + 1}: temperature or covariates differ between the rows of "
                                f"the set of day {sets[s]:.10g}; they are the set's, one value each")
            out[s, 1:2 + r] = covariates
        return out

    def _checked(self, table, source: str) -> np.ndarray:
        """The table's shape, one calendar day, finite times and temperatures, frequencies near the modes'."""
        c = self.config
        table = np.asarray(table, dtype=float)
        if table.ndim != 2 or table.shape[1] != len(c.columns) or table.shape[0] == 0:
            raise DataError(f"{source}: expected a table of shape (sets, {len(c.columns)}) with columns "
                            f"{', '.join(c.columns)}, got {table.shape}")
        n, r = c.n_modes, len(c.covariates)
        fixed = table[:, :2 + r]
        if not np.all(np.isfinite(fixed)):
            raise DataError(f"{source}: day, temperature and covariates need a finite value in every set")
        days = np.unique(np.floor(table[:, 0]))
        if days.size > 1:
            raise DataError(f"{source}: holds sets of {days.size} calendar days ({days[0]:.0f} to {days[-1]:.0f}); a "
                            f"dataset is the sets of one day: split it, or replay a whole CSV with seqbayes "
                            f"environment")
        f = table[:, 2 + r:2 + r + n]
        if np.all(np.isnan(f)):
            raise DataError(f"{source}: no mode identified in any set (every frequency is empty)")
        if np.any(np.isinf(table[:, 2 + r:])):
            raise DataError(f"{source}: a frequency or standard error is infinite")
        reference = np.asarray(self.config.build_model().reference_frequencies)
        observed = np.isfinite(f).any(axis=0)
        median = np.full(n, np.nan)
        median[observed] = np.median(np.where(np.isfinite(f[:, observed]), f[:, observed], np.nan), axis=0) \
            if np.all(np.isfinite(f[:, observed])) else np.array([np.median(c[np.isfinite(c)]) for c in f[:, observed].T])
        ratio = median / reference
        far = np.flatnonzero(np.isfinite(ratio) & ((ratio > MAX_FREQUENCY_RATIO) | (ratio < 1 / MAX_FREQUENCY_RATIO)))
        if far.size:
            i = int(far[0])
            raise DataError(f"{source}: mode {i + 1}'s frequencies (median {median[i]:.4g} Hz) lie "
                            f"{ratio[i]:.3g} times its reference {reference[i]:.4g} Hz; check the units (Hz), the "
                            f"column order and the run's model")
        return table

    # ------------------------------------------------------------- assimilation
    def assimilate(self, table, source: str = "<array>", *, replace_last: bool = False, write: bool = True,
                   **options) -> dict:
        """Assimilate one dataset (:meth:`read_datafile`'s table, or an array of its columns) and save the store.

        ``replace_last`` is refused (a day's sets are taken in once; a later record of the same day is a new
        dataset). Other keywords (the SMC store's ``executor``, ``loglike``, ...) change nothing here.

        Returns
        -------
        dict
            The day (:class:`~seqbayes.structural.monitor.table.MonitorDay` as JSON values), also kept in
            :attr:`infos`.
        """
        if replace_last:
            self.require("replace_last")
        where = "table" if source == "<array>" else f"table from {source}"
        table = self._checked(table, where)
        digest = dataset_digest(np.nan_to_num(table, nan=-1.0), self.config.columns)
        with self._updating(write):
            self.check_new_dataset(digest)
            monitor = self.monitor()
            try:
                day = monitor.update(*self._arguments(table))
            except ValueError as err:
                raise DataError(f"{where}: {err}") from None
            info = {"step": self.n_steps + 1, **day.to_dict()}
            self.tables.append(table)
            self.infos.append(info)
            self.state = monitor.state
            self.digests.append(digest)
            self.sources.append(str(source))
            self.rng_states.append(generator_state(monitor.rng))
            if write:
                self.write()
        return info

    # ------------------------------------------------------------------ writing
    def _append(self) -> bool:
        return False          # the state's arrays grow with the candidate days: always a whole, atomic write

    def _step_texts(self, k: int) -> tuple:
        return (json.dumps(self.infos[k]), json.dumps(self.rng_states[k + 1]), self.digests[k], self.sources[k], "")

    def _own_attrs(self) -> dict:
        return {"run_kind": RUN_KIND}

    def _step_rows(self, start: int, data: dict, coords: dict) -> None:
        data.update({"dataset_values": (("set", "column"), np.concatenate(self.tables[start:])),
                     "dataset_rows": (("step",), np.array([t.shape[0] for t in self.tables[start:]]))})

    def _whole_variables(self) -> tuple[dict, dict]:
        coords = {"column": list(self.config.columns), "parameter": list(self.names)}
        if self.state is None:
            return {}, coords
        arrays = _snapshot(self.state)
        return {_PREFIX + k: (_STATE[k], np.asarray(v)) for k, v in arrays.items()}, coords

    # ------------------------------------------------- what the command line asks
    def _unsupported(self, operations: list) -> str:
        if operations[0] == "replace_last":
            return (f"--replace-last: not available for a monitor run ({self.path}): its days are taken in once, "
                    f"in time order; re-create the run (seqbayes init --force) and replay its datasets")
        if operations[0].startswith("report "):
            return "--compare, --threshold and --data are for SEMC/SMC runs; a monitor report takes --level"
        return f"{self.path}: a monitor run; {operations[0]} is for SEMC/SMC runs (use seqbayes status or report)"

    def describe(self) -> str:
        c = self.config
        what = (f"{c.n_modes} tracked modes ({', '.join(f'{f:.4g}' for f in c.frequencies)} Hz), no structural "
                f"model" if c.model == "modes" else f"{c.n_modes}-storey shear building")
        return (f"monitor run {self.path} for model {c.name!r}: {what}; covariates: temperature (air, lagged)"
                f"{''.join(', ' + x for x in c.covariates)}; N = {c.n_particles}, seed {c.seed}; alarm when "
                f"P(damage) > {c.threshold:g} on {c.consecutive} days in a row; each dataset is one day's sets "
                f"({', '.join(c.columns[:2 + len(c.covariates)])}, {c.frequency_columns[0]}.."
                f"{c.frequency_columns[-1]} or a tracked modes table)")

    def step_summary(self, info: dict, source: str) -> str:
        from .monitor_report import damage_text

        return (f"step {info['step']} from {source}: day {info['day']} ({info['n_sets']} sets), "
                f"{damage_text(info)}, {'ALARM' if info['alarm'] else 'no alarm'} ({info['days_above']} day(s) "
                f"above {self.config.threshold:g}); ESS {info['ess']:.0f} of {self.config.n_particles}, "
                f"{info['n_stages']} resample-moves, {info['n_sweeps']} sweeps")

    def status(self, level: float = 0.95) -> str:
        from .monitor_report import format_status

        return format_status(self)

    def status_json(self, level: float = 0.95) -> dict:
        from .monitor_report import status_record

        return status_record(self)

    def write_report(self, output: str | os.PathLike, *, level: float = 0.95, embed: bool = True, others=(),
                     thresholds=(), fit_data=None, forecast_steps: int = 0, horizon: int = 0, **_) -> None:
        """The HTML report (:func:`seqbayes.store.monitor_report.write_monitor_report`)."""
        from .monitor_report import write_monitor_report

        self.require(*[f"report --{name}" for name, value in (("compare", others), ("threshold", thresholds),
                                                              ("data", fit_data)) if value])
        write_monitor_report(self, Path(output), embed=embed)
