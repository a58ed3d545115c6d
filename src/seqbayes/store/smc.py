"""The SMC/SEMC run store: a monitoring run on disk that resumes exactly where it stopped.

One run is one NetCDF-4 file (the locks, the journal and the atomic writes are
:mod:`seqbayes.store.files`; the hashes, open, append and whole writes :mod:`seqbayes.store.base`).
After every completed step it holds the whole
sampler state: the posterior and predictive samples of every step with their
weights and diagnostics (the :class:`~seqbayes.results.Result` layout), the
arrays the sampler needs to resume (:mod:`seqbayes.store.snapshot`: the next step's prior
density, or the values and datasets it re-evaluates), the stretch-move step size,
the cumulative log-evidence, the random generator's state after each step, the initial
prior draws, the validated configuration (prior, kernel, likelihood ``module:function``,
sampler settings), a format version, a model fingerprint and a content hash of every
assimilated dataset. A new process that opens the store and assimilates the next
dataset gives bit-for-bit the numbers of an uninterrupted run with the same seed,
because the sampler is rebuilt from the stored configuration and then
:meth:`~seqbayes.engine.drivers.SEMC.restore`-d to the stored state and generator. The
store does not know what the sampler's state is made of: :func:`seqbayes.store.snapshot.state_arrays`
turns it into named arrays, which the store writes per step, and
:func:`seqbayes.store.snapshot.state_from_arrays` turns them back.

Keeping every step's state (not only the last) allows :meth:`RunStore.assimilate` with
``replace_last=True``: the run is rolled back to the step before and the new dataset
assimilated in its place (the file is then written whole). Every read-modify-write
(:meth:`RunStore.assimilate`, :meth:`RunStore.write`) holds an exclusive lock on
``RUN.lock``; an object that opened the store before another process stored a step
takes that step in first, so concurrent updates are all kept.

Trust: a store is trusted like code (it names the module the likelihood comes
from), but runs only a module file whose SHA-256 it recorded
(:meth:`RunStore.load_likelihood`), imported by file path without touching
``sys.path``; opening, ``predict`` and reports run no user code. The numeric
arrays carry HDF5 Fletcher-32 checksums, verified as they are read. The text records
of each step (its :class:`~seqbayes.results.StepInfo`, generator state, dataset and module
hashes, file name) have a SHA-256 (``record_sha256``), and the configuration and those
per-step hashes a SHA-256 (``content_sha256``), all verified by :meth:`RunStore.open`,
which also refuses NaN samples and missing or inconsistent variables; a step appended
hashes only its own records.

Layout: ``posterior``, ``predictive`` ``(step, sample, parameter)``, ``log_weights``
``(step, sample)``, the state arrays of :mod:`seqbayes.store.snapshot` (e.g.
``mixture_centres (step, sample, parameter)``), with ``dataset_values (dataset_row, column)``
and ``dataset_rows (step)`` when the state needs the datasets,
``diagnostics (step, diagnostic)`` (acceptance, ESS, evidence, ... as float64 for
any NetCDF reader), ``step_info`` (the exact :class:`~seqbayes.results.StepInfo`
as JSON), ``dataset_sha256``, ``dataset_source``, ``likelihood_sha256``, ``record_sha256``,
``state_step_size``, ``initial_particles``, ``initial_log_weights``, ``rng_state (rng_index)``,
for SMC^2 its full state of the last two steps only (``nested_full_* (slot, ...)``, ``nested_slot_step``);
attributes ``config`` (with the likelihood module's file and hash), ``model_fingerprint``,
``content_sha256``, ``seqbayes_store_format``. The growing dimensions (``step``,
``rng_index``, ``dataset_row``) are unlimited, in chunks of a few steps. Few variables keep
a write fast (HDF5 pays per variable).

Why NetCDF (HDF5 underneath, written through h5netcdf, appended and read through h5py):
the content is a set of labelled float64 arrays ``(step, sample, parameter)`` plus small
metadata, which is exactly NetCDF's model; float64 values round-trip bit for bit (needed
for exact resumption); the file is self-describing and readable without
seqbayes (``xarray.open_dataset``, ``ncdump``, MATLAB, R), which matters for a
monitoring record kept for years; xarray and h5netcdf are already required by
:meth:`seqbayes.Result.to_netcdf`, so no new dependency. Pickle was rejected
(tied to code versions, unsafe to load), a folder of ``.npy`` files
(no atomic multi-file update), SQLite/Zarr (an extra dependency for no gain at
these sizes: N = 1000, d = 4, 100 steps is about 10 MB).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import shutil
import warnings
from dataclasses import replace as _replace
from pathlib import Path

import numpy as np

from ..predictive.smc2 import nested_record_moments
from ..prognostics import FirstPassage, time_to_threshold
from ..results import Result, StepInfo, StepRecord
from ..rng import generator_from_state
from . import snapshot
from .base import HASHED_ATTRS, RECORD_TEXT, BaseStore, Provenance, check_finite, json_value, json_values
from .config import RunConfig
from .datasets import as_likelihood_data, check_table, dataset_digest
from .errors import BoundWarning, ModelChangedError, StoreError, StoreWarning
from .modules import ConfigError, ModuleSource, load_located, locate_module
from .registry import register

__all__ = ["RunStore", "FORMAT_VERSION", "posterior_to_arviz", "content_hash_v3"]

#: Version of the on-disk layout; a store of another version is refused. Version 2 added the
#: history prior of static kernels, version 3 the likelihood module's hash per step, the
#: content hash of the text variables and HDF5 checksums, version 4 the per-step record
#: hashes (so that an appended step hashes only its own records), version 5 SMC^2's full state for the
#: last two steps only (``nested_full_*``), not for every step. Versions 1 to 4 are still read; the next
#: update rewrites them in version 5.
FORMAT_VERSION = 5
#: SMC^2's full state (all but :data:`~seqbayes.store.snapshot.NESTED_PER_STEP`) is kept for the last two steps
#: only, in two slots (step ``k`` in slot ``(k - 1) % 2``): ``nested_full_<name> (slot, ...)`` and the step each
#: slot holds, ``nested_slot_step (slot)`` (0: none). An append rewrites the slot of its step in place.
_FULL = "nested_full_"
_SLOT_STEP = "nested_slot_step"


def content_hash_v3(attrs: dict, variables: dict) -> str:
    """The content hash of format 3 stores (all text records hashed together), to verify them on open."""
    h = hashlib.sha256()
    for key in HASHED_ATTRS:
        h.update(json.dumps([key, str(attrs.get(key))]).encode())
    for name in RECORD_TEXT:
        if name in variables:
            h.update(json.dumps([name, [str(v) for v in variables[name]]]).encode())
    return h.hexdigest()


@register("semc")
class RunStore(BaseStore):
    """A persistent on-line run (one NetCDF file); see the module docstring.

    Create one with :meth:`create`, open it with :meth:`open`, assimilate data
    with :meth:`update` (a file) or :meth:`assimilate` (an array).

    Attributes
    ----------
    path : pathlib.Path
    config : RunConfig
    result : Result
        Every completed step.
    states : list of dict
        Per step, the sampler's state arrays (:func:`seqbayes.store.snapshot.state_arrays`).
    tables : list of (n_rows, n_columns) arrays
        The assimilated datasets, kept when the state needs them (:func:`seqbayes.store.snapshot.needs_datasets`).
    digests : list of str
        SHA-256 of each assimilated dataset's content.
    sources : list of str
        File name of each assimilated dataset.

    Examples
    --------
    >>> store = RunStore.create("bridge.nc", load_config("run.toml"))   # doctest: +SKIP
    >>> store.update("month1.csv").log_evidence                         # doctest: +SKIP
    """

    title = "SEMC/SMC"
    format_version = FORMAT_VERSION
    readable_versions = (1, 2, 3, 4, 5)
    growing = {"step": 8, "rng_index": 8, "dataset_row": 256, **{f"{name}_row": 8 for name in snapshot.RAGGED}}
    operations = frozenset({"predict", "compare", "replace_last", "report --compare", "report --threshold",
                            "report --data"})
    evaluates_likelihood = True
    #: the configuration class a stored run is read back as (a subclass's: seqbayes.store.modal)
    config_type = RunConfig

    def __init__(self, path, config: RunConfig, provenance: Provenance, *, initial_particles, initial_log_weights,
                 initial_step_size, result: Result, states, step_sizes, tables=(), module_hashes=None):
        super().__init__(path, config, provenance)
        self.initial_particles = initial_particles
        self.initial_log_weights = initial_log_weights
        self.initial_step_size = float(initial_step_size)
        self.result = result
        self.states = list(states)                  # S dicts of state arrays (seqbayes.store.snapshot)
        self.tables = list(tables)                  # the S datasets, when the state needs them
        self.step_sizes = list(step_sizes)          # S state step sizes
        # SHA-256 of the likelihood module each step ran ("" for steps written before they were recorded)
        self.module_hashes = list(module_hashes) if module_hashes is not None else [""] * len(self.digests)

    # ----------------------------------------------------------------- creation
    @classmethod
    def _new(cls, path: Path, config: RunConfig) -> "RunStore":
        """A new run: the initial prior samples drawn (this runs no user code).

        The likelihood's module is located (not run) and its file and SHA-256 recorded,
        unless ``config`` already records them (:func:`~seqbayes.store.config.load_config` does).
        """
        if config.likelihood_sha256 is None:
            located = config.locate_likelihood()
            config = _replace(config, likelihood_file=located.file, likelihood_sha256=located.sha256)
        sampler = config.build_sampler(loglike=_likelihood_not_needed)  # drawing the prior runs no user code
        state, records, rng_state = sampler.snapshot()
        return cls(path, config, Provenance([rng_state]), initial_particles=np.array(state.particles),
                   initial_log_weights=np.array(state.log_weights), initial_step_size=state.step_size,
                   result=Result(sampler.names, (), {}), states=[], step_sizes=[])

    # ------------------------------------------------------------------ reading
    @classmethod
    def _from_file(cls, path: Path, attrs: dict, variables: dict, config: RunConfig | None,
                   version: int) -> "RunStore":
        n_steps = int(attrs["n_steps"])
        text, record_hashes = cls._read_records(path, attrs, variables, version)
        rng_text = text["rng_state"]
        if version == 3 and attrs.get("content_sha256") != content_hash_v3(attrs, variables):
            raise StoreError(f"{path}: damaged run store: the content hash of its configuration and records "
                             f"does not match (the file was edited or corrupted)")
        try:
            stored = cls.config_type.from_dict(json.loads(attrs["config"]))
        except (json.JSONDecodeError, TypeError) as err:
            raise StoreError(f"{path}: damaged run store: unreadable config attribute ({err})") from None
        cls._check_config(path, attrs, stored, config)
        state_names = [name for name in variables if snapshot.is_state_variable(name)
                       and not name.startswith(_FULL) and name != _SLOT_STEP]
        required = ["initial_particles", "initial_log_weights"]
        if n_steps:
            required += ["posterior", "log_weights", "predictive", "step_info", "dataset_sha256", "dataset_source",
                         "state_step_size"]
            if not state_names:
                required.append("mixture_centres" if stored.predictive_method != "smc2" else "nested_outer")
        missing = [name for name in required if name not in variables]
        if missing:
            raise StoreError(f"{path}: damaged run store: missing variable(s) {', '.join(missing)}")
        rng_states = json_values(rng_text, path, "rng_state")
        for i, state in enumerate(rng_states):
            if not (isinstance(state, dict) and isinstance(state.get("bit_generator"), str)
                    and isinstance(state.get("state"), dict)):
                raise StoreError(f"{path}: damaged run store: rng_state[{i}] is not a numpy generator state")
        try:  # the state the next update resumes from (a crafted bit_generator name would be called)
            generator_from_state(rng_states[-1])
        except ValueError as err:
            raise StoreError(f"{path}: damaged run store: rng_state[{len(rng_states) - 1}]: {err}") from None
        records = [StepRecord(StepInfo.from_dict(info), variables["posterior"][i], variables["log_weights"][i],
                              variables["predictive"][i])
                   for i, info in enumerate(json_values(text.get("step_info", []), path, "step_info"))]
        result = Result(stored.names, tuple(records), json_value(attrs.get("result_meta", "{}"), path, "result_meta"))
        ragged = {}                           # state arrays of another length at every step, concatenated
        for name in state_names:
            if name in snapshot.RAGGED:
                rows = variables.get(f"{name}_rows", np.zeros(0, dtype=int))
                if rows.shape != (n_steps,) or int(rows.sum()) != variables[name].shape[0]:
                    raise StoreError(f"{path}: inconsistent store ({name}_rows {rows.tolist()} for "
                                     f"{variables[name].shape[0]} stored rows)")
                ragged[name] = np.split(variables[name], np.cumsum(rows)[:-1]) if n_steps else []
        states = [{name: ragged[name][i] if name in ragged else variables[name][i] for name in state_names}
                  for i in range(n_steps)]
        for arrays, posterior in zip(states, variables.get("posterior", ())):
            snapshot.fill_missing(arrays, posterior.shape[0])   # a state array added since the store was written
        if _SLOT_STEP in variables:           # SMC^2's full state of the last two steps
            held = [int(k) for k in variables[_SLOT_STEP]]
            if sorted(k for k in held if k) != list(range(max(n_steps - 1, 1), n_steps + 1)):
                raise StoreError(f"{path}: inconsistent store ({_SLOT_STEP} {held} for {n_steps} steps)")
            for slot, k in enumerate(held):
                if k:
                    states[k - 1].update({"nested_" + name[len(_FULL):]: variables[name][slot]
                                          for name in variables if name.startswith(_FULL)})
        _keep_full_state(states)
        if n_steps and snapshot.state_kind(states[0]) == "nested":  # SMC^2's Rao-Blackwellised moments
            records = [dataclasses.replace(r, moments=nested_record_moments(
                {k[len("nested_"):]: v for k, v in a.items()})) for r, a in zip(records, states)]
            result = Result(stored.names, tuple(records), result.meta)
        if n_steps and snapshot.state_kind(states[0]) == "mixture" and stored.predictive_method == "history":
            raise StoreError(f"{path}: written by an earlier seqbayes, which gave static parameters a "
                             f"kernel-density prior; this version uses their exact history prior. Re-create "
                             f"the run (seqbayes init --force) and assimilate its datasets again, or keep "
                             f"the seqbayes version that wrote it ({attrs.get('seqbayes_version', '?')})")
        tables = []
        if n_steps and "dataset_rows" in variables:
            rows, values = variables["dataset_rows"], variables["dataset_values"]
            if rows.shape != (n_steps,) or int(rows.sum()) != values.shape[0]:
                raise StoreError(f"{path}: inconsistent store (dataset_rows {rows.tolist()} for "
                                 f"{values.shape[0]} stored data rows)")
            tables = np.split(values, np.cumsum(rows)[:-1])
        if n_steps and snapshot.needs_datasets(states[-1]) and len(tables) != n_steps:
            raise StoreError(f"{path}: damaged run store: missing variable(s) dataset_values, dataset_rows")
        step_sizes = [float(v) for v in variables["state_step_size"]] if n_steps else []
        if len(step_sizes) != n_steps:
            raise StoreError(f"{path}: inconsistent store ({len(step_sizes)} step sizes, n_steps = {n_steps})")
        check_finite(path, variables, snapshot.output_name)
        if not 0.0 <= float(attrs["initial_step_size"]) < np.inf:
            raise StoreError(f"{path}: damaged run store: initial_step_size is {float(attrs['initial_step_size'])}; "
                             f"expected a finite number >= 0")
        provenance = Provenance(rng_states, text["dataset_sha256"], text["dataset_source"], attrs.get("created"),
                                record_hashes)
        return cls(path, stored, provenance, initial_particles=variables["initial_particles"],
                   initial_log_weights=variables["initial_log_weights"],
                   initial_step_size=float(attrs["initial_step_size"]), result=result, states=states,
                   step_sizes=step_sizes, tables=tables, module_hashes=text["likelihood_sha256"])

    # ------------------------------------------------------------------ writing
    def _step_texts(self, k: int) -> tuple:
        """Step ``k``'s (0-based) text records, in the order of :data:`~seqbayes.store.base.RECORD_TEXT`."""
        return (json.dumps(self.result.steps[k].info.to_dict()), json.dumps(self.rng_states[k + 1]),
                self.digests[k], self.sources[k], self.module_hashes[k])

    def _own_attrs(self) -> dict:
        return {"result_meta": json.dumps(self.result.meta, default=str), "initial_step_size": self.initial_step_size}

    def _step_rows(self, start: int, data: dict, coords: dict) -> None:
        steps = self.result.steps[start:]
        infos = [r.info.to_dict() for r in steps]
        numeric = [k for k, v in infos[0].items() if isinstance(v, (int, float)) and k != "step"]
        coords.update(step=np.array([r.info.step for r in steps]), diagnostic=numeric)
        data.update({
            "posterior": (("step", "sample", "parameter"), np.stack([r.posterior for r in steps])),
            "log_weights": (("step", "sample"), np.stack([r.log_weights for r in steps])),
            "predictive": (("step", "sample", "parameter"), np.stack([r.predictive for r in steps])),
            # for readers without seqbayes; step_info holds the exact records
            "diagnostics": (("step", "diagnostic"), np.array([[float(i[k]) for k in numeric] for i in infos])),
            "state_step_size": (("step",), np.array(self.step_sizes[start:], dtype=float)),
        })
        for name in [name for name in self.states[start] if snapshot.per_step(name)]:
            if name in snapshot.RAGGED:       # concatenated along a growing dimension, with a count per step
                parts = [arrays[name] for arrays in self.states[start:]]
                data[name] = ((f"{name}_row",) + snapshot.state_dims(name, parts[0].ndim)[1:], np.concatenate(parts))
                data[f"{name}_rows"] = (("step",), np.array([len(part) for part in parts]))
                continue
            stacked = np.stack([arrays[name] for arrays in self.states[start:]])
            data[name] = (("step",) + snapshot.state_dims(name, stacked.ndim - 1), stacked)
        if self.tables:  # the datasets the state needs (history prior, SMC^2)
            coords["column"] = list(self.config.columns)
            data.update(dataset_values=(("dataset_row", "column"), np.concatenate(self.tables[start:])),
                        dataset_rows=(("step",), np.array([t.shape[0] for t in self.tables[start:]])))

    def _whole_variables(self) -> tuple[dict, dict]:
        data = {"initial_particles": (("sample", "parameter"), self.initial_particles),
                "initial_log_weights": (("sample",), self.initial_log_weights)}
        held = self._slot_steps()
        if held:          # SMC^2: the full state of the last two steps, a slot each (zeros in an empty slot)
            full = {k: self.states[k - 1] for k in held if k}
            last = full[self.n_steps]
            data[_SLOT_STEP] = (("slot",), np.array(held))
            for name in (name for name in last if not snapshot.per_step(name)):
                dims = snapshot.state_dims(_FULL + name[len("nested_"):], last[name].ndim)
                data[_FULL + name[len("nested_"):]] = (("slot",) + dims, np.stack(
                    [full[k][name] if k else np.zeros_like(last[name]) for k in held]))
        return data, {"sample": np.arange(self.initial_particles.shape[0]), "parameter": list(self.names)}

    def _slot_steps(self) -> list:
        """The step each slot of SMC^2's full state holds (``[]``: not an SMC^2 run, or no step yet)."""
        if not self.n_steps or snapshot.state_kind(self.states[-1]) != "nested":
            return []
        held = [0, 0]
        for k in range(max(self.n_steps - 1, 1), self.n_steps + 1):
            held[(k - 1) % 2] = k
        return held

    def _rewritten(self, start: int) -> list:
        """An append's rewrites of SMC^2's slots: the slots of the new steps among the last two."""
        held = self._slot_steps()
        out = [(_SLOT_STEP, slice(None), np.array(held))] if held else []
        for k in (k for k in held if k > start):
            out += [(_FULL + name[len("nested_"):], (k - 1) % 2, value)
                    for name, value in self.states[k - 1].items() if not snapshot.per_step(name)]
        return out

    # ---------------------------------------------------------------- the state
    def state_at(self, step: int) -> tuple:
        """``(state, records, rng_state)`` after ``step`` datasets, for :meth:`SEMC.restore`
        (the state from :func:`seqbayes.store.snapshot.state_from_arrays`)."""
        if not 0 <= step <= self.n_steps:
            raise ValueError(f"step: must lie in [0, {self.n_steps}], got {step}")
        if step and _full(self.states[-1]) and not _full(self.states[step - 1]):
            raise ValueError(f"step: an SMC^2 run keeps its sampler's full state for the last two steps only "
                             f"({max(self.n_steps - 1, 1)} and {self.n_steps}), not step {step}; every step's "
                             f"posterior is in result.steps")
        prior = self.config.build_prior()
        if step == 0:
            state = snapshot.initial_state(self.config.predictive_method, prior, self.initial_particles,
                                           self.initial_log_weights, self.initial_step_size)
        else:
            datasets = tuple(as_likelihood_data(t, self.config) for t in self.tables[:step])
            state = snapshot.state_from_arrays(self.states[:step], self.result.steps[:step], self.step_sizes[step - 1],
                                               prior, datasets)
        return state, tuple(self.result.steps[:step]), self.rng_states[step]

    # ------------------------------------------------------------ the likelihood
    def likelihood_candidates(self) -> list[ModuleSource]:
        """Files that could be the run's likelihood module, located without running them.

        In order: the config's folder (where the module was recorded), the store's
        own folder, ``sys.path`` (an installed module). Only a candidate whose
        SHA-256 is the recorded one is ever run (see :meth:`load_likelihood`).
        """
        module_name = self.config.likelihood.split(":")[0]
        out = []
        for folder in (self.config.search_path, str(self.path.resolve().parent)):
            if folder and Path(folder).is_dir():
                found = locate_module(module_name, folder, search_installed=False)
                if found is not None and found.files not in [c.files for c in out]:
                    out.append(found)
        with contextlib.suppress(ConfigError):
            found = locate_module(module_name, None)
            if found.files not in [c.files for c in out]:
                out.append(found)
        return out

    def _verified_likelihood(self, accept_model_change: bool = False):
        """``(function, ModuleSource)``: the likelihood from a file whose content the run recorded."""
        spec, recorded = self.config.likelihood, self.config.likelihood_sha256
        candidates = self.likelihood_candidates()
        if recorded is None:
            # a store written before module hashes were recorded: only the config's folder (or an
            # installed module), never the folder the store happens to lie in; the hash is recorded
            # with the next step
            trusted = self.config.search_path and str(Path(self.config.search_path).resolve())
            candidates = [c for c in candidates if c.folder is None or c.folder == trusted]
            chosen = candidates[0] if candidates else None
        else:
            chosen = next((c for c in candidates if c.sha256 == recorded), None)
            legacy = next((c for c in candidates if c.legacy_sha256 == recorded), None) if chosen is None else None
            if legacy is not None:   # recorded when only the module's own files were hashed: from now on, its package
                warnings.warn(f"{self.path}: the run recorded the hash of {legacy.name!r}'s own files only; its "
                              f"package's {legacy.package_files} files are hashed from this step on (a change "
                              f"to them before now cannot be told)", StoreWarning, stacklevel=3)
                chosen = legacy
            if chosen is None and accept_model_change and candidates:
                chosen = candidates[0]
        if chosen is None:
            raise ModelChangedError(self._model_changed_message(candidates))
        try:
            return load_located(spec, chosen), chosen
        except ConfigError as err:
            raise StoreError(f"{self.path}: {err}") from None

    def _model_changed_message(self, candidates) -> str:
        module_name = self.config.likelihood.split(":")[0]
        recorded = self.config.likelihood_sha256 or "?"
        where = self.config.likelihood_file or f"{module_name}.py in {self.config.search_path}"
        if not candidates:
            return (f"{self.path}: the likelihood module {module_name!r} the run recorded ({where}, sha256 "
                    f"{recorded[:12]}) is not there, nor next to the store, nor installed; copy that file next "
                    f"to the store")
        found = "; ".join(f"{_hashed_what(c)} has sha256 {c.sha256[:12] or '(no source)'}" for c in candidates)
        return (f"{self.path}: the likelihood module changed since the run recorded it (sha256 {recorded[:12]} "
                f"for {where}); {found}; it is not run. If the change is intended, update with "
                f"--accept-model-change (API: accept_model_change=True): the new hash is recorded for the "
                f"steps that follow")

    def load_likelihood(self, accept_model_change: bool = False) -> Callable[[np.ndarray, Any], np.ndarray]:
        """The run's likelihood, imported by file path from a file whose SHA-256 the run recorded.

        Candidates are :meth:`likelihood_candidates`; a module file whose content
        differs from the recorded one is not run (:class:`ModelChangedError`) unless
        ``accept_model_change``.
        """
        return self._verified_likelihood(accept_model_change)[0]

    def load_predict(self) -> Callable[[np.ndarray, Any], np.ndarray] | None:
        """The configuration's ``[model] predict`` function (``None`` when it names none), from the same
        verified module file as the likelihood (:meth:`load_likelihood`)."""
        if self.config.predict is None:
            return None
        _, source = self._verified_likelihood()
        try:
            return load_located(f"{self.config.likelihood.split(':')[0]}:{self.config.predict}", source)
        except ConfigError as err:
            raise StoreError(f"{self.path}: {str(err).replace('model.likelihood:', 'model.predict:', 1)}") from None

    def share_likelihood(self, executor: Any, source: ModuleSource | None = None) -> None:
        """Make the user's likelihood module importable on a Dask cluster's workers.

        A module that lives next to the config (or the store) is not installed on the
        workers, which then cannot unpickle the likelihood. For a
        :class:`dask.distributed.Client` the module file (or, for a dotted name, its
        top-level package as a zip) is sent with ``Client.upload_file``, which also
        reaches workers that join later. Installed modules and other executors
        (``concurrent.futures`` workers are forked with the parent's modules) need nothing.
        """
        if executor is None or not hasattr(executor, "upload_file"):
            return
        source = source or self._verified_likelihood()[1]
        if source.folder is None or not source.files:
            return
        if len(source.files) == 1:
            executor.upload_file(source.file)
            return
        import tempfile

        top = source.name.split(".")[0]
        with tempfile.TemporaryDirectory() as tmp:
            archive = shutil.make_archive(str(Path(tmp) / top), "zip", root_dir=source.folder, base_dir=top)
            executor.upload_file(archive)

    def sampler(self, step: int | None = None, executor: Any = None,
                loglike: Callable[[np.ndarray, Any], np.ndarray] | None = None) -> SEMC | SMC:
        """A sampler restored to the state after ``step`` datasets (default: the last).

        Without ``loglike`` the run's verified likelihood is loaded (:meth:`load_likelihood`).
        With a Dask client as ``executor`` the likelihood's module is first sent to the
        workers (:meth:`share_likelihood`).
        """
        step = self.n_steps if step is None else int(step)
        if loglike is None:
            loglike, source = self._verified_likelihood()
            self.share_likelihood(executor, source)
        sampler = self.config.build_sampler(executor=executor, loglike=loglike)
        try:  # a state variable renamed or missing (the file was edited): one line, not a KeyError
            state = self.state_at(step)
            unknown = sorted(set(self.states[step - 1]) - set(snapshot.state_arrays(state[0]))) if step else []
            if unknown:
                raise KeyError(unknown[0])
        except KeyError as err:
            raise StoreError(f"{self.path}: damaged run store: the sampler state after step {step} does not match "
                             f"its variables ({str(err)[:60]}); the file was edited or written by an incompatible "
                             f"seqbayes") from None
        sampler.restore(*state)
        return sampler

    # ------------------------------------------------------------- assimilation
    def assimilate(self, table: ArrayLike, source: str = "<array>", *, replace_last: bool = False,
                   executor: Any = None, loglike: Callable[[np.ndarray, Any], np.ndarray] | None = None,
                   write: bool = True, accept_model_change: bool = False) -> StepInfo:
        """Assimilate one dataset given as an ``(n_rows, n_columns)`` array and save the store.

        The read-modify-write holds the store's lock; steps another process stored since
        this object read the file are taken in first, so concurrent updates are all kept.

        Parameters
        ----------
        table : (n_rows, n_columns) array
            Columns in the order of ``config.columns``; real, finite numbers.
        source : str
            Where it came from (recorded).
        replace_last : bool
            Roll back the last step and assimilate ``table`` in its place.
        executor : object with ``map``, optional
            Parallel likelihood evaluation (same numbers as serial).
        loglike : callable, optional
            Replaces the configured likelihood's function (e.g. a wrapper that reports
            progress); the module is still verified and its hash recorded.
        write : bool
            Save the store (default).
        accept_model_change : bool
            Run the likelihood module even though its file changed since the run
            recorded it; the new hash is recorded for this step and the next ones.

        Returns
        -------
        StepInfo

        Raises
        ------
        seqbayes.store.datasets.DataError
            Complex, non-numeric, NaN/inf values or the wrong shape.
        DuplicateDatasetError
            Already assimilated.
        ModelChangedError
            The likelihood module's file is missing or has changed.
        ValueError
            From the likelihood or the sampler (wrong shape, ...); the store is unchanged.

        Warns
        -----
        BoundWarning
            Most of the new posterior lies at a bound of the prior.
        """
        table = check_table(table, self.config, "table" if source == "<array>" else f"table from {source}")
        digest = dataset_digest(table, self.config.columns)
        with self._updating(write, replace_last):
            if replace_last and self.n_steps == 0:
                raise StoreError(f"{self.path}: replace_last: no step to replace")
            self.check_new_dataset(digest, replace_last)
            base = self.n_steps - 1 if replace_last else self.n_steps
            function, module = self._verified_likelihood(accept_model_change)
            self.share_likelihood(executor, module)
            sampler = self.sampler(base, executor=executor, loglike=function if loglike is None else loglike)
            info = sampler.update(as_likelihood_data(table, self.config))
            state, records, rng_state = sampler.snapshot()
            try:
                arrays = snapshot.state_arrays(state)
                snapshot.check_state(state, records[-1])
            except (snapshot.UnsupportedState, ValueError) as err:
                raise StoreError(f"{self.path}: this seqbayes cannot store the sampler's state ({err}; predictive = "
                                 f"{self.config.predictive_method!r}); the run store is unchanged") from None
            # commit to memory only now that the step succeeded
            self._disk_steps = min(self._disk_steps, base)
            self._record_hashes = self._record_hashes[:base]
            self.result = _replace(sampler.result, steps=tuple(records))
            self.states = self.states[:base] + [arrays]
            _keep_full_state(self.states)
            if snapshot.needs_datasets(arrays) or self.tables:  # steps whose dataset is not kept: 0 rows
                kept = self.tables[:base] + [np.zeros((0, table.shape[1]))] * (base - len(self.tables))
                self.tables = kept + [table]
            self.step_sizes = self.step_sizes[:base] + [float(state.step_size)]
            self.rng_states = self.rng_states[:base + 1] + [rng_state]
            self.digests = self.digests[:base] + [digest]
            self.sources = self.sources[:base] + [str(source)]
            self.module_hashes = self.module_hashes[:base] + [module.sha256]
            if (module.file, module.sha256) != (self.config.likelihood_file, self.config.likelihood_sha256):
                self.config = _replace(self.config, likelihood_file=module.file, likelihood_sha256=module.sha256)
            if write:
                self.write()
        for message in self.bound_messages():
            warnings.warn(message, BoundWarning, stacklevel=2)
        return info


    def bound_messages(self, step: int = -1, mass: float = 0.5, margin: float = 0.01) -> list[str]:
        """Parameters whose posterior at ``step`` piles up at a finite bound of the prior.

        A parameter is reported when more than ``mass`` of its posterior weight lies
        within ``margin`` of the prior's central 99 % range from a finite bound of its
        support (the prior itself puts about 1 % there): usually data in the wrong
        units or a prior too narrow for the structure.
        """
        if not self.n_steps:
            return []
        record = self.result.steps[step]
        weights = np.exp(record.log_weights - np.max(record.log_weights))
        weights /= weights.sum()
        out = []
        for j, (name, dist) in enumerate(zip(self.names, self.config.build_prior().distributions)):
            lower, upper = map(float, dist.support())
            width = float(dist.ppf(0.995) - dist.ppf(0.005))
            values = record.posterior[:, j]
            for side, bound, near in (("lower", lower, values <= lower + margin * width),
                                      ("upper", upper, values >= upper - margin * width)):
                share = float(weights[near].sum()) if np.isfinite(bound) else 0.0
                if share > mass:
                    out.append(f"{self.path}: step {record.info.step}: {share:.0%} of the posterior of {name!r} lies "
                               f"at the prior's {side} bound {bound:g}; check the data's units and the prior's range")
        return out

    # ----------------------------------------------------------------- queries
    def predict(self, n_steps: int) -> np.ndarray:
        """Forecast ``(n_steps, N, d)`` from the last posterior; reproducible, does not change the store.

        The kernels of a configuration are built in, so this runs no user code (the
        likelihood is not imported).

        Raises
        ------
        TypeError
            ``n_steps`` is not an integer (``1.7`` is refused, not truncated).
        ValueError
            ``n_steps < 1`` or no dataset assimilated yet.
        """
        if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)):
            raise TypeError(f"n_steps: expected an integer, got {n_steps!r}")
        return self.sampler(loglike=_likelihood_not_needed).predict(int(n_steps))

    def time_to_threshold(self, parameter: str, threshold: float, horizon: int, *, direction: str = "below",
                          paths_per_sample: int = 1) -> FirstPassage:
        """Distribution of the first future step at which ``parameter`` crosses ``threshold``.

        The last posterior's equal-weight draws are propagated through the run's kernel
        (:func:`seqbayes.prognostics.time_to_threshold`); reproducible like :meth:`predict`
        (the generator is the one stored after the last step) and runs no user code.

        Parameters
        ----------
        parameter : str
            A parameter name (see :attr:`names`).
        threshold : float
        horizon : int
            Future steps simulated, ``>= 1``.
        direction : {"below", "above"}
        paths_per_sample : int
            Kernel paths per posterior draw.

        Returns
        -------
        FirstPassage
            ``probability (horizon,)`` of a first crossing at each future step, its cumulative
            distribution and their Monte Carlo standard errors.
        """
        if parameter not in self.names:
            raise ValueError(f"parameter: {parameter!r} is not a parameter of this run; choose from "
                             f"{', '.join(self.names)}")
        if not self.n_steps:
            raise ValueError(f"{self.path}: no dataset assimilated yet; nothing to forecast from")
        sampler = self.sampler(loglike=_likelihood_not_needed)
        samples = sampler.result.steps[-1].equal_weight_samples(sampler.rng)
        return time_to_threshold(samples, sampler.problem.kernel, self.names.index(parameter), threshold, horizon,
                                 direction=direction, rng=sampler.rng, paths_per_sample=paths_per_sample,
                                 support=sampler.problem.support)

    def to_arviz(self, step: int | None = None, rng: int | np.random.Generator | None = None, **kwargs: Any) -> az.InferenceData:
        """The run as :class:`arviz.InferenceData` (:meth:`seqbayes.Result.to_arviz`; step 1's prior
        draws are the run's own initial draws)."""
        return self.result.to_arviz(step, rng, prior=self.initial_particles, **kwargs)

    # ------------------------------------------------- what the command line asks
    def make_executor(self) -> tuple:
        return self.config.make_executor()

    def user_code(self) -> tuple:
        return self.config.likelihood, self.config.likelihood_file

    def describe(self) -> str:
        config = self.config
        return (f"run {self.path} for model {config.name!r}: {len(config.names)} parameters "
                f"({', '.join(config.names)}), {config.sampler} with N = {config.n_samples}, seed {config.seed}")

    def step_summary(self, info: StepInfo, source: str) -> str:
        moves = ("no moves" if math.isnan(info.acceptance_rate)  # SMC^2 moves only when the ESS falls
                 else f"acceptance {info.acceptance_rate:.3f}")
        return (f"step {info.step} from {source}: log-evidence increment {info.log_evidence_increment:.4f}, "
                f"cumulative {info.log_evidence:.4f}, {moves}, ESS {info.ess:.1f} of N = {self.config.n_samples} "
                f"(last tempering stage, before resampling), {info.n_distinct} distinct samples after the step, "
                f"{info.n_loglike_evals} likelihood evaluations in {info.wall_time:.2f} s")

    def status(self, level: float = 0.95) -> str:
        from .report import format_status

        text = format_status(self, level)
        if not self.n_steps:
            return text
        # the cost per update and amortised: what an expensive model's user plans by
        infos = [record.info for record in self.result.steps]
        last = infos[-1]
        line = (f"\nlikelihood evaluations: last update {last.n_loglike_evals:,}, amortised "
                f"{sum(i.n_loglike_evals for i in infos) / len(infos):,.0f} per update, largest "
                f"{max(i.n_loglike_evals for i in infos):,}")
        if np.isfinite(last.pmmh_acceptance):
            line += (f"; SMC^2 PMMH acceptance {last.pmmh_acceptance:.2f}, {last.pending_moves:,} moves pending "
                     f"for later updates")
        return text + line

    def status_json(self, level: float = 0.95) -> dict:
        from .report import status_rows

        return {"run": str(self.path), "model": self.config.name, "steps": status_rows(self, level)}

    def write_report(self, output: str | os.PathLike, *, level: float = 0.95, embed: bool = True,
                     others: Sequence[RunStore] = (), forecast_steps: int = 3, thresholds: Sequence = (),
                     horizon: int = 20, fit_data: tuple | None = None, modes: str | None = None) -> None:
        """The HTML report (:func:`seqbayes.store.report.write_report`); ``modes`` (mode shapes of SG-EnMCMC
        runs) has no use here."""
        from .report import write_report

        write_report(self, Path(output), others=list(others), forecast_steps=forecast_steps, level=level,
                     embed=embed, thresholds=list(thresholds), horizon=horizon, fit_data=fit_data)


