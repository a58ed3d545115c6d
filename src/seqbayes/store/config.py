"""Run configuration in TOML, validated with errors that name the field.

A run is described by one TOML file::

    [model]
    name = "bridge-drift"              # optional, shown in reports and comparisons
    likelihood = "mymodel:loglike"     # module:function; the module may sit next to this file
    predict = "predict"                # optional: a function of the same module, predict(theta, data)
                                       # -> (N, n_rows) model values of the observed column (report)
    observed = "y"                     # optional: that column (default: the last one)

    [data]
    columns = ["t", "y"]               # columns every data file must hold, in this order
    format = "array"                   # the likelihood gets an (n_rows, n_columns) array,
                                       # or "columns": a dict column -> (n_rows,) array
    rows = 50                          # optional: exact number of rows per dataset

    [priors]                           # one entry per parameter, in order: scipy.stats name
    k = { dist = "uniform", loc = 0.5, scale = 1.5 }     # and its parameters (args and/or keywords)
    c = { dist = "lognorm", args = [0.5], scale = 0.1 }

    [kernel]                           # evolution of each parameter between datasets
    k = { type = "drift", rate = -0.05, noise_std = 0.02 }   # k_{s+1} = k_s - 0.05 + nu
    c = { type = "static" }            # parameters not listed are static
    # also: { type = "decay", rate = 0.1, noise_std = 0.01 }  (x_{s+1} = exp(-rate) x_s + nu)
    # sudden damage: the base's drift/decay with prob 1 - p, a drop by f * reference with
    # f ~ N(drop_mean, drop_sd^2) with prob p (tail = "heavy": a scale mixture; docs/jump_kernels.md)
    # { type = "jump", base = "decay", rate = 0.02, noise_std = 0.02, p = 0.05,
    #   drop_mean = 0.3, drop_sd = 0.1, reference = 3.0 }

    [sampler]
    type = "SEMC"                      # or "SMC"
    n_samples = 500
    seed = 2024
    # any flat setting of seqbayes.engine.settings.FLAT (mapped onto the sampler's components):
    # tempering, resampling, target_acceptance, step_size, remedy_lag, ...

    [parallel]                         # optional
    executor = "serial"                # "serial", "processes" or "dask"
    workers = 2
    address = "tcp://scheduler:8786"   # dask only; without it a local cluster is started

The likelihood is called as ``loglike(theta (N, d), data) -> (N,)``. Everything
here is validated by :func:`load_config` / :func:`parse_config`; a mistake
raises :class:`ConfigError` with a message such as
``run.toml: priors.k.dist: unknown scipy.stats distribution 'unifrom'``.
"""

from __future__ import annotations

import difflib
import importlib.util
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .schema import StoredConfig, check_keys, fail, number, table
from .modules import (ConfigError, ModuleSource, split_likelihood, file_sha256, load_likelihood, load_located,
                      locate_module, read_toml)

__all__ = ["ConfigError", "RunConfig", "load_config", "parse_config", "load_likelihood", "locate_module",
           "load_located", "ModuleSource", "file_sha256"]

KERNEL_TYPES = {"static": (), "drift": ("rate",), "decay": ("rate",),
                "jump": ("base", "rate", "p", "drop_mean", "drop_sd", "reference")}
#: Optional settings of a jump kernel entry (``tail``: "gaussian" or "heavy"; or explicit ``scales``).
JUMP_OPTIONAL = ("tail", "scales", "scale_weights")
EXECUTORS = ("serial", "processes", "dask")
#: Top-level table -> ``parse(raw, source, base_dir=...)`` of the configurations it marks, registered by the
#: configuration module of a run kind that subclasses RunConfig (``"modal"``: seqbayes.store.modal_config)
SECTION_PARSERS: dict = {}
#: RunConfig fields that do not define the model (not in :meth:`RunConfig.fingerprint`).
NOT_FINGERPRINTED = ("name", "search_path", "executor", "workers", "address", "likelihood_file",
                     "likelihood_sha256", "predict", "observed")


