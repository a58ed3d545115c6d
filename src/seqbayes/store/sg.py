"""The SG-EnMCMC run store: a shear building identified on-line, block by block.

A TOML configuration with a ``[building]`` section (:mod:`seqbayes.store.sg_config`) describes the
building, its sensors, the prior box of the storey stiffness ratios and the
:class:`~seqbayes.structural.sgenmcmc.SGEnMCMC` settings.
:class:`SGRunStore` keeps such a run in one NetCDF-4 file. Each ``update`` assimilates the next
block of the record (a CSV or NetCDF file with the columns above) with
:meth:`SGEnMCMC.update <seqbayes.structural.sgenmcmc.SGEnMCMC.update>` and appends one *step* to the file:
the block's table, the particles and their Kalman filters at the block's end
(:meth:`SGEnMCMC.snapshot <seqbayes.structural.sgenmcmc.SGEnMCMC.snapshot>`), the per-sample histories of the
block (posterior mean, variance, quantiles, ESS, evidence increments) and the generator's state.
A new process restores the identifier from the file and continues bit for bit as an
uninterrupted run would (tested). The writing machinery is every store's
(:mod:`seqbayes.store.base`, :mod:`seqbayes.store.files`): an exclusive lock per update, in-place
append through the redo journal, per-step record hashes chained into a content hash, Fletcher-32 on
the arrays, a whole write to a temporary file and ``os.replace`` for a new layout; a failed update
leaves the file unchanged.

Layout (``seqbayes_store_format = 5``, ``run_kind = "sgenmcmc"``; SEMC/SMC stores are still written
in format 4): ``sg_<name> (step, ...)`` for each array of the snapshot that has one value per step
(``theta (N, d)``, ``log_weights``, ``past``, ``filter_mean``, ``filter_cov``, ``frozen``),
``sg_<name> (time, ...)`` for the per-sample ones (``log_evidence_increments``, ``resampled``,
``history_mean``, ...: only the block's rows are appended), ``sg_events (event, 4)`` with
``sg_event_rows (step)``, ``dataset_values (time, column)`` with ``dataset_rows (step)``,
``rng_state (rng_index)`` and the text records of every step (``step_info``, ``dataset_sha256``,
``dataset_source``, ``likelihood_sha256`` (empty), ``record_sha256``). The store knows the snapshot
only by these naming rules: an array whose first axis follows the record must be called
``history_*`` or be listed in :data:`_PER_TIME` (its earlier rows may not change after a block);
any other array is kept whole at every step.

With ``[monitor]``, each ``update`` also runs the :class:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor`
on the block and stores its state with the step (``sg_monitor_class_* (step, class, ...)``,
``sg_monitor_active``, ``sg_monitor_low_steps`` and the block's summary ``sg_monitor_block_*``; its
generator's state and the class probabilities are in ``step_info["monitor"]``);
:meth:`SGRunStore.monitor` restores it bit for bit (the summaries' wall time ``seconds`` is not stored:
0 in restored blocks).

Trust: updates, ``status`` and reports run no user code (a ``[building] module`` ran once, when the
configuration was read, and the building it returned is recorded).
"""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np

from ..rng import as_generator, generator_from_state, generator_state
from .base import BaseStore, Provenance, check_finite, json_value, json_values
from .datasets import DataError, check_table, dataset_digest
from .errors import StoreError
from .registry import register
from .sg_config import RUN_KIND, SGRunConfig

__all__ = ["SGRunStore", "SG_FORMAT_VERSION"]

#: Layout version of SG-EnMCMC run stores (format 4's machinery plus ``run_kind``).
SG_FORMAT_VERSION = 5
#: Snapshot arrays with one row per sample of the record (only a block's new rows are appended).
_PER_TIME = ("log_evidence_increments", "resampled")
_PER_TIME_PREFIX = "history_"
#: Snapshot entries the store does not keep as arrays: the record (kept as ``dataset_values``), the
#: generator (``rng_state``), the stage buffer (empty after each block: :meth:`SGEnMCMC.result` flushes
#: it), the events (``sg_events``) and the wall time (in ``step_info``).
_NOT_ARRAYS = ("u", "y", "rng_state", "buffer_steps", "buffer_weights", "events", "elapsed")
_PREFIX = "sg_"
#: DropBlock fields that are NaN where a class has no dropped particle (stored as 0, restored from ``changed``).
_MONITOR_NAN_FIELDS = ("drop_mean", "change_time_mean")


