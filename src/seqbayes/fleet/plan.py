"""Which stores a fleet update touches and which datasets each one gets, in order.

A fleet is given as a folder or as a manifest (docs/fleet.md):

* **A folder** holds run stores ``NAME.nc`` and, beside each, a folder ``NAME/`` of its new datasets
  (``.csv`` or NetCDF files), assimilated in natural name order (``d2.csv`` before ``d10.csv``; dates
  written ``YYYY-MM-DD`` sort as they should). Hidden entries (journals, locks' temporary files, the
  fleet's record) are not looked at; a store without a folder has nothing new.
* **A manifest** (``.toml`` or ``.json``) lists the stores and their datasets::

      [[store]]
      path = "stores/bridge-17.nc"                 # relative to the manifest's folder
      datasets = ["data/b17/2026-11-01.csv", "data/b17/2026-11-02.csv"]   # in this order
      [[store]]
      path = "stores/tower-3.nc"
      datasets = "data/tower-3"                    # or a folder: its data files in natural name order
      name = "tower 3"                             # optional (default: the store's file name without .nc)

  the JSON form is ``{"store": [{"path": ..., "datasets": [...]}, ...]}``.

:func:`plan_fleet` reads either into a :class:`FleetPlan` of one :class:`StoreTask` per store, without
opening a store or a data file. What is wrong with the manifest as a whole (it does not parse, a key is
unknown, a store is listed twice) is a :class:`FleetError`; what is wrong with one store's entry (its data
folder is missing) is that task's ``problem``, reported as its outcome while the others run.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path

__all__ = ["FleetError", "StoreTask", "FleetPlan", "plan_fleet", "is_fleet", "natural_key", "data_files",
           "MANIFEST_SUFFIXES", "DATA_SUFFIXES", "STORE_SUFFIX", "MAX_MANIFEST_BYTES"]

#: A manifest is a file with one of these suffixes; anything else given as the fleet is a folder or a store.
MANIFEST_SUFFIXES = (".toml", ".json")
#: Files of a datasets folder that are datasets (the store's readers: CSV or NetCDF); others are listed as ignored.
DATA_SUFFIXES = (".csv", ".nc", ".nc4", ".netcdf", ".h5", ".hdf5")
#: The suffix of a store in a fleet folder.
STORE_SUFFIX = ".nc"
#: A manifest larger than this is refused before it is read (a listing of 10^5 stores is a few MB).
MAX_MANIFEST_BYTES = 16 * 2 ** 20


class FleetError(ValueError):
    """A fleet's folder, manifest or option is unusable as a whole: one line, and no store is touched."""


@dataclass(frozen=True)
class StoreTask:
    """One store's part of a fleet update: its datasets, in the order they are assimilated.

    Attributes
    ----------
    name : str
        How the store is called in messages (its file name without ``.nc``, or the manifest's ``name``).
    store : pathlib.Path
        The run store (absolute).
    datasets : tuple of pathlib.Path
        Its data files (absolute), in order.
    problem : str or None
        Why the task cannot run (e.g. its datasets folder is missing); its outcome then says so.
    ignored : tuple of str
        Files of its datasets folder that are not data files (by their suffix), by name.
    """

    name: str
    store: Path
    datasets: tuple = ()
    problem: str | None = None
    ignored: tuple = ()


@dataclass(frozen=True)
class FleetPlan:
    """Every store of a fleet with its datasets (:func:`plan_fleet`).

    Attributes
    ----------
    source : pathlib.Path
        The folder or manifest the plan was read from.
    kind : {"folder", "manifest"}
    tasks : tuple of StoreTask
        One per store, in the order of the folder (natural name order) or the manifest.
    """

    source: Path
    kind: str
    tasks: tuple

    @property
    def inputs(self) -> frozenset:
        """Every file the fleet reads or writes as input (manifest, stores and their side files, data files):
        an output target that is one of them is refused."""
        paths = [self.source] if self.kind == "manifest" else []
        for task in self.tasks:
            store = task.store
            paths += [store, store.with_name(store.name + ".lock"), store.with_name(f".{store.name}.journal"),
                      *task.datasets]
        return frozenset(os.path.realpath(p) for p in paths)