@dataclass(frozen=True)
class RunConfig(StoredConfig):
    """A validated run configuration (see the module docstring for the TOML layout).

    Attributes
    ----------
    name : str
        Model name for reports and comparisons.
    likelihood : str
        ``"module:function"``.
    search_path : str or None
        Folder searched first when importing the likelihood's module (the config's folder).
    columns : tuple of str
        Data columns, in the order given to the likelihood.
    data_format : {"array", "columns"}
    rows : int or None
        Required number of rows per dataset.
    priors : dict
        ``name -> {"dist": str, "args": list, "kwds": dict}`` in parameter order.
    kernel : dict
        ``name -> {"type": str, "rate": float, "noise_std": float}`` for every parameter.
    sampler : {"SEMC", "SMC"}
    n_samples : int
    seed : int
    settings : dict
        Further sampler settings, flat (:data:`seqbayes.engine.settings.FLAT`: each maps onto a field of one of
        the sampler's components, :func:`~seqbayes.engine.settings.from_flat`).
    executor : {"serial", "processes", "dask"}
    workers : int
    address : str or None
    likelihood_file : str or None
        The likelihood module's file when the config was loaded (absolute path).
    likelihood_sha256 : str or None
        SHA-256 of that file's content (see :class:`ModuleSource`): a run store
        runs the module only while the file still has this content.
    predict : str or None
        Name of a function in the likelihood's module, ``predict(theta (N, d), data) -> (N, n_rows)``:
        the model's values of the ``observed`` column, for the report's data-versus-fit panel.
    observed : str or None
        The data column ``predict`` models (``None``: the last column).
    """

    name: str
    likelihood: str
    columns: tuple
    priors: dict
    kernel: dict
    sampler: str = "SEMC"
    n_samples: int = 1000
    seed: int = 0
    settings: dict = field(default_factory=dict)
    data_format: str = "array"
    rows: int | None = None
    search_path: str | None = None
    executor: str = "serial"
    workers: int = 2
    address: str | None = None
    likelihood_file: str | None = None
    likelihood_sha256: str | None = None
    predict: str | None = None
    observed: str | None = None

    #: the run kind (:mod:`seqbayes.store.registry`): an SMC/SEMC run
    kind = "semc"
    unfingerprinted = NOT_FINGERPRINTED

    # ------------------------------------------------------------------ builders
    @property
    def names(self) -> tuple:
        """Parameter names, in order."""
        return tuple(self.priors)

    def build_prior(self) -> JointPrior:
        """The :class:`~seqbayes.priors.JointPrior`."""
        from ..priors import JointPrior

        return JointPrior({name: _freeze(spec, "<config>", f"priors.{name}") for name, spec in self.priors.items()})

    def build_kernel(self) -> MarkovKernel:
        """The :class:`~seqbayes.kernels.MarkovKernel`, one component per parameter."""
        from ..kernels import Decay, Drift, Jump, MarkovKernel, Static

        parts = []
        for name in self.names:
            spec = self.kernel[name]
            kind = spec["base"] if spec["type"] == "jump" else spec["type"]
            if kind == "static":
                part = Static()
            else:
                part = (Drift if kind == "drift" else Decay)(spec["rate"], noise_std=spec["noise_std"])
            if spec["type"] == "jump":
                part = Jump(part, spec["p"], spec["drop_mean"], spec["drop_sd"], spec["reference"],
                            tuple(spec["scales"]), tuple(spec["scale_weights"]))
            parts.append(part)
        return MarkovKernel(parts)

    @property
    def predictive_method(self) -> str:
        """The sampler's predictive prior, ``"auto"`` resolved (``"history"`` for static kernels).

        Raises
        ------
        ValueError
            ``predictive = "history"`` with a kernel that is not static.
        """
        from ..engine.settings import from_flat
        from ..predictive.base import resolve_predictive

        return resolve_predictive(from_flat(self.sampler, **self.settings)["predictive"], self.build_kernel()).method

    def locate_likelihood(self) -> "ModuleSource":
        """The likelihood's module (:class:`ModuleSource`), found in :attr:`search_path` or on ``sys.path``."""
        return locate_module(split_likelihood(self.likelihood)[0], self.search_path)

    def load_likelihood(self) -> Callable[[np.ndarray, Any], np.ndarray]:
        """Import and return the likelihood function (a config is trusted like code)."""
        return load_likelihood(self.likelihood, self.search_path)

    def build_sampler(self, executor: Any = None,
                      loglike: Callable[[np.ndarray, Any], np.ndarray] | None = None) -> SEMC | SMC:
        """A fresh :class:`~seqbayes.SEMC` or :class:`~seqbayes.SMC` for this configuration.

        Parameters
        ----------
        executor : object with ``map``, optional
            Passed to the sampler (see :mod:`seqbayes.parallel`).
        loglike : callable, optional
            Overrides the configured likelihood (e.g. a wrapper counting evaluations).
        """
        from ..engine.drivers import SEMC, SMC
        from ..engine.settings import from_flat

        cls = SEMC if self.sampler == "SEMC" else SMC
        loglike = self.load_likelihood() if loglike is None else loglike
        return cls(self.build_prior(), self.build_kernel(), loglike, n_samples=self.n_samples, rng=self.seed,
                   executor=executor, **from_flat(self.sampler, **self.settings))

    # ------------------------------------------------------------- persistence
    def to_dict(self) -> dict:
        """Plain JSON-able dict (stored in the run store)."""
        return {"name": self.name, "likelihood": self.likelihood, "columns": list(self.columns),
                "priors": self.priors, "kernel": self.kernel, "sampler": self.sampler,
                "n_samples": self.n_samples, "seed": self.seed, "settings": self.settings,
                "data_format": self.data_format, "rows": self.rows, "search_path": self.search_path,
                "executor": self.executor, "workers": self.workers, "address": self.address,
                "likelihood_file": self.likelihood_file, "likelihood_sha256": self.likelihood_sha256,
                "predict": self.predict, "observed": self.observed}

    @classmethod
    def from_dict(cls, data: dict, source: str = "stored configuration") -> "RunConfig":
        """Inverse of :meth:`to_dict`, validated as a TOML file is (a store is a file someone was handed:
        ``tempering = "false"`` or a negative noise sd in it is refused, not run).

        Raises
        ------
        ConfigError
            Naming ``source`` and the field.
        """
        if not isinstance(data, dict) or set(data) - set(cls.__dataclass_fields__) or "priors" not in data:
            raise ConfigError(f"{source}: not a run configuration")
        parse_config(_as_toml(data, source), source, check_likelihood=False)
        data = dict(data)
        data["columns"] = tuple(data["columns"])
        return cls(**data)

    def make_executor(self) -> tuple[Any, Callable[[], None]]:
        """``(executor, close)`` for the ``[parallel]`` section (:func:`seqbayes.parallel.make_executor`)."""
        from ..parallel import make_executor

        return make_executor(self.executor, self.workers, self.address)


