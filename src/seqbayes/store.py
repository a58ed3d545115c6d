"""The run store: a monitoring run on disk that resumes exactly where it stopped.

One run is one NetCDF-4 file. After every completed step it holds the whole
sampler state: the posterior and predictive samples of every step with their
weights and diagnostics (the :class:`~seqbayes.results.Result` layout), the
arrays the sampler needs to resume (:mod:`seqbayes.snapshot`: the next step's prior
density, or the values and datasets it re-evaluates), the stretch-move step size,
the cumulative log-evidence, the random generator's state after each step, the initial
prior draws, the validated configuration (prior, kernel, likelihood ``module:function``,
sampler settings), a format version, a model fingerprint and a content hash of every
assimilated dataset. A new process that opens the store and assimilates the next
dataset gives bit-for-bit the numbers of an uninterrupted run with the same seed,
because the sampler is rebuilt from the stored configuration and then
:meth:`~seqbayes.engine.drivers.SEMC.restore`-d to the stored state and generator. The
store does not know what the sampler's state is made of: :func:`seqbayes.snapshot.state_arrays`
turns it into named arrays, which the store writes per step, and
:func:`seqbayes.snapshot.state_from_arrays` turns them back.

Keeping every step's state (not only the last) allows :meth:`RunStore.assimilate` with
``replace_last=True``: the run is rolled back to the step before and the new dataset
assimilated in its place.

Writes are atomic, and an update writes only what it adds. A new step is appended
in place, through a redo journal: HDF5 appends the step's rows to an in-memory overlay
of the file (:class:`_PendingWrites`), the changed pages are written to the journal
``.RUN.journal`` with their SHA-256 and ``fsync``-ed (from then on the step is
committed), written into the store under an exclusive lock on it, and the journal is
removed. A crash before the journal is complete leaves the store as it was (an
incomplete journal is ignored and removed); a crash after it leaves a complete journal,
which readers lay over the file and the next writer applies (writing pages is
idempotent). Readers hold a shared lock on the file while they read it, so they see the
store before or after a step, never between. A new layout (the first step,
``replace_last``, an older store) is written whole by HDF5 to memory, then to a
temporary file in the same folder (``.RUN.tmp-PID``) with plain OS calls, ``fsync``-ed and
moved over the old one with :func:`os.replace` keeping the old file's permission bits. A
full disk or a read-only folder is one :class:`StoreError`. Every read-modify-write
(:meth:`RunStore.assimilate`, :meth:`RunStore.write`) holds an exclusive lock on
``RUN.lock``; an object that opened the store before another process stored a step
takes that step in first, so concurrent updates are all kept. The locks are ``flock``
on POSIX and ``msvcrt.locking`` on Windows (:func:`lock_file`).

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
``(step, sample)``, the state arrays of :mod:`seqbayes.snapshot` (e.g.
``mixture_centres (step, sample, parameter)``), with ``dataset_values (dataset_row, column)``
and ``dataset_rows (step)`` when the state needs the datasets,
``diagnostics (step, diagnostic)`` (acceptance, ESS, evidence, ... as float64 for
any NetCDF reader), ``step_info`` (the exact :class:`~seqbayes.results.StepInfo`
as JSON), ``dataset_sha256``, ``dataset_source``, ``likelihood_sha256``, ``record_sha256``,
``state_step_size``, ``initial_particles``, ``initial_log_weights``, ``rng_state (rng_index)``;
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
import datetime as _dt
import errno
import hashlib
import io
import json
import mmap
import os
import shutil
import signal
import struct
import sys
import threading
import time
import warnings
from dataclasses import replace as _replace
from pathlib import Path

import numpy as np

from . import snapshot
from .config import NOT_FINGERPRINTED, RunConfig
from .modules import ConfigError, ModuleSource, load_located, locate_module
from .datasets import as_likelihood_data, check_table, dataset_digest, read_datafile
from .prognostics import FirstPassage, time_to_threshold
from .results import Result, StepInfo, StepRecord

__all__ = ["RunStore", "StoreError", "DuplicateDatasetError", "ModelChangedError", "BoundWarning",
           "FORMAT_VERSION", "store_lock", "lock_file"]

#: Version of the on-disk layout; a store of another version is refused. Version 2 added the
#: history prior of static kernels, version 3 the likelihood module's hash per step, the
#: content hash of the text variables and HDF5 checksums, version 4 the per-step record
#: hashes (so that an appended step hashes only its own records). Versions 1 to 3 are still
#: read; the next update rewrites them in version 4.
FORMAT_VERSION = 4
_READABLE_VERSIONS = (1, 2, 3, 4)

#: Environment variable naming a fault-injection point (tests only): the process
#: SIGKILLs itself there. One of ``before-write``, ``mid-write`` (the temporary file or the
#: journal half written), ``before-replace`` (complete, not yet in place), ``mid-apply`` (half
#: the journal's pages written into the store), ``after-replace``.
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


# ------------------------------------------------------------------------- locks
def lock_file(fh: BinaryIO, exclusive: bool = True) -> None:
    """Block until this process holds an advisory lock on the open file ``fh``.

    POSIX: ``flock`` (shared or exclusive, released when ``fh`` is closed or by
    :func:`unlock_file`). Windows: ``msvcrt.locking`` of one byte far beyond any
    run store's end (Windows locks are mandatory, so a lock on the content would block
    readers of it), always exclusive, retried every 10 ms.
    """
    if os.name == "nt":  # pragma: no cover - exercised on Windows only
        import msvcrt

        fh.seek(_WINDOWS_LOCK_OFFSET)
        while True:
            try:
                msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)
                return
            except OSError:
                time.sleep(0.01)
    import fcntl

    fcntl.flock(fh.fileno(), fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)


def unlock_file(fh) -> None:
    """Release :func:`lock_file`'s lock on ``fh``."""
    if os.name == "nt":  # pragma: no cover - exercised on Windows only
        import msvcrt

        fh.seek(_WINDOWS_LOCK_OFFSET)
        msvcrt.locking(fh.fileno(), msvcrt.LK_UNLCK, 1)
        return
    import fcntl

    fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