def is_fleet(path: str | os.PathLike) -> bool:
    """Whether ``path`` names a fleet (a folder, or a ``.toml``/``.json`` manifest) rather than one run store."""
    path = Path(path)
    return path.is_dir() or path.suffix.lower() in MANIFEST_SUFFIXES


def natural_key(name: str) -> tuple:
    """Sort key of a file name in natural order: runs of digits compare as numbers (``d2`` before ``d10``).

    >>> sorted(["d10.csv", "d2.csv", "d1.csv"], key=natural_key)
    ['d1.csv', 'd2.csv', 'd10.csv']
    """
    parts = re.split(r"(\d+)", name)
    return tuple((0, int(p), p) if p.isdigit() else (1, 0, p) for p in parts if p), name


def data_files(folder: Path) -> tuple[tuple, tuple]:
    """``(datasets, ignored)``: the data files of ``folder`` in natural name order (absolute paths), and the
    names of its other regular files; hidden entries and sub-folders are not looked at.

    Raises
    ------
    OSError
        The folder cannot be listed.
    """
    datasets, ignored = [], []
    with os.scandir(folder) as entries:
        for entry in entries:
            if entry.name.startswith(".") or not entry.is_file():
                continue
            if Path(entry.name).suffix.lower() in DATA_SUFFIXES:
                datasets.append(entry.name)
            else:
                ignored.append(entry.name)
    datasets.sort(key=natural_key)
    return (tuple(Path(os.path.abspath(folder / n)) for n in datasets),
            tuple(sorted(ignored, key=natural_key)))


def plan_fleet(source: str | os.PathLike) -> FleetPlan:
    """The fleet's :class:`FleetPlan` from a folder or a manifest (module docstring).

    Raises
    ------
    FleetError
        ``source`` is missing, or a manifest that does not parse or lists something other than stores
        with their datasets (the message names the manifest and the entry), or names a store twice.
    """
    source = Path(source)
    if source.is_dir():
        return _plan_folder(source)
    if source.suffix.lower() not in MANIFEST_SUFFIXES:
        raise FleetError(f"{source}: a fleet is a folder of run stores or a .toml/.json manifest")
    return _plan_manifest(source)


def _plan_folder(folder: Path) -> FleetPlan:
    try:
        entries = sorted(os.listdir(folder), key=natural_key)
    except OSError as err:
        raise FleetError(f"{folder}: cannot list the fleet's folder: {err.strerror or err}") from None
    names = set(entries)
    tasks = []
    for entry in entries:
        if entry.startswith(".") or not entry.endswith(STORE_SUFFIX) or (folder / entry).is_dir():
            continue
        name = entry[:-len(STORE_SUFFIX)]
        store = Path(os.path.abspath(folder / entry))
        if name in names and (folder / name).is_dir():
            tasks.append(_folder_task(name, store, folder / name))
        else:
            tasks.append(StoreTask(name, store))
    for entry in entries:   # a folder of datasets without its store is a mistake to report, not to pass over
        if (entry.startswith(".") or entry + STORE_SUFFIX in names or not (folder / entry).is_dir()
                or not _holds_data(folder / entry)):
            continue
        store = Path(os.path.abspath(folder / (entry + STORE_SUFFIX)))
        tasks.append(StoreTask(entry, store, problem=f"{folder / entry}: a folder of datasets without its store "
                                                     f"{store.name} beside it (create it with `seqbayes init "
                                                     f"CONFIG.toml {store}`)"))
    tasks.sort(key=lambda task: natural_key(task.name))
    return FleetPlan(folder, "folder", tuple(tasks))