# ---------------------------------------------------------------------- priors
def _freeze(spec, source, prefix):
    from scipy import stats

    dist = getattr(stats, spec["dist"], None)
    if dist is None or not isinstance(dist, (stats.rv_continuous, stats.rv_discrete)):
        fail(source, f"{prefix}.dist", f"unknown scipy.stats distribution {spec['dist']!r}")
    if isinstance(dist, stats.rv_discrete):
        fail(source, f"{prefix}.dist", f"{spec['dist']!r} is discrete; parameters need a continuous distribution")
    try:
        frozen = dist(*spec["args"], **spec["kwds"])
        frozen.logpdf(frozen.mean() if np.isfinite(frozen.mean()) else frozen.median())
    except Exception as err:  # scipy raises TypeError / ValueError with its own wording
        fail(source, prefix, f"scipy.stats.{spec['dist']}(args={spec['args']}, {spec['kwds']}) failed: {err}")
    if not np.isfinite(frozen.logpdf(frozen.median())):
        fail(source, prefix, f"invalid parameters for scipy.stats.{spec['dist']}: args={spec['args']}, "
                              f"{spec['kwds']}")
    return frozen


def _parse_prior(name, raw, source):
    prefix = f"priors.{name}"
    if not isinstance(raw, dict):
        fail(source, prefix, f"expected a table like {{ dist = \"norm\", loc = 0, scale = 1 }}, got {raw!r}")
    if "dist" not in raw:
        fail(source, f"{prefix}.dist", "missing (a scipy.stats distribution name such as \"uniform\")")
    if not isinstance(raw["dist"], str):
        fail(source, f"{prefix}.dist", f"expected a string, got {raw['dist']!r}")
    args = raw.get("args", [])
    if not isinstance(args, list):
        fail(source, f"{prefix}.args", f"expected a list of numbers, got {args!r}")
    args = [number(a, source, f"{prefix}.args[{i}]") for i, a in enumerate(args)]
    kwds = {k: number(v, source, f"{prefix}.{k}") for k, v in raw.items() if k not in ("dist", "args")}
    if raw["dist"] == "uniform" and {"lower", "upper"} & set(kwds):
        kwds = _uniform_bounds(kwds, args, source, prefix)
    _check_prior_keywords(raw["dist"], kwds, len(args), source, prefix)
    spec = {"dist": raw["dist"], "args": args, "kwds": kwds}
    _freeze(spec, source, prefix)
    return spec


