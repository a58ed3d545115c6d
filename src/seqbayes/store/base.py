"""The base of every run store backend: hashes, open, create, append and whole writes, duplicate checks.

A run store keeps one monitoring run in one NetCDF-4 file (:mod:`seqbayes.store.files` for the
locks, the journal and the writes). Every backend stores, per step (one assimilated dataset), the
same text records: the step's summary (``step_info``, JSON), the generator's state after it
(``rng_state``; one more, before the first step), the SHA-256 and file name of its dataset
(``dataset_sha256``, ``dataset_source``) and of the likelihood module it ran
(``likelihood_sha256``), and a SHA-256 of these records (``record_sha256``). The content hash
(attribute ``content_sha256``) chains the key attributes, the first generator state and every
step's record hash, so an appended step hashes only its own records and :meth:`BaseStore.open`
verifies all of it. The numeric arrays carry HDF5 Fletcher-32 checksums.

:class:`BaseStore` owns all of that. A backend (:mod:`seqbayes.store.smc`, :mod:`seqbayes.store.sg`)
says what a step holds: its arrays (:meth:`BaseStore._step_rows`), how they are read back
(:meth:`BaseStore._from_file`), how a dataset is assimilated, and how a run is described to the
command line (:meth:`BaseStore.describe`, :meth:`BaseStore.step_summary`, :meth:`BaseStore.status`,
:meth:`BaseStore.write_report`); it registers its run kind with :func:`seqbayes.store.registry.register`.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..engine.drivers import violation
from . import files, registry
from .datasets import read_datafile
from .errors import DuplicateDatasetError, StoreError

__all__ = ["BaseStore", "Provenance", "RECORD_TEXT", "record_hash", "content_hash", "rehash", "json_value",
           "json_values", "check_finite"]

#: Attributes covered by the store's content hash (the numeric arrays carry HDF5 Fletcher-32 checksums).
HASHED_ATTRS = ("config", "model_fingerprint", "n_steps", "initial_step_size", "result_meta")
#: A step's text records, in the order its record hash takes them (``rng_state`` of the step is
#: the generator state after it).
RECORD_TEXT = ("step_info", "rng_state", "dataset_sha256", "dataset_source", "likelihood_sha256")


def record_hash(texts) -> str:
    """SHA-256 of one step's text records (:data:`RECORD_TEXT`, in that order)."""
    return hashlib.sha256(json.dumps([str(t) for t in texts]).encode()).hexdigest()


def content_hash(attrs: dict, initial_rng: str, record_hashes) -> str:
    """The store's content hash (format 4 on): its key attributes, the generator state before the
    first step and the record hash of every step. A step appended adds one record hash."""
    h = hashlib.sha256()
    for key in HASHED_ATTRS:
        h.update(json.dumps([key, str(attrs.get(key))]).encode())
    h.update(json.dumps(["rng_state", str(initial_rng)]).encode())
    h.update("".join(record_hashes).encode())
    return h.hexdigest()


def rehash(ds) -> None:
    """Redo the record and content hashes of a store as an :class:`xarray.Dataset` (what a writer
    does): tests use it to make an edit consistent and check what else catches it."""
    rng = [str(v) for v in ds["rng_state"].values]
    n_steps = int(ds.attrs["n_steps"])
    hashes = []
    if n_steps:
        columns = [rng[1:] if name == "rng_state" else [str(v) for v in ds[name].values] for name in RECORD_TEXT]
        hashes = [record_hash(texts) for texts in zip(*columns)]
        ds["record_sha256"] = (("step",), np.array(hashes, dtype=object))
    ds.attrs["content_sha256"] = content_hash(ds.attrs, rng[0], hashes)


def json_values(texts: list, path, what) -> list:
    """Every JSON text of a text variable, parsed in one call (500 calls cost 10 ms); a damaged one is
    named by its index."""
    try:
        values = json.loads("[" + ",".join(texts) + "]")
        if len(values) == len(texts):             # a text holding "1],[2" would add elements
            return values
    except json.JSONDecodeError:
        pass
    return [json_value(text, path, f"{what}[{i}]") for i, text in enumerate(texts)]


