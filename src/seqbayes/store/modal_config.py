"""The configuration of modal runs: identified modes updating a model, with no user code (docs/modal.md).

A TOML run configuration whose ``[model]`` names the built-in modal likelihood and whose ``[modal]``
table says which model predicts the modes::

    [model]
    name = "mast"
    likelihood = "modal"              # the built-in ModalLikelihood (seqbayes.structural.modal_likelihood)

    [modal]
    model = "modes"                   # each tracked mode's frequency is a parameter (one per prior, in order);
                                      # or "shear_building" (with masses, stiffnesses, storeys below)
    frequency_error = 0.002           # relative prediction error of the frequencies: a number, one per mode,
                                      # or the name of a parameter (learned)
    std_scale = 1.0                   # factor on the OMA's std_frequency_hz (0: ignore them)
    # shape_error = 0.02              # use the mode shapes (phi_<channel> columns): their prediction error,
                                      # a number or a parameter name
    # pairing = "mode"                # measured mode r is model mode r ("mode"), or paired per particle by
                                      # assignment ("assignment"; the default with shapes)
    # gate = 3.5                      # untracked datasets (an OMA table, a raw record) are tracked against
    # mac_gate = 0.8                  # the run's posterior with this gate
    # record_dt = 0.01                # a raw record's sampling step [s] (without a time column)
    # masses = [...]                  # shear_building: floor masses [kg], nominal storey stiffnesses [N/m]
    # stiffnesses = [...]             # and the storeys whose stiffness ratio the parameters are
    # storeys = [1, 2]                # (default: all, in order)
    # channels = ["a1", "a2", ...]    # the floors' channel names in the records (default "1" .. "n")

    [priors]                          # as any run: the model's parameters first, then the learned errors
    f1 = { dist = "uniform", lower = 0.33, upper = 0.37 }
    ...

    [kernel] / [sampler] / [parallel] as in seqbayes.store.config

There is no ``[data]`` section: a dataset is one record's modes table (docs/modal.md), whose columns the
run fixes: ``mode, frequency_hz, std_frequency_hz`` and, with shapes, ``phi_<channel>,
std_phi_<channel>`` for the model's channels (a shear building's floors are ``1 .. n``).
:class:`ModalRunConfig` is a :class:`~seqbayes.store.config.RunConfig` with the ``[modal]`` table, of
run kind ``"modal"`` (:class:`seqbayes.store.modal.ModalRunStore`).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from dataclasses import dataclass, field

import numpy as np

from .config import SECTION_PARSERS, RunConfig, parse_config
from .modules import ConfigError

__all__ = ["ModalRunConfig", "parse_modal_config", "RUN_KIND", "LIKELIHOOD"]

#: The ``run_kind`` of a modal run.
RUN_KIND = "modal"
#: What a modal run's ``likelihood`` field records (the built-in likelihood; nothing is imported from it).
LIKELIHOOD = "seqbayes.structural.modal_likelihood:ModalLikelihood"
MODELS = ("modes", "shear_building")
_KEYS = {"model", "frequency_error", "shape_error", "std_scale", "pairing", "model_modes", "gate", "mac_gate",
         "record_dt", "masses", "stiffnesses", "storeys", "channels"}
_BUILDING_KEYS = {"masses", "stiffnesses", "storeys", "channels"}


def _fail(source, name, message):
    raise ConfigError(f"{source}: modal.{name}: {message}")


def _number(value, source, name, *, minimum=None, positive=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        _fail(source, name, f"expected a finite number, got {value!r}")
    if positive and value <= 0:
        _fail(source, name, f"must be positive, got {value!r}")
    if minimum is not None and value < minimum:
        _fail(source, name, f"must be >= {minimum:g}, got {value!r}")
    return float(value)


def _error(value, source, name, names, model_names):
    """A prediction error: a number >= 0, a list of them (one per mode) or the name of a parameter."""
    if isinstance(value, str):
        if value not in names:
            close = difflib.get_close_matches(value, names, n=1)
            _fail(source, name, f"{value!r} is not a parameter{f' (did you mean {close[0]!r}?)' if close else ''}; "
                                f"the priors define {', '.join(names)}")
        if value in model_names:
            _fail(source, name, f"{value!r} is one of the model's parameters; a learned error needs its own prior, "
                                f"after the model's")
        return value
    if isinstance(value, list):
        if not value:
            _fail(source, name, "expected a non-empty list of sds (one per mode)")
        return [_number(v, source, f"{name}[{i}]", minimum=0.0) for i, v in enumerate(value)]
    return _number(value, source, name, minimum=0.0)


def parse_modal(spec: dict, names: tuple, source: str) -> dict:
    """The validated ``[modal]`` table (a plain dict, stored in the run) for the parameters ``names``."""
    if not isinstance(spec, dict):
        _fail(source, "<table>", f"expected a table, got {type(spec).__name__}")
    for key in spec:
        if key not in _KEYS:
            close = difflib.get_close_matches(str(key), sorted(_KEYS), n=1)
            _fail(source, key, f"unknown setting{f' (did you mean {close[0]!r}?)' if close else ''}; expected one "
                               f"of {', '.join(sorted(_KEYS))}")
    model = spec.get("model")
    if model not in MODELS:
        _fail(source, "model", f"expected one of {', '.join(map(repr, MODELS))}, got {model!r}")
    learned = [v for k, v in spec.items() if k in ("frequency_error", "shape_error") and isinstance(v, str)]
    model_names = tuple(n for n in names if n not in learned)
    if tuple(names[:len(model_names)]) != model_names:
        _fail(source, "frequency_error", "the learned errors' priors must come after the model's parameters")
    out = {"model": model}
    if model == "shear_building":
        for key in ("masses", "stiffnesses"):
            values = spec.get(key)
            if not isinstance(values, list) or not values:
                _fail(source, key, "expected a non-empty list of positive numbers (bottom to top)")
            out[key] = [_number(v, source, f"{key}[{i}]", positive=True) for i, v in enumerate(values)]
        if len(out["masses"]) != len(out["stiffnesses"]):
            _fail(source, "stiffnesses", f"expected {len(out['masses'])} values (one per storey), got "
                                         f"{len(out['stiffnesses'])}")
        storeys = spec.get("storeys", list(range(1, len(out["masses"]) + 1)))
        n = len(out["masses"])
        if (not isinstance(storeys, list) or not storeys or any(isinstance(s, bool) or not isinstance(s, int)
                                                              or not 1 <= s <= n for s in storeys)
                or len(set(storeys)) != len(storeys)):
            _fail(source, "storeys", f"expected distinct storeys in 1..{n}, got {storeys!r}")
        out["storeys"] = list(storeys)
        channels = spec.get("channels", [str(i + 1) for i in range(n)])
        if (not isinstance(channels, list) or len(channels) != n or not all(isinstance(c, str) and c for c in channels)
                or len(set(channels)) != n):
            _fail(source, "channels", f"expected {n} distinct names (the floors' channels, bottom to top, as in the "
                                      f"records' phi_<channel> columns), got {channels!r}")
        out["channels"] = list(channels)
        if len(storeys) != len(model_names):
            _fail(source, "storeys", f"{len(storeys)} storeys but {len(model_names)} model parameters "
                                     f"({', '.join(model_names)}); one prior per storey")
    else:
        extra = sorted(_BUILDING_KEYS & set(spec))
        if extra:
            _fail(source, extra[0], "only for model = \"shear_building\"")
    out["frequency_error"] = _error(spec.get("frequency_error", 0.01), source, "frequency_error", names, model_names)
    if "shape_error" in spec:
        if model == "modes":
            _fail(source, "shape_error", "model = \"modes\" predicts no mode shapes")
        out["shape_error"] = _error(spec["shape_error"], source, "shape_error", names, model_names)
    out["std_scale"] = _number(spec.get("std_scale", 1.0), source, "std_scale", minimum=0.0)
    if out["std_scale"] == 0 and out["frequency_error"] == 0:
        _fail(source, "frequency_error", "zero, with std_scale = 0: the frequencies would have no variance")
    pairing = spec.get("pairing", "assignment" if "shape_error" in out else "mode")
    if pairing not in ("mode", "assignment"):
        _fail(source, "pairing", f"expected \"mode\" or \"assignment\", got {pairing!r}")
    out["pairing"] = pairing
    if "model_modes" in spec:
        modes = spec["model_modes"]
        if pairing != "mode" or not isinstance(modes, list) or not all(
                isinstance(m, int) and not isinstance(m, bool) and m >= 1 for m in modes):
            _fail(source, "model_modes", "expected a list of model modes (1-based), with pairing = \"mode\"")
        out["model_modes"] = list(modes)
    out["gate"] = _number(spec.get("gate", 3.5), source, "gate", positive=True)
    out["mac_gate"] = _number(spec.get("mac_gate", 0.8), source, "mac_gate", minimum=0.0)
    if out["mac_gate"] >= 1:
        _fail(source, "mac_gate", f"must be below 1, got {out['mac_gate']}")
    if "record_dt" in spec:
        out["record_dt"] = _number(spec["record_dt"], source, "record_dt", positive=True)
    return out


def build_modal_likelihood(modal: dict, names: tuple):
    """The :class:`~seqbayes.structural.modal_likelihood.ModalLikelihood` of a validated ``[modal]`` table."""
    from ..structural.modal_likelihood import ByAssignment, ByMode, Fixed, Learned, ModalLikelihood
    from ..structural.structures import ShearBuilding
    from ..structural.structures.linear import ModeLevel, ShearBuildingModel

    learned = [v for k, v in modal.items() if k in ("frequency_error", "shape_error") and isinstance(v, str)]
    n_model = len(names) - len(learned)
    if modal["model"] == "modes":
        model = ModeLevel(n_model)
    else:
        model = ShearBuildingModel(ShearBuilding(modal["masses"], modal["stiffnesses"]), modal["storeys"],
                                   modal.get("channels"))

    def error(value):
        if value is None:
            return None
        return Learned(list(names).index(value)) if isinstance(value, str) else Fixed(
            tuple(value) if isinstance(value, list) else value)

    pairing = ByAssignment() if modal["pairing"] == "assignment" else ByMode(
        tuple(modal["model_modes"]) if "model_modes" in modal else None)
    return ModalLikelihood(model, frequency_error=error(modal["frequency_error"]),
                           shape_error=error(modal.get("shape_error")), std_scale=modal["std_scale"], pairing=pairing)


def modal_columns(modal: dict) -> tuple:
    """The dataset columns of a modal run."""
    columns = ["mode", "frequency_hz", "std_frequency_hz"]
    if "shape_error" in modal:
        channels = modal.get("channels", [str(i + 1) for i in range(len(modal["masses"]))])
        columns += [f"phi_{c}" for c in channels] + [f"std_phi_{c}" for c in channels]
    return tuple(columns)


@dataclass(frozen=True)
class ModalRunConfig(RunConfig):
    """A :class:`~seqbayes.store.config.RunConfig` whose likelihood is the built-in modal one (module docstring).

    Attributes
    ----------
    modal : dict
        The validated ``[modal]`` table.
    """

    modal: dict = field(default_factory=dict)

    kind = RUN_KIND

    def build_likelihood(self):
        """The run's :class:`~seqbayes.structural.modal_likelihood.ModalLikelihood` (no user code)."""
        return build_modal_likelihood(self.modal, self.names)

    def load_likelihood(self):
        return self.build_likelihood()

    def to_dict(self) -> dict:
        return {**super().to_dict(), "modal": self.modal}

    @classmethod
    def from_dict(cls, data: dict, source: str = "stored configuration") -> ModalRunConfig:
        """Inverse of :meth:`to_dict`, validated as the TOML is."""
        if not isinstance(data, dict) or "modal" not in data:
            raise ConfigError(f"{source}: not a modal run configuration (no modal table)")
        data = dict(data)
        modal = data.pop("modal")
        base = RunConfig.from_dict(data, source)
        if base.likelihood != LIKELIHOOD or tuple(base.columns) != modal_columns(parse_modal(modal, base.names, source)):
            raise ConfigError(f"{source}: a modal run's likelihood and columns are the built-in ones")
        return cls(**{f.name: getattr(base, f.name) for f in dataclasses.fields(RunConfig)},
                   modal=parse_modal(modal, base.names, source))