def _uniform_bounds(kwds, args, source, prefix):
    """``lower``/``upper`` of a uniform prior as scipy's ``loc``/``scale`` (stored so: the fingerprint of
    ``U(0, 2)`` does not depend on how it was written)."""
    if set(kwds) != {"lower", "upper"} or args:
        fail(source, prefix, "a uniform prior takes lower and upper together, or loc and scale; not a mix")
    if not kwds["lower"] < kwds["upper"]:
        fail(source, f"{prefix}.upper", f"must be above lower = {kwds['lower']:g}, got {kwds['upper']:g}")
    return {"loc": kwds["lower"], "scale": kwds["upper"] - kwds["lower"]}


def _check_prior_keywords(dist_name, kwds, n_args, source, prefix):
    """Refuse keywords the scipy.stats distribution does not take, naming the ones it does (scipy's own
    message is ``_parse_args() got an unexpected keyword argument``)."""
    from scipy import stats

    dist = getattr(stats, dist_name, None)
    if not isinstance(dist, stats.rv_continuous):
        return                                  # named by _freeze
    shapes = [p.strip() for p in (dist.shapes or "").split(",") if p.strip()]
    takes = [*shapes, "loc", "scale"] + (["lower", "upper"] if dist_name == "uniform" else [])
    for key in kwds:
        if key not in takes:
            close = difflib.get_close_matches(key, takes, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            fail(source, f"{prefix}.{key}", f"scipy.stats.{dist_name} has no parameter {key!r}{hint}; it takes "
                                             f"{', '.join(takes)} (shape parameters also as args = [...])")
    given = [*shapes, "loc", "scale"][:n_args]
    twice = [key for key in kwds if key in given]
    if twice:
        fail(source, f"{prefix}.{twice[0]}", "given both in args and as a keyword")


def _memory_bound(n_samples, dim, source):
    """Refuse a sample size whose arrays cannot fit in this machine's memory (numpy's MemoryError
    would come mid-step, as a traceback). About 32 arrays of ``(N, d + 2)`` float64 are alive during a
    step (particles, proposals, their log-densities, the tempering and mixture buffers)."""
    need = 32 * n_samples * (dim + 2) * 8
    try:
        have = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, ValueError, OSError):  # not POSIX: no bound known
        return
    if need > have:
        fail(source, "sampler.n_samples", f"{n_samples} samples of {dim} parameters need about "
                                           f"{need / 2**30:.3g} GiB of memory; this machine has {have / 2**30:.3g} GiB")


def _typed_setting(key, value, source):
    """A ``[sampler]`` setting checked against its type (:data:`seqbayes.engine.settings.FLAT`).

    ``tempering = "false"`` (a string, which Python would take as true) or ``max_stages = 10.5``
    are refused rather than silently reinterpreted.
    """
    from ..engine.settings import FLAT

    kind = FLAT[key][2]
    name = f"sampler.{key}"
    if kind == "bool":
        if not isinstance(value, bool):
            fail(source, name, f"expected true or false, got {value!r}")
        return value
    if kind in ("int", "float"):  # checked, but kept as written: the stored config (and fingerprint) stay the same
        number(value, source, name, integer=kind == "int")
    if kind == "str" and not isinstance(value, str):
        fail(source, name, f"expected a string, got {value!r}")
    return value