def _holds_data(folder: Path) -> bool:
    try:
        return bool(data_files(folder)[0])
    except OSError:
        return False


def _folder_task(name: str, store: Path, datasets: Path) -> StoreTask:
    """The task of a store whose datasets are the data files of the folder ``datasets``."""
    try:
        found, ignored = data_files(datasets)
    except OSError as err:
        return StoreTask(name, store, problem=f"{datasets}: cannot list its datasets: {err.strerror or err}")
    return StoreTask(name, store, found, ignored=ignored)


def _read_manifest(path: Path):
    """The manifest's parsed content: read by the store's strict reader (a regular file of at most
    :data:`MAX_MANIFEST_BYTES`, no FIFO waited on, no device read), then TOML or JSON."""
    import tomllib

    from ..store.datasets import printable, read_regular

    raw = read_regular(path, "fleet manifest", MAX_MANIFEST_BYTES, error=FleetError)
    try:
        text = raw.decode("utf-8-sig")
        return json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except UnicodeDecodeError:
        raise FleetError(f"{printable(str(path))}: the fleet manifest is not UTF-8 text") from None
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as err:
        raise FleetError(f"{printable(str(path))}: the fleet manifest does not parse: "
                         f"{printable(str(err))[:200]}") from None


def _plan_manifest(path: Path) -> FleetPlan:
    from ..store.datasets import printable

    content = _read_manifest(path)
    if not isinstance(content, dict) or set(content) - {"store"}:
        extra = sorted(set(content) - {"store"}) if isinstance(content, dict) else []
        what = f"unknown key {printable(extra[0])[:40]!r}" if extra else "expected a table of [[store]] entries"
        raise FleetError(f"{path}: {what} (a manifest lists [[store]] entries with path and datasets)")
    entries = content.get("store", [])
    if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
        raise FleetError(f"{path}: store: expected a list of entries with path and datasets")
    base = path.parent
    tasks, seen = [], {}
    for i, entry in enumerate(entries):
        where = f"{path}: store[{i + 1}]"
        unknown = sorted(set(entry) - {"path", "datasets", "name"})
        if unknown:
            raise FleetError(f"{where}: unknown key {printable(unknown[0])[:40]!r} (expected path, datasets, name)")
        store_path = entry.get("path")
        if not isinstance(store_path, str) or not store_path:
            raise FleetError(f"{where}.path: expected the run store's file name, got {printable(store_path)[:40]!r}")
        store = Path(os.path.abspath(base / store_path))
        real = os.path.realpath(store)
        if real in seen:
            raise FleetError(f"{where}.path: {printable(store_path)[:80]} is the same store as store[{seen[real]}] "
                             f"(a store's datasets are one ordered list)")
        seen[real] = i + 1
        name = entry.get("name", Path(store_path).name.removesuffix(STORE_SUFFIX))
        if not isinstance(name, str) or not name or len(name) > 200:
            raise FleetError(f"{where}.name: expected a short text, got {printable(name)[:40]!r}")
        datasets = entry.get("datasets", [])
        if isinstance(datasets, str):
            folder = Path(os.path.abspath(base / datasets))
            if not folder.is_dir():
                tasks.append(StoreTask(name, store, problem=f"{folder}: no such folder of datasets (store[{i + 1}] "
                                                            f"of {path})"))
                continue
            tasks.append(_folder_task(name, store, folder))
        elif isinstance(datasets, list) and all(isinstance(d, str) and d for d in datasets):
            tasks.append(StoreTask(name, store, tuple(Path(os.path.abspath(base / d)) for d in datasets)))
        else:
            raise FleetError(f"{where}.datasets: expected a list of data file names or a folder name")
    names = [t.name for t in tasks]
    if len(set(names)) < len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise FleetError(f"{path}: two stores are called {printable(twice)[:80]!r}; give them different names")
    return FleetPlan(path, "manifest", tuple(tasks))