# ------------------------------------------------------------------------------ the store
@register(RUN_KIND)
class SGRunStore(BaseStore):
    """An on-line SG-EnMCMC identification kept in one NetCDF-4 file (module docstring).

    Create with :meth:`create`, open with :meth:`open`, assimilate blocks of the record with
    :meth:`update` (a file) or :meth:`assimilate` (an array).

    Attributes
    ----------
    path : pathlib.Path
    config : SGRunConfig
    tables : list of (n_k, c) arrays
        The assimilated blocks (columns ``config.columns``).
    fixed : list of dict
        Per step, the snapshot arrays with one value per step (``theta``, ``log_weights``, ...).
    per_time : dict of str -> array
        The snapshot's per-sample arrays over the whole record so far (``history_mean (T, d)``, ...).
    events : (E, 4) array
        Resample-move events (sample index, tempering exponent, acceptance, sweeps).
    event_rows : list of int
        Events per step.
    infos : list of dict
        Per step: block summary (rows, log-evidence, ESS, moves, wall time).
    rng_states : list of dict
        The generator's state before the first block and after each.
    digests, sources : list of str
    """

    title = "SG-EnMCMC"
    format_version = SG_FORMAT_VERSION
    readable_versions = (SG_FORMAT_VERSION,)
    growing = {"step": 8, "rng_index": 8, "time": 512, "event": 64}
    unit = "block"

    def __init__(self, path, config: SGRunConfig, provenance: Provenance, *, tables=(), fixed=(), per_time=None,
                 events=None, event_rows=(), infos=()):
        super().__init__(path, config, provenance)
        self.tables = list(tables)
        self.fixed = list(fixed)
        self.per_time = dict(per_time or {})
        self.events = np.zeros((0, 4)) if events is None else np.asarray(events, float).reshape(-1, 4)
        self.event_rows = list(event_rows)
        self.infos = list(infos)

    # ----------------------------------------------------------------------- basics
    @property
    def n_samples(self) -> int:
        """Samples of the record assimilated so far."""
        return int(sum(t.shape[0] for t in self.tables))

    @property
    def log_evidence(self) -> float:
        """Cumulative log-evidence of the record so far."""
        return float(self.per_time["log_evidence_increments"].sum()) if self.n_steps else 0.0

    @classmethod
    def _new(cls, path: Path, config: SGRunConfig) -> "SGRunStore":
        """A new run: nothing is drawn yet (the first block draws the prior particles from the generator
        seeded by ``config.seed``)."""
        return cls(path, config, Provenance([generator_state(as_generator(config.seed))]))

    @classmethod
    def _from_file(cls, path: Path, attrs: dict, variables: dict, config: SGRunConfig | None,
                   version: int) -> "SGRunStore":
        n_steps = int(attrs["n_steps"])
        text, record_hashes = cls._read_records(path, attrs, variables, version)
        stored = SGRunConfig.from_dict(json_value(attrs["config"], path, "config"))
        cls._check_config(path, attrs, stored, config)
        config = stored
        check_finite(path, variables)
        rng_states = json_values(text["rng_state"], path, "rng_state")
        infos = json_values(text["step_info"], path, "step_info")
        tables, fixed, per_time, events, event_rows = [], [], {}, np.zeros((0, 4)), []
        if n_steps:
            rows = variables["dataset_rows"]
            values = variables["dataset_values"]
            if rows.shape != (n_steps,) or int(rows.sum()) != values.shape[0] or values.shape[1] != len(config.columns):
                raise StoreError(f"{path}: inconsistent store (dataset_rows {rows.tolist()} for data of shape "
                                 f"{values.shape})")
            tables = np.split(values, np.cumsum(rows)[:-1])
            names = [name for name in variables if name.startswith(_PREFIX) and name != "sg_event_rows"
                     and name != "sg_events"]
            for name in names:
                key = name[len(_PREFIX):]
                if _is_per_time(key):
                    if variables[name].shape[0] != values.shape[0]:
                        raise StoreError(f"{path}: inconsistent store ({name} has {variables[name].shape[0]} rows "
                                         f"for a record of {values.shape[0]} samples)")
                    per_time[key] = variables[name]
                elif variables[name].shape[0] != n_steps:
                    raise StoreError(f"{path}: inconsistent store ({name} has {variables[name].shape[0]} rows for "
                                     f"{n_steps} steps)")
            fixed = [{name[len(_PREFIX):]: variables[name][i] for name in names
                      if not _is_per_time(name[len(_PREFIX):])} for i in range(n_steps)]
            missing = [key for key in ("theta", "log_weights", "past", "filter_mean", "filter_cov", "frozen")
                       if key not in fixed[0]]
            if missing or not per_time:
                raise StoreError(f"{path}: damaged run store: missing variable(s) "
                                 f"{', '.join(_PREFIX + k for k in missing) or 'sg_history_mean'}")
            event_rows = [int(v) for v in variables["sg_event_rows"]]
            events = variables["sg_events"].reshape(-1, 4)
            if len(event_rows) != n_steps or sum(event_rows) != events.shape[0]:
                raise StoreError(f"{path}: inconsistent store (sg_event_rows {event_rows} for {events.shape[0]} "
                                 f"events)")
        provenance = Provenance(rng_states, text["dataset_sha256"], text["dataset_source"], attrs.get("created"),
                                record_hashes)
        return cls(path, config, provenance, tables=tables, fixed=fixed, per_time=per_time, events=events,
                   event_rows=event_rows, infos=infos)

    # ------------------------------------------------------------------- the identifier
    def snapshot_at(self, step: int | None = None) -> dict:
        """The :meth:`SGEnMCMC.snapshot <seqbayes.structural.sgenmcmc.SGEnMCMC.snapshot>` after ``step`` blocks
        (default: the last; ``step >= 1``)."""
        step = self.n_steps if step is None else int(step)
        if not 1 <= step <= self.n_steps:
            raise ValueError(f"step: must lie in [1, {self.n_steps}], got {step}")
        T = int(sum(t.shape[0] for t in self.tables[:step]))
        record = np.concatenate(self.tables[:step])
        offset = 1 if self.config.time else 0
        out = {key: np.array(value) for key, value in self.fixed[step - 1].items()}
        out.update({key: np.array(value[:T]) for key, value in self.per_time.items()})
        out.update(u=record[:, offset], y=record[:, offset + 1:],
                   events=self.events[:sum(self.event_rows[:step])].copy(),
                   elapsed=np.array(sum(float(info.get("wall_time", 0.0)) for info in self.infos[:step])),
                   buffer_steps=np.zeros(0, int), buffer_weights=np.zeros((0, self.config.n_members)),
                   rng_state=self.rng_states[step])
        return out

    def identifier(self, step: int | None = None):
        """An :class:`~seqbayes.structural.sgenmcmc.SGEnMCMC` restored to the state after ``step`` blocks
        (default: the last; ``0``: reset to the prior, ready for the first block)."""
        step = self.n_steps if step is None else int(step)
        sampler = self.config.build_identifier()
        if step == 0:
            sampler.reset(generator_from_state(self.rng_states[0]))
        else:
            sampler.restore(self.snapshot_at(step))
        return sampler

    def monitor(self, step: int | None = None):
        """The :class:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor` of ``[monitor]`` restored to the state
        after ``step`` blocks (default: the last; ``0``: reset, ready for the first block), bit for bit as
        an uninterrupted monitor; its :attr:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor.history` holds
        every block's summary (``seconds`` 0: wall times are not stored).

        Raises
        ------
        ValueError
            The run has no ``[monitor]`` section, or ``step`` is out of range.
        """
        step = self.n_steps if step is None else int(step)
        monitor = self.config.build_monitor()
        if monitor is None:
            raise ValueError(f"{self.path}: the run has no [monitor] section")
        if not 0 <= step <= self.n_steps:
            raise ValueError(f"step: must lie in [0, {self.n_steps}], got {step}")
        if step == 0:
            monitor.reset(as_generator(int(self.config.monitor["seed"])))
            return monitor
        record = np.concatenate(self.tables[:step])
        offset = 1 if self.config.time else 0
        last = self.fixed[step - 1]
        snap = {f"setting_{k}": v for k, v in monitor._settings().items()}
        snap.update({key[len("monitor_"):]: np.array(value) for key, value in last.items()
                     if key.startswith("monitor_") and not key.startswith("monitor_block_")})
        snap.update(u=record[:, offset], y=record[:, offset + 1:],
                    rng_state=np.array(json.dumps(self.infos[step - 1]["monitor"]["rng_state"])))
        from ..structural.stiffness_drop import DropBlock

        blocks = self.fixed[:step]
        for f in dataclasses.fields(DropBlock):
            if f.name == "seconds":
                snap["history_seconds"] = np.zeros(step)
                continue
            values = np.stack([np.asarray(b[f"monitor_block_{f.name}"]) for b in blocks])
            if f.name in _MONITOR_NAN_FIELDS:
                changed = np.stack([np.asarray(b["monitor_block_changed"], float) for b in blocks])
                values = np.where(changed > 0, values, np.nan)
                values[:, 0] = np.nan
            elif f.name in ("active", "detected"):
                values = values.astype(bool)
            snap[f"history_{f.name}"] = values
        monitor.restore(snap)
        return monitor

    def result(self):
        """The :class:`~seqbayes.structural.sgenmcmc.SGEnMCMCResult` of the record so far (histories per sample)."""
        if not self.n_steps:
            raise ValueError(f"{self.path}: no block assimilated yet")
        return self.identifier().result()

    # ----------------------------------------------------------------------- assimilation
    def _si_block(self, table, source: str) -> np.ndarray:
        """The table checked (:func:`~seqbayes.store.datasets.check_table`) and in SI units (``[data] units``)."""
        table = check_table(table, self.config, source)
        factors = self.config.si_factors()
        return table if np.all(factors == 1.0) else table * factors

    def _check_block(self, table, source: str) -> np.ndarray:
        """The SI table (:meth:`_si_block`) not assimilated before and, with a time column, in step with
        ``dt`` and continuing the record."""
        self.check_new_dataset(dataset_digest(table, self.config.columns))
        if self.config.time:
            t = table[:, 0]
            dt = self.config.dt
            if t.size > 1 and np.max(np.abs(np.diff(t) - dt)) > 1e-6 * dt + 1e-9 * np.max(np.abs(t)):
                raise DataError(f"{source}: column {self.config.time!r}: the time step is not data.dt = {dt:g} s "
                                f"throughout the block")
            if self.tables:
                expected = self.tables[-1][-1, 0] + dt
                if abs(t[0] - expected) > 1e-6 * dt + 1e-9 * abs(expected):
                    raise DataError(f"{source}: column {self.config.time!r}: the block starts at t = {t[0]:g} s, "
                                    f"but the record so far ends at {self.tables[-1][-1, 0]:g} s; the next block "
                                    f"must start at {expected:g} s (blocks are assimilated in order)")
        return table

    def assimilate(self, table: ArrayLike, source: str = "<array>", *, replace_last: bool = False,
                   executor: Any = None, loglike: Any = None, write: bool = True,
                   accept_model_change: bool = False) -> dict:
        """Assimilate the next block of the record, an ``(n, c)`` array with the columns
        ``config.columns``, and save the store.

        ``replace_last`` is refused (the blocks are one continuous record). ``executor``, ``loglike``
        and ``accept_model_change`` are the SMC store's keywords, taken so that every backend answers
        the same call: an SG-EnMCMC run has no user likelihood, so they change nothing.

        Returns
        -------
        dict
            The block's summary (also kept in :attr:`infos`): ``step``, ``rows``, ``first_sample``,
            ``log_evidence_increment``, ``log_evidence``, ``ess``, ``moves``, ``acceptance``, ``wall_time``.

        Raises
        ------
        seqbayes.store.datasets.DataError
            Wrong shape or column count, no rows, NaN/inf, a time column out of step.
        DuplicateDatasetError
            The block was assimilated before.
        StoreError
            The store cannot be written (it is left as it was).
        """
        import time

        if replace_last:
            self.require("replace_last")
        where = "table" if source == "<array>" else f"table from {source}"
        table = self._check_block(self._si_block(table, where), where)
        with self._updating(write):
            if write:
                table = self._check_block(table, where)
            sampler = self.identifier()
            offset = 1 if self.config.time else 0
            started = time.perf_counter()
            result = sampler.update(table[:, offset], table[:, offset + 1:])   # flushes the stage's histories
            wall = time.perf_counter() - started
            snap = sampler.snapshot()
            digest = dataset_digest(table, self.config.columns)
            if len(snap["buffer_steps"]):  # pragma: no cover - result() flushed it
                raise StoreError(f"{self.path}: the identifier's stage buffer is not empty after the block")
            T0, T = self.n_samples, self.n_samples + table.shape[0]
            events = np.asarray(snap["events"], float).reshape(-1, 4)
            new_events = events[self.events.shape[0]:]
            w = np.exp(snap["log_weights"] - snap["log_weights"].max())
            w /= w.sum()
            increment = float(result.log_evidence_increments[T0:T].sum())
            info = {"step": self.n_steps + 1, "rows": int(table.shape[0]), "first_sample": T0,
                    "time_start": float(T0 * self.config.dt), "log_evidence_increment": increment,
                    "log_evidence": float(result.log_evidence_increments[:T].sum()),
                    "ess": float(result.ess[T - 1]), "ess_end": float(1.0 / (w @ w)),
                    "moves": int(new_events.shape[0]),
                    "acceptance": float(new_events[:, 2].mean()) if len(new_events) else None,
                    "wall_time": wall}
            fixed = {key: np.array(value) for key, value in snap.items()
                     if key not in _NOT_ARRAYS and not _is_per_time(key)}
            if self.config.monitor is not None:
                monitor = self.monitor()
                block = monitor.update(table[:, offset], table[:, offset + 1:])
                fixed.update(_monitor_arrays(monitor.snapshot()))
                info["monitor"] = {"class_probabilities": block.class_probabilities.tolist(),
                                   "change_probability": block.change_probability, "detected": block.detected,
                                   "storey": block.storey, "wall_time": block.seconds,
                                   "rng_state": generator_state(monitor._run["rng"])}
            per_time = {key: np.array(value) for key, value in snap.items() if _is_per_time(key)}
            # commit to memory only now that the block succeeded
            self.tables.append(table)
            self.fixed.append(fixed)
            self.per_time = {key: value.astype(float) for key, value in per_time.items()}
            self.events = events
            self.event_rows.append(int(new_events.shape[0]))
            self.infos.append(info)
            self.digests.append(digest)
            self.sources.append(str(source))
            self.rng_states.append(snap["rng_state"])
            if write:
                self.write()
        return info
    # ----------------------------------------------------------------------- summaries
    def block_posterior(self, step: int = -1, level: float = 0.95) -> dict:
        """The posterior of the stiffness ratios at the end of a block: ``{name: {mean, sd, lower,
        upper}}`` from the weighted particles (the central ``level`` interval)."""
        from ..structural.summaries import weighted_quantiles

        if not 0 < level < 1:
            raise ValueError(f"level: must lie in (0, 1), got {level}")
        fixed = self.fixed[step]
        theta, logw = fixed["theta"], fixed["log_weights"]
        w = np.exp(logw - logw.max())
        w /= w.sum()
        mean = w @ theta
        sd = np.sqrt(np.maximum(w @ (theta - mean) ** 2, 0))
        q = weighted_quantiles(theta, w, [(1 - level) / 2, (1 + level) / 2])
        return {name: {"mean": float(mean[j]), "sd": float(sd[j]), "lower": float(q[0, j]), "upper": float(q[1, j])}
                for j, name in enumerate(self.names)}

    def posterior_samples(self, step: int = -1) -> tuple[np.ndarray, np.ndarray]:
        """``(theta (N, d), weights (N,))``: the particles and normalised weights at the end of a block."""
        fixed = self.fixed[step]
        w = np.exp(fixed["log_weights"] - fixed["log_weights"].max())
        return np.array(fixed["theta"]), w / w.sum()

    def modal(self, step: int = -1, identified_shapes: ArrayLike | None = None):
        """Modal results of the posterior at the end of a block
        (:func:`~seqbayes.structural.structures.modal.modal_summary`): natural frequencies, damping ratios and
        mode shapes, with the MAC against ``identified_shapes (n, k)`` if given."""
        from ..structural.structures.modal import modal_summary

        if not self.n_steps:
            raise ValueError(f"{self.path}: no block assimilated yet")
        theta, w = self.posterior_samples(step)
        return modal_summary(self.config.build_building(), theta[:, :self.config.n_storeys], w, identified_shapes)
    # ----------------------------------------------------------------------- writing
    def _step_texts(self, k: int) -> tuple:
        return (json.dumps(self.infos[k]), json.dumps(self.rng_states[k + 1]), self.digests[k], self.sources[k], "")

    def _own_attrs(self) -> dict:
        return {"run_kind": RUN_KIND}

    def _step_rows(self, start: int, data: dict, coords: dict) -> None:
        T0 = int(sum(t.shape[0] for t in self.tables[:start]))
        E0 = int(sum(self.event_rows[:start]))
        data.update({
            "dataset_values": (("time", "column"), np.concatenate(self.tables[start:])),
            "dataset_rows": (("step",), np.array([t.shape[0] for t in self.tables[start:]])),
            "sg_events": (("event", "event_field"), self.events[E0:]),
            "sg_event_rows": (("step",), np.array(self.event_rows[start:])),
        })
        for key in self.fixed[start]:
            stacked = np.stack([np.asarray(f[key], float) for f in self.fixed[start:]])
            data[_PREFIX + key] = (("step",) + _fixed_dims(key, stacked.ndim - 1), stacked)
        for key, value in self.per_time.items():
            data[_PREFIX + key] = (("time",) + tuple(f"{key}_{a}" for a in range(1, value.ndim)), value[T0:])

    def _whole_variables(self) -> tuple[dict, dict]:
        return {}, {"parameter": list(self.names), "column": list(self.config.columns)}

    # ------------------------------------------------- what the command line asks
    def _unsupported(self, operations: list) -> str:
        if operations[0] == "replace_last":
            return (f"--replace-last: not available for an SG-EnMCMC run ({self.path}): its blocks are one "
                    f"continuous record; re-create the run (seqbayes init --force) to assimilate it again")
        if operations[0].startswith("report "):
            return ("--compare, --threshold and --data are for SEMC/SMC runs; an SG-EnMCMC report takes --modes, "
                    "--level and --no-embed")
        what = {"predict": "predict (a forecast through the Markov kernel)"}.get(operations[0], operations[0])
        return (f"{self.path}: an SG-EnMCMC run; {what} is for SEMC/SMC runs (use seqbayes status or seqbayes "
                f"report)")

    def describe(self) -> str:
        config = self.config
        sensors = ", ".join([f"acceleration {f}" for f in config.accelerations]
                            + [f"drift {f}" for f in config.drifts])
        boxes = [f"U({lo:g}, {up:g})" for lo, up in zip(config.lower, config.upper)]
        prior = f"{boxes[0]} each" if len(set(boxes)) == 1 else ", ".join(boxes)
        return (f"SG-EnMCMC run {self.path} for model {config.name!r}: {config.n_storeys}-storey shear building, "
                f"stiffness ratios {', '.join(config.names)} ~ {prior}; sensors: {sensors}; N = {config.n_members}, "
                f"seed {config.seed}; each block needs the columns {', '.join(config.columns)} at dt = "
                f"{config.dt:g} s")

    def step_summary(self, info: dict, source: str) -> str:
        post = self.block_posterior(info["step"] - 1)
        ratios = ", ".join(f"{name} {p['mean']:.4g} +- {p['sd']:.2g}" for name, p in post.items())
        moves = (f"{info['moves']} resample-moves (acceptance {info['acceptance']:.3f})" if info["moves"]
                 else "no resample-moves")
        last = info["first_sample"] + info["rows"] - 1
        return (f"step {info['step']} from {source}: samples {info['first_sample']}-{last} (t = "
                f"{info['time_start']:.2f}-{last * self.config.dt:.2f} s), log-evidence increment "
                f"{info['log_evidence_increment']:.4f}, cumulative {info['log_evidence']:.4f}, ESS "
                f"{info['ess_end']:.1f} of N = {self.config.n_members}, {moves}; {ratios}")

    def status(self, level: float = 0.95) -> str:
        from .sg_report import format_sg_status

        return format_sg_status(self, level)

    def status_json(self, level: float = 0.95) -> dict:
        from .sg_report import sg_status_rows

        return {"run": str(self.path), "model": self.config.name, "kind": RUN_KIND,
                "steps": sg_status_rows(self, level)}

    def write_report(self, output: str | os.PathLike, *, level: float = 0.95, embed: bool = True,
                     modes: str | os.PathLike | None = None, others=(), thresholds=(), fit_data=None,
                     forecast_steps: int = 0, horizon: int = 0) -> None:
        """The HTML report (:func:`seqbayes.store.sg_report.write_sg_report`) with the MAC against the mode
        shapes in the CSV file ``modes``. ``others``, ``thresholds`` and ``fit_data`` are for SEMC/SMC
        runs (refused); there is no forecast, so ``forecast_steps`` and ``horizon`` have no use."""
        from .sg_report import read_mode_shapes, write_sg_report

        self.require(*[f"report --{name}" for name, value in (("compare", others), ("threshold", thresholds),
                                                              ("data", fit_data)) if value])
        identified = read_mode_shapes(modes, self.config.n_storeys) if modes else None
        write_sg_report(self, Path(output), level=level, embed=embed, identified_shapes=identified,
                        identified_source=Path(modes).name if modes else None)