def _parse_kernel(name, raw, source):
    prefix = f"kernel.{name}"
    if not isinstance(raw, dict):
        fail(source, prefix, f"expected a table like {{ type = \"drift\", rate = -0.1, noise_std = 0.05 }}, "
                              f"got {raw!r}")
    kind = raw.get("type")
    if kind not in KERNEL_TYPES:
        fail(source, f"{prefix}.type", f"expected one of {', '.join(KERNEL_TYPES)}, got {kind!r}")
    allowed = {"type", "noise_std", *KERNEL_TYPES[kind], *(JUMP_OPTIONAL if kind == "jump" else ())}
    check_keys(raw, allowed, source, prefix)
    for key in KERNEL_TYPES[kind]:
        if key not in raw:
            fail(source, f"{prefix}.{key}", f"missing (required for type = \"{kind}\")")
    noise = number(raw.get("noise_std", 0.0), source, f"{prefix}.noise_std")
    if noise < 0:
        fail(source, f"{prefix}.noise_std", f"must be >= 0, got {noise}")
    if kind == "static" and noise != 0:
        fail(source, f"{prefix}.noise_std", "a static parameter has no process noise; use type = \"drift\" "
                                             "with rate = 0 for a random walk")
    rate = number(raw["rate"], source, f"{prefix}.rate") if "rate" in raw else 0.0
    if kind == "jump":
        return _parse_jump(prefix, raw, rate, noise, source)
    return {"type": kind, "rate": rate, "noise_std": noise}


def _parse_jump(prefix, raw, rate, noise, source):
    """A ``type = "jump"`` entry (:class:`~seqbayes.kernels.Jump`): its base, spike noise and slab."""
    from ..kernels import HEAVY_TAIL_SCALES, HEAVY_TAIL_WEIGHTS

    if raw["base"] not in ("drift", "decay"):
        fail(source, f"{prefix}.base", f"expected \"drift\" or \"decay\" (the no-jump evolution), got {raw['base']!r}")
    if noise <= 0:
        fail(source, f"{prefix}.noise_std", "a jump kernel needs the base's noise_std > 0 (the no-jump branch "
                                             "is a Gaussian)")
    p = number(raw["p"], source, f"{prefix}.p")
    if not 0.0 < p < 1.0:
        fail(source, f"{prefix}.p", f"the jump probability must lie in (0, 1), got {p}")
    drop_mean = number(raw["drop_mean"], source, f"{prefix}.drop_mean")
    drop_sd = number(raw["drop_sd"], source, f"{prefix}.drop_sd", positive=True)
    reference = number(raw["reference"], source, f"{prefix}.reference", positive=True)
    tail = raw.get("tail", "gaussian")
    if tail not in ("gaussian", "heavy"):
        fail(source, f"{prefix}.tail", f"expected \"gaussian\" or \"heavy\", got {tail!r}")
    if ("scales" in raw) != ("scale_weights" in raw) or ("scales" in raw and "tail" in raw):
        fail(source, f"{prefix}.scales", "give scales and scale_weights together, and not with tail")
    if "scales" in raw:
        lists = {}
        for key in ("scales", "scale_weights"):
            value = raw[key]
            if not isinstance(value, list) or not value:
                fail(source, f"{prefix}.{key}", f"expected a non-empty list of positive numbers, got {value!r}")
            lists[key] = [number(v, source, f"{prefix}.{key}", positive=True) for v in value]
        if len(lists["scales"]) != len(lists["scale_weights"]):
            fail(source, f"{prefix}.scale_weights", f"expected {len(lists['scales'])} weights (one per scale), "
                                                     f"got {len(lists['scale_weights'])}")
        scales, weights = lists["scales"], lists["scale_weights"]
    else:
        scales, weights = (list(HEAVY_TAIL_SCALES), list(HEAVY_TAIL_WEIGHTS)) if tail == "heavy" else ([1.0], [1.0])
    return {"type": "jump", "base": raw["base"], "rate": rate, "noise_std": noise, "p": p, "drop_mean": drop_mean,
            "drop_sd": drop_sd, "reference": reference, "scales": scales, "scale_weights": weights}


