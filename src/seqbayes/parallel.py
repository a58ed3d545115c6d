"""Likelihood evaluation over a batch of samples, serially or through an executor.

An executor is a :class:`ProcessWorkers` pool, any object with ``map`` (a
:mod:`concurrent.futures` executor) or a :class:`dask.distributed.Client`. The batch is
split into one contiguous chunk per worker, so the result is identical to the serial
evaluation whatever the number of workers. What makes a pool pay for an expensive model
(docs/parallel.md measures it):

* **The likelihood and the dataset travel once.** :class:`ProcessWorkers` and a Dask
  client keep them on the workers, keyed by a fingerprint of their pickled bytes (so a
  buffer the caller refilled in place is sent again, never used stale); each call then
  ships only the samples. A plain ``concurrent.futures`` executor cannot address its
  workers and gets both with every chunk.
* **Few hops per call.** On Dask each worker holds one actor (:class:`_DaskEvaluator`) that
  the client calls directly, without the scheduler.
* **A cheap batch stays here.** The likelihood's own time per sample (timed around the
  call, in the worker or here, so without the round trip; on the very first call, from
  its first sample, evaluated here) is remembered per executor and likelihood; when a
  chunk would take less than :data:`MIN_CHUNK_SECONDS` (the round trip's order), the batch
  is evaluated serially.

The user's function gets read-only views of the samples and the data (:func:`read_only`):
writing into them raises instead of corrupting the sampler's particles or a stored dataset.
"""

from __future__ import annotations

import hashlib
import pickle
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from .core.likelihood import call_loglike, read_only

__all__ = ["evaluate_loglike", "read_only", "ProcessWorkers", "Workers", "MIN_CHUNK_SECONDS", "make_executor"]

#: A chunk expected to take less than this (seconds) is not worth a round trip: the batch is evaluated
#: serially (the round trips' costs, Dask's and a local process pool's: docs/parallel.md).
MIN_CHUNK_SECONDS = 0.02

#: Payloads (likelihood, dataset) kept per pool; the history prior's past datasets each need one.
_KEPT_PAYLOADS = 16


@dataclass(frozen=True)
class Workers:
    """An executor and the number of chunks each batch is split into (``None``: one per worker), as a sampler's
    ``executor``: ``SEMC(..., executor=Workers(client, n_chunks=8))``."""

    executor: Any
    n_chunks: int | None = None

    def evaluate(self, loglike, theta, dataset) -> np.ndarray:
        """``loglike(theta, dataset)`` for ``theta (N, d)`` on the workers (:func:`evaluate_loglike`), ``(N,)``."""
        return evaluate_loglike(loglike, theta, dataset, self.executor, self.n_chunks)


# ---------------------------------------------------------------- worker side: payloads kept by key
_STORED: OrderedDict = OrderedDict()


def _store(key, payload: bytes) -> None:
    """In a worker: keep the unpickled ``(loglike, dataset)`` under ``key`` (the newest few)."""
    _STORED[key] = pickle.loads(payload)
    while len(_STORED) > _KEPT_PAYLOADS:
        _STORED.popitem(last=False)


def _timed(loglike, theta, dataset):
    """In a worker: ``(values, seconds spent in the likelihood)``: the cost without the round trip."""
    start = time.perf_counter()
    values = call_loglike(loglike, theta, dataset)
    return values, time.perf_counter() - start


def _call_stored(key, theta):
    """In a worker: the kept likelihood on the kept dataset at ``theta``, timed."""
    loglike, dataset = _STORED[key]
    return _timed(loglike, theta, dataset)


class _DaskEvaluator:
    """A Dask actor, one per worker: keeps payloads like :func:`_store` and evaluates chunks like
    :func:`_call_stored`. Calls to an actor go from the client to its worker directly, without the
    scheduler: a round trip costs 10 ms instead of 68 ms for ``Client.map`` (load 12.6,
    ``benchmarks/bench_parallel.py --round-trip``)."""

    def __init__(self):
        self.stored: OrderedDict = OrderedDict()

    def store(self, key, payload: bytes) -> bool:
        self.stored[key] = pickle.loads(payload)
        while len(self.stored) > _KEPT_PAYLOADS:
            self.stored.popitem(last=False)
        return True

    def evaluate(self, key, theta):
        loglike, dataset = self.stored[key]
        return _timed(loglike, theta, dataset)


