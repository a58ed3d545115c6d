"""The run store: a monitoring run on disk that resumes exactly where it stopped.

One run is one NetCDF-4 file. After every completed step it holds the whole
sampler state: the posterior and predictive samples of every step with their
weights and diagnostics (the :class:`~seqbayes.results.Result` layout), the
next step's prior (the Gaussian-mixture density of Eq. A3 or, for static
parameters, the exact history prior's values at the particles and the
assimilated datasets themselves, which it re-evaluates), the
stretch-move step size, the cumulative log-evidence, the random generator's
state after each step, the initial prior draws, the validated configuration
(prior, kernel, likelihood ``module:function``, sampler settings), a format
version, a model fingerprint and a content hash of every assimilated dataset.
A new process that opens the store and assimilates the next dataset gives
bit-for-bit the numbers of an uninterrupted run with the same seed, because the
sampler is rebuilt from the stored configuration and then
:meth:`~seqbayes.sequential.SEMC.restore`-d to the stored state and generator.

Keeping every step's state (not only the last) costs one ``(N, d)`` mixture (or
one ``(N,)`` vector and the dataset) per step and allows :meth:`RunStore.assimilate` with ``replace_last=True``: the run
is rolled back to the step before and the new dataset assimilated in its place.

Writes are atomic: a new step is appended to a copy of the file that the kernel
makes (``copy_file_range``, a reflink where the filesystem shares extents), so the
bytes HDF5 writes per step do not grow with the run; a new layout (the first step,
``replace_last``, an older store) is written whole by HDF5 to memory and then to the
temporary file with plain OS calls. Either way the temporary file in the same folder
(``.RUN.tmp-PID``) is ``fsync``-ed and moved over the old one with :func:`os.replace`
(atomic on POSIX) keeping the old file's permission bits, and the folder is
``fsync``-ed; readers see the old file or the new one. A
crash or ``SIGKILL`` at any point leaves either the previous store or the new
one, never a mixture; a leftover temporary file of this store (exactly that
name) is removed by the next write. A full disk or a read-only folder is one
:class:`StoreError`, the previous store kept. Every read-modify-write
(:meth:`RunStore.assimilate`, :meth:`RunStore.write`) holds an advisory lock on
``RUN.lock``; an object that opened the store before another process stored a
step takes that step in first, so concurrent updates are all kept.

Trust: a store is trusted like code (it names the module the likelihood comes
from), but runs only a module file whose SHA-256 it recorded
(:meth:`RunStore.load_likelihood`), imported by file path without touching
``sys.path``; opening, ``predict`` and reports run no user code. The numeric
arrays carry HDF5 Fletcher-32 checksums and the configuration and text records a
SHA-256 (``content_sha256``), verified by :meth:`RunStore.open`, which also
refuses NaN samples and missing or inconsistent variables.

Layout: ``posterior``, ``predictive`` ``(step, sample, parameter)``, ``log_weights``
``(step, sample)``, ``mixture_centres``/``_bandwidth``/``_log_weights`` or
``state_log_prior (step, sample)`` with ``dataset_values (dataset_row, column)``
and ``dataset_rows (step)``,
``diagnostics (step, diagnostic)`` (acceptance, ESS, evidence, ... as float64 for
any NetCDF reader), ``step_info`` (the exact :class:`~seqbayes.results.StepInfo`
as JSON), ``dataset_sha256``, ``dataset_source``, ``state_step_size``,
``initial_particles``, ``rng_state (rng_index)``, ``likelihood_sha256 (step)``;
attributes ``config`` (with the likelihood module's file and hash), ``model_fingerprint``,
``content_sha256``, ``seqbayes_store_format``. The per-step sampler state is written by
:meth:`RunStore._state_variables`, read by :func:`_read_state` and rebuilt by
:meth:`RunStore.state_at` (with :meth:`RunStore._store_state` keeping it after a step).
Few variables keep a write fast (HDF5 pays per variable).

Why NetCDF (HDF5 underneath, through xarray and h5netcdf): the content is a set
of labelled float64 arrays ``(step, sample, parameter)`` plus small metadata,
which is exactly NetCDF's model; float64 values round-trip bit for bit (needed
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
import datetime as _dt
import errno
import hashlib
import io
import json
import os
import shutil
import signal
import sys
import threading
import warnings
from dataclasses import replace as _replace
from pathlib import Path

import numpy as np

from .config import (NOT_FINGERPRINTED, ConfigError, ModuleSource, RunConfig, as_likelihood_data,
                     check_table, dataset_digest, load_located, locate_module, read_datafile)
from .density import GaussianMixture, HistoryPrior
from .results import Result, StepInfo, StepRecord
from .nested import NestedState, nested_guide, nested_state_arrays, nested_state_from_arrays, start_nested
from .prognostics import FirstPassage, time_to_threshold
from .sequential import SamplerState

__all__ = ["RunStore", "StoreError", "DuplicateDatasetError", "ModelChangedError", "BoundWarning",
           "FORMAT_VERSION", "store_lock"]

#: Version of the on-disk layout; a store of another version is refused. Version 2 added the
#: history prior of static kernels, version 3 the likelihood module's hash per step, the
#: content hash of the text variables and HDF5 checksums; versions 1 and 2 are still read.
FORMAT_VERSION = 3
_READABLE_VERSIONS = (1, 2, 3)

#: Environment variable naming a fault-injection point (tests only): the process
#: SIGKILLs itself there. One of ``before-write``, ``mid-write``, ``before-replace``,
#: ``after-replace``.
FAULT_ENV = "SEQBAYES_STORE_FAULT"


class StoreError(ValueError):
    """A run store is missing, damaged, of another format version or for another model."""


class DuplicateDatasetError(StoreError):
    """The dataset has already been assimilated in this run."""


class ModelChangedError(StoreError):
    """The likelihood module's file no longer has the content the run recorded (or is missing)."""


class BoundWarning(UserWarning):
    """Most of a step's posterior lies at a bound of the prior (wrong units? too narrow a prior?)."""