def _as_toml(data, source) -> dict:
    """A stored configuration (:meth:`RunConfig.to_dict`) back in the TOML layout that :func:`parse_config` checks."""
    try:
        model = {"name": data.get("name"), "likelihood": data.get("likelihood"),
                 **{k: data[k] for k in ("predict", "observed") if data.get(k) is not None}}
        table = {"columns": data.get("columns"), "format": data.get("data_format", "array"),
                 **({"rows": data["rows"]} if data.get("rows") is not None else {})}
        priors = {name: {"dist": spec["dist"], "args": spec["args"], **spec["kwds"]}
                  for name, spec in data["priors"].items()}
        kernel = {}
        for name, spec in (data.get("kernel") or {}).items():
            entry = dict(spec)
            if entry.get("type") == "static":  # stored with rate 0 and noise_std 0, written without them
                entry = {"type": "static", **{k: v for k, v in entry.items() if k != "type" and v != 0}}
            kernel[name] = entry
        sampler = {"type": data.get("sampler"), "n_samples": data.get("n_samples"), "seed": data.get("seed"),
                   **data.get("settings", {})}
        parallel = {"executor": data.get("executor", "serial"), "workers": data.get("workers", 2),
                    **({"address": data["address"]} if data.get("address") is not None else {})}
    except (AttributeError, KeyError, TypeError) as err:
        raise ConfigError(f"{source}: malformed ({type(err).__name__}: {err})") from None
    return {"model": model, "data": table, "priors": priors, "kernel": kernel, "sampler": sampler,
            "parallel": parallel}


# ---------------------------------------------------------------------- parsing
def parse_config(raw: dict, source: str = "<config>", base_dir: str | Path | None = None,
                 check_likelihood: bool = True) -> RunConfig:
    """Validate a parsed TOML mapping and return a :class:`RunConfig`.

    Parameters
    ----------
    raw : dict
        As returned by :func:`tomllib.load`.
    source : str
        File name used in error messages.
    base_dir : path, optional
        Folder searched first for the likelihood's module.
    check_likelihood : bool
        Import the likelihood now (default), so that a typo fails at ``init``.
    """
    check_keys(raw, {"model", "data", "priors", "kernel", "sampler", "parallel"}, source, "<top level>")
    model = table(raw, "model", source)
    check_keys(model, {"name", "likelihood", "predict", "observed"}, source, "model")
    if "likelihood" not in model:
        fail(source, "model.likelihood", "missing (\"module:function\")")
    likelihood = model["likelihood"]
    if not isinstance(likelihood, str) or likelihood.count(":") != 1 or not all(likelihood.split(":")):
        fail(source, "model.likelihood", f"expected \"module:function\", got {likelihood!r}")
    name = model.get("name", likelihood.split(":")[1])
    if not isinstance(name, str) or not name:
        fail(source, "model.name", f"expected a non-empty string, got {name!r}")

    data = table(raw, "data", source)
    check_keys(data, {"columns", "format", "rows"}, source, "data")
    columns = data.get("columns")
    if (not isinstance(columns, list) or not columns or not all(isinstance(c, str) and c for c in columns)):
        fail(source, "data.columns", f"expected a non-empty list of column names, got {columns!r}")
    if len(set(columns)) != len(columns):
        fail(source, "data.columns", f"duplicate column names in {columns}")
    data_format = data.get("format", "array")
    if data_format not in ("array", "columns"):
        fail(source, "data.format", f"expected \"array\" or \"columns\", got {data_format!r}")
    rows = data.get("rows")
    if rows is not None:
        rows = number(rows, source, "data.rows", integer=True, positive=True)

    priors_raw = table(raw, "priors", source)
    if not priors_raw:
        fail(source, "[priors]", "at least one parameter is needed")
    priors = {str(n): _parse_prior(n, spec, source) for n, spec in priors_raw.items()}

    kernel_raw = table(raw, "kernel", source, required=False)
    for n in kernel_raw:
        if n not in priors:
            fail(source, f"kernel.{n}", f"not a parameter; the priors define {', '.join(priors)}")
    kernel = {n: _parse_kernel(n, kernel_raw[n], source) if n in kernel_raw
              else {"type": "static", "rate": 0.0, "noise_std": 0.0} for n in priors}

    sampler_raw = dict(table(raw, "sampler", source, required=False))
    kind = sampler_raw.pop("type", "SEMC")
    if kind not in ("SEMC", "SMC"):
        fail(source, "sampler.type", f"expected \"SEMC\" or \"SMC\", got {kind!r}")
    from ..engine.settings import SamplerConfig, flat_names, from_flat

    allowed = flat_names(kind)
    n_samples = number(sampler_raw.pop("n_samples", 1000), source, "sampler.n_samples", integer=True,
                        positive=True)
    seed = number(sampler_raw.pop("seed", 0), source, "sampler.seed", integer=True)
    if seed < 0:
        fail(source, "sampler.seed", f"must be >= 0, got {seed}")
    check_keys(sampler_raw, {*allowed, "type", "n_samples", "seed"}, source, "sampler")
    settings = {key: _typed_setting(key, value, source) for key, value in sampler_raw.items()}
    try:  # the components validate the values, naming the field
        SamplerConfig(n_samples, **from_flat(kind, **settings))
    except (TypeError, ValueError) as err:
        fail(source, "sampler", str(err))
    if kind == "SEMC" and n_samples < 2 * len(priors):
        fail(source, "sampler.n_samples", f"SEMC needs at least 2 d = {2 * len(priors)} samples, got {n_samples}")
    _memory_bound(n_samples, len(priors), source)

    parallel = table(raw, "parallel", source, required=False)
    check_keys(parallel, {"executor", "workers", "address"}, source, "parallel")
    executor = parallel.get("executor", "serial")
    if executor not in EXECUTORS:
        fail(source, "parallel.executor", f"expected one of {', '.join(EXECUTORS)}, got {executor!r}")
    if executor == "dask" and check_likelihood and importlib.util.find_spec("distributed") is None:
        fail(source, "parallel.executor", "\"dask\" needs the optional dependency dask.distributed, which is "
                                           "not installed: pip install \"seqbayes[dask]\" (or use \"processes\")")
    workers = number(parallel.get("workers", 2), source, "parallel.workers", integer=True, positive=True)
    address = parallel.get("address")
    if address is not None and not isinstance(address, str):
        fail(source, "parallel.address", f"expected a string, got {address!r}")

    predict = model.get("predict")
    if predict is not None and (not isinstance(predict, str) or not predict.isidentifier()):
        fail(source, "model.predict", f"expected the name of a function in the likelihood's module, got {predict!r}")
    observed = model.get("observed")
    if observed is not None and observed not in columns:
        fail(source, "model.observed", f"expected one of the data columns {columns}, got {observed!r}")

    config = RunConfig(name=name, likelihood=likelihood, columns=tuple(columns), priors=priors, kernel=kernel,
                       sampler=kind, n_samples=n_samples, seed=seed, settings=settings, data_format=data_format,
                       rows=rows, search_path=str(Path(base_dir).resolve()) if base_dir is not None else None,
                       executor=executor, workers=workers, address=address, predict=predict, observed=observed)
    try:  # a history prior needs every parameter static
        config.predictive_method
    except ValueError as err:
        fail(source, "sampler.predictive", str(err))
    if check_likelihood:
        try:
            located = config.locate_likelihood()
            load_located(likelihood, located)
            if predict is not None:
                try:
                    load_located(f"{likelihood.split(':')[0]}:{predict}", located)
                except ConfigError as err:
                    raise ConfigError(str(err).replace("model.likelihood:", "model.predict:", 1)) from None
        except ConfigError as err:
            raise ConfigError(f"{source}: {err}") from None
        config = replace(config, likelihood_file=located.file, likelihood_sha256=located.sha256)
    return config


