"""One computation of a long run per test run, whichever tests and workers read it (tests/conftest.py
says how to use it).

:func:`shared_run` keys a result by the run's name, its arguments, the hash of the code that makes it
(every file of the ``seqbayes`` package, the module of the function called) and the versions of
Python, numpy and scipy. It keeps the result in memory for the process and as a pickle in pytest's
cache folder (``.pytest_cache/d/shared-runs``; with ``-p no:cacheprovider``, in memory only), written
under a file lock: a second pytest-xdist worker that asks for the same run while
the first computes it waits for the file, and a later test run on unchanged code reads it instead of
recomputing (``pytest --cache-clear`` forgets them; a fresh clone has none).
"""

from __future__ import annotations

import contextlib
import fcntl
import functools
import hashlib
import inspect
import os
import pickle
import platform
import sys
from pathlib import Path

_DIRECTORY: Path | None = None
_MEMORY: dict[str, object] = {}


def configure(directory: Path) -> None:
    """Where the results are kept (conftest.py's ``pytest_configure``)."""
    global _DIRECTORY
    _DIRECTORY = Path(directory)
    _DIRECTORY.mkdir(parents=True, exist_ok=True)


@functools.lru_cache(maxsize=None)
def _tree_hash(root: str) -> str:
    digest = hashlib.sha256()
    for path in sorted(Path(root).rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def code_hash(fn) -> str:
    """A hash of the package's files, ``fn``'s module and the numerical stack's versions."""
    import numpy
    import scipy

    import seqbayes

    digest = hashlib.sha256(_tree_hash(str(Path(seqbayes.__file__).parent)).encode())
    module = inspect.getsourcefile(fn) if not isinstance(fn, functools.partial) else inspect.getsourcefile(fn.func)
    if module:
        digest.update(Path(module).read_bytes())
    digest.update(f"{sys.version}|{numpy.__version__}|{scipy.__version__}|{platform.machine()}".encode())
    return digest.hexdigest()


@contextlib.contextmanager
def _locked(path: Path):
    with open(path, "a+b") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def shared_run(name: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, computed once for every test and worker of a test run.

    Parameters
    ----------
    name : str
        The run's name (a file name: letters, digits and dashes).
    fn : callable
        A deterministic function of its arguments (a seeded study); its result must pickle.
    *args, **kwargs
        Its arguments; their ``repr`` is part of the key.
    """
    key = hashlib.sha256(f"{name}|{args!r}|{sorted(kwargs.items())!r}|{code_hash(fn)}".encode()).hexdigest()[:20]
    tag = f"{name}-{key}"
    if tag in _MEMORY:
        return _MEMORY[tag]
    if _DIRECTORY is None:
        _MEMORY[tag] = result = fn(*args, **kwargs)
        return result
    target = _DIRECTORY / f"{tag}.pickle"
    with _locked(_DIRECTORY / f"{name}.lock"):
        if target.exists():
            with open(target, "rb") as handle:
                result = pickle.load(handle)
        else:
            result = fn(*args, **kwargs)
            partial = target.with_suffix(f".{os.getpid()}.tmp")
            with open(partial, "wb") as handle:
                pickle.dump(result, handle, protocol=pickle.HIGHEST_PROTOCOL)
            os.replace(partial, target)
            for old in _DIRECTORY.glob(f"{name}-*.pickle"):   # the same run on older code
                if old != target:
                    old.unlink(missing_ok=True)
    _MEMORY[tag] = result
    return result