def _fault(point: str) -> None:
    if os.environ.get(FAULT_ENV) == point:  # pragma: no cover - the process dies here
        os.kill(os.getpid(), signal.SIGKILL)


_LOCKS: dict = {}                      # resolved lock path -> [threading.RLock, depth]
_LOCKS_GUARD = threading.Lock()


@contextlib.contextmanager
def store_lock(path):
    """Advisory exclusive lock on ``<path>.lock`` (POSIX ``flock``), held for a read-modify-write.

    Re-entrant within a process (the CLI holds it around :meth:`RunStore.assimilate`, which
    takes it too) and exclusive between threads and between processes.

    Raises
    ------
    StoreError
        The lock file cannot be created (a read-only folder, ...).
    """
    import fcntl

    lock_path = str(path) + ".lock"
    key = os.path.abspath(lock_path)
    with _LOCKS_GUARD:
        entry = _LOCKS.setdefault(key, [threading.RLock(), 0, None])
    with entry[0]:
        if entry[1] == 0:
            try:
                fh = open(lock_path, "a")
            except OSError as err:
                raise StoreError(f"{path}: cannot take the lock {lock_path}: {_os_message(err)}") from None
            fcntl.flock(fh, fcntl.LOCK_EX)
            entry[2] = fh
        entry[1] += 1
        try:
            yield
        finally:
            entry[1] -= 1
            if entry[1] == 0:
                fh, entry[2] = entry[2], None
                fcntl.flock(fh, fcntl.LOCK_UN)
                fh.close()


def _os_message(err: OSError) -> str:
    """``strerror`` (and the file, when the error names one) of an OS error, for one-line messages."""
    text = err.strerror or str(err)
    return f"{text} ({err.filename})" if err.filename else text