def load_config(path: str | os.PathLike, check_likelihood: bool = True) -> RunConfig:
    """Read and validate a TOML run configuration (the likelihood's module may sit next to it).

    A configuration with a ``[building]`` section is an SG-EnMCMC run: it is validated by
    :func:`seqbayes.store.sg_config.parse_sg_config` and returned as a :class:`~seqbayes.store.sg_config.SGRunConfig`;
    one with a table named in :data:`SECTION_PARSERS` by that table's parser (``[modal]``: a modal run,
    :func:`seqbayes.store.modal_config.parse_modal_config`).
    """
    path = Path(path)
    raw = read_toml(path)
    if "building" in raw:  # a shear building identified by SG-EnMCMC (seqbayes.store.sg_config)
        from .sg_config import parse_sg_config

        return parse_sg_config(raw, str(path), base_dir=path.parent)
    for section, parse in SECTION_PARSERS.items():   # e.g. [modal]: seqbayes.store.modal_config
        if section in raw:
            return parse(raw, str(path), base_dir=path.parent)
    return parse_config(raw, str(path), base_dir=path.parent, check_likelihood=check_likelihood)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable
    from typing import Any

    from ..kernels import MarkovKernel
    from ..priors import JointPrior
    from ..engine.drivers import SEMC, SMC
