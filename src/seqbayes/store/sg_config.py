"""The configuration of SG-EnMCMC runs: a shear building identified on-line, block by block.

A TOML configuration with a ``[building]`` section (:func:`parse_sg_config`) describes a
shear building, its sensors, the prior box of the storey stiffness ratios and the
:class:`~seqbayes.structural.sgenmcmc.SGEnMCMC` settings::

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
    n_particles = 200                   # (seqbayes.structural.stiffness_drop.StiffnessDropMonitor; one model
    threshold = 0.99                    # class per storey); any of its keywords: drop_range,
    seed = 2                            # change_rate, change_every, prune_below, ... (seed: default
                                        # the sampler's seed + 1)

:func:`load_sg_config` reads it (:func:`seqbayes.store.load_config` does, for a configuration with a
``[building]`` section) and :class:`SGRunConfig` holds it; :class:`seqbayes.store.sg.SGRunStore`
keeps the run.

Trust: the configuration's numbers define the building; with ``[building] module`` the function
runs once, when the configuration is read (like a likelihood module, it is located next to the
configuration and its SHA-256 recorded), and the building it returns is recorded, so updates,
``status`` and reports run no user code.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .modules import ConfigError, load_located, locate_module, read_toml
from .schema import StoredConfig, check_keys, fail, numbers

__all__ = ["SGRunConfig", "parse_sg_config", "load_sg_config", "RUN_KIND"]

#: The ``run_kind`` of an SG-EnMCMC run (:mod:`seqbayes.store.registry`).
RUN_KIND = "sgenmcmc"
#: [sampler] settings handled by the store itself (every other key is an SGEnMCMC keyword).
_OWN_SAMPLER_KEYS = ("n_members", "seed")
#: SGEnMCMC keywords a configuration may not set (the store decides them or they are not data).
_FIXED_KEYWORDS = ("building", "dt", "lower", "upper", "measurement_noise", "process_noise_std", "channels",
                   "transition", "sampler", "blas_threads")
#: DropBlock fields that are NaN where a class has no dropped particle (stored as 0, restored from ``changed``).


def _check_stored(data, source) -> None:
    """The fields of a stored :meth:`SGRunConfig.to_dict`: types, finiteness and signs, named like the TOML's."""
    if not isinstance(data, dict):
        fail(source, "config", f"expected a table, got {type(data).__name__}")
    fields = {f.name for f in dataclasses.fields(SGRunConfig)}
    check_keys(data, fields | {"kind"}, source, "config")
    missing = sorted({"name", "masses", "stiffnesses", "damping_ratios", "damping_modes", "accelerations", "drifts",
                      "dt", "input", "responses", "lower", "upper", "measurement_std"} - set(data))
    if missing:
        fail(source, "config", f"missing field(s) {', '.join(missing)}")
    if not isinstance(data["name"], str) or not data["name"]:
        fail(source, "model.name", f"expected a non-empty string, got {data['name']!r}")
    n = len(numbers(data["masses"], source, "building.masses", positive=True))
    numbers(data["stiffnesses"], source, "building.stiffnesses", n=n, positive=True)
    if min(numbers(data["damping_ratios"], source, "building.damping_ratios", n=2)) < 0:
        fail(source, "building.damping_ratios", f"must be >= 0, got {data['damping_ratios']!r}")
    for key, table in (("damping_modes", "building"), ("accelerations", "sensors"), ("drifts", "sensors")):
        values = data[key]
        if not isinstance(values, list) or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= n
                                                   for v in values):
            fail(source, f"{table}.{key}", f"expected a list of floor/storey numbers 1-{n}, got {values!r}")
    numbers(data["dt"], source, "data.dt", positive=True)
    lower = numbers(data["lower"], source, "priors.lower")
    upper = numbers(data["upper"], source, "priors.upper", n=len(lower))
    if not all(lo < hi for lo, hi in zip(lower, upper)):
        fail(source, "priors.upper", f"must lie above lower, got lower {lower} and upper {upper}")
    numbers(data["measurement_std"], source, "noise.measurement_std", positive=True)
    if numbers(data.get("process_std", 0.0), source, "noise.process_std")[0] < 0:
        fail(source, "noise.process_std", f"must be >= 0, got {data['process_std']!r}")
    for key in ("n_members", "seed"):
        value = data.get(key, 0 if key == "seed" else 500)
        if isinstance(value, bool) or not isinstance(value, int) or value < (2 if key == "n_members" else 0):
            fail(source, f"sampler.{key}", f"expected a{' positive' if key == 'n_members' else ' non-negative'} "
                                            f"integer, got {value!r}")
    settings = data.get("settings", {})
    check_keys(settings, set(settings), source, "sampler")
    from ..structural.settings import flat_defaults

    defaults = flat_defaults()
    for key, value in settings.items():
        if key not in defaults or key in _FIXED_KEYWORDS:
            fail(source, f"sampler.{key}", "not a setting of SGEnMCMC")
        default = defaults[key]
        if isinstance(default, bool) and not isinstance(value, bool):
            fail(source, f"sampler.{key}", f"expected true or false, got {value!r}")
        if isinstance(default, (int, float)) and not isinstance(default, bool):
            numbers(value, source, f"sampler.{key}")
            if value < 0:
                fail(source, f"sampler.{key}", f"must be >= 0, got {value!r}")
        if isinstance(default, str) and default != "auto" and not isinstance(value, str):
            fail(source, f"sampler.{key}", f"expected a string, got {value!r}")