def _file_stamp(path):
    """What changes when the file is replaced or rewritten: inode, size, modification time."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_size, st.st_mtime_ns


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _config_diff(a: RunConfig, b: RunConfig) -> list[str]:
    skip = NOT_FINGERPRINTED
    da, db = a.to_dict(), b.to_dict()
    out = []
    for key in da:
        if key in skip:
            continue
        if isinstance(da[key], dict) and isinstance(db.get(key), dict):
            for sub in sorted(set(da[key]) | set(db[key])):
                if da[key].get(sub) != db[key].get(sub):
                    out.append(f"{key}.{sub}")
        elif json.dumps(da[key], sort_keys=True) != json.dumps(db.get(key), sort_keys=True):
            out.append(key)
    return out


class RunStore:
    """A persistent on-line run (one NetCDF file); see the module docstring.

    Create one with :meth:`create`, open it with :meth:`open`, assimilate data
    with :meth:`update` (a file) or :meth:`assimilate` (an array).

    Attributes
    ----------
    path : pathlib.Path
    config : RunConfig
    result : Result
        Every completed step.
    digests : list of str
        SHA-256 of each assimilated dataset's content.
    sources : list of str
        File name of each assimilated dataset.

    Examples
    --------
    >>> store = RunStore.create("bridge.nc", load_config("run.toml"))   # doctest: +SKIP
    >>> store.update("month1.csv").log_evidence                         # doctest: +SKIP
    """

    def __init__(self, path, config: RunConfig, *, initial_particles, initial_log_weights, initial_step_size,
                 rng_states, result: Result, mixtures, step_sizes, digests, sources, log_priors=(), tables=(),
                 created=None, module_hashes=None, nested=()):
        self.path = Path(path)
        self.config = config
        self.initial_particles = initial_particles
        self.initial_log_weights = initial_log_weights
        self.initial_step_size = float(initial_step_size)
        self.rng_states = list(rng_states)          # S + 1 generator states (after step 0, 1, ..., S)
        self.result = result
        self.mixtures = list(mixtures)              # S tuples (centres, bandwidth, log_weights), or none
        self.log_priors = list(log_priors)          # or, with a history prior, S (N,) prior values
        self.tables = list(tables)                  # and the S datasets it re-evaluates (also for SMC^2)
        self.nested = list(nested)                  # or, with SMC^2, S dicts of state arrays (seqbayes.nested)
        self.step_sizes = list(step_sizes)          # S state step sizes
        self.digests = list(digests)
        self.sources = list(sources)
        # SHA-256 of the likelihood module each step ran ("" for steps written before they were recorded)
        self.module_hashes = list(module_hashes) if module_hashes is not None else [""] * len(self.digests)
        self.created = created or _now()
        self._stamp = None                          # the file as last read or written (see _reload_if_changed)
        self._disk_steps = 0                        # leading steps the file holds exactly as this object does

    # ----------------------------------------------------------------- creation
    @classmethod
    def create(cls, path, config: RunConfig, *, overwrite: bool = False) -> "RunStore":
        """Start a new run at ``path`` from ``config`` (draws the initial prior samples) and write it.

        The likelihood's module is located (not run) and its file and SHA-256 recorded,
        unless ``config`` already records them (:func:`~seqbayes.config.load_config` does).

        Raises
        ------
        StoreError
            If ``path`` exists and ``overwrite`` is false, or cannot be written.
        """
        path = Path(path)
        if path.is_dir():
            raise StoreError(f"{path}: is a folder; give the run store's file name, e.g. {path / 'run.nc'}")
        with store_lock(path):
            if path.exists() and not overwrite:
                raise StoreError(f"{path}: a run store already exists (pass overwrite=True / --force to replace it)")
            if config.likelihood_sha256 is None:
                located = config.locate_likelihood()
                config = _replace(config, likelihood_file=located.file, likelihood_sha256=located.sha256)
            sampler = config.build_sampler(loglike=_likelihood_not_needed)  # drawing the prior runs no user code
            state, records, rng_state = sampler.snapshot()
            store = cls(path, config, initial_particles=np.array(state.particles),
                        initial_log_weights=np.array(state.log_weights), initial_step_size=state.step_size,
                        rng_states=[rng_state], result=Result(sampler.names, (), {}), mixtures=[], step_sizes=[],
                        digests=[], sources=[])
            store.write()
        return store

    # ------------------------------------------------------------------ reading
    @classmethod
    def open(cls, path, config: RunConfig | None = None) -> "RunStore":
        """Load a run store (this runs no user code).

        Parameters
        ----------
        path : path-like
        config : RunConfig, optional
            If given, the store must have been created for the same model
            (same fingerprint); otherwise a :class:`StoreError` lists the fields that differ.

        Raises
        ------
        StoreError
            Missing or unreadable file, a file that is not a seqbayes run store,
            another format version, another model, or a damaged store (checksum or
            content hash mismatch, missing or inconsistent variables, NaN samples).
        """
        path = Path(path)
        stamp = _file_stamp(path)
        ds = _read_dataset(path)
        try:
            store = cls._from_dataset(path, ds, config)
        except StoreError:
            raise
        except (KeyError, IndexError, ValueError, TypeError, AttributeError) as err:
            what = (f"missing variable or attribute {err}" if isinstance(err, KeyError)
                    else f"{type(err).__name__}: {err}")
            raise StoreError(f"{path}: damaged or inconsistent run store ({what})") from None
        store._stamp = stamp
        store._disk_steps = store.n_steps
        return store

    @classmethod
    def _from_dataset(cls, path: Path, ds, config: RunConfig | None) -> "RunStore":
        version = ds.attrs.get("seqbayes_store_format")
        if version is None:
            raise StoreError(f"{path}: not a seqbayes run store (no seqbayes_store_format attribute)")
        if int(version) not in _READABLE_VERSIONS:
            raise StoreError(f"{path}: run-store format version {int(version)}, but this seqbayes reads version "
                             f"{FORMAT_VERSION}; use the seqbayes version that wrote it (it says "
                             f"{ds.attrs.get('seqbayes_version', '?')})")
        if int(version) >= 3 and ds.attrs.get("content_sha256") != _content_hash(ds):
            raise StoreError(f"{path}: damaged run store: the content hash of its configuration and records "
                             f"does not match (the file was edited or corrupted)")
        try:
            stored = RunConfig.from_dict(json.loads(ds.attrs["config"]))
        except (json.JSONDecodeError, TypeError) as err:
            raise StoreError(f"{path}: damaged run store: unreadable config attribute ({err})") from None
        if stored.fingerprint() != ds.attrs.get("model_fingerprint"):
            raise StoreError(f"{path}: model fingerprint does not match the stored configuration "
                             f"(the file was edited or written by an incompatible seqbayes)")
        if config is not None and config.fingerprint() != stored.fingerprint():
            fields = ", ".join(_config_diff(stored, config)) or "?"
            raise StoreError(f"{path}: the run was created for another model (fingerprint "
                             f"{stored.fingerprint()[:12]} vs {config.fingerprint()[:12]}); differing fields: {fields}")
        n_steps = int(ds.attrs["n_steps"])
        required = ["initial_particles", "initial_log_weights", "rng_state"]
        if n_steps:
            required += ["posterior", "log_weights", "predictive", "step_info", "dataset_sha256", "dataset_source",
                         "state_step_size"]
            required += (["state_log_prior", "dataset_values", "dataset_rows"] if "state_log_prior" in ds
                         else ["nested_outer", "nested_scalars", "dataset_values", "dataset_rows"]
                         if stored.predictive_method == "smc2"
                         else ["mixture_centres", "mixture_bandwidth", "mixture_log_weights"])
        missing = [name for name in required if name not in ds]
        if missing:
            raise StoreError(f"{path}: damaged run store: missing variable(s) {', '.join(missing)}")
        if n_steps:
            records = []
            for i in range(n_steps):
                info = _step_info(_json(ds["step_info"].values[i], path, f"step_info[{i}]"))
                records.append(StepRecord(info, ds["posterior"].values[i], ds["log_weights"].values[i],
                                          ds["predictive"].values[i]))
            result = Result(stored.names, tuple(records), _json(ds.attrs.get("result_meta", "{}"), path, "result_meta"))
            digests = [str(v) for v in ds["dataset_sha256"].values]
            sources = [str(v) for v in ds["dataset_source"].values]
            module_hashes = ([str(v) for v in ds["likelihood_sha256"].values] if "likelihood_sha256" in ds
                             else [""] * n_steps)
        else:
            result, digests, sources, module_hashes = Result(stored.names, (), {}), [], [], []
        state = _read_state(path, ds, stored, n_steps)
        if not (len(state["rng_states"]) == n_steps + 1 and len(result.steps) == n_steps == len(digests)
                == len(sources) == len(module_hashes) == len(state["step_sizes"])):
            raise StoreError(f"{path}: inconsistent store ({len(result.steps)} steps, {len(state['rng_states'])} "
                             f"generator states, {len(digests)} dataset hashes, n_steps = {n_steps})")
        _check_finite(path, ds)
        return cls(path, stored, initial_particles=ds["initial_particles"].values,
                   initial_log_weights=ds["initial_log_weights"].values,
                   initial_step_size=float(ds.attrs["initial_step_size"]), result=result, digests=digests,
                   sources=sources, created=ds.attrs.get("created"), module_hashes=module_hashes, **state)

    @property
    def n_steps(self) -> int:
        """Datasets assimilated so far."""
        return len(self.result.steps)

    @property
    def names(self) -> tuple:
        return tuple(self.config.names)

    # ------------------------------------------------------------------ writing
    def to_xarray(self):
        """The store's content as an :class:`xarray.Dataset` (what :meth:`write` saves)."""
        import xarray as xr

        from . import __version__

        coords = {"sample": np.arange(self.initial_particles.shape[0]), "parameter": list(self.names)}
        data = {}
        if self.n_steps:
            steps = self.result.steps
            infos = [dataclasses.asdict(r.info) for r in steps]
            numeric = [k for k, v in infos[0].items() if isinstance(v, (int, float)) and k != "step"]
            coords.update(step=np.array([r.info.step for r in steps]), diagnostic=numeric)
            data = {
                "posterior": (("step", "sample", "parameter"), np.stack([r.posterior for r in steps])),
                "log_weights": (("step", "sample"), np.stack([r.log_weights for r in steps])),
                "predictive": (("step", "sample", "parameter"), np.stack([r.predictive for r in steps])),
                # for readers without seqbayes; step_info holds the exact records
                "diagnostics": (("step", "diagnostic"), np.array([[float(i[k]) for k in numeric] for i in infos])),
                "step_info": (("step",), np.array([json.dumps(i) for i in infos], dtype=object)),
                "dataset_sha256": (("step",), np.array(self.digests, dtype=object)),
                "dataset_source": (("step",), np.array(self.sources, dtype=object)),
                "likelihood_sha256": (("step",), np.array(self.module_hashes, dtype=object)),
            }
        state_data, state_coords = self._state_variables()
        data.update(state_data)
        coords.update(state_coords)
        ds = xr.Dataset(data, coords=coords)
        ds.attrs["result_meta"] = json.dumps(self.result.meta, default=str)
        ds["initial_particles"] = (("sample", "parameter"), self.initial_particles)
        ds["initial_log_weights"] = (("sample",), self.initial_log_weights)
        ds.attrs.update({
            "seqbayes_store_format": FORMAT_VERSION, "seqbayes_version": __version__,
            "model_fingerprint": self.config.fingerprint(), "config": json.dumps(self.config.to_dict()),
            "model_name": self.config.name, "n_steps": self.n_steps, "initial_step_size": self.initial_step_size,
            "created": self.created, "updated": _now(),
        })
        ds.attrs["content_sha256"] = _content_hash(ds)
        return ds

    # The sampler's state, per step: what SEMC.restore needs besides the step records. Reading
    # (_read_state), writing (_state_variables) and rebuilding (state_at) live here together.
    def _state_variables(self) -> tuple[dict, dict]:
        """``(data_vars, coords)`` of the per-step sampler state for :meth:`to_xarray`."""
        data = {"rng_state": (("rng_index",), np.array([json.dumps(s) for s in self.rng_states], dtype=object))}
        coords = {}
        if not self.n_steps:
            return data, coords
        data["state_step_size"] = (("step",), np.array(self.step_sizes, dtype=float))
        if self.tables:  # the datasets the history prior re-evaluates, or SMC^2's PMMH re-runs
            coords["column"] = list(self.config.columns)
            data.update(dataset_values=(("dataset_row", "column"), np.concatenate(self.tables)),
                        dataset_rows=(("step",), np.array([t.shape[0] for t in self.tables])))
        if self.log_priors:  # the history prior: its values at the particles
            data.update(state_log_prior=(("step", "sample"), np.stack(self.log_priors)))
        elif self.nested:  # SMC^2: outer particles, inner filters, likelihood estimates (seqbayes.nested)
            for key in self.nested[0]:
                stacked = np.stack([arrays[key] for arrays in self.nested])
                dims = ("step",) + tuple(f"nested_{key}_{axis}" for axis in range(1, stacked.ndim))
                data[f"nested_{key}"] = (dims, stacked)
        else:
            data.update(
                mixture_centres=(("step", "sample", "parameter"), np.stack([m[0] for m in self.mixtures])),
                mixture_bandwidth=(("step", "parameter"), np.stack([m[1] for m in self.mixtures])),
                mixture_log_weights=(("step", "sample"), np.stack([m[2] for m in self.mixtures])))
        return data, coords

    def write(self) -> None:
        """Write the store atomically (temporary file in the same folder, fsync, :func:`os.replace`).

        Holds the store's lock. The file keeps its permission bits. Refused up front
        when the folder lacks the free space the file needs.

        Raises
        ------
        StoreError
            The folder is read-only, full, or the path is a folder; the previous store is kept.
        """
        with store_lock(self.path):
            self._write_locked()

    def _write_locked(self) -> None:
        folder = self.path.resolve().parent
        if self.path.is_dir():
            raise StoreError(f"{self.path}: is a folder, not a run store file")
        prefix = f".{self.path.name}.tmp-"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            for entry in os.listdir(folder):  # left by a killed writer (the lock is held: no live one)
                if entry.startswith(prefix) and entry[len(prefix):].isdigit():
                    with contextlib.suppress(OSError):
                        os.remove(folder / entry)
        except OSError as err:
            raise StoreError(f"{self.path}: cannot write in {folder}: {_os_message(err)}") from None
        ds = self.to_xarray()
        mode = None
        with contextlib.suppress(OSError):
            mode = os.stat(self.path).st_mode & 0o7777
        tmp = folder / f"{prefix}{os.getpid()}"
        if self._append_to_copy(ds, folder, tmp, mode):
            return
        # HDF5 writes to memory; the file is written by plain OS calls, so a full disk or an I/O
        # error is one OSError here, never an error inside HDF5 (which, on ENOSPC, crashed the process)
        content = _netcdf_bytes(ds, _encoding(ds), unlimited_dims=[d for d in _GROWING if d in ds.dims])
        _check_free_space(self.path, folder, len(content))
        _fault("before-write")
        self._replace_with(tmp, folder, mode, lambda path: _write_file(path, content))

    def _replace_with(self, tmp: Path, folder: Path, mode, fill) -> None:
        """Write the temporary file ``tmp`` with ``fill(tmp)``, give it the store's permission bits
        ``mode`` and move it over the store (:func:`os.replace`, then ``fsync`` of the folder).
        On any error ``tmp`` is removed and the store is untouched; an ``OSError`` becomes one
        :class:`StoreError` line."""
        try:
            fill(tmp)
            if os.environ.get(FAULT_ENV) == "mid-write":  # pragma: no cover - simulate a torn temporary file
                os.truncate(tmp, os.path.getsize(tmp) // 2)
                _fault("mid-write")
            if mode is not None:
                os.chmod(tmp, mode)
            _fault("before-replace")
            os.replace(tmp, self.path)
        except OSError as err:
            with contextlib.suppress(OSError):
                os.remove(tmp)
            raise StoreError(f"{self.path}: cannot write the run store: {_os_message(err)}; the previous "
                             f"store is kept") from None
        except BaseException:
            with contextlib.suppress(OSError):
                os.remove(tmp)
            raise
        _fsync_dir(folder)
        self._stamp = _file_stamp(self.path)
        self._disk_steps = self.n_steps
        _fault("after-replace")

    def _append_to_copy(self, ds, folder: Path, tmp: Path, mode) -> bool:
        """Write by appending: copy the file (in the kernel; a reflink where the filesystem has them),
        append the new steps' rows to the copy, ``fsync`` and :func:`os.replace` it.

        Used when the file on disk holds this object's first steps unchanged (no
        ``replace_last`` since) in the appendable layout; returns False (nothing written)
        otherwise, and the caller writes the whole file. Readers see the old file or the
        new one, as with a whole write.
        """
        import h5netcdf

        if not (self._disk_steps and self._disk_steps < self.n_steps and self._stamp is not None
                and _file_stamp(self.path) == self._stamp):
            return False
        old_size = os.path.getsize(self.path)
        _check_free_space(self.path, folder, old_size + 4 * sum(
            v.values[self._disk_steps:].nbytes if v.dtype != object else 0 for v in ds.variables.values()
            if v.dims and v.dims[0] == "step") + 1024 * 1024)
        _fault("before-write")

        def append_rows(path):
            _copy_file(self.path, path)
            with open(path, "r+b") as fh:
                pending = _PendingWrites(fh)   # HDF5 writes to memory; applied below with plain OS calls
                with h5netcdf.File(pending, "r+") as f:
                    if not _appendable(f, ds, self._disk_steps):
                        raise _NotAppendable
                    old = {dim: f.dimensions[dim].size for dim in _GROWING if dim in ds.dims}
                    for dim in old:
                        f.resize_dimension(dim, ds.sizes[dim])
                    for name, var in ds.variables.items():
                        if var.dims and var.dims[0] in old:
                            f.variables[name][old[var.dims[0]]:] = var.values[old[var.dims[0]]:]
                    for key, value in ds.attrs.items():
                        f.attrs[key] = value
                pending.apply()

        try:
            self._replace_with(tmp, folder, mode, append_rows)
        except _NotAppendable:  # the temporary copy is already removed: write the whole file instead
            return False
        return True

    # ---------------------------------------------------------------- the state
    def _mixture(self, i) -> GaussianMixture:
        centres, bandwidth, log_weights = self.mixtures[i]
        mixture = GaussianMixture(centres, bandwidth, log_weights)
        # keep the stored normalised weights bit for bit (normalising twice may move the last ulp)
        object.__setattr__(mixture, "log_weights", np.asarray(log_weights, dtype=float))
        return mixture

    def state_at(self, step: int) -> tuple[SamplerState, tuple, dict]:
        """``(state, records, rng_state)`` after ``step`` datasets, for :meth:`SEMC.restore`."""
        if not 0 <= step <= self.n_steps:
            raise ValueError(f"step: must lie in [0, {self.n_steps}], got {step}")
        if self.config.predictive_method == "smc2":  # the default inner filter's outer particles hold every column
            if step == 0:
                state = start_nested(self.config.build_prior(), np.arange(self.initial_particles.shape[1]),
                                     self.initial_particles, self.initial_step_size)
            else:
                datasets = tuple(as_likelihood_data(t, self.config) for t in self.tables[:step])
                guides = tuple(nested_guide(arrays) for arrays in self.nested[:step - 1])
                state = nested_state_from_arrays(self.nested[step - 1], datasets, guides)
        elif step == 0:
            state = SamplerState(step=0, particles=self.initial_particles, log_weights=self.initial_log_weights,
                                 prior=self.config.build_prior(), log_evidence=0.0,
                                 step_size=self.initial_step_size)
        else:
            rec = self.result.steps[step - 1]
            # the sampler's state after a step is built from the step's record (sequential.assimilate);
            # _check_state verifies this identity whenever a state is stored
            if self.log_priors:
                datasets = tuple(as_likelihood_data(t, self.config) for t in self.tables[:step])
                prior, log_prior = (HistoryPrior(self.config.build_prior(), datasets, rec.info.log_evidence),
                                    self.log_priors[step - 1])
            else:
                prior, log_prior = self._mixture(step - 1), None
            state = SamplerState(step=step, particles=rec.predictive, log_weights=rec.log_weights,
                                 prior=prior, log_evidence=rec.info.log_evidence,
                                 step_size=self.step_sizes[step - 1], posterior=rec.posterior,
                                 posterior_log_weights=rec.log_weights, log_prior=log_prior)
        return state, tuple(self.result.steps[:step]), self.rng_states[step]

    def _store_state(self, base: int, state: SamplerState, rng_state: dict, table) -> None:
        """Keep the sampler state after step ``base + 1`` (the steps after ``base`` are dropped)."""
        if isinstance(state, NestedState):
            self.nested = self.nested[:base] + [nested_state_arrays(state)]
            self.tables = self.tables[:base] + [table]
        elif isinstance(state.prior, HistoryPrior):
            self.log_priors = self.log_priors[:base] + [np.array(state.log_prior)]
            self.tables = self.tables[:base] + [table]
        else:
            self.mixtures = self.mixtures[:base] + [(np.array(state.prior.centres), np.array(state.prior.bandwidth),
                                                     np.array(state.prior.log_weights))]
        self.step_sizes = self.step_sizes[:base] + [float(state.step_size)]
        self.rng_states = self.rng_states[:base + 1] + [rng_state]

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
        found = "; ".join(f"{c.file or c.name} has sha256 {c.sha256[:12] or '(no source)'}" for c in candidates)
        return (f"{self.path}: the likelihood module changed since the run recorded it (sha256 {recorded[:12]} "
                f"for {where}); {found}; it is not run. If the change is intended, update with "
                f"--accept-model-change (API: accept_model_change=True): the new hash is recorded for the "
                f"steps that follow")

    def load_likelihood(self, accept_model_change: bool = False):
        """The run's likelihood, imported by file path from a file whose SHA-256 the run recorded.

        Candidates are :meth:`likelihood_candidates`; a module file whose content
        differs from the recorded one is not run (:class:`ModelChangedError`) unless
        ``accept_model_change``.
        """
        return self._verified_likelihood(accept_model_change)[0]

    def share_likelihood(self, executor, source: ModuleSource | None = None) -> None:
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

    def sampler(self, step: int | None = None, executor=None, loglike=None):
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
        sampler.restore(*self.state_at(step))
        return sampler

    # ------------------------------------------------------------- assimilation
    def check_new_dataset(self, digest: str, replace_last: bool = False) -> None:
        """Refuse a dataset already assimilated (unless it is the last step and ``replace_last``)."""
        if digest in self.digests:
            step = self.digests.index(digest) + 1
            if not (replace_last and step == self.n_steps):
                hint = (" (use --replace-last / replace_last=True to redo the last step)"
                        if step == self.n_steps else "")
                raise DuplicateDatasetError(f"{self.path}: this dataset was already assimilated as step {step} "
                                            f"(from {self.sources[step - 1]}, sha256 {digest[:12]}){hint}")

    def _reload_if_changed(self, replace_last: bool) -> None:
        """Under the lock: take in the steps another process (or object) stored since this one read the file."""
        if self._stamp is None or _file_stamp(self.path) == self._stamp:
            return
        if replace_last:
            raise StoreError(f"{self.path}: the run store changed since it was opened (another update); open it "
                             f"again before replacing the last step")
        fresh = RunStore.open(self.path)
        if fresh.config.fingerprint() != self.config.fingerprint():
            raise StoreError(f"{self.path}: the run store was replaced by a run of another model since it was "
                             f"opened")
        self.__dict__.update(fresh.__dict__)

    def assimilate(self, table, source: str = "<array>", *, replace_last: bool = False, executor=None,
                   loglike=None, write: bool = True, accept_model_change: bool = False):
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
        seqbayes.config.DataError
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
        with store_lock(self.path) if write else contextlib.nullcontext():
            if write:
                self._reload_if_changed(replace_last)
            if replace_last and self.n_steps == 0:
                raise StoreError(f"{self.path}: replace_last: no step to replace")
            self.check_new_dataset(digest, replace_last)
            base = self.n_steps - 1 if replace_last else self.n_steps
            self._disk_steps = min(self._disk_steps, base)
            function, module = self._verified_likelihood(accept_model_change)
            self.share_likelihood(executor, module)
            sampler = self.sampler(base, executor=executor, loglike=function if loglike is None else loglike)
            info = sampler.update(as_likelihood_data(table, self.config))
            state, records, rng_state = sampler.snapshot()
            if not (isinstance(state, NestedState)
                    or isinstance(state, SamplerState) and isinstance(state.prior, (GaussianMixture, HistoryPrior))):
                kind = type(state).__name__ if not isinstance(state, SamplerState) else type(state.prior).__name__
                raise StoreError(f"{self.path}: this seqbayes cannot store a sampler state of type {kind} yet "
                                 f"(predictive = {self.config.predictive_method!r}); set predictive = \"transition\" "
                                 f"under [sampler]; the run store is unchanged")
            _check_state(state, records[-1])
            # commit to memory only now that the step succeeded
            self.result = _replace(sampler.result, steps=tuple(records))
            self._store_state(base, state, rng_state, table)
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

    def update(self, datafile, *, replace_last: bool = False, executor=None, loglike=None,
               accept_model_change: bool = False):
        """Read a CSV/NetCDF data file (:func:`~seqbayes.config.read_datafile`) and :meth:`assimilate` it."""
        table = read_datafile(datafile, self.config)
        return self.assimilate(table, Path(datafile).name, replace_last=replace_last, executor=executor,
                               loglike=loglike, accept_model_change=accept_model_change)

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
                                 direction=direction, rng=sampler.rng, paths_per_sample=paths_per_sample)

    def to_arviz(self, step: int | None = None, rng=None, **kwargs):
        """The run as :class:`arviz.InferenceData` (:meth:`seqbayes.Result.to_arviz`; step 1's prior
        draws are the run's own initial draws)."""
        return self.result.to_arviz(step, rng, prior=self.initial_particles, **kwargs)