def json_value(text, path, what):
    """One JSON text of the store; a :class:`StoreError` naming ``what`` if it does not parse."""
    try:
        return json.loads(str(text))
    except json.JSONDecodeError as err:
        raise StoreError(f"{path}: damaged run store: {what} is not valid JSON ({err})") from None


#: Run-store variables that hold an engine output under another name (:mod:`seqbayes.engine.drivers`).
_OUTPUT_NAMES = {"initial_particles": "particles", "initial_log_weights": "log_weights", "dataset_values": "dataset"}


def check_finite(path: Path, variables: dict, output_name=None) -> None:
    """Refuse a non-finite value where the engine may not leave one (:data:`seqbayes.engine.drivers.OUTPUTS`,
    the rules of the engine's own check after every step): a store holding it cannot be resumed.

    ``output_name(variable)`` is the engine's name of a variable (default: the variable's own, or
    ``initial_particles`` -> ``particles`` ...)."""
    for name, values in variables.items():
        rule_name = output_name(name) if output_name is not None else _OUTPUT_NAMES.get(name, name)
        message = violation(name, values, rule_name)
        if message is not None:
            raise StoreError(f"{path}: damaged run store: {message}")


def _encoding(ds, growing: dict) -> dict:
    """HDF5 Fletcher-32 checksums on the numeric arrays (verified on read) and, along the growing
    dimensions, chunks of a few steps, so that appending a step writes a few chunks."""
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


@dataclass(frozen=True)
class Provenance:
    """Where a run's steps came from, as a store keeps them: the generator's state before the first step and after
    each, each dataset's SHA-256 and file name, when the run was created and each step's record hash (verified ones
    from the file; new steps hash when written)."""

    rng_states: tuple
    digests: tuple = ()
    sources: tuple = ()
    created: str | None = None
    record_hashes: tuple = ()


