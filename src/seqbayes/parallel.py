"""Likelihood evaluation over a batch of samples, serially or through an executor.

An executor is anything with ``map`` (a :mod:`concurrent.futures` executor) or a
:class:`dask.distributed.Client` (``map`` returns futures, gathered here). The
batch is split into contiguous chunks, so the result is identical to the serial
evaluation whatever the number of workers. The user's function gets read-only views
of the samples and the data (:func:`read_only`): writing into them raises instead of
corrupting the sampler's particles or a stored dataset.
"""

from __future__ import annotations

import numpy as np

__all__ = ["evaluate_loglike", "read_only"]


def read_only(value):
    """``value`` as user code may see it: arrays as read-only views, dicts, lists and tuples rebuilt
    around read-only views (so the caller's containers cannot be changed either); others as they are.

    >>> a = np.zeros(2)
    >>> read_only(a).flags.writeable, a.flags.writeable
    (False, True)
    """
    if isinstance(value, np.ndarray):
        view = value.view()
        view.flags.writeable = False
        return view
    if isinstance(value, dict):
        return {key: read_only(item) for key, item in value.items()}
    if type(value) in (list, tuple):
        return type(value)(read_only(item) for item in value)
    return value


def _call(loglike, theta, dataset):
    """The user's ``loglike`` on read-only views; its values as a new float array."""
    try:
        values = loglike(read_only(theta), read_only(dataset))
    except ValueError as err:
        if "read-only" not in str(err):
            raise
        raise ValueError(f"loglike: wrote into its input theta or data ({err}); they are read-only so that "
                         f"the run cannot be corrupted: copy them first (np.array(theta)) to change them") from err
    if np.iscomplexobj(values):
        raise ValueError("loglike: returned complex values; a log-likelihood is real")
    return np.array(values, dtype=float)  # a copy: never a view of theta


def evaluate_loglike(loglike, theta, dataset, executor=None, n_chunks: int | None = None) -> np.ndarray:
    """``loglike(theta, dataset)`` for ``theta (N, d)``, optionally in chunks across workers; ``(N,)``."""
    if executor is None or theta.shape[0] < 2:
        return _call(loglike, theta, dataset)
    n_chunks = n_chunks or _default_chunks(executor)
    chunks = np.array_split(theta, min(n_chunks, theta.shape[0]))
    if hasattr(executor, "gather"):  # dask.distributed.Client
        futures = executor.map(_call, [loglike] * len(chunks), chunks, [dataset] * len(chunks), pure=False)
        parts = executor.gather(futures)
    else:
        parts = list(executor.map(_call, [loglike] * len(chunks), chunks, [dataset] * len(chunks)))
    return np.concatenate([np.atleast_1d(p) for p in parts])


def _default_chunks(executor) -> int:
    if hasattr(executor, "nthreads"):  # dask Client
        try:
            return max(1, sum(executor.nthreads().values()))
        except Exception:  # pragma: no cover - a client without workers yet
            return 2
    return getattr(executor, "_max_workers", 2) or 2