def _likelihood_not_needed(theta, data):  # pragma: no cover - a sampler built only to draw or forecast
    raise RuntimeError("the likelihood is not loaded for forecasts and new runs")


_NETCDF3 = (b"CDF\x01", b"CDF\x02", b"CDF\x05")
_HDF5 = b"\x89HDF\r\n\x1a\n"


def _read_dataset(path: Path):
    """The store's :class:`xarray.Dataset`, loaded; a :class:`StoreError` for anything that is not one."""
    import xarray as xr

    if path.is_dir():
        raise StoreError(f"{path}: is a folder, not a run store")
    if not path.is_file():
        raise StoreError(f"{path}: no such run store (create one with `seqbayes init CONFIG {path}`)")
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
    except OSError as err:
        raise StoreError(f"{path}: cannot read the run store: {_os_message(err)}") from None
    if head[:4] in _NETCDF3:
        raise StoreError(f"{path}: a NetCDF-3 (classic) file; run stores are NetCDF-4 (HDF5) files written by "
                         f"`seqbayes init`, so this is not a run store")
    if head != _HDF5:
        raise StoreError(f"{path}: not a run store (not a NetCDF-4/HDF5 file)")
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            return ds.load()
    except Exception as err:
        hint = ("; a checksum failed: the file is corrupted" if "filter" in str(err).lower()
                or "checksum" in str(err).lower() else "")
        raise StoreError(f"{path}: cannot read the run store: {type(err).__name__}: {err}{hint}") from None


