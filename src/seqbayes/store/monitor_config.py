"""The configuration of monitor runs: a structure watched day by day for damage under a learned environment
(docs/environment.md, "The monitor run store").

A TOML configuration with a ``[monitor]`` table and no ``[building]`` (an SG-EnMCMC run's ``[monitor]`` sits
beside its ``[building]``)::

    [model]
    name = "mast"

    [monitor]
    model = "modes"                     # no structural model: each tracked mode's reference frequency [Hz]
    frequencies = [0.375, 0.397, 1.06]  # (a loss is a lasting drop of one or more modes; no location)
    # model = "shear_building"          # or a shear building: floor masses [kg] and storey stiffnesses
    # masses = [2e5, 2e5, 2e5, 1.6e5]   # [N/m], bottom to top (a loss is located in a storey)
    # stiffnesses = [3e8, 2.6e8, 2.2e8, 1.8e8]
    covariates = []                     # further covariates by name (columns of the datasets), linear
    n_particles = 256                   # particles over the static parameters of the environmental law
    seed = 0
    hazard = 0.00274                    # daily probability of a loss (its day's geometric prior)
    threshold = 0.95                    # alarm: P(damage) above threshold ...
    consecutive = 2                     # ... at the end of this many days in a row

:class:`MonitorRunConfig` holds it; :class:`seqbayes.store.monitor.MonitorRunStore` keeps the run. The numbers
define the model: nothing of the user's is imported, then or at an update.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field

from .config import SECTION_PARSERS
from .schema import StoredConfig, check_keys, fail, number, numbers, table

__all__ = ["MonitorRunConfig", "parse_monitor_config", "RUN_KIND"]

#: The ``run_kind`` of a monitor run.
RUN_KIND = "monitor"
MODELS = ("modes", "shear_building")
_KEYS = {"model", "frequencies", "masses", "stiffnesses", "covariates", "n_particles", "seed", "hazard", "threshold",
         "consecutive"}
#: Most modes and particles a run may have (memory: the change bank holds particles x modes x 16 x days values).
MAX_MODES = 50
MAX_PARTICLES = 20000


@dataclass(frozen=True)
class MonitorRunConfig(StoredConfig):
    """A validated monitor configuration (module docstring)."""

    name: str
    model: str
    frequencies: tuple = ()
    masses: tuple = ()
    stiffnesses: tuple = ()
    covariates: tuple = ()
    n_particles: int = 256
    seed: int = 0
    hazard: float = 1.0 / 365.0
    threshold: float = 0.95
    consecutive: int = 2
    settings: dict = field(default_factory=dict)

    kind = RUN_KIND

    @property
    def n_samples(self) -> int:
        return self.n_particles

    @property
    def n_modes(self) -> int:
        return len(self.frequencies) if self.model == "modes" else len(self.masses)

    @property
    def frequency_columns(self) -> tuple:
        return tuple(f"f{i + 1}" for i in range(self.n_modes))

    @property
    def columns(self) -> tuple:
        """The stored table of a dataset: one row per set."""
        n = self.n_modes
        return (("day", "temperature") + tuple(self.covariates) + self.frequency_columns
                + tuple(f"sf{i + 1}" for i in range(n)))

    @property
    def names(self) -> tuple:
        """The static parameters the particles carry."""
        from ..structural.monitor.law import MonitorPrior

        return MonitorPrior().names(self.n_modes)

    def build_model(self):
        """The :class:`~seqbayes.structural.monitor.model.MonitorModel`."""
        from ..structural.monitor.model import MonitorModel

        if self.model == "modes":
            return MonitorModel.mode_level(list(self.frequencies), covariates=tuple(self.covariates))
        from ..structural.structures import ShearBuilding
        from ..structural.structures.linear import ShearBuildingModel

        return MonitorModel.linear(ShearBuildingModel(ShearBuilding(list(self.masses), list(self.stiffnesses))),
                                   covariates=tuple(self.covariates))

    def build_settings(self):
        """The :class:`~seqbayes.structural.monitor.model.MonitorSettings`."""
        from ..structural.monitor.model import AlarmRule, MonitorSettings

        return MonitorSettings(n_particles=self.n_particles, hazard=self.hazard,
                               alarm=AlarmRule(self.threshold, self.consecutive), **self.settings)

    def to_dict(self) -> dict:
        out = asdict(self)
        for key in ("frequencies", "masses", "stiffnesses", "covariates"):
            out[key] = list(out[key])
        return {"kind": RUN_KIND, **out}

    @classmethod
    def from_dict(cls, data: dict, source: str = "stored configuration") -> "MonitorRunConfig":
        data = {k: v for k, v in data.items() if k != "kind"}
        try:
            return parse_monitor_config({"model": {"name": data.pop("name")}, "monitor": data}, source)
        except (KeyError, TypeError) as err:
            fail(source, "monitor", f"not a monitor configuration ({err})")


def parse_monitor_config(raw: dict, source: str = "<config>", base_dir=None) -> MonitorRunConfig:
    """Validate a TOML monitor configuration (module docstring); every error names the field."""
    check_keys(raw, {"model", "monitor"}, source, "")
    model_table = table(raw, "model", source, required=False)
    check_keys(model_table, {"name"}, source, "model")
    name = model_table.get("name", "monitor")
    if not isinstance(name, str) or not name.strip():
        fail(source, "model.name", f"expected a non-empty string, got {name!r}")
    mon = table(raw, "monitor", source)
    check_keys(mon, _KEYS | {"settings"}, source, "monitor")
    kind = mon.get("model", "modes")
    if kind not in MODELS:
        fail(source, "monitor.model", f"expected one of {', '.join(MODELS)}, got {kind!r}")
    frequencies, masses, stiffnesses = (), (), ()
    if kind == "modes":
        if "frequencies" not in mon:
            fail(source, "monitor.frequencies", "missing: each tracked mode's reference frequency [Hz]")
        frequencies = tuple(numbers(mon["frequencies"], source, "monitor.frequencies", positive=True))
        if any(b <= a for a, b in zip(frequencies, frequencies[1:])):
            fail(source, "monitor.frequencies", f"expected increasing frequencies (mode 1 lowest), got "
                                                f"{list(frequencies)}")
        n = len(frequencies)
    else:
        for key in ("masses", "stiffnesses"):
            if key not in mon:
                fail(source, f"monitor.{key}", "missing (a shear building needs masses and stiffnesses, bottom to top)")
        masses = tuple(numbers(mon["masses"], source, "monitor.masses", positive=True))
        stiffnesses = tuple(numbers(mon["stiffnesses"], source, "monitor.stiffnesses", n=len(masses), positive=True))
        n = len(masses)
    if n > MAX_MODES:
        fail(source, "monitor", f"{n} modes; a monitor takes at most {MAX_MODES}")
    covariates = mon.get("covariates", [])
    if not isinstance(covariates, list) or not all(isinstance(c, str) and c.strip() for c in covariates):
        fail(source, "monitor.covariates", f"expected a list of column names, got {covariates!r}")
    reserved = {"day", "temperature", *(f"f{i + 1}" for i in range(n)), *(f"sf{i + 1}" for i in range(n))}
    clash = [c for c in covariates if c in reserved]
    if clash or len(set(covariates)) != len(covariates):
        fail(source, "monitor.covariates", f"expected distinct names other than day, temperature and the frequency "
                                           f"columns, got {covariates!r}")
    n_particles = number(mon.get("n_particles", 256), source, "monitor.n_particles", integer=True)
    if not 10 <= n_particles <= MAX_PARTICLES:
        fail(source, "monitor.n_particles", f"expected 10 to {MAX_PARTICLES}, got {n_particles}")
    seed = number(mon.get("seed", 0), source, "monitor.seed", integer=True)
    if not 0 <= seed < 2 ** 63:
        fail(source, "monitor.seed", f"expected 0 <= seed < 2^63, got {seed}")
    hazard = number(mon.get("hazard", 1.0 / 365.0), source, "monitor.hazard")
    threshold = number(mon.get("threshold", 0.95), source, "monitor.threshold")
    consecutive = number(mon.get("consecutive", 2), source, "monitor.consecutive", integer=True)
    for key, value, ok in (("hazard", hazard, 0 < hazard < 1), ("threshold", threshold, 0 < threshold < 1),
                           ("consecutive", consecutive, 1 <= consecutive <= 100_000)):
        if not ok:
            fail(source, f"monitor.{key}", f"out of range: {value!r} ({'1 to 100000' if key == 'consecutive' else 'a probability in (0, 1)'})")
    settings = table(mon, "settings", source, required=False)
    check_keys(settings, {"ess", "min_sweeps", "max_sweeps", "moved_fraction", "chunk_particles"}, source,
               "monitor.settings")
    config = MonitorRunConfig(name.strip(), kind, frequencies, masses, stiffnesses, tuple(covariates), n_particles,
                              seed, hazard, threshold, consecutive, dict(settings))
    try:
        config.build_settings()
        config.build_model()
    except (ValueError, TypeError) as err:
        fail(source, "monitor", str(err))
    json.dumps(config.to_dict())
    return config


SECTION_PARSERS["monitor"] = parse_monitor_config