class ProcessWorkers:
    """A pool of worker processes that keep the likelihood and the dataset between calls.

    Each worker is its own one-process executor, so a payload can be sent to every worker once
    and each chunk addressed to one worker. Usable as an ordinary executor (``map``) too.

    Parameters
    ----------
    n_workers : int
    mp_context : multiprocessing context, optional
        E.g. ``multiprocessing.get_context("spawn")`` (the platform's default otherwise).

    Examples
    --------
    >>> with ProcessWorkers(2) as pool:                       # doctest: +SKIP
    ...     sampler = seqbayes.SEMC(prior, kernel, loglike, executor=pool)
    """

    def __init__(self, n_workers: int = 2, mp_context=None):
        if isinstance(n_workers, bool) or int(n_workers) != n_workers or n_workers < 1:
            raise ValueError(f"n_workers: expected an integer >= 1, got {n_workers!r}")
        self._executors = [ProcessPoolExecutor(1, mp_context=mp_context) for _ in range(int(n_workers))]
        self._sent: OrderedDict = OrderedDict()

    @property
    def n_workers(self) -> int:
        return len(self._executors)

    def map(self, fn, *iterables):
        """``fn`` over the iterables, round-robin over the workers; results in order."""
        futures = [self._executors[i % self.n_workers].submit(fn, *args) for i, args in enumerate(zip(*iterables))]
        return [f.result() for f in futures]

    def evaluate(self, key, payload: bytes, chunks) -> list:
        """Chunk ``i`` on worker ``i``; the payload is sent to the workers only the first time ``key`` is seen."""
        # first in, first out like the workers' _STORED (a use refreshes neither): the keys here are exactly those
        # every worker keeps, whichever workers the chunks reached
        if key not in self._sent:
            for f in [e.submit(_store, key, payload) for e in self._executors]:
                f.result()
            self._sent[key] = True
            while len(self._sent) > _KEPT_PAYLOADS:
                self._sent.popitem(last=False)
        futures = [self._executors[i % self.n_workers].submit(_call_stored, key, chunk) for i, chunk in enumerate(chunks)]
        return [f.result() for f in futures]

    def shutdown(self, wait: bool = True) -> None:
        for executor in self._executors:
            executor.shutdown(wait=wait)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.shutdown()


class _Plan:
    """What one executor remembers: the measured cost per sample of each likelihood; for Dask, its actors
    (one per worker) and the payloads they keep."""

    def __init__(self):
        self.seconds_per_row: dict = {}
        self.actors: tuple = ()
        self.workers: tuple = ()
        self.sent: OrderedDict = OrderedDict()

    def remember(self, key) -> None:
        """``key`` was sent to every actor: kept first in, first out, as the actors keep it."""
        self.sent[key] = True
        while len(self.sent) > _KEPT_PAYLOADS:
            self.sent.popitem(last=False)


#: Seconds to wait for a Dask cluster with no worker (one being restarted) before giving up.
DASK_WORKER_WAIT = 120.0


def _dask_actors(client, plan) -> tuple:
    """One :class:`_DaskEvaluator` actor per worker of ``client`` (made again when the workers change)."""
    workers = tuple(sorted(client.scheduler_info()["workers"]))
    if not workers:  # a worker being restarted (lost under load): wait for one rather than send chunks to none
        try:
            client.wait_for_workers(1, timeout=DASK_WORKER_WAIT)
        except TimeoutError as error:
            raise RuntimeError(f"executor: the Dask cluster has had no worker for {DASK_WORKER_WAIT:.0f} s") from error
        workers = tuple(sorted(client.scheduler_info()["workers"]))
    if workers != plan.workers:
        plan.actors = tuple(client.submit(_DaskEvaluator, actor=True, workers=[w], pure=False).result()
                            for w in workers)
        plan.workers = workers
        plan.sent.clear()
    return plan.actors


_PLANS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_UNWEAKABLE_PLANS: dict = {}


def _plan(executor) -> _Plan:
    try:
        return _PLANS.setdefault(executor, _Plan())
    except TypeError:  # an executor that takes no weak reference: kept by id while it lives
        return _UNWEAKABLE_PLANS.setdefault(id(executor), _Plan())


def _payload(loglike, dataset):
    """The pickled ``(loglike, dataset)`` and its fingerprint (cloudpickle for what pickle cannot take)."""
    try:
        payload = pickle.dumps((loglike, dataset), protocol=pickle.HIGHEST_PROTOCOL)
    except (pickle.PicklingError, AttributeError, TypeError):
        import cloudpickle

        payload = cloudpickle.dumps((loglike, dataset))
    return payload, hashlib.blake2b(payload, digest_size=16).hexdigest()