def _monitor_arrays(snapshot: dict) -> dict:
    """The per-step arrays of a monitor's snapshot: its state (``monitor_class_*``, ``monitor_active``,
    ``monitor_low_steps``) and the last block's summary (``monitor_block_<field>``, NaN stored as 0)."""
    out = {f"monitor_{key}": np.array(value) for key, value in snapshot.items()
           if key.startswith("class_") or key in ("active", "low_steps")}
    for key, value in snapshot.items():
        if key.startswith("history_") and key != "history_seconds":
            last = np.array(value[-1])
            if key[len("history_"):] in _MONITOR_NAN_FIELDS:
                last = np.nan_to_num(last, nan=0.0)
            out[f"monitor_block_{key[len('history_'):]}"] = last
    return out


def _is_per_time(key: str) -> bool:
    return key in _PER_TIME or key.startswith(_PER_TIME_PREFIX)


_FIXED_DIMS = {"theta": ("sample", "parameter"), "log_weights": ("sample",), "past": ("sample",)}


def _fixed_dims(key: str, ndim: int) -> tuple:
    dims = _FIXED_DIMS.get(key)
    return dims if dims is not None and len(dims) == ndim else tuple(f"{key}_{a}" for a in range(1, ndim + 1))




import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any

    from numpy.typing import ArrayLike