class BaseStore:
    """A run kept in one NetCDF-4 file: what every backend shares (module docstring).

    A backend sets the class attributes below, registers its kind
    (:func:`seqbayes.store.registry.register`) and implements :meth:`_new`, :meth:`_from_file`,
    :meth:`_step_texts`, :meth:`_step_rows`, ``assimilate`` and the command-line descriptions.

    Attributes
    ----------
    path : pathlib.Path
    config
        The run's validated configuration (it has ``kind``, ``name``, ``names``, ``columns``,
        ``to_dict`` and ``fingerprint``).
    rng_states : list of dict
        The generator's state before the first step and after each.
    digests, sources : list of str
        SHA-256 and file name of each assimilated dataset.
    """

    #: the ``run_kind`` the backend registered (:mod:`seqbayes.store.registry`)
    kind = ""
    #: what the run is called in messages ("SEMC/SMC", "SG-EnMCMC")
    title = ""
    #: the layout version written, and the ones read
    format_version = 0
    readable_versions: tuple = ()
    #: growing dimensions (unlimited in the file, so that a step can be appended) and the chunk length along them
    growing: dict = {}
    #: what one assimilated table is called in messages ("dataset", "block")
    unit = "dataset"
    #: what the run can do beyond assimilating and reporting (see :meth:`require`)
    operations: frozenset = frozenset()
    #: whether an update runs a likelihood the command line can count evaluations of
    evaluates_likelihood = False

    def __init__(self, path, config, provenance: Provenance):
        self.path = Path(path)
        self.config = config
        self.rng_states = list(provenance.rng_states)
        self.digests = list(provenance.digests)
        self.sources = list(provenance.sources)
        self.created = provenance.created or files.now()
        self._record_hashes = list(provenance.record_hashes or ())
        self._token = None                          # (content hash, n_steps) of the file as last read or written
        self._disk_steps = 0                        # leading steps the file holds exactly as this object does

    @property
    def n_steps(self) -> int:
        """Datasets (blocks) assimilated so far."""
        return len(self.digests)

    @property
    def names(self) -> tuple:
        return tuple(self.config.names)

    # ----------------------------------------------------------------- creation
    @classmethod
    def create(cls, path: str | os.PathLike, config, *, overwrite: bool = False):
        """Start a new run at ``path`` from ``config`` and write it.

        Raises
        ------
        StoreError
            ``path`` exists (and not ``overwrite``), is a folder, or cannot be written.
        """
        path = Path(path)
        if path.is_dir():
            raise StoreError(f"{path}: is a folder; give the run store's file name, e.g. {path / 'run.nc'}")
        with files.store_lock(path, create=True):
            if path.exists() and not overwrite:
                raise StoreError(f"{path}: a run store already exists (pass overwrite=True / --force to replace it)")
            store = cls._new(path, config)
            store.write()
        return store

    @classmethod
    def _new(cls, path: Path, config):
        """The store of a new run (before its first step), not yet written."""
        raise NotImplementedError

    # ------------------------------------------------------------------ reading
    @classmethod
    def open(cls, path: str | os.PathLike, config=None):
        """Load and verify a run store (this runs no user code).

        Reads the file under a shared lock (so never between the two halves of a step
        another process appends), laying a committed journal over it.

        Parameters
        ----------
        path : path-like
        config : optional
            If given, the store must have been created for the same model (same fingerprint).

        Raises
        ------
        StoreError
            Missing or unreadable file, a file that is not a run store of this kind, another
            format version, another model, or a damaged store (checksum or content hash
            mismatch, missing or inconsistent variables, NaN samples).
        """
        path = Path(path)
        attrs, variables = files.read_file(path)
        try:
            version = cls._check_header(path, attrs, variables)
            store = cls._from_file(path, attrs, variables, config, version)
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
    def _check_header(cls, path: Path, attrs: dict, variables: dict) -> int:
        """The file's format version, once its kind and version are this backend's."""
        version = attrs.get("seqbayes_store_format")
        if version is None:
            raise StoreError(f"{path}: not a seqbayes run store (no seqbayes_store_format attribute)")
        kind = str(attrs.get("run_kind", registry.DEFAULT_KIND))
        if kind != cls.kind:
            other = registry.backend_or_none(kind)
            if other is None:
                raise StoreError(f"{path}: a run store of kind {kind!r}, which this seqbayes does not know")
            raise StoreError(f"{path}: an {other.title} run store (run_kind {kind!r}); open it with "
                             f"seqbayes.store.open_run or seqbayes.{other.__name__}.open (the seqbayes commands "
                             f"init, update, status and report take it)")
        if int(version) not in cls.readable_versions:
            plural = "s" if len(cls.readable_versions) > 1 else ""
            raise StoreError(f"{path}: run-store format version {int(version)}, but this seqbayes reads version"
                             f"{plural} {', '.join(map(str, cls.readable_versions))}; use the seqbayes version that "
                             f"wrote it (it says {attrs.get('seqbayes_version', '?')})")
        if "n_steps" not in attrs or "rng_state" not in variables:
            raise StoreError(f"{path}: damaged run store: missing {'n_steps' if 'n_steps' not in attrs else 'rng_state'}")
        return int(version)

    @classmethod
    def _read_records(cls, path: Path, attrs: dict, variables: dict, version: int) -> tuple[dict, list]:
        """``(text, record_hashes)``: each step's text records (``text[name]``, a list of str per name of
        :data:`RECORD_TEXT`, ``rng_state`` with one more) and their hashes, verified against the stored
        ones and the content hash (format 4 on; the caller checks older formats)."""
        n_steps = int(attrs["n_steps"])
        text = {name: [str(v) for v in variables[name]] for name in RECORD_TEXT + ("record_sha256",)
                if name in variables}
        rng_text = text["rng_state"]
        if not (len(rng_text) == n_steps + 1 and all(len(text.get(name, ())) == n_steps for name in RECORD_TEXT
                                                     if name not in ("rng_state", "likelihood_sha256") and n_steps)):
            raise StoreError(f"{path}: inconsistent store ({len(text.get('step_info', ()))} steps, {len(rng_text)} "
                             f"generator states, {len(text.get('dataset_sha256', ()))} dataset hashes, n_steps = "
                             f"{n_steps})")
        text.setdefault("likelihood_sha256", [""] * n_steps)    # not recorded before format 3
        for name in ("step_info", "dataset_sha256", "dataset_source"):
            text.setdefault(name, [])
        per_step = zip(text["step_info"], rng_text[1:], text["dataset_sha256"], text["dataset_source"],
                       text["likelihood_sha256"])
        record_hashes = [record_hash(texts) for texts in per_step]
        if version >= 4:
            stored = text.get("record_sha256", [])
            if n_steps and "record_sha256" not in variables:
                raise StoreError(f"{path}: damaged run store: missing variable(s) record_sha256")
            bad = [i + 1 for i, (a, b) in enumerate(zip(stored, record_hashes)) if a != b]
            if bad or len(stored) != n_steps or attrs.get("content_sha256") != content_hash(attrs, rng_text[0],
                                                                                          record_hashes):
                where = f" (the records of step {bad[0]})" if bad else ""
                raise StoreError(f"{path}: damaged run store: the content hash of its configuration and records "
                                 f"does not match{where} (the file was edited or corrupted)")
        return text, record_hashes

    @staticmethod
    def _check_config(path: Path, attrs: dict, stored, config) -> None:
        """Refuse a stored configuration whose fingerprint is not the file's, or (``config`` given) that
        defines another model than ``config``."""
        if stored.fingerprint() != attrs.get("model_fingerprint"):
            raise StoreError(f"{path}: model fingerprint does not match the stored configuration "
                             f"(the file was edited or written by an incompatible seqbayes)")
        if config is not None and config.fingerprint() != stored.fingerprint():
            fields = ", ".join(stored.differing_fields(config)) or "?"
            raise StoreError(f"{path}: the run was created for another model (fingerprint "
                             f"{stored.fingerprint()[:12]} vs {config.fingerprint()[:12]}); differing fields: {fields}")

    @classmethod
    def _from_file(cls, path: Path, attrs: dict, variables: dict, config, version: int):
        """The store from the file's attributes and variables (:func:`seqbayes.store.files.read_file`)."""
        raise NotImplementedError

    # ------------------------------------------------------------- assimilation
    def check_new_dataset(self, digest: str, replace_last: bool = False) -> None:
        """Refuse a dataset already assimilated (unless it is the last step and ``replace_last``)."""
        if digest in self.digests:
            step = self.digests.index(digest) + 1
            if not (replace_last and step == self.n_steps):
                hint = (" (use --replace-last / replace_last=True to redo the last step)"
                        if step == self.n_steps and "replace_last" in self.operations else "")
                raise DuplicateDatasetError(f"{self.path}: this {self.unit} was already assimilated as step {step} "
                                            f"(from {self.sources[step - 1]}, sha256 {digest[:12]}){hint}")

    def _reload_if_changed(self, replace_last: bool = False) -> None:
        """Under the lock: take in the steps another process (or object) stored since this one read the file."""
        if self._token is None or files.read_token(self.path) == self._token:
            return
        if replace_last:
            raise StoreError(f"{self.path}: the run store changed since it was opened (another update); open it "
                             f"again before replacing the last step")
        fresh = type(self).open(self.path)
        if fresh.config.fingerprint() != self.config.fingerprint():
            raise StoreError(f"{self.path}: the run store was replaced by a run of another model since it was "
                             f"opened")
        self.__dict__.update(fresh.__dict__)

    @contextlib.contextmanager
    def _updating(self, write: bool, replace_last: bool = False):
        """The read-modify-write of one step: with ``write``, under the store's lock, after finishing a step
        an interrupted update left in the journal and taking in the steps others stored since."""
        if not write:
            yield
            return
        with files.store_lock(self.path):
            files.recover_journal(self.path)
            self._reload_if_changed(replace_last)
            yield

    def read_datafile(self, datafile: str | os.PathLike) -> np.ndarray:
        """A CSV/NetCDF data file as the ``(n_rows, n_columns)`` table of this run's columns
        (:func:`~seqbayes.store.datasets.read_datafile`)."""
        return read_datafile(datafile, self.config)

    def update(self, datafile: str | os.PathLike, **options):
        """Read a CSV/NetCDF data file (:meth:`read_datafile`) and assimilate it (``options``: the
        backend's ``assimilate`` keywords)."""
        return self.assimilate(self.read_datafile(datafile), Path(datafile).name, **options)

    def assimilate(self, table, source: str = "<array>", **options):
        """Assimilate one dataset and save the store (the backend's)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ writing
    def _step_texts(self, k: int) -> tuple:
        """Step ``k``'s (0-based) text records, in the order of :data:`RECORD_TEXT`."""
        raise NotImplementedError

    def _step_rows(self, start: int, data: dict, coords: dict) -> None:
        """Add the backend's arrays of steps ``start ..`` (0-based) to ``data`` (name -> (dims, values))
        and ``coords``, along the growing dimensions."""
        raise NotImplementedError

    def _whole_variables(self) -> tuple[dict, dict]:
        """Variables and coordinates written once, not per step: ``(data, coords)`` for a whole write."""
        return {}, {}

    def _rewritten(self, start: int) -> list:
        """``(name, index, values)``: the parts of :meth:`_whole_variables` that an append of the steps after
        ``start`` rewrites in place (``f[name][index] = values``, the same shape); none by default."""
        return []

    def _own_attrs(self) -> dict:
        """The backend's file attributes beside the common ones."""
        return {}

    def _attrs(self, record_hashes) -> dict:
        """The file's attributes, with the content hash over ``record_hashes``."""
        from .._version import __version__

        attrs = {"seqbayes_store_format": self.format_version, "seqbayes_version": __version__,
                 "model_fingerprint": self.config.fingerprint(), "config": json.dumps(self.config.to_dict()),
                 "model_name": self.config.name, "n_steps": self.n_steps, **self._own_attrs(),
                 "created": self.created, "updated": files.now()}
        attrs["content_sha256"] = content_hash(attrs, json.dumps(self.rng_states[0]), record_hashes)
        return attrs

    def _rows(self, start: int) -> tuple[dict, dict, list]:
        """``(data_vars, coords, texts)`` of steps ``start ..`` (0-based) along the growing dimensions,
        for :meth:`to_xarray` (``start = 0``) and the append of :meth:`write`; ``texts`` are the steps'
        :meth:`_step_texts`."""
        texts = [self._step_texts(k) for k in range(start, self.n_steps)]
        rng_from = 0 if start == 0 else start + 1
        data = {"rng_state": (("rng_index",), np.array([json.dumps(s) for s in self.rng_states[rng_from:]],
                                                      dtype=object))}
        coords = {}
        if not texts:
            return data, coords, texts
        columns = list(zip(*texts))
        coords["step"] = np.arange(start + 1, self.n_steps + 1)
        data.update({
            "step_info": (("step",), np.array(columns[0], dtype=object)),
            "dataset_sha256": (("step",), np.array(columns[2], dtype=object)),
            "dataset_source": (("step",), np.array(columns[3], dtype=object)),
            "likelihood_sha256": (("step",), np.array(columns[4], dtype=object)),
            "record_sha256": (("step",), np.array([record_hash(t) for t in texts], dtype=object)),
        })
        self._step_rows(start, data, coords)
        return data, coords, texts

    def _hashes_through(self, texts, start: int) -> list:
        """Record hashes of every step: the known ones before ``start``, the others from ``texts``."""
        known = self._record_hashes[:start]
        if len(known) < start:  # steps read from a file without record hashes (format 1-3): hash them now
            known += [record_hash(self._step_texts(k)) for k in range(len(known), start)]
        return known + [record_hash(t) for t in texts]

    def to_xarray(self):
        """The store's content as an :class:`xarray.Dataset` (what a whole write saves)."""
        import xarray as xr

        data, coords, texts = self._rows(0)
        whole, whole_coords = self._whole_variables()
        ds = xr.Dataset({**data, **whole}, coords={**coords, **whole_coords})
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
        with files.store_lock(self.path, create=True):
            self._write_locked()

    def _write_locked(self) -> None:
        """With the lock held: in place through the journal when :meth:`_append` can, else the whole file
        to a temporary file that replaces it (fsync-ed, the file mode kept; a killed writer's temporary
        files are removed first). A symbolic link to the store is written through: its target is replaced."""
        real = files.target(self.path)
        folder = real.parent
        if self.path.is_dir():
            raise StoreError(f"{self.path}: is a folder, not a run store file")
        prefix = f".{real.name}.tmp-"
        try:
            folder.mkdir(parents=True, exist_ok=True)
            for entry in os.listdir(folder):  # left by a killed writer (the lock is held: no live one)
                if entry.startswith(prefix) and entry[len(prefix):].isdigit():
                    with contextlib.suppress(OSError):
                        os.remove(folder / entry)
        except OSError as err:
            raise StoreError(f"{self.path}: cannot write in {folder}: {files.os_message(err)}") from None
        files.recover_journal(self.path)
        if self._append():
            return
        ds = self.to_xarray()
        mode = files.file_mode(real)
        # HDF5 writes to memory; the file is written by plain OS calls, so a full disk or an I/O
        # error is one OSError here, never an error inside HDF5 (which, on ENOSPC, crashed the process)
        content = files.netcdf_bytes(ds, _encoding(ds, self.growing),
                                     unlimited_dims=[d for d in self.growing if d in ds.dims])
        files.check_free_space(self.path, folder, len(content))
        files.fault("before-write")
        tmp = folder / f"{prefix}{os.getpid()}"
        try:
            files.write_file(tmp, content, mode=mode)
            if os.environ.get(files.FAULT_ENV) == "mid-write":  # pragma: no cover - simulate a torn temporary file
                os.truncate(tmp, len(content) // 2)
                files.fault("mid-write")
            files.fault("before-replace")
            os.replace(tmp, real)
        except OSError as err:
            with contextlib.suppress(OSError):
                os.remove(tmp)
            raise StoreError(f"{self.path}: cannot write the run store: {files.os_message(err)}; the previous "
                             f"store is kept") from None
        except BaseException:
            with contextlib.suppress(OSError):
                os.remove(tmp)
            raise
        files.fsync_dir(folder)
        self._written(ds.attrs["content_sha256"], [str(h) for h in ds["record_sha256"].values] if self.n_steps else [])
        files.fault("after-replace")

    def _written(self, content_hash: str, record_hashes: list) -> None:
        self._record_hashes = list(record_hashes)
        self._token = (content_hash, self.n_steps)
        self._disk_steps = self.n_steps

    def _append(self) -> bool:
        """Append the steps after ``_disk_steps`` in place, through the journal (:mod:`seqbayes.store.files`).

        Used when the file holds this object's first steps unchanged (no ``replace_last``
        since, no other writer) in this layout; returns False (nothing written)
        otherwise, and the caller writes the whole file.
        """
        import h5py

        start = self._disk_steps
        if not (0 < start < self.n_steps and self._token is not None and files.read_token(self.path) == self._token):
            return False
        rows, coords, texts = self._rows(start)
        rows["step"] = (("step",), coords["step"])
        record_hashes = self._hashes_through(texts, start)
        attrs = self._attrs(record_hashes)
        try:
            with open(self.path, "rb") as fh:
                pending = files.PendingWrites(fh)   # HDF5 writes to memory; applied below with plain OS calls
                with h5py.File(pending, "r+") as f:
                    if not self._extend_file(f, rows, start):
                        return False
                    for key, value in attrs.items():
                        f.attrs[key] = value
                journal = (pending.on_disk, pending.size, pending.changes())
        except OSError as err:
            raise StoreError(f"{self.path}: cannot read the run store to append: {files.os_message(err)}; the "
                             f"previous store is kept") from None
        files.apply_with_journal(self.path, journal)
        self._written(attrs["content_sha256"], record_hashes)
        files.fault("after-replace")
        return True

    def _extend_file(self, f, rows: dict, start: int) -> bool:
        """Grow the open file ``f`` by ``rows`` (name -> (dims, values) of the steps after ``start``),
        or return False when ``f`` is not this layout's store of ``start`` steps: the same growing
        variables, each as long as its dimension and with the same trailing shape."""
        if (int(files.plain(f.attrs.get("seqbayes_store_format", 0))) != self.format_version
                or int(files.plain(f.attrs.get("n_steps", -1))) != start):
            return False
        growing = {name for name, obj in f.items() if obj.shape and obj.maxshape[0] is None
                   and not files.bare_dimension(obj)}
        if growing != set(rows):
            return False
        added = {}                               # growing dimension -> rows added along it
        for name, (dims, values) in rows.items():
            dataset = f[name]
            if (dims[0] not in f or dataset.shape[0] != f[dims[0]].shape[0]
                    or dataset.shape[1:] != np.shape(values)[1:] or added.setdefault(dims[0], len(values)) != len(values)):
                return False
        rewritten = self._rewritten(start)
        if any(name not in f or name in growing or np.empty(f[name].shape, bool)[index].shape != np.shape(values)
               for name, index, values in rewritten):
            return False
        for name, index, values in rewritten:
            f[name][index] = values
        for dim, n in added.items():
            if dim not in rows:                  # a dimension without coordinates: its scale grows too
                files.extend(f[dim], n)
        for name, (dims, values) in rows.items():
            files.extend(f[name], len(values), values)
        return True

    # ------------------------------------------------- what the command line asks
    def require(self, *operations: str) -> None:
        """Refuse what this kind of run cannot do (``"predict"``, ``"compare"``, ``"replace_last"``,
        ``"report --compare"``, ...) with a :class:`StoreError` that says what it can do instead."""
        missing = [op for op in operations if op not in self.operations]
        if missing:
            raise StoreError(self._unsupported(missing))

    def _unsupported(self, operations: list) -> str:
        return f"{self.path}: a {self.title} run; {', '.join(operations)} is not available for it"

    def predict(self, n_steps: int) -> np.ndarray:
        """Forecast ``(n_steps, N, d)`` from the last posterior (backends with a Markov kernel)."""
        self.require("predict")
        raise NotImplementedError

    def load_likelihood(self, accept_model_change: bool = False):
        """The run's likelihood, for runs that evaluate one (:attr:`evaluates_likelihood`)."""
        raise StoreError(f"{self.path}: a {self.title} run evaluates no user likelihood")

    def make_executor(self):
        """``(executor, close)`` for the run's parallel likelihood evaluation (none by default)."""
        return None, lambda: None

    def user_code(self) -> tuple | None:
        """``(module:function, file)`` of the user's code an update runs, or None (for error messages)."""
        return None

    def describe(self) -> str:
        """One line on the run, as ``seqbayes init`` prints it after "created "."""
        raise NotImplementedError

    def step_summary(self, info, source: str) -> str:
        """One line on an assimilated step (what ``assimilate`` returned), as ``seqbayes update`` prints it."""
        raise NotImplementedError

    def status(self, level: float = 0.95) -> str:
        """The ``seqbayes status`` table."""
        raise NotImplementedError

    def status_json(self, level: float = 0.95) -> dict:
        """What ``seqbayes status --json`` prints."""
        raise NotImplementedError

    def write_report(self, output: str | os.PathLike, **options) -> None:
        """Write the HTML report (``seqbayes report``)."""
        raise NotImplementedError