def _json(text, path, what):
    try:
        return json.loads(str(text))
    except json.JSONDecodeError as err:
        raise StoreError(f"{path}: damaged run store: {what} is not valid JSON ({err})") from None


def _read_state(path: Path, ds, config: RunConfig, n_steps: int) -> dict:
    """The per-step sampler state (see :meth:`RunStore._state_variables`) as :class:`RunStore` keywords."""
    rng_states = [_json(v, path, f"rng_state[{i}]") for i, v in enumerate(ds["rng_state"].values)]
    for i, state in enumerate(rng_states):
        if not (isinstance(state, dict) and isinstance(state.get("bit_generator"), str)
                and isinstance(state.get("state"), dict)):
            raise StoreError(f"{path}: damaged run store: rng_state[{i}] is not a numpy generator state")
    state = {"rng_states": rng_states, "mixtures": [], "log_priors": [], "tables": [], "step_sizes": [],
             "nested": []}
    if not n_steps:
        return state
    state["step_sizes"] = [float(v) for v in ds["state_step_size"].values]
    if "dataset_rows" in ds:
        rows = ds["dataset_rows"].values
        if rows.shape != (n_steps,) or int(rows.sum()) != ds["dataset_values"].shape[0]:
            raise StoreError(f"{path}: inconsistent store (dataset_rows {rows.tolist()} for "
                             f"{ds['dataset_values'].shape[0]} stored data rows)")
        state["tables"] = np.split(ds["dataset_values"].values, np.cumsum(rows)[:-1])
    nested_keys = [name for name in ds.data_vars if name.startswith("nested_")]
    if "state_log_prior" in ds:
        state["log_priors"] = list(ds["state_log_prior"].values)
    elif nested_keys:
        state["nested"] = [{name[len("nested_"):]: ds[name].values[i] for name in nested_keys}
                           for i in range(n_steps)]
    else:
        state["mixtures"] = [(ds["mixture_centres"].values[i], ds["mixture_bandwidth"].values[i],
                              ds["mixture_log_weights"].values[i]) for i in range(n_steps)]
        if config.predictive_method == "history":
            raise StoreError(f"{path}: written by an earlier seqbayes, which gave static parameters a "
                             f"kernel-density prior; this version uses their exact history prior. Re-create "
                             f"the run (seqbayes init --force) and assimilate its datasets again, or keep "
                             f"the seqbayes version that wrote it ({ds.attrs.get('seqbayes_version', '?')})")
    return state


