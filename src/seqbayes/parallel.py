"""Likelihood evaluation over a batch of samples, serially or through an executor.

An executor is anything with ``map`` (a :mod:`concurrent.futures` executor) or a
:class:`dask.distributed.Client` (``map`` returns futures, gathered here). The
batch is split into contiguous chunks, so the result is identical to the serial
evaluation whatever the number of workers.
"""

from __future__ import annotations

import numpy as np

__all__ = ["evaluate_loglike"]


def _call(loglike, theta, dataset):
    return np.asarray(loglike(theta, dataset), dtype=float)


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