def evaluate_loglike(loglike, theta, dataset, executor=None, n_chunks: int | None = None) -> np.ndarray:
    """``loglike(theta, dataset)`` for ``theta (N, d)``, optionally in chunks across workers; ``(N,)``.

    Parameters
    ----------
    loglike : callable ``(theta (k, d), dataset) -> (k,)``
    theta : (N, d) array
    dataset : object
    executor : ProcessWorkers, concurrent.futures executor or dask Client, optional
    n_chunks : int, optional
        Chunks per call (default: one per worker).
    """
    n = theta.shape[0]
    if executor is None or n < 2:
        return call_loglike(loglike, theta, dataset)
    n_chunks = min(n_chunks or _default_chunks(executor), n)
    plan = _plan(executor)
    cost = plan.seconds_per_row.get(id(loglike))
    head = None
    if cost is None and MIN_CHUNK_SECONDS > 0:  # first call: time one sample here (it is needed anyway)
        start = time.perf_counter()
        head = call_loglike(loglike, theta[:1], dataset)
        cost = plan.seconds_per_row[id(loglike)] = time.perf_counter() - start
        theta = theta[1:]
        n_chunks = min(n_chunks, theta.shape[0])
    if cost is not None and cost * theta.shape[0] / n_chunks < MIN_CHUNK_SECONDS:
        values, seconds = _timed(loglike, theta, dataset)
    else:
        values, seconds = _parallel(loglike, theta, dataset, executor, n_chunks, plan)
    plan.seconds_per_row[id(loglike)] = seconds / max(1, theta.shape[0])  # the likelihood's own time
    return values if head is None else np.concatenate([head, values])


def _parallel(loglike, theta, dataset, executor, n_chunks, plan) -> np.ndarray:
    chunks = np.array_split(theta, n_chunks)
    if isinstance(executor, ProcessWorkers):
        payload, key = _payload(loglike, dataset)
        parts = executor.evaluate(key, payload, chunks)
    elif hasattr(executor, "gather"):  # dask.distributed.Client: one actor per worker keeps the payload
        payload, key = _payload(loglike, dataset)
        actors = _dask_actors(executor, plan)
        if key not in plan.sent:
            for f in [actor.store(key, payload) for actor in actors]:
                f.result()
        plan.remember(key)
        futures = [actors[i % len(actors)].evaluate(key, chunk) for i, chunk in enumerate(chunks)]
        parts = [f.result() for f in futures]
    else:
        parts = list(executor.map(_timed, [loglike] * len(chunks), chunks, [dataset] * len(chunks)))
    return np.concatenate([np.atleast_1d(values) for values, _ in parts]), sum(seconds for _, seconds in parts)


def _default_chunks(executor) -> int:
    if isinstance(executor, ProcessWorkers):
        return executor.n_workers
    if hasattr(executor, "nthreads"):  # dask Client
        try:
            return max(1, sum(executor.nthreads().values()))
        except Exception:  # pragma: no cover - a client without workers yet
            return 2
    return getattr(executor, "_max_workers", 2) or 2


def make_executor(kind: str, workers: int = 2, address: str | None = None) -> tuple[Any, Callable[[], None]]:
    """``(executor, close)`` for a run configuration's ``[parallel]`` section.

    Parameters
    ----------
    kind : {"serial", "processes", "dask"}
        ``"serial"`` gives ``(None, no-op)``; ``"processes"`` a :class:`ProcessWorkers` pool of
        ``workers`` forked processes; ``"dask"`` a client of the cluster at ``address`` or of a
        local cluster of ``workers`` single-threaded processes bound to 127.0.0.1.
    """
    if kind == "serial":
        return None, lambda: None
    if kind == "processes":
        import multiprocessing

        # forked workers inherit the likelihood's module, which is imported by file path and so
        # is not importable by name in a spawned process (the default start method may change)
        context = (multiprocessing.get_context("fork") if "fork" in multiprocessing.get_all_start_methods()
                   else None)
        pool = ProcessWorkers(workers, mp_context=context)
        return pool, pool.shutdown
    if kind != "dask":
        raise ValueError(f"kind: expected 'serial', 'processes' or 'dask', got {kind!r}")
    from distributed import Client, LocalCluster  # optional extra: seqbayes[dask]

    if address:
        client = Client(address)
        return client, client.close
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                           host="127.0.0.1", dashboard_address="127.0.0.1:0")   # not on every interface
    client = Client(cluster)

    def close():
        client.close()
        cluster.close()

    return client, close
