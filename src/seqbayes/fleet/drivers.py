"""The drivers of a fleet update: the store tasks one after another here, or as tasks on a Dask cluster.

Both drivers run the same pure task (:func:`seqbayes.fleet.task.run_task`, one per store: a store's
datasets are sequential, the stores independent) and hand each :class:`~seqbayes.fleet.records.StoreOutcome`
to ``on_outcome`` as it comes. On Dask a task is one ``Client.submit`` of ``run_task``; a task whose worker
died under it (the likelihood crashed the process, the machine ran out of memory) comes back as Dask's
error after its retries (``distributed.scheduler.allowed-failures``) and becomes that store's failed
outcome, so the other stores still complete. A store's own lock and journal protect it wherever its task
runs, also when a worker is killed in the middle of a write.

The cluster is a ``distributed.LocalCluster`` of single-threaded worker processes bound to 127.0.0.1
(:func:`seqbayes.parallel.make_executor`, which a run's ``[parallel]`` section also uses), or the
scheduler at an address; its workers must see the stores and data files at the same paths (a shared
filesystem), and have seqbayes and the likelihood modules' dependencies installed.
"""

from __future__ import annotations

import contextlib
import importlib.util
import logging
import uuid

from .plan import FleetError
from .records import FAILED, StoreOutcome
from .task import TaskOptions, run_task

__all__ = ["run_serial", "run_dask", "dask_client"]


def run_serial(tasks, options: TaskOptions = TaskOptions(), on_outcome=None) -> list:
    """Every task in this process, in order; returns their outcomes (also passed to ``on_outcome``)."""
    outcomes = []
    for task in tasks:
        outcome = run_task(task, options)
        if on_outcome is not None:
            on_outcome(outcome)
        outcomes.append(outcome)
    return outcomes


def run_dask(tasks, client, options: TaskOptions = TaskOptions(), on_outcome=None) -> list:
    """Every task on the cluster of the ``distributed.Client`` ``client``; outcomes in the order they finish.

    The tasks are submitted in order (the scheduler starts them in that order as workers free up). A task
    that raised on the worker, or whose worker died, gives a failed outcome naming Dask's error.
    """
    from distributed import as_completed

    from ..store.datasets import printable

    run = uuid.uuid4().hex[:8]
    futures = {client.submit(run_task, task, options, key=f"seqbayes-fleet-{run}-{i}", pure=False): task
               for i, task in enumerate(tasks)}
    outcomes = []
    try:
        for future in as_completed(list(futures)):
            task = futures.pop(future)
            try:
                outcome = future.result()
            except Exception as err:
                outcome = StoreOutcome(task.name, str(task.store), FAILED,
                                       error=printable(f"its task did not complete on the cluster "
                                                       f"({type(err).__name__}: {err}); the store keeps every "
                                                       f"step committed before (a journal completes a step "
                                                       f"cut short)")[:600])
            future.release()
            if on_outcome is not None:
                on_outcome(outcome)
            outcomes.append(outcome)
    finally:
        for future in futures:          # stopped early (Ctrl-C): nothing more is started
            future.cancel()
    return outcomes


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """A ``distributed.Client``: of the scheduler at ``scheduler``, else of a local cluster of ``workers``
    single-threaded processes bound to 127.0.0.1, its workers' imports done; closed on leaving (the local
    cluster too).

    Raises
    ------
    FleetError
        ``distributed`` is not installed, or the cluster cannot be reached or started.
    """
    if importlib.util.find_spec("distributed") is None:
        raise FleetError("a fleet update on Dask needs the optional dependency distributed (pip install "
                         "'seqbayes[dask]'); --workers 0 updates the stores one after another in this process")
    from ..parallel import make_executor

    try:
        client, close = make_executor("dask", workers or 1, scheduler)
    except (OSError, TimeoutError, ValueError) as err:
        where = f"the scheduler at {scheduler}" if scheduler else f"a local cluster of {workers} workers"
        raise FleetError(f"cannot reach {where}: {type(err).__name__}: {err}") from None
    try:
        try:
            client.run(_import_store)  # every worker pays its imports now, not in its first store's time
        except Exception as err:
            raise FleetError(f"the cluster's workers cannot import seqbayes ({type(err).__name__}: {err}); install "
                             f"it where they run") from None
        yield client
    finally:
        nanny = logging.getLogger("distributed.nanny")
        level = nanny.level
        nanny.setLevel(logging.ERROR)  # the nanny's "still alive, killing" at close: a busy machine, not the user's concern
        try:
            close()
        finally:
            nanny.setLevel(level)


def _import_store() -> None:
    """On a worker: import the store and the engine (what a task needs first)."""
    from ..engine import drivers  # noqa: F401
    from ..store import open_run  # noqa: F401