_WINDOWS_LOCK_OFFSET = 2 ** 40
_LOCKS: dict = {}                      # resolved lock path -> [threading.RLock, depth, open lock file]
_LOCKS_GUARD = threading.Lock()


@contextlib.contextmanager
def store_lock(path: str | os.PathLike) -> Iterator[None]:
    """Exclusive advisory lock on ``<path>.lock`` (:func:`lock_file`), held for a read-modify-write.

    Re-entrant within a process (the CLI holds it around :meth:`RunStore.assimilate`, which
    takes it too) and exclusive between threads and between processes. The lock file
    stays (removing it would let two processes lock two different files).

    Raises
    ------
    StoreError
        The lock file cannot be created (a read-only folder, ...).
    """
    lock_path = str(path) + ".lock"
    key = os.path.abspath(lock_path)
    with _LOCKS_GUARD:
        entry = _LOCKS.setdefault(key, [threading.RLock(), 0, None])
    with entry[0]:
        if entry[1] == 0:
            try:
                fh = open(lock_path, "a+b")
            except OSError as err:
                raise StoreError(f"{path}: cannot take the lock {lock_path}: {_os_message(err)}") from None
            lock_file(fh)
            entry[2] = fh
        entry[1] += 1
        try:
            yield
        finally:
            entry[1] -= 1
            if entry[1] == 0:
                fh, entry[2] = entry[2], None
                unlock_file(fh)
                fh.close()


def _os_message(err: OSError) -> str:
    """``strerror`` (and the file, when the error names one) of an OS error, for one-line messages."""
    text = err.strerror or str(err)
    return f"{text} ({err.filename})" if err.filename else text


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


# ------------------------------------------------------------------ content hashes
#: Attributes covered by the store's content hash (the numeric arrays carry HDF5 Fletcher-32 checksums).
_HASHED_ATTRS = ("config", "model_fingerprint", "n_steps", "initial_step_size", "result_meta")
#: A step's text records, in the order its record hash takes them (``rng_state`` of the step is
#: the generator state after it).
_RECORD_TEXT = ("step_info", "rng_state", "dataset_sha256", "dataset_source", "likelihood_sha256")


def _record_hash(texts) -> str:
    """SHA-256 of one step's text records (:data:`_RECORD_TEXT`, in that order)."""
    return hashlib.sha256(json.dumps([str(t) for t in texts]).encode()).hexdigest()


def _content_hash(attrs: dict, initial_rng: str, record_hashes) -> str:
    """The store's content hash (format 4): its key attributes, the generator state before the
    first step and the record hash of every step. A step appended adds one record hash."""
    h = hashlib.sha256()
    for key in _HASHED_ATTRS:
        h.update(json.dumps([key, str(attrs.get(key))]).encode())
    h.update(json.dumps(["rng_state", str(initial_rng)]).encode())
    h.update("".join(record_hashes).encode())
    return h.hexdigest()


def _rehash(ds) -> None:
    """Redo the record and content hashes of a store as an :class:`xarray.Dataset` (what a writer
    does): tests use it to make an edit consistent and check what else catches it."""
    rng = [str(v) for v in ds["rng_state"].values]
    n_steps = int(ds.attrs["n_steps"])
    hashes = []
    if n_steps:
        columns = [rng[1:] if name == "rng_state" else [str(v) for v in ds[name].values] for name in _RECORD_TEXT]
        hashes = [_record_hash(texts) for texts in zip(*columns)]
        ds["record_sha256"] = (("step",), np.array(hashes, dtype=object))
    ds.attrs["content_sha256"] = _content_hash(ds.attrs, rng[0], hashes)