def parse_modal_config(raw: dict, source: str = "<config>", base_dir=None) -> ModalRunConfig:
    """Validate a parsed TOML mapping with a ``[modal]`` table (module docstring).

    Raises
    ------
    ConfigError
        Naming the file and the field.
    """
    raw = dict(raw)
    model = dict(raw.get("model") or {})
    if model.get("likelihood", "modal") != "modal":
        raise ConfigError(f"{source}: model.likelihood: a configuration with a [modal] table uses the built-in "
                          f"likelihood: likelihood = \"modal\" (or leave it out), got {model.get('likelihood')!r}")
    if "data" in raw:
        raise ConfigError(f"{source}: [data]: a modal run's datasets are modes tables whose columns [modal] fixes; "
                          f"remove the [data] section")
    spec = raw.pop("modal")
    names = tuple(str(n) for n in (raw.get("priors") or {}))
    modal = parse_modal(spec, names, source) if names else None
    if modal is None:
        raise ConfigError(f"{source}: [priors]: at least one parameter is needed")
    model.setdefault("name", "modal")
    raw["model"] = {**model, "likelihood": LIKELIHOOD}
    raw["data"] = {"columns": list(modal_columns(modal)), "format": "columns"}
    base = parse_config(raw, source, base_dir=base_dir, check_likelihood=False)
    config = ModalRunConfig(**{f.name: getattr(base, f.name) for f in dataclasses.fields(RunConfig)}, modal=modal)
    # the run is checked now, as a user likelihood would be at init: the likelihood builds and predicts
    try:
        like = config.build_likelihood()
        like.predict(np.asarray(config.build_prior().sample(2, np.random.default_rng(0)), dtype=float))
    except (ValueError, TypeError) as err:
        raise ConfigError(f"{source}: [modal]: {err}") from None
    return dataclasses.replace(config, likelihood_sha256="", search_path=None)


SECTION_PARSERS["modal"] = parse_modal_config