@dataclass(frozen=True)
class SGRunConfig(StoredConfig):
    """A validated SG-EnMCMC run configuration (module docstring for the TOML layout).

    Attributes
    ----------
    name : str
    masses, stiffnesses : tuple of float
        Floor masses [kg] and undamaged storey stiffnesses [N/m], bottom to top.
    damping_ratios, damping_modes : tuple
        Rayleigh damping (:class:`~seqbayes.structural.structures.ShearBuilding`).
    accelerations, drifts : tuple of int
        The sensor layout (:class:`~seqbayes.structural.structures.Sensors`).
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
        Further :class:`~seqbayes.structural.sgenmcmc.SGEnMCMC` keywords.
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
        With ``[monitor]``: the :class:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor` keywords and its
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
    #: what :mod:`seqbayes.store.datasets` reads: any number of rows, the table as an array
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
        from ..structural.structures.records import UNITS

        return np.array([UNITS[self.units[c]] if c in self.units else 1.0 for c in self.columns])

    def build_building(self):
        """The :class:`~seqbayes.structural.structures.ShearBuilding`."""
        from ..structural.structures import ShearBuilding

        return ShearBuilding(np.array(self.masses), np.array(self.stiffnesses), self.damping_ratios,
                             self.damping_modes)

    def build_sensors(self):
        """The :class:`~seqbayes.structural.structures.Sensors` layout."""
        from ..structural.structures.shear_building import Sensors

        return Sensors(accelerations=self.accelerations, drifts=self.drifts)

    def build_identifier(self):
        """A fresh :class:`~seqbayes.structural.sgenmcmc.SGEnMCMC` (``sampler="resample-move"``, the on-line one)."""
        from ..structural.sgenmcmc import SGEnMCMC

        from ..structural.settings import sg_from_flat

        return SGEnMCMC(self.build_building(), self.dt, np.array(self.lower), np.array(self.upper),
                        np.array(self.measurement_std), process_noise_std=self.process_std,
                        n_members=self.n_members, channels=self.build_sensors(),
                        **sg_from_flat(sampler="resample-move", **self.settings))

    def build_monitor(self):
        """A fresh :class:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor` of ``[monitor]`` (None without it)."""
        if self.monitor is None:
            return None
        from ..structural.stiffness_drop import StiffnessDropMonitor, monitor_from_flat

        n = self.n_storeys
        settings = {k: (tuple(v) if isinstance(v, list) else v) for k, v in self.monitor.items() if k != "seed"}
        size = {"n_particles": settings.pop("n_particles")} if "n_particles" in settings else {}
        return StiffnessDropMonitor(self.build_building(), self.dt, np.array(self.lower[:n]),
                                    np.array(self.upper[:n]), np.array(self.measurement_std),
                                    process_noise_std=self.process_std, channels=self.build_sensors(), **size,
                                    **monitor_from_flat(**settings))

    def to_dict(self) -> dict:
        """Plain JSON-able dict (stored in the run store)."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if out["monitor"] is None:  # absent, so runs without a monitor keep their fingerprint
            del out["monitor"]
        out = {k: list(v) if isinstance(v, tuple) else v for k, v in out.items()}
        out["kind"] = RUN_KIND
        return out

    @classmethod
    def from_dict(cls, data: dict, source: str = "stored configuration") -> "SGRunConfig":
        """Inverse of :meth:`to_dict`, its fields type-checked as a TOML file's are (a store is a file
        someone was handed: a negative noise sd or a string for a flag is refused, not run).

        Raises
        ------
        ConfigError
            Naming ``source`` and the field.
        """
        _check_stored(data, source)
        data = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k != "kind"}
        return cls(**data)


def parse_sg_config(raw: dict, source: str = "<config>", base_dir: str | os.PathLike | None = None) -> SGRunConfig:
    """Validate a parsed TOML mapping with a ``[building]`` section; errors name the field.

    Raises
    ------
    ConfigError
    """
    check_keys(raw, {"model", "building", "sensors", "data", "priors", "noise", "sampler", "monitor"}, source,
          "<top level>")
    model = raw.get("model", {})
    check_keys(model, {"name", "type"}, source, "model")
    if model.get("type", RUN_KIND) != RUN_KIND:
        fail(source, "model.type", f"a [building] configuration is an SG-EnMCMC run (type = \"{RUN_KIND}\"), "
                                    f"got {model.get('type')!r}")
    name = model.get("name", "shear-building")
    if not isinstance(name, str) or not name:
        fail(source, "model.name", f"expected a non-empty string, got {name!r}")

    building = raw.get("building")
    if building is None:
        fail(source, "[building]", "missing section")
    check_keys(building, {"masses", "stiffnesses", "damping_ratios", "damping_modes", "module"}, source, "building")
    module_spec = module_sha = None
    if "module" in building:
        if set(building) - {"module"}:
            fail(source, "building.module", "give either module or the numbers (masses, stiffnesses, ...), "
                                             "not both")
        module_spec = building["module"]
        if not isinstance(module_spec, str) or module_spec.count(":") != 1 or not all(module_spec.split(":")):
            fail(source, "building.module", f"expected \"module:function\", got {module_spec!r}")
        try:
            located = locate_module(module_spec.split(":")[0], base_dir)
            made = load_located(module_spec, located)()
        except ConfigError as err:
            raise ConfigError(f"{source}: {str(err).replace('model.likelihood:', 'building.module:', 1)}") from None
        except Exception as err:
            fail(source, "building.module", f"{module_spec}() raised {type(err).__name__}: {err}")
        from ..structural.structures import ShearBuilding

        if not isinstance(made, ShearBuilding):
            fail(source, "building.module", f"{module_spec}() must return a seqbayes.structural.structures.ShearBuilding, "
                                             f"got {type(made).__name__}")
        module_sha = located.sha256
        masses, stiffnesses = [float(v) for v in made.masses], [float(v) for v in made.stiffnesses]
        damping_ratios, damping_modes = list(made.damping_ratios), list(made.damping_modes)
    else:
        for key in ("masses", "stiffnesses", "damping_ratios"):
            if key not in building:
                fail(source, f"building.{key}", "missing")
        masses = numbers(building["masses"], source, "building.masses", positive=True)
        stiffnesses = numbers(building["stiffnesses"], source, "building.stiffnesses", n=len(masses),
                               positive=True)
        damping_ratios = numbers(building["damping_ratios"], source, "building.damping_ratios", n=2)
        modes = building.get("damping_modes", [1, 2] if len(masses) > 1 else [1, 1])
        if (not isinstance(modes, list) or len(modes) != 2
                or not all(isinstance(m, int) and not isinstance(m, bool) for m in modes)):
            fail(source, "building.damping_modes", f"expected two mode numbers, got {modes!r}")
        damping_modes = modes
    n = len(masses)

    sensors = raw.get("sensors", {"accelerations": list(range(1, n + 1))})
    check_keys(sensors, {"accelerations", "drifts"}, source, "sensors")
    layout = {}
    for key in ("accelerations", "drifts"):
        values = sensors.get(key, [])
        if (not isinstance(values, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in values)
                or any(not 1 <= v <= n for v in values) or len(set(values)) != len(values)):
            fail(source, f"sensors.{key}", f"expected distinct floor numbers in 1..{n}, got {values!r}")
        layout[key] = tuple(values)
    p = len(layout["accelerations"]) + len(layout["drifts"])
    if p == 0:
        fail(source, "[sensors]", "at least one sensor is needed")

    data = raw.get("data")
    if data is None:
        fail(source, "[data]", "missing section")
    check_keys(data, {"dt", "input", "responses", "time", "units"}, source, "data")
    if "dt" not in data:
        fail(source, "data.dt", "missing (the sampling step in seconds)")
    dt = numbers(data["dt"], source, "data.dt", positive=True)[0]
    column_input = data.get("input")
    if not isinstance(column_input, str) or not column_input:
        fail(source, "data.input", f"expected the name of the ground-acceleration column, got {column_input!r}")
    responses = data.get("responses")
    if not isinstance(responses, list) or not all(isinstance(c, str) and c for c in responses):
        fail(source, "data.responses", f"expected a list of column names, got {responses!r}")
    if len(responses) != p:
        fail(source, "data.responses", f"expected {p} columns (one per sensor of [sensors]: "
                                        f"{len(layout['accelerations'])} accelerations, then "
                                        f"{len(layout['drifts'])} drifts), got {len(responses)}")
    time_column = data.get("time")
    if time_column is not None and (not isinstance(time_column, str) or not time_column):
        fail(source, "data.time", f"expected a column name, got {time_column!r}")
    columns = ([time_column] if time_column else []) + [column_input] + responses
    if len(set(columns)) != len(columns):
        fail(source, "data", f"duplicate column names in {columns}")
    units = _parse_units(data.get("units"), column_input, responses, len(layout["accelerations"]), source)

    priors = raw.get("priors")
    if priors is None:
        fail(source, "[priors]", "missing section (lower and upper bounds of the stiffness ratios)")
    check_keys(priors, {"lower", "upper"}, source, "priors")
    for key in ("lower", "upper"):
        if key not in priors:
            fail(source, f"priors.{key}", "missing")
    lower = numbers(priors["lower"], source, "priors.lower", n=n, positive=True)
    upper = numbers(priors["upper"], source, "priors.upper", n=n, positive=True)
    if any(u <= lo for lo, u in zip(lower, upper)):
        fail(source, "priors.upper", f"must exceed priors.lower in every storey, got {lower} and {upper}")

    noise = raw.get("noise")
    if noise is None or "measurement_std" not in noise:
        fail(source, "noise.measurement_std", "missing (the measurement noise std of each response column)")
    check_keys(noise, {"measurement_std", "process_std"}, source, "noise")
    measurement_std = numbers(noise["measurement_std"], source, "noise.measurement_std", n=p, positive=True)
    process_std = numbers(noise.get("process_std", 0.0), source, "noise.process_std")[0]
    if process_std < 0:
        fail(source, "noise.process_std", f"must be >= 0, got {process_std}")

    sampler = dict(raw.get("sampler", {}))
    check_keys(sampler, set(sampler), source, "sampler")
    n_members = sampler.pop("n_members", 500)
    seed = sampler.pop("seed", 0)
    for key, value in (("n_members", n_members), ("seed", seed)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            fail(source, f"sampler.{key}", f"expected a non-negative integer, got {value!r}")
    from ..structural.settings import FLAT_SG

    keywords = set(FLAT_SG) - set(_FIXED_KEYWORDS) - set(_OWN_SAMPLER_KEYS)
    for key in sampler:
        if key not in keywords:
            fail(source, f"sampler.{key}", f"unknown setting; expected one of "
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
        fail(source, "building" if not str(err).startswith("dt") else "data.dt", str(err))
    try:
        identifier = config.build_identifier()
    except (TypeError, ValueError) as err:
        fail(source, "sampler", str(err))
    choice = getattr(identifier, "surrogate_choice", None)
    if choice is not None:
        # surrogate = "auto" measures the transitions' cost now, once: the choice is pinned as a
        # level (a timing-dependent choice at every update would break bit-identical resume)
        settings = {k: v for k, v in sampler.items() if k not in ("surrogate", "surrogate_options")}
        settings["level"] = choice.level
        config = dataclasses.replace(config, settings=settings, surrogate_choice=choice.reason)
    if "monitor" in raw:
        monitor = dict(raw["monitor"])
        from ..structural.stiffness_drop import FLAT_MONITOR

        # n_particles, the seed and the monitor's flat settings (the building, noise and prior box are the run's)
        check_keys(monitor, {"n_particles", "seed", *FLAT_MONITOR}, source, "monitor")
        monitor_seed = monitor.setdefault("seed", seed + 1)
        if isinstance(monitor_seed, bool) or not isinstance(monitor_seed, int) or monitor_seed < 0:
            fail(source, "monitor.seed", f"expected a non-negative integer, got {monitor_seed!r}")
        config = dataclasses.replace(config, monitor=monitor)
        try:
            config.build_monitor()
        except (TypeError, ValueError) as err:
            fail(source, "monitor", str(err))
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
        fail(source, "data.units", f"expected a unit (\"g\") or a table {{ column = \"unit\" }}, got {raw!r}")
    out = {}
    for column, unit in raw.items():
        if column not in kinds:
            fail(source, f"data.units.{column}", f"not an input or response column ({', '.join(kinds)})")
        allowed = _ACCELERATION_UNITS if kinds[column] == "acceleration" else _LENGTH_UNITS
        if unit not in allowed:
            fail(source, f"data.units.{column}", f"an {kinds[column]} column takes one of {', '.join(allowed)}, "
                                                  f"got {unit!r}")
        if unit not in ("m/s2", "m/s^2", "m"):
            out[column] = unit
    return out


def load_sg_config(path: str | os.PathLike) -> SGRunConfig:
    """Read and validate an SG-EnMCMC TOML configuration (:func:`parse_sg_config`)."""
    path = Path(path)
    raw = read_toml(path)
    return parse_sg_config(raw, str(path), base_dir=path.parent)



import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    import os