def _check_finite(path: Path, ds) -> None:
    """Refuse NaN (or inf) samples and NaN weights: a store holding them cannot be resumed."""
    finite = ("posterior", "predictive", "initial_particles", "mixture_centres", "mixture_bandwidth",
              "dataset_values")
    not_nan = ("log_weights", "initial_log_weights", "mixture_log_weights", "state_log_prior")
    for name in finite + not_nan:
        if name in ds:
            values = ds[name].values
            bad = np.isnan(values) if name in not_nan else ~np.isfinite(values)
            if bad.any():
                where = np.argwhere(bad)[0]
                raise StoreError(f"{path}: damaged run store: {name} holds {int(bad.sum())} NaN/inf value(s), "
                                 f"first at index {tuple(int(i) for i in where)}")
    if "log_weights" in ds and (ds["log_weights"].values == np.inf).any():
        raise StoreError(f"{path}: damaged run store: log_weights holds +inf")


#: Text variables and attributes covered by the store's content hash (the numeric arrays carry
#: HDF5 Fletcher-32 checksums).
_HASHED_TEXT = ("step_info", "rng_state", "dataset_sha256", "dataset_source", "likelihood_sha256")
_HASHED_ATTRS = ("config", "model_fingerprint", "n_steps", "initial_step_size", "result_meta")