def _content_hash_v3(attrs: dict, variables: dict) -> str:
    """The content hash of format 3 stores (all text records hashed together), to verify them on open."""
    h = hashlib.sha256()
    for key in _HASHED_ATTRS:
        h.update(json.dumps([key, str(attrs.get(key))]).encode())
    for name in _RECORD_TEXT:
        if name in variables:
            h.update(json.dumps([name, [str(v) for v in variables[name]]]).encode())
    return h.hexdigest()


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
    states : list of dict
        Per step, the sampler's state arrays (:func:`seqbayes.snapshot.state_arrays`).
    tables : list of (n_rows, n_columns) arrays
        The assimilated datasets, kept when the state needs them (:func:`seqbayes.snapshot.needs_datasets`).
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
                 rng_states, result: Result, states, step_sizes, digests, sources, tables=(), created=None,
                 module_hashes=None, record_hashes=None):
        self.path = Path(path)
        self.config = config
        self.initial_particles = initial_particles
        self.initial_log_weights = initial_log_weights
        self.initial_step_size = float(initial_step_size)
        self.rng_states = list(rng_states)          # S + 1 generator states (after step 0, 1, ..., S)
        self.result = result
        self.states = list(states)                  # S dicts of state arrays (seqbayes.snapshot)
        self.tables = list(tables)                  # the S datasets, when the state needs them
        self.step_sizes = list(step_sizes)          # S state step sizes
        self.digests = list(digests)
        self.sources = list(sources)
        # SHA-256 of the likelihood module each step ran ("" for steps written before they were recorded)
        self.module_hashes = list(module_hashes) if module_hashes is not None else [""] * len(self.digests)
        self.created = created or _now()
        # record hash of each step's text (verified ones from the file; new steps hash when written)
        self._record_hashes = list(record_hashes or ())
        self._token = None                          # (content hash, n_steps) of the file as last read or written
        self._disk_steps = 0                        # leading steps the file holds exactly as this object does

    # ----------------------------------------------------------------- creation
    @classmethod
    def create(cls, path: str | os.PathLike, config: RunConfig, *, overwrite: bool = False) -> "RunStore":
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
                        rng_states=[rng_state], result=Result(sampler.names, (), {}), states=[], step_sizes=[],
                        digests=[], sources=[])
            store.write()
        return store

    # ------------------------------------------------------------------ reading
    @classmethod
    def open(cls, path: str | os.PathLike, config: RunConfig | None = None) -> "RunStore":
        """Load a run store (this runs no user code).

        Reads the file under a shared lock (so never between the two halves of a step
        another process appends), laying a committed journal over it, and verifies it.

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
        attrs, variables = _read_file(path)
        try:
            store = cls._from_file(path, attrs, variables, config)
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
    def _from_file(cls, path: Path, attrs: dict, variables: dict, config: RunConfig | None) -> "RunStore":
        version = attrs.get("seqbayes_store_format")
        if attrs.get("run_kind", "semc") != "semc":
            raise StoreError(f"{path}: an SG-EnMCMC run store (run_kind {attrs.get('run_kind')!r}); open it with "
                             f"seqbayes.SGRunStore.open (the seqbayes commands init, update, status and report "
                             f"take it)")
        if version is None:
            raise StoreError(f"{path}: not a seqbayes run store (no seqbayes_store_format attribute)")
        if int(version) not in _READABLE_VERSIONS:
            raise StoreError(f"{path}: run-store format version {int(version)}, but this seqbayes reads versions "
                             f"{', '.join(map(str, _READABLE_VERSIONS))}; use the seqbayes version that wrote it "
                             f"(it says {attrs.get('seqbayes_version', '?')})")
        version = int(version)
        if "n_steps" not in attrs or "rng_state" not in variables:
            raise StoreError(f"{path}: damaged run store: missing {'n_steps' if 'n_steps' not in attrs else 'rng_state'}")
        n_steps = int(attrs["n_steps"])
        text = {name: [str(v) for v in variables[name]] for name in _RECORD_TEXT + ("record_sha256",)
                if name in variables}
        rng_text = text["rng_state"]
        if not (len(rng_text) == n_steps + 1 and all(len(text.get(name, ())) == n_steps for name in _RECORD_TEXT
                                                     if name not in ("rng_state", "likelihood_sha256") and n_steps)):
            raise StoreError(f"{path}: inconsistent store ({len(text.get('step_info', ()))} steps, {len(rng_text)} "
                             f"generator states, {len(text.get('dataset_sha256', ()))} dataset hashes, n_steps = "
                             f"{n_steps})")
        module_hashes = text.get("likelihood_sha256", [""] * n_steps)
        per_step = list(zip(text.get("step_info", ()), rng_text[1:], text.get("dataset_sha256", ()),
                            text.get("dataset_source", ()), module_hashes))
        record_hashes = [_record_hash(texts) for texts in per_step]
        if version >= 4:
            if n_steps and "record_sha256" not in variables:
                raise StoreError(f"{path}: damaged run store: missing variable(s) record_sha256")
            bad = [i + 1 for i, (a, b) in enumerate(zip(text.get("record_sha256", []), record_hashes)) if a != b]
            if bad or attrs.get("content_sha256") != _content_hash(attrs, rng_text[0], record_hashes):
                where = f" (the records of step {bad[0]})" if bad else ""
                raise StoreError(f"{path}: damaged run store: the content hash of its configuration and records "
                                 f"does not match{where} (the file was edited or corrupted)")
        if version == 3 and attrs.get("content_sha256") != _content_hash_v3(attrs, variables):
            raise StoreError(f"{path}: damaged run store: the content hash of its configuration and records "
                             f"does not match (the file was edited or corrupted)")
        try:
            stored = RunConfig.from_dict(json.loads(attrs["config"]))
        except (json.JSONDecodeError, TypeError) as err:
            raise StoreError(f"{path}: damaged run store: unreadable config attribute ({err})") from None
        if stored.fingerprint() != attrs.get("model_fingerprint"):
            raise StoreError(f"{path}: model fingerprint does not match the stored configuration "
                             f"(the file was edited or written by an incompatible seqbayes)")
        if config is not None and config.fingerprint() != stored.fingerprint():
            fields = ", ".join(_config_diff(stored, config)) or "?"
            raise StoreError(f"{path}: the run was created for another model (fingerprint "
                             f"{stored.fingerprint()[:12]} vs {config.fingerprint()[:12]}); differing fields: {fields}")
        state_names = [name for name in variables if snapshot.is_state_variable(name)]
        required = ["initial_particles", "initial_log_weights"]
        if n_steps:
            required += ["posterior", "log_weights", "predictive", "step_info", "dataset_sha256", "dataset_source",
                         "state_step_size"]
            if not state_names:
                required.append("mixture_centres" if stored.predictive_method != "smc2" else "nested_outer")
        missing = [name for name in required if name not in variables]
        if missing:
            raise StoreError(f"{path}: damaged run store: missing variable(s) {', '.join(missing)}")
        rng_states = _json_list(rng_text, path, "rng_state")
        for i, state in enumerate(rng_states):
            if not (isinstance(state, dict) and isinstance(state.get("bit_generator"), str)
                    and isinstance(state.get("state"), dict)):
                raise StoreError(f"{path}: damaged run store: rng_state[{i}] is not a numpy generator state")
        records = [StepRecord(_step_info(info), variables["posterior"][i], variables["log_weights"][i],
                              variables["predictive"][i])
                   for i, info in enumerate(_json_list(text.get("step_info", []), path, "step_info"))]
        result = Result(stored.names, tuple(records), _json(attrs.get("result_meta", "{}"), path, "result_meta"))
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
        _check_finite(path, variables)
        return cls(path, stored, initial_particles=variables["initial_particles"],
                   initial_log_weights=variables["initial_log_weights"],
                   initial_step_size=float(attrs["initial_step_size"]), rng_states=rng_states, result=result,
                   states=states, step_sizes=step_sizes, digests=text.get("dataset_sha256", []),
                   sources=text.get("dataset_source", []), tables=tables, created=attrs.get("created"),
                   module_hashes=module_hashes, record_hashes=record_hashes)

    @property
    def n_steps(self) -> int:
        """Datasets assimilated so far."""
        return len(self.result.steps)

    @property
    def names(self) -> tuple:
        return tuple(self.config.names)

    # ------------------------------------------------------------------ writing
    def _step_texts(self, k: int) -> tuple:
        """Step ``k``'s (0-based) text records, in the order of :data:`_RECORD_TEXT`."""
        return (json.dumps(dataclasses.asdict(self.result.steps[k].info)), json.dumps(self.rng_states[k + 1]),
                self.digests[k], self.sources[k], self.module_hashes[k])

    def _attrs(self, record_hashes) -> dict:
        """The file's attributes, with the content hash over ``record_hashes``."""
        from . import __version__

        attrs = {"result_meta": json.dumps(self.result.meta, default=str),
                 "seqbayes_store_format": FORMAT_VERSION, "seqbayes_version": __version__,
                 "model_fingerprint": self.config.fingerprint(), "config": json.dumps(self.config.to_dict()),
                 "model_name": self.config.name, "n_steps": self.n_steps, "initial_step_size": self.initial_step_size,
                 "created": self.created, "updated": _now()}
        attrs["content_sha256"] = _content_hash(attrs, json.dumps(self.rng_states[0]), record_hashes)
        return attrs

    def _rows(self, start: int) -> tuple[dict, dict, list]:
        """``(data_vars, coords, texts)`` of steps ``start ..`` (0-based) along the growing dimensions,
        for :meth:`to_xarray` (``start = 0``) and the append of :meth:`write`; ``texts`` are the steps'
        :meth:`_step_texts`."""
        steps = self.result.steps[start:]
        texts = [self._step_texts(k) for k in range(start, self.n_steps)]
        rng_from = 0 if start == 0 else start + 1
        data = {"rng_state": (("rng_index",), np.array([json.dumps(s) for s in self.rng_states[rng_from:]],
                                                      dtype=object))}
        coords = {}
        if not steps:
            return data, coords, texts
        infos = [dataclasses.asdict(r.info) for r in steps]
        numeric = [k for k, v in infos[0].items() if isinstance(v, (int, float)) and k != "step"]
        coords.update(step=np.array([r.info.step for r in steps]), diagnostic=numeric)
        columns = list(zip(*texts))
        data.update({
            "posterior": (("step", "sample", "parameter"), np.stack([r.posterior for r in steps])),
            "log_weights": (("step", "sample"), np.stack([r.log_weights for r in steps])),
            "predictive": (("step", "sample", "parameter"), np.stack([r.predictive for r in steps])),
            # for readers without seqbayes; step_info holds the exact records
            "diagnostics": (("step", "diagnostic"), np.array([[float(i[k]) for k in numeric] for i in infos])),
            "step_info": (("step",), np.array(columns[0], dtype=object)),
            "dataset_sha256": (("step",), np.array(columns[2], dtype=object)),
            "dataset_source": (("step",), np.array(columns[3], dtype=object)),
            "likelihood_sha256": (("step",), np.array(columns[4], dtype=object)),
            "record_sha256": (("step",), np.array([_record_hash(t) for t in texts], dtype=object)),
            "state_step_size": (("step",), np.array(self.step_sizes[start:], dtype=float)),
        })
        for name in self.states[start]:
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
        return data, coords, texts

    def _hashes_through(self, texts, start: int) -> list:
        """Record hashes of every step: the known ones before ``start``, the others from ``texts``."""
        known = self._record_hashes[:start]
        if len(known) < start:  # steps read from a format 1-3 file: hash them now
            known += [_record_hash(self._step_texts(k)) for k in range(len(known), start)]
        return known + [_record_hash(t) for t in texts]

    def to_xarray(self) -> xr.Dataset:
        """The store's content as an :class:`xarray.Dataset` (what :meth:`write` saves)."""
        import xarray as xr

        data, coords, texts = self._rows(0)
        coords.update(sample=np.arange(self.initial_particles.shape[0]), parameter=list(self.names))
        ds = xr.Dataset(data, coords=coords)
        ds["initial_particles"] = (("sample", "parameter"), self.initial_particles)
        ds["initial_log_weights"] = (("sample",), self.initial_log_weights)
        ds.attrs.update(self._attrs(self._hashes_through(texts, 0)))
        return ds

    def write(self) -> None:
        """Write the store atomically: append the new steps through the journal, or write it whole.

        Holds the store's lock. The file keeps its permission bits. Refused up front
        when the folder lacks the free space the write needs.

        Raises
        ------
        StoreError
            The folder is read-only, full, or the path is a folder; the previous store is kept.
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
        """Append the steps after ``_disk_steps`` in place, through the journal (module docstring).

        Used when the file holds this object's first steps unchanged (no ``replace_last``
        since, no other writer) in the format-4 layout; returns False (nothing written)
        otherwise, and the caller writes the whole file.
        """
        import h5py

        start = self._disk_steps
        if not (0 < start < self.n_steps and self._token is not None and _read_token(self.path) == self._token):
            return False
        rows, coords, texts = self._rows(start)
        record_hashes = self._hashes_through(texts, start)
        attrs = self._attrs(record_hashes)
        data = {name: values for name, (dims, values) in rows.items()}
        data["step"] = coords["step"]
        try:
            with open(self.path, "rb") as fh:
                pending = _PendingWrites(fh)   # HDF5 writes to memory; applied below with plain OS calls
                with h5py.File(pending, "r+") as f:
                    if not _appendable(f, data, start, len(self.config.columns)):
                        return False
                    for name, values in data.items():
                        if name in _BARE_DIMS:       # the dimension without coordinates it grows along
                            _extend(f[_BARE_DIMS[name]], len(values))
                        _extend(f[name], len(values), values)
                    for key, value in attrs.items():
                        f.attrs[key] = value
                journal = (pending.on_disk, pending.size, pending.changes())
        except OSError as err:
            raise StoreError(f"{self.path}: cannot read the run store to append: {_os_message(err)}; the "
                             f"previous store is kept") from None
        _apply_with_journal(self.path, journal)
        self._written(attrs["content_sha256"], record_hashes)
        _fault("after-replace")
        return True

    # ---------------------------------------------------------------- the state
    def state_at(self, step: int) -> tuple:
        """``(state, records, rng_state)`` after ``step`` datasets, for :meth:`SEMC.restore`
        (the state from :func:`seqbayes.snapshot.state_from_arrays`)."""
        if not 0 <= step <= self.n_steps:
            raise ValueError(f"step: must lie in [0, {self.n_steps}], got {step}")
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
        if self._token is None or _read_token(self.path) == self._token:
            return
        if replace_last:
            raise StoreError(f"{self.path}: the run store changed since it was opened (another update); open it "
                             f"again before replacing the last step")
        fresh = RunStore.open(self.path)
        if fresh.config.fingerprint() != self.config.fingerprint():
            raise StoreError(f"{self.path}: the run store was replaced by a run of another model since it was "
                             f"opened")
        self.__dict__.update(fresh.__dict__)

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
        seqbayes.datasets.DataError
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
                _recover_journal(self.path)
                self._reload_if_changed(replace_last)
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

    def update(self, datafile: str | os.PathLike, *, replace_last: bool = False, executor: Any = None,
               loglike: Callable[[np.ndarray, Any], np.ndarray] | None = None,
               accept_model_change: bool = False) -> StepInfo:
        """Read a CSV/NetCDF data file (:func:`~seqbayes.datasets.read_datafile`) and :meth:`assimilate` it."""
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
                                 direction=direction, rng=sampler.rng, paths_per_sample=paths_per_sample,
                                 support=sampler.problem.support)

    def to_arviz(self, step: int | None = None, rng: int | np.random.Generator | None = None, **kwargs: Any) -> az.InferenceData:
        """The run as :class:`arviz.InferenceData` (:meth:`seqbayes.Result.to_arviz`; step 1's prior
        draws are the run's own initial draws)."""
        return self.result.to_arviz(step, rng, prior=self.initial_particles, **kwargs)



def _likelihood_not_needed(theta, data):  # pragma: no cover - a sampler built only to draw or forecast
    raise RuntimeError("the likelihood is not loaded for forecasts and new runs")


# -------------------------------------------------------------------------- reading
_NETCDF3 = (b"CDF\x01", b"CDF\x02", b"CDF\x05")
_HDF5 = b"\x89HDF\r\n\x1a\n"


def _plain(value):
    """An HDF5 attribute as a Python value (text attributes may come back as bytes)."""
    if isinstance(value, (bytes, np.bytes_)):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.shape == (1,):   # h5netcdf writes numbers as 1-element arrays
        return value[0]
    return value


def _read_file(path: Path) -> tuple[dict, dict]:
    """``(attributes, variables)`` of the store: every variable read whole (text as ``str``), under a
    shared lock on the file and through a committed journal; a :class:`StoreError` for anything that
    is not a readable run store."""
    import h5py

    if path.is_dir():
        raise StoreError(f"{path}: is a folder, not a run store")
    if not path.is_file():
        raise StoreError(f"{path}: no such run store (create one with `seqbayes init CONFIG {path}`)")
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
            if head[:4] in _NETCDF3:
                raise StoreError(f"{path}: a NetCDF-3 (classic) file; run stores are NetCDF-4 (HDF5) files written "
                                 f"by `seqbayes init`, so this is not a run store")
            if head != _HDF5:
                raise StoreError(f"{path}: not a run store (not a NetCDF-4/HDF5 file)")
            with contextlib.suppress(OSError):   # a filesystem without locks: read unlocked
                lock_file(fh, exclusive=False)
            journal = _read_journal(path)
            # HDF5 reads the file itself (faster than through Python) unless a journal is laid over it;
            # the shared lock taken on fh holds either way
            source = _PendingWrites(fh, journal) if journal is not None else path
            with h5py.File(source, "r") as f:
                attrs = {key: _plain(value) for key, value in f.attrs.items()}
                variables = {}
                for name, obj in f.items():
                    if not isinstance(obj, h5py.Dataset) or _bare_dimension(obj):
                        continue
                    variables[name] = obj.asstr()[()] if h5py.check_string_dtype(obj.dtype) else obj[()]
    except StoreError:
        raise
    except OSError as err:
        if err.errno is not None:
            raise StoreError(f"{path}: cannot read the run store: {_os_message(err)}") from None
        raise StoreError(f"{path}: cannot read the run store: {err}{_checksum_hint(err)}") from None
    except Exception as err:
        raise StoreError(f"{path}: cannot read the run store: {type(err).__name__}: {err}{_checksum_hint(err)}") from None
    return attrs, variables


def _bare_dimension(dataset) -> bool:
    """Whether an HDF5 dataset is a NetCDF-4 dimension without coordinates (it holds no data). Those
    are float32, which no store variable is, so only they have their attributes read (slow in h5py)."""
    return (dataset.dtype.kind == "f" and dataset.dtype.itemsize == 4
            and str(_plain(dataset.attrs.get("NAME", b""))).startswith("This is a netCDF dimension but not"))


def _checksum_hint(err) -> str:
    text = str(err).lower()
    return "; a checksum failed: the file is corrupted" if "filter" in text or "checksum" in text else ""


def _read_token(path: Path):
    """``(content hash, n_steps)`` of the file as it is on disk (``None`` if it cannot be read)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return _plain(f.attrs.get("content_sha256")), int(_plain(f.attrs["n_steps"]))
    except Exception:
        return None


_STEP_INFO_FIELDS = {f.name: f.type for f in dataclasses.fields(StepInfo)}


def _step_info(values: dict) -> StepInfo:
    """A :class:`StepInfo` from its stored dict: directly when it has this version's fields (what
    this version wrote; several times faster, which counts at 500 steps), else by
    :meth:`StepInfo.from_dict` (tolerant of fields added or removed since)."""
    if isinstance(values, dict) and values.keys() == _STEP_INFO_FIELDS.keys():
        # what StepInfo(**values) makes (a frozen dataclass without __post_init__), without its 38
        # object.__setattr__ calls (16 -> 9 ms of profiled time for 500 steps)
        info = object.__new__(StepInfo)
        info.__dict__.update(values, temperatures=tuple(values["temperatures"]))
        return info
    return StepInfo.from_dict(values)


def _json_list(texts: list, path, what) -> list:
    """Every JSON text of a text variable, parsed in one call (500 calls cost 10 ms); a damaged one is
    named by its index."""
    try:
        values = json.loads("[" + ",".join(texts) + "]")
        if len(values) == len(texts):             # a text holding "1],[2" would add elements
            return values
    except json.JSONDecodeError:
        pass
    return [_json(text, path, f"{what}[{i}]") for i, text in enumerate(texts)]


def _json(text, path, what):
    try:
        return json.loads(str(text))
    except json.JSONDecodeError as err:
        raise StoreError(f"{path}: damaged run store: {what} is not valid JSON ({err})") from None


def _check_finite(path: Path, variables: dict) -> None:
    """Refuse NaN anywhere in the numbers, and inf in samples and data: a store holding them cannot be resumed."""
    finite = ("posterior", "predictive", "initial_particles", "dataset_values")
    for name, values in variables.items():
        if values.dtype.kind != "f" or name == "diagnostics":   # a diagnostic may be NaN (not computed)
            continue
        bad = ~np.isfinite(values) if name in finite else np.isnan(values)
        if name == "log_weights":
            bad |= values == np.inf
        if bad.any():
            where = np.argwhere(bad)[0]
            raise StoreError(f"{path}: damaged run store: {name} holds {int(bad.sum())} NaN/inf value(s), "
                             f"first at index {tuple(int(i) for i in where)}")


# -------------------------------------------------------------------------- writing
#: Dimensions that grow with the run (unlimited in the file, so that a step can be appended),
#: with the chunk length along them.
_GROWING = {"step": 8, "rng_index": 8, "dataset_row": 256, **{f"{name}_row": 8 for name in snapshot.RAGGED}}
#: Variables along a growing dimension other than ``step`` (a dimension without coordinates).
_BARE_DIMS = {"rng_state": "rng_index", "dataset_values": "dataset_row",
              **{name: f"{name}_row" for name in snapshot.RAGGED}}


def _write_whole(store, growing: dict) -> None:
    """Write a run store (``store``: a :class:`RunStore` or :class:`~seqbayes.sgstore.SGRunStore`,
    with the lock held): in place through the journal when ``store._append()`` can, else the whole
    file to a temporary file that replaces it (fsync-ed, the file mode kept; a killed writer's
    temporary files are removed first). ``growing``: the dimensions that grow with the run."""
    folder = store.path.resolve().parent
    if store.path.is_dir():
        raise StoreError(f"{store.path}: is a folder, not a run store file")
    prefix = f".{store.path.name}.tmp-"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for entry in os.listdir(folder):  # left by a killed writer (the lock is held: no live one)
            if entry.startswith(prefix) and entry[len(prefix):].isdigit():
                with contextlib.suppress(OSError):
                    os.remove(folder / entry)
    except OSError as err:
        raise StoreError(f"{store.path}: cannot write in {folder}: {_os_message(err)}") from None
    _recover_journal(store.path)
    if store._append():
        return
    ds = store.to_xarray()
    mode = None
    with contextlib.suppress(OSError):
        mode = os.stat(store.path).st_mode & 0o7777
    # HDF5 writes to memory; the file is written by plain OS calls, so a full disk or an I/O
    # error is one OSError here, never an error inside HDF5 (which, on ENOSPC, crashed the process)
    content = _netcdf_bytes(ds, _encoding(ds, growing), unlimited_dims=[d for d in growing if d in ds.dims])
    _check_free_space(store.path, folder, len(content))
    _fault("before-write")
    tmp = folder / f"{prefix}{os.getpid()}"
    try:
        _write_file(tmp, content)
        if os.environ.get(FAULT_ENV) == "mid-write":  # pragma: no cover - simulate a torn temporary file
            os.truncate(tmp, len(content) // 2)
            _fault("mid-write")
        if mode is not None:
            os.chmod(tmp, mode)
        _fault("before-replace")
        os.replace(tmp, store.path)
    except OSError as err:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise StoreError(f"{store.path}: cannot write the run store: {_os_message(err)}; the previous "
                         f"store is kept") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise
    _fsync_dir(folder)
    store._written(ds.attrs["content_sha256"], [str(h) for h in ds["record_sha256"].values] if store.n_steps else [])
    _fault("after-replace")


def _encoding(ds, growing: dict | None = None) -> dict:
    """HDF5 Fletcher-32 checksums on the numeric arrays (verified on read) and, along the growing
    dimensions, chunks of a few steps, so that appending a step writes a few chunks."""
    growing = _GROWING if growing is None else growing
    encoding = {}
    for name, var in ds.variables.items():
        enc = {}
        if var.dtype.kind in "fiu" and var.ndim and (var.size or var.dims[0] in growing):
            enc["fletcher32"] = True
        if var.dims and var.dims[0] in growing:
            enc["chunksizes"] = (growing[var.dims[0]],) + tuple(max(1, s) for s in var.shape[1:])
        if enc:
            encoding[name] = enc
    return encoding


def _appendable(f, data: dict, disk_steps: int, n_columns: int) -> bool:
    """Whether the open file ``f`` is the format-4 store of ``disk_steps`` steps that ``data`` (the
    rows of the steps after them, :meth:`RunStore._rows`) extends: the same growing variables,
    each of the expected length and with the same trailing shape."""
    if (int(_plain(f.attrs.get("seqbayes_store_format", 0))) != FORMAT_VERSION
            or int(_plain(f.attrs.get("n_steps", -1))) != disk_steps):
        return False
    growing = {name for name, obj in f.items() if obj.shape and obj.maxshape[0] is None
               and not _bare_dimension(obj)}
    if growing != set(data):
        return False
    counts = {"dataset_values": "dataset_rows", **{name: f"{name}_rows" for name in snapshot.RAGGED}}
    lengths = {"rng_state": disk_steps + 1,
               **{name: int(f[rows][()].sum()) if rows in f else 0 for name, rows in counts.items()}}
    for name, values in data.items():
        dataset = f[name]
        if dataset.shape[0] != lengths.get(name, disk_steps) or dataset.shape[1:] != np.shape(values)[1:]:
            return False
    return "dataset_values" not in data or f["dataset_values"].shape[1] == n_columns


def _extend(dataset, n: int, values=None) -> None:
    """Grow an HDF5 dataset by ``n`` rows along its first axis and write ``values`` there."""
    old = dataset.shape[0]
    dataset.resize(old + n, axis=0)
    if values is not None:
        dataset[old:] = values


def _pread(fd: int, n: int, offset: int) -> bytes:
    """``os.pread``, or seek and read where it does not exist (Windows; the descriptor is this module's own)."""
    if hasattr(os, "pread"):
        return os.pread(fd, n, offset)
    os.lseek(fd, offset, os.SEEK_SET)  # pragma: no cover - Windows
    return os.read(fd, n)  # pragma: no cover - Windows


def _pwrite(fd: int, data, offset: int) -> int:
    """``os.pwrite``, or seek and write where it does not exist (Windows)."""
    if hasattr(os, "pwrite"):
        return os.pwrite(fd, data, offset)
    os.lseek(fd, offset, os.SEEK_SET)  # pragma: no cover - Windows
    return os.write(fd, data)  # pragma: no cover - Windows


class _PendingWrites(io.RawIOBase):
    """The file HDF5 appends to, or reads: reads come from the file with pending pages laid over
    them, writes stay in memory (the pages then go to the journal, :func:`_apply_with_journal`).
    So a full disk or an I/O error is an OSError raised by plain OS calls, never inside HDF5
    (where ENOSPC crashed the process). With ``journal`` (:func:`_read_journal`) it is the file as a
    committed journal makes it."""

    PAGE = 1 << 12                              # the journal holds whole pages: small ones keep it small

    def __init__(self, fh, journal=None):
        self.fd = fh.fileno()
        self.size = os.fstat(self.fd).st_size       # the logical size
        self.on_disk = self.size                    # bytes of the file below which the disk content is valid
        self.pages = {}
        self.pos = 0
        if journal is not None:
            self.on_disk, self.size, pages = journal
            self.pages = {offset // self.PAGE: bytearray(data.ljust(self.PAGE, b"\0")) for offset, data in pages}

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
        data = _pread(self.fd, valid, start) if valid else b""
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

    def changes(self) -> list:
        """``[(offset, bytes)]``: every page whose content differs from the file's, within the new size
        (a page below the old size that a truncation zeroed counts too)."""
        old_size = os.fstat(self.fd).st_size
        for index in range(self.on_disk // self.PAGE, (min(old_size, self.size) + self.PAGE - 1) // self.PAGE):
            if index not in self.pages:             # zeros where the file still holds old bytes
                self.pages[index] = bytearray(self._disk(index * self.PAGE, self.PAGE))
        return [(index * self.PAGE, bytes(self.pages[index][:min(self.PAGE, self.size - index * self.PAGE)]))
                for index in sorted(self.pages) if index * self.PAGE < self.size]


# ------------------------------------------------------------------------ the journal
_JOURNAL_MAGIC = b"seqbayes run-store journal 1\n"


def _journal_path(path: Path) -> Path:
    return path.parent / f".{path.name}.journal"


def _encode_journal(old_size: int, new_size: int, pages) -> bytes:
    """The journal: magic, ``(old size, new size, page count)``, ``(offset, length, bytes)`` per page, SHA-256."""
    parts = [_JOURNAL_MAGIC, struct.pack("<QQQ", old_size, new_size, len(pages))]
    for offset, data in pages:
        parts += [struct.pack("<QQ", offset, len(data)), data]
    body = b"".join(parts)
    return body + hashlib.sha256(body).digest()


def _read_journal(path: Path):
    """``(old size, new size, [(offset, bytes)])`` of a complete journal of the store ``path``, or
    ``None`` when there is none or it is incomplete (torn by a crash while it was written: then the
    store was not touched)."""
    try:
        content = _journal_path(path).read_bytes()
    except OSError:
        return None
    body, digest = content[:-32], content[-32:]
    if not body.startswith(_JOURNAL_MAGIC) or hashlib.sha256(body).digest() != digest:
        return None
    pos = len(_JOURNAL_MAGIC)
    old_size, new_size, count = struct.unpack_from("<QQQ", body, pos)
    pos += 24
    pages = []
    for _ in range(count):
        offset, length = struct.unpack_from("<QQ", body, pos)
        pos += 16
        pages.append((offset, body[pos:pos + length]))
        pos += length
    return old_size, new_size, pages


def _apply_pages(path: Path, journal, fault: bool = False) -> None:
    """Write a journal's pages into the store and set its size, under an exclusive lock on it, then
    ``fsync`` (idempotent: a second application after a crash in the first gives the same file).

    Where the filesystem takes it, the pages go with ``O_DIRECT`` (one aligned buffer, a partial last
    page padded with zeros before the size is set): a buffered write of 4 KiB into a page-cache folio
    that readahead made large sends the whole folio to the disk, so the bytes reaching the disk
    would grow with the store."""
    _, new_size, pages = journal
    with open(path, "r+b") as fh:
        lock_file(fh, exclusive=True)
        direct = _direct_fd(path)
        fd = fh.fileno() if direct is None else direct
        try:
            buffer = mmap.mmap(-1, _PendingWrites.PAGE) if direct is not None else None
            for i, (offset, data) in enumerate(pages):
                if fault and i == len(pages) // 2:
                    _fault("mid-apply")
                view = memoryview(data)
                if buffer is not None:             # a page (the last may be shorter), aligned for O_DIRECT
                    buffer[:len(data)] = data
                    buffer[len(data):] = bytes(len(buffer) - len(data))
                    view = memoryview(buffer)
                while view:
                    written = _pwrite(fd, view, offset)
                    view, offset = view[written:], offset + written
            os.ftruncate(fd, new_size)
            os.fsync(fd)
        finally:
            if direct is not None:
                os.close(direct)
        # the journal goes while readers are still locked out: they never see the store half written
        os.remove(_journal_path(path))
        _fsync_dir(path.resolve().parent)


def _direct_fd(path: Path):
    """A descriptor of ``path`` opened with ``O_DIRECT``, or None where there is none (tmpfs, Windows, macOS)."""
    if not hasattr(os, "O_DIRECT"):
        return None
    try:
        return os.open(path, os.O_RDWR | os.O_DIRECT)
    except OSError:
        return None


def _recover_journal(path: Path) -> None:
    """Under the store's lock: finish a step a crash left in a complete journal, or drop an incomplete one."""
    journal_file = _journal_path(path)
    if not journal_file.exists():
        return
    journal = _read_journal(path)
    try:
        if journal is None or not path.exists():
            os.remove(journal_file)
        else:
            _apply_pages(path, journal)
    except OSError as err:
        raise StoreError(f"{path}: cannot complete the step left in {journal_file.name} by an interrupted update: "
                         f"{_os_message(err)}; readers still see it") from None


def _apply_with_journal(path: Path, journal) -> None:
    """Commit the appended pages ``journal = (old size, new size, [(offset, bytes)])``
    (:meth:`_PendingWrites.changes`): the store's new size is allocated (``posix_fallocate``,
    so that writing the pages cannot meet a full disk), the journal is written and
    ``fsync``-ed (the step is committed), then its pages are written into the store
    (:func:`_apply_pages`). A failure before the commit restores the store's size: the
    store stays byte-identical."""
    content = _encode_journal(*journal)
    folder = path.resolve().parent
    old_size = os.path.getsize(path)
    _check_free_space(path, folder, len(content) + max(0, journal[1] - old_size))
    _fault("before-write")
    journal_file = _journal_path(path)
    try:
        if journal[1] > old_size and hasattr(os, "posix_fallocate"):
            with open(path, "r+b") as fh:
                os.posix_fallocate(fh.fileno(), 0, journal[1])   # beyond HDF5's end of file: readers ignore it
        if os.environ.get(FAULT_ENV) == "mid-write":  # pragma: no cover - simulate a torn journal
            _write_file(journal_file, content[:len(content) // 2])
            _fault("mid-write")
        _write_file(journal_file, content)
        _fsync_dir(folder)
    except OSError as err:
        with contextlib.suppress(OSError):
            os.remove(journal_file)
        with contextlib.suppress(OSError):
            if os.path.getsize(path) != old_size:
                os.truncate(path, old_size)
        raise StoreError(f"{path}: cannot write the run store: {_os_message(err)}; the previous store is "
                         f"kept") from None
    _fault("before-replace")
    try:
        _apply_pages(path, journal, fault=True)
    except OSError as err:  # an I/O error, not a full disk (the space was allocated)
        raise StoreError(f"{path}: the new step is committed in {journal_file.name} but could not be written into "
                         f"the store: {_os_message(err)}; readers see the step, and the next update completes the "
                         f"store once the cause is fixed") from None


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


def posterior_to_arviz(result: Result, step: int | None = -1, rng: int | np.random.Generator | None = None,
                       **kwargs: Any) -> az.InferenceData:
    """A step's posterior (``step=None``: every step) as :class:`arviz.InferenceData`:
    :meth:`seqbayes.Result.to_arviz`."""
    return result.to_arviz(step, rng, **kwargs)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable, Iterator
    from typing import Any, BinaryIO

    import arviz as az
    import xarray as xr
    from numpy.typing import ArrayLike

    from .engine.drivers import SEMC, SMC