def _likelihood_not_needed(theta, data):  # pragma: no cover - a sampler built only to draw or forecast
    raise RuntimeError("the likelihood is not loaded for forecasts and new runs")


def _keep_full_state(states: list) -> None:
    """Drop (in place) SMC^2's full state of every step but the last two, as the file keeps it: only those can
    be resumed from (:meth:`RunStore.state_at`), and an object kept open for many steps does not grow."""
    for k in range(len(states) - 2):
        if _full(states[k]):
            states[k] = {name: value for name, value in states[k].items() if snapshot.per_step(name)}


def _full(arrays: dict) -> bool:
    """Whether a step's state arrays hold SMC^2's full state (not only what every step keeps)."""
    return not all(snapshot.per_step(name) for name in arrays)


def posterior_to_arviz(result: Result, step: int | None = -1, rng: int | np.random.Generator | None = None,
                       **kwargs: Any) -> az.InferenceData:
    """A step's posterior (``step=None``: every step) as :class:`arviz.InferenceData`:
    :meth:`seqbayes.Result.to_arviz`."""
    return result.to_arviz(step, rng, **kwargs)


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    import os
    from collections.abc import Callable, Sequence
    from typing import Any

    import arviz as az
    from numpy.typing import ArrayLike

    from ..engine.drivers import SEMC, SMC


def _hashed_what(source) -> str:
    """What a module's hash covers: its file, or every Python file of its package."""
    if source.package_files > 1:
        return f"the package of {source.file} ({source.package_files} .py files)"
    return source.file or source.name
