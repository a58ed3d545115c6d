"""Run kinds and their store backends: every run is opened and created through here.

A run store file records its kind in the attribute ``run_kind`` (files without it are SMC/SEMC
runs, the first kind). A backend class registers itself for its kind with :func:`register`, and
its configuration names the kind in ``config.kind``; :func:`open_run` and :func:`create_run`
find the backend, so the command line never asks which kind a run is.

Adding a backend is one new module in :mod:`seqbayes.store` with a
:class:`~seqbayes.store.base.BaseStore` subclass decorated ``@register("mykind")`` (and its import
in ``seqbayes/store/__init__.py``, which loads the backends).
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from .errors import StoreError

__all__ = ["DEFAULT_KIND", "register", "backend", "backend_or_none", "kinds", "run_kind", "open_run", "create_run"]

#: The kind of a store without a ``run_kind`` attribute (SMC/SEMC stores never wrote one).
DEFAULT_KIND = "semc"
_BACKENDS: dict = {}


def register(kind: str):
    """Class decorator: the backend of runs whose ``run_kind`` is ``kind``."""
    def decorate(cls):
        if kind in _BACKENDS and _BACKENDS[kind] is not cls:
            raise ValueError(f"kind: {kind!r} already has the store backend {_BACKENDS[kind].__name__}")
        cls.kind = kind
        _BACKENDS[kind] = cls
        return cls
    return decorate


def backend_or_none(kind: str):
    """The backend class registered for ``kind``, or None."""
    return _BACKENDS.get(kind)


def backend(kind: str):
    """The backend class registered for ``kind``.

    Raises
    ------
    StoreError
        No backend has that kind.
    """
    cls = _BACKENDS.get(kind)
    if cls is None:
        raise StoreError(f"run kind {kind!r}: this seqbayes has no store for it (it knows "
                         f"{', '.join(sorted(_BACKENDS))})")
    return cls


def kinds() -> tuple:
    """The registered run kinds."""
    return tuple(_BACKENDS)


def run_kind(path: str | os.PathLike) -> str:
    """The ``run_kind`` a run store file records (:data:`DEFAULT_KIND` for a file without one, or one
    that is not a readable store: its backend then reads or refuses it with its own message)."""
    import h5py

    from . import files

    try:
        with open(path, "rb") as fh:
            with contextlib.suppress(OSError):   # as the store's readers: never between two halves of a step
                files.lock_file(fh, exclusive=False)
            journal = files.read_journal(Path(path))      # a committed step not yet written into the file
            with h5py.File(files.PendingWrites(fh, journal) if journal is not None else fh, "r") as f:
                return str(files.plain(f.attrs.get("run_kind", DEFAULT_KIND)))
    except Exception:
        return DEFAULT_KIND


def open_run(path: str | os.PathLike):
    """Open the run store at ``path`` with the backend of its kind (runs no user code).

    Raises
    ------
    StoreError
        As the backend's ``open``; or a kind this seqbayes has no backend for.
    """
    return backend(run_kind(path)).open(path)


def create_run(path: str | os.PathLike, config, *, overwrite: bool = False):
    """Start a new run at ``path`` with the backend of ``config.kind`` (:func:`seqbayes.store.load_config`)."""
    return backend(config.kind).create(path, config, overwrite=overwrite)
