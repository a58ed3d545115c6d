"""SG-EnMCMC runs in the run store: a shear building identified on-line, block by block.

A TOML configuration with a ``[building]`` section (:func:`parse_sg_config`) describes a
shear building, its sensors, the prior box of the storey stiffness ratios and the
:class:`~seqbayes.sgenmcmc.SGEnMCMC` settings::

    [model]
    name = "shake-table"

    [building]                          # or: module = "mybuilding:building" (a function returning a
    masses = [24e3, 20e3, 20e3, 16e3]   # ShearBuilding, run once at init; its numbers are recorded)
    stiffnesses = [36e6, 30e6, 24e6, 16e6]    # undamaged storey stiffnesses k^u [N/m]
    damping_ratios = [0.02, 0.04]       # Rayleigh damping of modes damping_modes (default 1 and 2)

    [sensors]
    accelerations = [1, 2, 3, 4]        # floors with an accelerometer (absolute acceleration)
    drifts = []                         # storeys with a drift sensor

    [data]
    dt = 0.02                           # sampling step [s]
    input = "ag"                        # column of the ground acceleration [m/s^2]
    responses = ["a1", "a2", "a3", "a4"]   # one column per sensor: accelerations, then drifts
    time = "t"                          # optional time column [s]: checked uniform and continuous
    units = "g"                         # optional: unit of the acceleration columns (default m/s^2), or
                                        # { ag = "g", d1 = "mm" } per column; blocks are stored in SI

    [priors]
    lower = 0.7                         # uniform box of the ratios (a number or one per storey)
    upper = 1.3

    [noise]
    measurement_std = 0.05              # per channel (a number or one per response column)
    process_std = 0.0                   # std of the unmeasured input noise [m/s^2]

    [sampler]
    n_members = 500
    seed = 1
    # any other SGEnMCMC keyword: ess_threshold, proposal, moves_per_particle, likelihood, level,
    # noise_parameters ("channel" or "shared": noise scales estimated with the ratios), ...;
    # surrogate = "auto" is measured once, at init, and pinned as a level

    [monitor]                           # optional: on-line stiffness-drop detection alongside
    n_particles = 200                   # (seqbayes.stiffness_drop.StiffnessDropMonitor; one model
    threshold = 0.99                    # class per storey); any of its keywords: drop_range,
    seed = 2                            # change_rate, change_every, prune_below, ... (seed: default
                                        # the sampler's seed + 1)

:class:`SGRunStore` keeps such a run in one NetCDF-4 file. Each ``update`` assimilates the next
block of the record (a CSV or NetCDF file with the columns above) with
:meth:`SGEnMCMC.update <seqbayes.sgenmcmc.SGEnMCMC.update>` and appends one *step* to the file:
the block's table, the particles and their Kalman filters at the block's end
(:meth:`SGEnMCMC.snapshot <seqbayes.sgenmcmc.SGEnMCMC.snapshot>`), the per-sample histories of the
block (posterior mean, variance, quantiles, ESS, evidence increments) and the generator's state.
A new process restores the identifier from the file and continues bit for bit as an
uninterrupted run would (tested). The writing machinery is the SEMC store's
(:mod:`seqbayes.store`): an exclusive lock per update, in-place append through the redo journal,
per-step record hashes chained into a content hash, Fletcher-32 on the arrays, a whole write to a
temporary file and ``os.replace`` for a new layout; a failed update leaves the file unchanged.

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

With ``[monitor]``, each ``update`` also runs the :class:`~seqbayes.stiffness_drop.StiffnessDropMonitor`
on the block and stores its state with the step (``sg_monitor_class_* (step, class, ...)``,
``sg_monitor_active``, ``sg_monitor_low_steps`` and the block's summary ``sg_monitor_block_*``; its
generator's state and the class probabilities are in ``step_info["monitor"]``);
:meth:`SGRunStore.monitor` restores it bit for bit (the summaries' wall time ``seconds`` is not stored:
0 in restored blocks).

Trust: the configuration's numbers define the building; with ``[building] module`` the function
runs once, at ``init`` (like a likelihood module, it is located next to the configuration and its
SHA-256 recorded), and the building it returns is recorded, so updates, ``status`` and reports run
no user code.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import inspect
import json
import math
import os
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .datasets import DataError, check_table, dataset_digest, read_datafile
from .modules import ConfigError, load_located, locate_module, read_toml
from ..rng import as_generator, generator_from_state, generator_state
from .smc import (StoreError, DuplicateDatasetError, _apply_with_journal, _check_finite, _check_free_space,
                    _content_hash, _extend, _fault, _fsync_dir, _json, _json_list, _netcdf_bytes, _now, _os_message,
                    _PendingWrites, _plain, _read_file, _read_journal, _read_token, _record_hash, _recover_journal, _write_file,
                    _write_whole, lock_file, store_lock)

__all__ = ["SGRunConfig", "SGRunStore", "parse_sg_config", "load_sg_config", "run_kind", "SG_FORMAT_VERSION",
           "RUN_KIND"]

#: Layout version of SG-EnMCMC run stores (format 4's machinery plus ``run_kind``).
SG_FORMAT_VERSION = 5
#: The ``run_kind`` attribute of an SG-EnMCMC run store.
RUN_KIND = "sgenmcmc"
#: Snapshot arrays with one row per sample of the record (only a block's new rows are appended).
_PER_TIME = ("log_evidence_increments", "resampled")
_PER_TIME_PREFIX = "history_"
#: Snapshot entries the store does not keep as arrays: the record (kept as ``dataset_values``), the
#: generator (``rng_state``), the stage buffer (empty after each block: :meth:`SGEnMCMC.result` flushes
#: it), the events (``sg_events``) and the wall time (in ``step_info``).
_NOT_ARRAYS = ("u", "y", "rng_state", "buffer_steps", "buffer_weights", "events", "elapsed")
_PREFIX = "sg_"
#: Growing dimensions and the chunk length along them.
_GROWING = {"step": 8, "rng_index": 8, "time": 512, "event": 64}
#: Variables along a growing dimension without coordinates (extended with it when a step is appended).
_BARE = ("rng_index", "time", "event")
_RECORD_TEXT = ("step_info", "rng_state", "dataset_sha256", "dataset_source", "likelihood_sha256")
#: [sampler] settings handled by the store itself (every other key is an SGEnMCMC keyword).
_OWN_SAMPLER_KEYS = ("n_members", "seed")
#: SGEnMCMC keywords a configuration may not set (the store decides them or they are not data).
_FIXED_KEYWORDS = ("building", "dt", "lower", "upper", "measurement_noise", "process_noise_std", "channels",
                   "transition", "sampler", "blas_threads")
#: [monitor] settings: StiffnessDropMonitor keywords (the building, noise and prior box are the run's).
_MONITOR_KEYWORDS = ("n_particles", "drop_range", "change_rate", "change_every", "jump_proposal", "prior_no_change",
                     "threshold", "prune_below", "prune_after", "ess_threshold", "moves_per_particle", "max_sweeps",
                     "resampling")
#: DropBlock fields that are NaN where a class has no dropped particle (stored as 0, restored from ``changed``).
_MONITOR_NAN_FIELDS = ("drop_mean", "change_time_mean")


def _fail(source, name, message):
    raise ConfigError(f"{source}: {name}: {message}")


def _numbers(value, source, name, n=None, positive=False, allow_empty=False):
    """A number or a list of numbers as a list of floats (``n``: broadcast a number to ``n``)."""
    values = value if isinstance(value, list) else [value]
    if not values and not allow_empty:
        _fail(source, name, "expected a number or a non-empty list of numbers")
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            _fail(source, name, f"expected finite numbers, got {value!r}")
        if positive and v <= 0:
            _fail(source, name, f"must be positive, got {value!r}")
        out.append(float(v))
    if n is not None:
        if not isinstance(value, list):
            out = out * n
        elif len(out) != n:
            _fail(source, name, f"expected {n} values (one per storey/channel) or one number, got {len(out)}")
    return out


def _keys(table, allowed, source, prefix):
    if not isinstance(table, dict):
        _fail(source, prefix, f"expected a table, got {table!r}")
    for key in table:
        if key not in allowed:
            _fail(source, f"{prefix}.{key}", f"unknown setting; expected one of {', '.join(sorted(allowed))}")


@dataclass(frozen=True)
class SGRunConfig:
    """A validated SG-EnMCMC run configuration (module docstring for the TOML layout).

    Attributes
    ----------
    name : str
    masses, stiffnesses : tuple of float
        Floor masses [kg] and undamaged storey stiffnesses [N/m], bottom to top.
    damping_ratios, damping_modes : tuple
        Rayleigh damping (:class:`~seqbayes.structures.ShearBuilding`).
    accelerations, drifts : tuple of int
        The sensor layout (:class:`~seqbayes.structures.Sensors`).
    dt : float
    input, responses, time : str, tuple of str, str or None
        Data columns.
    lower, upper : tuple of float
        Prior box of the stiffness ratios (one per storey).
    measurement_std : tuple of float
        Measurement noise std of each response column.
    process_std : float
    n_members, seed : int
    settings : dict
        Further :class:`~seqbayes.sgenmcmc.SGEnMCMC` keywords.
    units : dict
        ``{column: unit}`` of the block columns not in SI (``[data] units``).
    surrogate_choice : str or None
        With ``surrogate = "auto"`` in ``[sampler]``: why the transition was chosen; the choice is
        made once, when the configuration is read, and pinned as ``settings["level"]``.
    building_module, building_sha256 : str or None
        With ``[building] module``: the ``module:function`` and its file's SHA-256 (run at init only).
    search_path : str or None
        The configuration's folder.
    monitor : dict or None
        With ``[monitor]``: the :class:`~seqbayes.stiffness_drop.StiffnessDropMonitor` keywords and its
        ``seed``.
    """

    name: str
    masses: tuple
    stiffnesses: tuple
    damping_ratios: tuple
    damping_modes: tuple
    accelerations: tuple
    drifts: tuple
    dt: float
    input: str
    responses: tuple
    lower: tuple
    upper: tuple
    measurement_std: tuple
    process_std: float = 0.0
    n_members: int = 500
    seed: int = 0
    settings: dict = field(default_factory=dict)
    time: str | None = None
    units: dict = field(default_factory=dict)
    surrogate_choice: str | None = None
    building_module: str | None = None
    building_sha256: str | None = None
    search_path: str | None = None
    monitor: dict | None = None

    kind = RUN_KIND
    #: what :mod:`seqbayes.datasets` reads: any number of rows, the table as an array
    rows = None
    data_format = "array"

    @property
    def columns(self) -> tuple:
        """Data columns in the order of a block's table: time (if any), input, responses."""
        return ((self.time,) if self.time else ()) + (self.input,) + tuple(self.responses)

    @property
    def names(self) -> tuple:
        """Parameter names: ``theta_1 .. theta_n``, the storey stiffness ratios, then with
        ``noise_parameters`` the log noise-scale factors (as :attr:`SGEnMCMC.parameter_names`)."""
        names = tuple(f"theta_{j + 1}" for j in range(len(self.masses)))
        noise = self.settings.get("noise_parameters")
        if noise == "shared":
            return names + ("log_noise_scale",)
        if noise == "channel":
            return names + tuple(f"log_noise_scale_{c + 1}" for c in range(len(self.responses)))
        return names

    @property
    def n_storeys(self) -> int:
        return len(self.masses)

    def si_factors(self) -> np.ndarray:
        """Per column of a block (:attr:`columns`), the factor that converts it to SI (``[data] units``)."""
        from ..structures.records import UNITS

        return np.array([UNITS[self.units[c]] if c in self.units else 1.0 for c in self.columns])

    def build_building(self):
        """The :class:`~seqbayes.structures.ShearBuilding`."""
        from ..structures import ShearBuilding

        return ShearBuilding(np.array(self.masses), np.array(self.stiffnesses), self.damping_ratios,
                             self.damping_modes)

    def build_sensors(self):
        """The :class:`~seqbayes.structures.Sensors` layout."""
        from ..structures.shear_building import Sensors

        return Sensors(accelerations=self.accelerations, drifts=self.drifts)

    def build_identifier(self):
        """A fresh :class:`~seqbayes.sgenmcmc.SGEnMCMC` (``sampler="resample-move"``, the on-line one)."""
        from ..sgenmcmc import SGEnMCMC

        return SGEnMCMC(self.build_building(), self.dt, np.array(self.lower), np.array(self.upper),
                        np.array(self.measurement_std), process_noise_std=self.process_std,
                        n_members=self.n_members, channels=self.build_sensors(), sampler="resample-move",
                        **self.settings)

    def build_monitor(self):
        """A fresh :class:`~seqbayes.stiffness_drop.StiffnessDropMonitor` of ``[monitor]`` (None without it)."""
        if self.monitor is None:
            return None
        from ..stiffness_drop import StiffnessDropMonitor

        n = self.n_storeys
        settings = {k: (tuple(v) if isinstance(v, list) else v) for k, v in self.monitor.items() if k != "seed"}
        return StiffnessDropMonitor(self.build_building(), self.dt, np.array(self.lower[:n]),
                                    np.array(self.upper[:n]), np.array(self.measurement_std),
                                    process_noise_std=self.process_std, channels=self.build_sensors(), **settings)

    def to_dict(self) -> dict:
        """Plain JSON-able dict (stored in the run store)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if out["monitor"] is None:  # absent, so runs without a monitor keep their fingerprint
            del out["monitor"]
        out = {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}
        out["kind"] = RUN_KIND
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "SGRunConfig":
        """Inverse of :meth:`to_dict`."""
        data = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k != "kind"}
        return cls(**data)

    def fingerprint(self) -> str:
        """SHA-256 of everything that defines the model and the random stream (not the name or folder)."""
        content = {k: v for k, v in self.to_dict().items() if k not in ("name", "search_path")}
        return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


def parse_sg_config(raw: dict, source: str = "<config>", base_dir: str | os.PathLike | None = None) -> SGRunConfig:
    """Validate a parsed TOML mapping with a ``[building]`` section; errors name the field.

    Raises
    ------
    ConfigError
    """
    _keys(raw, {"model", "building", "sensors", "data", "priors", "noise", "sampler", "monitor"}, source,
          "<top level>")
    model = raw.get("model", {})
    _keys(model, {"name", "type"}, source, "model")
    if model.get("type", RUN_KIND) != RUN_KIND:
        _fail(source, "model.type", f"a [building] configuration is an SG-EnMCMC run (type = \"{RUN_KIND}\"), "
                                    f"got {model.get('type')!r}")
    name = model.get("name", "shear-building")
    if not isinstance(name, str) or not name:
        _fail(source, "model.name", f"expected a non-empty string, got {name!r}")

    building = raw.get("building")
    if building is None:
        _fail(source, "[building]", "missing section")
    _keys(building, {"masses", "stiffnesses", "damping_ratios", "damping_modes", "module"}, source, "building")
    module_spec = module_sha = None
    if "module" in building:
        if set(building) - {"module"}:
            _fail(source, "building.module", "give either module or the numbers (masses, stiffnesses, ...), "
                                             "not both")
        module_spec = building["module"]
        if not isinstance(module_spec, str) or module_spec.count(":") != 1 or not all(module_spec.split(":")):
            _fail(source, "building.module", f"expected \"module:function\", got {module_spec!r}")
        try:
            located = locate_module(module_spec.split(":")[0], base_dir)
            made = load_located(module_spec, located)()
        except ConfigError as err:
            raise ConfigError(f"{source}: {str(err).replace('model.likelihood:', 'building.module:', 1)}") from None
        except Exception as err:
            _fail(source, "building.module", f"{module_spec}() raised {type(err).__name__}: {err}")
        from ..structures import ShearBuilding

        if not isinstance(made, ShearBuilding):
            _fail(source, "building.module", f"{module_spec}() must return a seqbayes.structures.ShearBuilding, "
                                             f"got {type(made).__name__}")
        module_sha = located.sha256
        masses, stiffnesses = [float(v) for v in made.masses], [float(v) for v in made.stiffnesses]
        damping_ratios, damping_modes = list(made.damping_ratios), list(made.damping_modes)
    else:
        for key in ("masses", "stiffnesses", "damping_ratios"):
            if key not in building:
                _fail(source, f"building.{key}", "missing")
        masses = _numbers(building["masses"], source, "building.masses", positive=True)
        stiffnesses = _numbers(building["stiffnesses"], source, "building.stiffnesses", n=len(masses),
                               positive=True)
        damping_ratios = _numbers(building["damping_ratios"], source, "building.damping_ratios", n=2)
        modes = building.get("damping_modes", [1, 2] if len(masses) > 1 else [1, 1])
        if (not isinstance(modes, list) or len(modes) != 2
                or not all(isinstance(m, int) and not isinstance(m, bool) for m in modes)):
            _fail(source, "building.damping_modes", f"expected two mode numbers, got {modes!r}")
        damping_modes = modes
    n = len(masses)

    sensors = raw.get("sensors", {"accelerations": list(range(1, n + 1))})
    _keys(sensors, {"accelerations", "drifts"}, source, "sensors")
    layout = {}
    for key in ("accelerations", "drifts"):
        values = sensors.get(key, [])
        if (not isinstance(values, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in values)
                or any(not 1 <= v <= n for v in values) or len(set(values)) != len(values)):
            _fail(source, f"sensors.{key}", f"expected distinct floor numbers in 1..{n}, got {values!r}")
        layout[key] = tuple(values)
    p = len(layout["accelerations"]) + len(layout["drifts"])
    if p == 0:
        _fail(source, "[sensors]", "at least one sensor is needed")

    data = raw.get("data")
    if data is None:
        _fail(source, "[data]", "missing section")
    _keys(data, {"dt", "input", "responses", "time", "units"}, source, "data")
    if "dt" not in data:
        _fail(source, "data.dt", "missing (the sampling step in seconds)")
    dt = _numbers(data["dt"], source, "data.dt", positive=True)[0]
    column_input = data.get("input")
    if not isinstance(column_input, str) or not column_input:
        _fail(source, "data.input", f"expected the name of the ground-acceleration column, got {column_input!r}")
    responses = data.get("responses")
    if not isinstance(responses, list) or not all(isinstance(c, str) and c for c in responses):
        _fail(source, "data.responses", f"expected a list of column names, got {responses!r}")
    if len(responses) != p:
        _fail(source, "data.responses", f"expected {p} columns (one per sensor of [sensors]: "
                                        f"{len(layout['accelerations'])} accelerations, then "
                                        f"{len(layout['drifts'])} drifts), got {len(responses)}")
    time_column = data.get("time")
    if time_column is not None and (not isinstance(time_column, str) or not time_column):
        _fail(source, "data.time", f"expected a column name, got {time_column!r}")
    columns = ([time_column] if time_column else []) + [column_input] + responses
    if len(set(columns)) != len(columns):
        _fail(source, "data", f"duplicate column names in {columns}")
    units = _parse_units(data.get("units"), column_input, responses, len(layout["accelerations"]), source)

    priors = raw.get("priors")
    if priors is None:
        _fail(source, "[priors]", "missing section (lower and upper bounds of the stiffness ratios)")
    _keys(priors, {"lower", "upper"}, source, "priors")
    for key in ("lower", "upper"):
        if key not in priors:
            _fail(source, f"priors.{key}", "missing")
    lower = _numbers(priors["lower"], source, "priors.lower", n=n, positive=True)
    upper = _numbers(priors["upper"], source, "priors.upper", n=n, positive=True)
    if any(u <= lo for lo, u in zip(lower, upper)):
        _fail(source, "priors.upper", f"must exceed priors.lower in every storey, got {lower} and {upper}")

    noise = raw.get("noise")
    if noise is None or "measurement_std" not in noise:
        _fail(source, "noise.measurement_std", "missing (the measurement noise std of each response column)")
    _keys(noise, {"measurement_std", "process_std"}, source, "noise")
    measurement_std = _numbers(noise["measurement_std"], source, "noise.measurement_std", n=p, positive=True)
    process_std = _numbers(noise.get("process_std", 0.0), source, "noise.process_std")[0]
    if process_std < 0:
        _fail(source, "noise.process_std", f"must be >= 0, got {process_std}")

    sampler = dict(raw.get("sampler", {}))
    _keys(sampler, set(sampler), source, "sampler")
    n_members = sampler.pop("n_members", 500)
    seed = sampler.pop("seed", 0)
    for key, value in (("n_members", n_members), ("seed", seed)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            _fail(source, f"sampler.{key}", f"expected a non-negative integer, got {value!r}")
    from ..sgenmcmc import SGEnMCMC

    keywords = set(inspect.signature(SGEnMCMC).parameters) - set(_FIXED_KEYWORDS) - set(_OWN_SAMPLER_KEYS)
    for key in sampler:
        if key not in keywords:
            _fail(source, f"sampler.{key}", f"unknown setting; expected one of "
                                            f"{', '.join(sorted(keywords | set(_OWN_SAMPLER_KEYS)))}")
    config = SGRunConfig(name=name, masses=tuple(masses), stiffnesses=tuple(stiffnesses),
                         damping_ratios=tuple(damping_ratios), damping_modes=tuple(damping_modes),
                         accelerations=layout["accelerations"], drifts=layout["drifts"], dt=dt,
                         input=column_input, responses=tuple(responses), lower=tuple(lower), upper=tuple(upper),
                         measurement_std=tuple(measurement_std), process_std=process_std, n_members=n_members,
                         seed=seed, settings=sampler, time=time_column, units=units, building_module=module_spec,
                         building_sha256=module_sha,
                         search_path=str(Path(base_dir).resolve()) if base_dir is not None else None)
    try:  # the building and the identifier validate the numbers, naming the argument
        config.build_building().check_sampling(dt)
    except ValueError as err:
        _fail(source, "building" if not str(err).startswith("dt") else "data.dt", str(err))
    try:
        identifier = config.build_identifier()
    except (TypeError, ValueError) as err:
        _fail(source, "sampler", str(err))
    choice = getattr(identifier, "surrogate_choice", None)
    if choice is not None:
        # surrogate = "auto" measures the transitions' cost now, once: the choice is pinned as a
        # level (a timing-dependent choice at every update would break bit-identical resume)
        settings = {k: v for k, v in sampler.items() if k not in ("surrogate", "surrogate_options")}
        settings["level"] = choice.level
        config = dataclasses.replace(config, settings=settings, surrogate_choice=choice.reason)
    if "monitor" in raw:
        monitor = dict(raw["monitor"])
        _keys(monitor, set(_MONITOR_KEYWORDS) | {"seed"}, source, "monitor")
        monitor_seed = monitor.setdefault("seed", seed + 1)
        if isinstance(monitor_seed, bool) or not isinstance(monitor_seed, int) or monitor_seed < 0:
            _fail(source, "monitor.seed", f"expected a non-negative integer, got {monitor_seed!r}")
        config = dataclasses.replace(config, monitor=monitor)
        try:
            config.build_monitor()
        except (TypeError, ValueError) as err:
            _fail(source, "monitor", str(err))
    return config


_ACCELERATION_UNITS = ("g", "m/s2", "m/s^2", "cm/s2", "cm/s^2", "gal", "mm/s2", "mm/s^2")
_LENGTH_UNITS = ("m", "cm", "mm")


def _parse_units(raw, column_input, responses, n_accelerations, source) -> dict:
    """``[data] units``: one unit for every acceleration column (a string), or ``{column: unit}``;
    accelerations (the input and the accelerometers) take acceleration units, drifts lengths.
    Returns ``{column: unit}`` of the columns not already in SI."""
    kinds = {column_input: "acceleration", **{c: "acceleration" if i < n_accelerations else "drift"
                                             for i, c in enumerate(responses)}}
    if raw is None:
        return {}
    if isinstance(raw, str):
        raw = {c: raw for c, kind in kinds.items() if kind == "acceleration"}
    if not isinstance(raw, dict):
        _fail(source, "data.units", f"expected a unit (\"g\") or a table {{ column = \"unit\" }}, got {raw!r}")
    out = {}
    for column, unit in raw.items():
        if column not in kinds:
            _fail(source, f"data.units.{column}", f"not an input or response column ({', '.join(kinds)})")
        allowed = _ACCELERATION_UNITS if kinds[column] == "acceleration" else _LENGTH_UNITS
        if unit not in allowed:
            _fail(source, f"data.units.{column}", f"an {kinds[column]} column takes one of {', '.join(allowed)}, "
                                                  f"got {unit!r}")
        if unit not in ("m/s2", "m/s^2", "m"):
            out[column] = unit
    return out


def load_sg_config(path: str | os.PathLike) -> SGRunConfig:
    """Read and validate an SG-EnMCMC TOML configuration (:func:`parse_sg_config`)."""
    path = Path(path)
    raw = read_toml(path)
    return parse_sg_config(raw, str(path), base_dir=path.parent)


def run_kind(path: str | os.PathLike) -> str:
    """``"sgenmcmc"`` for an SG-EnMCMC run store, ``"semc"`` for any other file (which
    :meth:`seqbayes.RunStore.open` then reads or refuses with its own message)."""
    import h5py

    try:
        with open(path, "rb") as fh:
            with contextlib.suppress(OSError):   # as the store's readers: never between two halves of a step
                lock_file(fh, exclusive=False)
            journal = _read_journal(Path(path))      # a committed step not yet written into the file
            with h5py.File(_PendingWrites(fh, journal) if journal is not None else fh, "r") as f:
                return str(_plain(f.attrs.get("run_kind", "semc")))
    except Exception:
        return "semc"


# ------------------------------------------------------------------------------ the store
class SGRunStore:
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

    def __init__(self, path, config: SGRunConfig, *, rng_states, tables=(), fixed=(), per_time=None,
                 events=None, event_rows=(), infos=(), digests=(), sources=(), created=None, record_hashes=()):
        self.path = Path(path)
        self.config = config
        self.rng_states = list(rng_states)
        self.tables = list(tables)
        self.fixed = list(fixed)
        self.per_time = dict(per_time or {})
        self.events = np.zeros((0, 4)) if events is None else np.asarray(events, float).reshape(-1, 4)
        self.event_rows = list(event_rows)
        self.infos = list(infos)
        self.digests = list(digests)
        self.sources = list(sources)
        self.created = created or _now()
        self._record_hashes = list(record_hashes)
        self._token = None
        self._disk_steps = 0

    # ----------------------------------------------------------------------- basics
    @property
    def n_steps(self) -> int:
        """Blocks assimilated so far."""
        return len(self.tables)

    @property
    def n_samples(self) -> int:
        """Samples of the record assimilated so far."""
        return int(sum(t.shape[0] for t in self.tables))

    @property
    def names(self) -> tuple:
        return self.config.names

    @property
    def log_evidence(self) -> float:
        """Cumulative log-evidence of the record so far."""
        return float(self.per_time["log_evidence_increments"].sum()) if self.n_steps else 0.0

    @classmethod
    def create(cls, path: str | os.PathLike, config: SGRunConfig, *, overwrite: bool = False) -> "SGRunStore":
        """Start a new run at ``path`` (nothing is drawn yet: the first block draws the prior
        particles from the generator seeded by ``config.seed``) and write it.

        Raises
        ------
        StoreError
            ``path`` exists (and not ``overwrite``), is a folder, or cannot be written.
        """
        path = Path(path)
        if path.is_dir():
            raise StoreError(f"{path}: is a folder; give the run store's file name, e.g. {path / 'run.nc'}")
        with store_lock(path):
            if path.exists() and not overwrite:
                raise StoreError(f"{path}: a run store already exists (pass overwrite=True / --force to replace it)")
            store = cls(path, config, rng_states=[generator_state(as_generator(config.seed))])
            store.write()
        return store

    @classmethod
    def open(cls, path: str | os.PathLike) -> "SGRunStore":
        """Load and verify an SG-EnMCMC run store (runs no user code).

        Raises
        ------
        StoreError
            Missing, damaged (hash or checksum mismatch, NaN, missing or inconsistent
            variables), not an SG-EnMCMC store, or of another format version.
        """
        path = Path(path)
        attrs, variables = _read_file(path)
        try:
            store = cls._from_file(path, attrs, variables)
        except StoreError:
            raise
        except (KeyError, IndexError, ValueError, TypeError, AttributeError) as err:
            what = (f"missing variable or attribute {err}" if isinstance(err, KeyError)
                    else f"{type(err).__name__}: {err}")
            raise StoreError(f"{path}: damaged or inconsistent run store ({what})") from None
        store._token = (attrs.get("content_sha256"), store.n_steps)
        store._disk_steps = store.n_steps
        return store

    @classmethod
    def _from_file(cls, path: Path, attrs: dict, variables: dict) -> "SGRunStore":
        if attrs.get("run_kind") != RUN_KIND:
            raise StoreError(f"{path}: not an SG-EnMCMC run store (open it with seqbayes.RunStore.open)")
        version = int(attrs.get("seqbayes_store_format", -1))
        if version != SG_FORMAT_VERSION:
            raise StoreError(f"{path}: SG-EnMCMC run-store format version {version}, but this seqbayes reads "
                             f"version {SG_FORMAT_VERSION}")
        n_steps = int(attrs["n_steps"])
        text = {name: [str(v) for v in variables[name]] if name in variables else []
                for name in _RECORD_TEXT + ("record_sha256",)}
        rng_text = text["rng_state"]
        if len(rng_text) != n_steps + 1 or any(len(text.get(name, ())) != n_steps for name in _RECORD_TEXT
                                               if name != "rng_state"):
            raise StoreError(f"{path}: inconsistent store ({len(rng_text)} generator states and "
                             f"{len(text.get('step_info', ()))} step records for n_steps = {n_steps})")
        per_step = list(zip(*[text[name] if name != "rng_state" else rng_text[1:] for name in _RECORD_TEXT]))
        record_hashes = [_record_hash(texts) for texts in per_step]
        bad = [i + 1 for i, (a, b) in enumerate(zip(text.get("record_sha256", []), record_hashes)) if a != b]
        if (bad or len(text.get("record_sha256", [])) != n_steps
                or attrs.get("content_sha256") != _content_hash(attrs, rng_text[0], record_hashes)):
            where = f" (the records of step {bad[0]})" if bad else ""
            raise StoreError(f"{path}: damaged run store: the content hash of its configuration and records does "
                             f"not match{where} (the file was edited or corrupted)")
        config = SGRunConfig.from_dict(_json(attrs["config"], path, "config"))
        if config.fingerprint() != attrs.get("model_fingerprint"):
            raise StoreError(f"{path}: model fingerprint does not match the stored configuration (the file was "
                             f"edited or written by an incompatible seqbayes)")
        _check_finite(path, variables)
        rng_states = _json_list(rng_text, path, "rng_state")
        infos = _json_list(text["step_info"], path, "step_info")
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
        return cls(path, config, rng_states=rng_states, tables=tables, fixed=fixed, per_time=per_time,
                   events=events, event_rows=event_rows, infos=infos, digests=text["dataset_sha256"],
                   sources=text["dataset_source"], created=attrs.get("created"), record_hashes=record_hashes)

    # ------------------------------------------------------------------- the identifier
    def snapshot_at(self, step: int | None = None) -> dict:
        """The :meth:`SGEnMCMC.snapshot <seqbayes.sgenmcmc.SGEnMCMC.snapshot>` after ``step`` blocks
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
        """An :class:`~seqbayes.sgenmcmc.SGEnMCMC` restored to the state after ``step`` blocks
        (default: the last; ``0``: reset to the prior, ready for the first block)."""
        step = self.n_steps if step is None else int(step)
        sampler = self.config.build_identifier()
        if step == 0:
            sampler.reset(generator_from_state(self.rng_states[0]))
        else:
            sampler.restore(self.snapshot_at(step))
        return sampler

    def monitor(self, step: int | None = None):
        """The :class:`~seqbayes.stiffness_drop.StiffnessDropMonitor` of ``[monitor]`` restored to the state
        after ``step`` blocks (default: the last; ``0``: reset, ready for the first block), bit for bit as
        an uninterrupted monitor; its :attr:`~seqbayes.stiffness_drop.StiffnessDropMonitor.history` holds
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
        from ..stiffness_drop import DropBlock

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
        """The :class:`~seqbayes.sgenmcmc.SGEnMCMCResult` of the record so far (histories per sample)."""
        if not self.n_steps:
            raise ValueError(f"{self.path}: no block assimilated yet")
        return self.identifier().result()

    # ----------------------------------------------------------------------- assimilation
    def _si_block(self, table, source: str) -> np.ndarray:
        """The table checked (:func:`~seqbayes.datasets.check_table`) and in SI units (``[data] units``)."""
        table = check_table(table, self.config, source)
        factors = self.config.si_factors()
        return table if np.all(factors == 1.0) else table * factors

    def _check_block(self, table, source: str) -> np.ndarray:
        """The SI table (:meth:`_si_block`) not assimilated before and, with a time column, in step with
        ``dt`` and continuing the record."""
        digest = dataset_digest(table, self.config.columns)
        if digest in self.digests:
            step = self.digests.index(digest) + 1
            raise DuplicateDatasetError(f"{self.path}: this block was already assimilated as step {step} (from "
                                        f"{self.sources[step - 1]}, sha256 {digest[:12]})")
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

    def assimilate(self, table: ArrayLike, source: str = "<array>", *, write: bool = True) -> dict:
        """Assimilate the next block of the record, an ``(n, c)`` array with the columns
        ``config.columns``, and save the store.

        Returns
        -------
        dict
            The block's summary (also kept in :attr:`infos`): ``step``, ``rows``, ``first_sample``,
            ``log_evidence_increment``, ``log_evidence``, ``ess``, ``moves``, ``acceptance``, ``wall_time``.

        Raises
        ------
        seqbayes.datasets.DataError
            Wrong shape or column count, no rows, NaN/inf, a time column out of step.
        DuplicateDatasetError
            The block was assimilated before.
        StoreError
            The store cannot be written (it is left as it was).
        """
        import time

        where = "table" if source == "<array>" else f"table from {source}"
        table = self._check_block(self._si_block(table, where), where)
        with store_lock(self.path) if write else contextlib.nullcontext():
            if write:
                _recover_journal(self.path)
                self._reload_if_changed()
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

    def update(self, datafile: str | os.PathLike) -> dict:
        """Read a block file (CSV with a header, or NetCDF; :func:`~seqbayes.datasets.read_datafile`)
        and :meth:`assimilate` it."""
        table = read_datafile(datafile, self.config)
        return self.assimilate(table, Path(datafile).name)

    def _reload_if_changed(self) -> None:
        """Under the lock: take in the blocks another process stored since this object read the file."""
        if self._token is None or _read_token(self.path) == self._token:
            return
        fresh = SGRunStore.open(self.path)
        if fresh.config.fingerprint() != self.config.fingerprint():
            raise StoreError(f"{self.path}: the run store was replaced by a run of another model since it was opened")
        self.__dict__.update(fresh.__dict__)

    # ----------------------------------------------------------------------- summaries
    def block_posterior(self, step: int = -1, level: float = 0.95) -> dict:
        """The posterior of the stiffness ratios at the end of a block: ``{name: {mean, sd, lower,
        upper}}`` from the weighted particles (the central ``level`` interval)."""
        from ..sgenmcmc import weighted_quantiles

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
        (:func:`~seqbayes.structures.modal.modal_summary`): natural frequencies, damping ratios and
        mode shapes, with the MAC against ``identified_shapes (n, k)`` if given."""
        from ..structures.modal import modal_summary

        if not self.n_steps:
            raise ValueError(f"{self.path}: no block assimilated yet")
        theta, w = self.posterior_samples(step)
        return modal_summary(self.config.build_building(), theta[:, :self.config.n_storeys], w, identified_shapes)

    # ----------------------------------------------------------------------- writing
    def _step_texts(self, k: int) -> tuple:
        return (json.dumps(self.infos[k]), json.dumps(self.rng_states[k + 1]), self.digests[k], self.sources[k], "")

    def _attrs(self, record_hashes) -> dict:
        from .. import __version__

        attrs = {"seqbayes_store_format": SG_FORMAT_VERSION, "run_kind": RUN_KIND, "seqbayes_version": __version__,
                 "model_fingerprint": self.config.fingerprint(), "config": json.dumps(self.config.to_dict()),
                 "model_name": self.config.name, "n_steps": self.n_steps, "created": self.created, "updated": _now()}
        attrs["content_sha256"] = _content_hash(attrs, json.dumps(self.rng_states[0]), record_hashes)
        return attrs

    def _rows(self, start: int) -> tuple[dict, list]:
        """``(variables, texts)``: name -> (dims, values) of steps ``start ..`` along the growing dimensions."""
        texts = [self._step_texts(k) for k in range(start, self.n_steps)]
        rng_from = 0 if start == 0 else start + 1
        data = {"rng_state": (("rng_index",), np.array([json.dumps(s) for s in self.rng_states[rng_from:]],
                                                      dtype=object))}
        if start >= self.n_steps:
            return data, texts
        columns = list(zip(*texts))
        T0 = int(sum(t.shape[0] for t in self.tables[:start]))
        E0 = int(sum(self.event_rows[:start]))
        data.update({
            "step": (("step",), np.arange(start + 1, self.n_steps + 1)),
            "step_info": (("step",), np.array(columns[0], dtype=object)),
            "dataset_sha256": (("step",), np.array(columns[2], dtype=object)),
            "dataset_source": (("step",), np.array(columns[3], dtype=object)),
            "likelihood_sha256": (("step",), np.array(columns[4], dtype=object)),
            "record_sha256": (("step",), np.array([_record_hash(t) for t in texts], dtype=object)),
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
        return data, texts

    def _hashes_through(self, texts, start: int) -> list:
        return self._record_hashes[:start] + [_record_hash(t) for t in texts]

    def to_xarray(self):
        """The store's content as an :class:`xarray.Dataset` (what a whole write saves)."""
        import xarray as xr

        data, texts = self._rows(0)
        coords = {"parameter": list(self.names), "column": list(self.config.columns)}
        if "step" in data:
            coords["step"] = data.pop("step")[1]
        ds = xr.Dataset(data, coords=coords)
        ds.attrs.update(self._attrs(self._hashes_through(texts, 0)))
        return ds

    def write(self) -> None:
        """Write the store: append the new steps in place through the journal, or write it whole.

        Raises
        ------
        StoreError
            The folder is read-only or full, or the path is a folder; the previous store is kept.
        """
        with store_lock(self.path):
            self._write_locked()

    def _write_locked(self) -> None:
        _write_whole(self, _GROWING)

    def _written(self, content_hash: str, record_hashes: list) -> None:
        self._record_hashes = list(record_hashes)
        self._token = (content_hash, self.n_steps)
        self._disk_steps = self.n_steps

    def _append(self) -> bool:
        """Append the steps after ``_disk_steps`` in place through the journal (:mod:`seqbayes.store`);
        False (nothing written) when the file is not this object's earlier steps in this layout."""
        import h5py

        start = self._disk_steps
        if not (0 < start < self.n_steps and self._token is not None and _read_token(self.path) == self._token):
            return False
        rows, texts = self._rows(start)
        record_hashes = self._hashes_through(texts, start)
        attrs = self._attrs(record_hashes)
        data = {name: values for name, (dims, values) in rows.items()}
        dims = {name: d[0] for name, (d, values) in rows.items()}
        try:
            with open(self.path, "rb") as fh:
                pending = _PendingWrites(fh)
                with h5py.File(pending, "r+") as f:
                    growing = {name for name, obj in f.items() if obj.shape and obj.maxshape[0] is None
                               and name not in _BARE}
                    if (int(_plain(f.attrs.get("seqbayes_store_format", 0))) != SG_FORMAT_VERSION
                            or int(_plain(f.attrs.get("n_steps", -1))) != start or growing != set(data)
                            or any(f[name].shape[1:] != np.shape(values)[1:] for name, values in data.items())):
                        return False
                    for dim in _BARE:
                        extra = {len(data[name]) for name in data if dims[name] == dim}
                        if len(extra) != 1:
                            return False
                        _extend(f[dim], extra.pop())
                    for name, values in data.items():
                        _extend(f[name], len(values), values)
                    for key, value in attrs.items():
                        f.attrs[key] = value
                journal = (pending.on_disk, pending.size, pending.changes())
        except OSError as err:
            raise StoreError(f"{self.path}: cannot read the run store to append: {_os_message(err)}; the previous "
                             f"store is kept") from None
        _apply_with_journal(self.path, journal)
        self._written(attrs["content_sha256"], record_hashes)
        _fault("after-replace")
        return True


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
    from numpy.typing import ArrayLike