def _content_hash(ds) -> str:
    """SHA-256 of the store's text records and key attributes (see :data:`_HASHED_TEXT`)."""
    h = hashlib.sha256()
    for key in _HASHED_ATTRS:
        h.update(json.dumps([key, str(ds.attrs.get(key))]).encode())
    for name in _HASHED_TEXT:
        if name in ds:
            h.update(json.dumps([name, [str(v) for v in ds[name].values]]).encode())
    return h.hexdigest()


#: Dimensions that grow with the run (unlimited in the file, so that a step can be appended),
#: with the chunk length along them.
_GROWING = {"step": 8, "rng_index": 8, "dataset_row": 256}


class _NotAppendable(Exception):
    """The file on disk cannot take the new steps by appending (another layout or content)."""


def _encoding(ds) -> dict:
    """HDF5 Fletcher-32 checksums on the numeric arrays (verified on read) and, along the growing
    dimensions, chunks of a few steps, so that appending a step writes a few chunks."""
    encoding = {}
    for name, var in ds.variables.items():
        enc = {}
        if var.dtype.kind in "fiu" and var.ndim and var.size:
            enc["fletcher32"] = True
        if var.dims and var.dims[0] in _GROWING:
            enc["chunksizes"] = (_GROWING[var.dims[0]],) + tuple(var.shape[1:])
        if enc:
            encoding[name] = enc
    return encoding


def _appendable(f, ds, disk_steps: int) -> bool:
    """Whether the open file ``f`` is ``ds`` minus the rows after ``disk_steps`` steps."""
    if int(f.attrs.get("n_steps", -1)) != disk_steps or set(f.variables) != set(ds.variables):
        return False
    for dim, size in ds.sizes.items():
        if dim not in f.dimensions:
            return False
        if dim in _GROWING:
            if not f.dimensions[dim].isunlimited() or f.dimensions[dim].size > size:
                return False
        elif f.dimensions[dim].size != size:
            return False
    return all(tuple(f.variables[name].dimensions) == tuple(var.dims) for name, var in ds.variables.items())


class _PendingWrites(io.RawIOBase):
    """The file HDF5 appends to: reads come from the file with the pending writes laid over them,
    writes stay in memory until :meth:`apply` writes them with plain OS calls. So a full disk or an
    I/O error is an OSError raised here, never inside HDF5 (where ENOSPC crashed the process)."""

    PAGE = 1 << 16

    def __init__(self, fh):
        self.fd = fh.fileno()
        self.size = os.fstat(self.fd).st_size       # the logical size
        self.on_disk = self.size                    # bytes of the file below which the disk content is valid
        self.pages = {}
        self.pos = 0

    def readable(self):
        return True

    def writable(self):
        return True

    def seekable(self):
        return True

    def seek(self, offset, whence=io.SEEK_SET):
        self.pos = {io.SEEK_SET: 0, io.SEEK_CUR: self.pos, io.SEEK_END: self.size}[whence] + offset
        return self.pos

    def tell(self):
        return self.pos

    def _disk(self, start, length) -> bytes:
        valid = max(0, min(length, self.on_disk - start))
        data = os.pread(self.fd, valid, start) if valid else b""
        return data.ljust(length, b"\0")

    def readinto(self, buffer):
        view = memoryview(buffer).cast("B")
        n = max(0, min(len(view), self.size - self.pos))
        done = 0
        while done < n:
            index, offset = divmod(self.pos + done, self.PAGE)
            take = min(self.PAGE - offset, n - done)
            page = self.pages.get(index)
            view[done:done + take] = (page[offset:offset + take] if page is not None
                                      else self._disk(self.pos + done, take))
            done += take
        self.pos += n
        return n

    def write(self, data):
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):
            index, offset = divmod(self.pos + done, self.PAGE)
            take = min(self.PAGE - offset, len(view) - done)
            page = self.pages.get(index)
            if page is None:
                page = self.pages[index] = bytearray(self._disk(index * self.PAGE, self.PAGE))
            page[offset:offset + take] = view[done:done + take]
            done += take
        self.pos += len(view)
        self.size = max(self.size, self.pos)
        return len(view)

    def truncate(self, size=None):
        size = self.pos if size is None else size
        if size < self.size:                        # what lies beyond must read as zeros if the file grows again
            self.on_disk = min(self.on_disk, size)
            for index in [i for i in self.pages if i * self.PAGE >= size]:
                del self.pages[index]
            if size // self.PAGE in self.pages:
                page = self.pages[size // self.PAGE]
                page[size % self.PAGE:] = bytes(self.PAGE - size % self.PAGE)
        self.size = size
        return size

    def flush(self):
        pass

    def apply(self) -> None:
        """Write the pending pages, set the size and ``fsync``."""
        for index in sorted(self.pages):
            start = index * self.PAGE
            if start < self.size:
                view = memoryview(self.pages[index])[:min(self.PAGE, self.size - start)]
                while view:
                    written = os.pwrite(self.fd, view, start)
                    view, start = view[written:], start + written
        os.ftruncate(self.fd, self.size)
        os.fsync(self.fd)


def _copy_file(source: Path, target: Path) -> None:
    """Copy a file in the kernel (``copy_file_range``: a reflink on filesystems that share extents)."""
    with open(source, "rb") as fin, open(target, "wb") as fout:
        remaining = os.fstat(fin.fileno()).st_size
        try:
            while remaining > 0:
                copied = os.copy_file_range(fin.fileno(), fout.fileno(), remaining)
                if copied == 0:
                    break
                remaining -= copied
        except OSError as err:
            if err.errno not in (errno.EXDEV, errno.ENOSYS, errno.EOPNOTSUPP, errno.EINVAL):
                raise
            fin.seek(0)
            fout.seek(0)
            fout.truncate()
            shutil.copyfileobj(fin, fout)


def _netcdf_bytes(ds, encoding, unlimited_dims=()):
    """The NetCDF-4 file of ``ds`` as bytes. With a Dask client active xarray would take a
    distributed lock named after the target (here a buffer); the write is local, so Dask's
    synchronous scheduler is used for it."""
    kwargs = dict(engine="h5netcdf", encoding=encoding, unlimited_dims=list(unlimited_dims))
    if "dask" in sys.modules:
        import dask

        with dask.config.set(scheduler="synchronous"):
            return ds.to_netcdf(**kwargs)
    return ds.to_netcdf(**kwargs)


def _write_file(path: Path, content) -> None:
    """Write ``content`` to a new file ``path`` and ``fsync`` it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
    try:
        view = memoryview(content)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
    finally:
        os.close(fd)


def _check_free_space(path: Path, folder: Path, needed: int) -> None:
    """Refuse a write the folder has no room for (the old file stays until the new one is complete)."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:  # pragma: no cover - no statvfs
        return
    if free < needed:
        raise StoreError(f"{path}: not enough free space in {folder}: about {needed // 1024} KiB needed, "
                         f"{free // 1024} KiB free ({os.strerror(errno.ENOSPC)}); the previous store is kept")


def _step_info(values: dict) -> StepInfo:
    """A :class:`StepInfo` from its stored dict (see :meth:`StepInfo.from_dict`)."""
    return StepInfo.from_dict(values)


def _check_state(state: SamplerState, record: StepRecord) -> None:
    if isinstance(state, NestedState):  # SMC^2 keeps its own arrays; its posterior is the record's
        same = (np.array_equal(state.particles, record.posterior) and np.array_equal(state.log_weights, record.log_weights)
                and state.log_evidence == record.info.log_evidence)
    else:
        same = (np.array_equal(state.particles, record.predictive)
                and np.array_equal(state.log_weights, record.log_weights)
                and np.array_equal(state.posterior, record.posterior) and state.log_evidence == record.info.log_evidence)
    if not same:  # pragma: no cover - guards the identity state_at relies on
        raise StoreError("the sampler state differs from its step record; the run-store format needs updating")


def posterior_to_arviz(result: Result, step: int | None = -1, rng=None, **kwargs):
    """A step's posterior (``step=None``: every step) as :class:`arviz.InferenceData`:
    :meth:`seqbayes.Result.to_arviz`."""
    return result.to_arviz(step, rng, **kwargs)
