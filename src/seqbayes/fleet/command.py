"""``seqbayes update FLEET`` and ``seqbayes status FLEET``: the fleet's commands, which the CLI hands over to.

The command checks everything that can be checked before a store is touched (the plan, the options, the
output targets, whose room it takes), then runs the driver, printing one line per store as its outcome
comes, then writes the fleet's record and the ``--json`` outcome, and prints a summary. Its exit status is
0 when every store's task succeeded, 1 when some failed (the others completed: their lines say so, and
each failure is repeated on stderr), and 2 when the command refused to start (one line, no store touched).
"""

from __future__ import annotations

import json
import sys
import time

from .drivers import dask_client, run_dask, run_serial
from .outputs import check_targets, outcome_size, read_record, reserve_room
from .plan import FleetError, plan_fleet
from .records import collect
from .status import fleet_status, format_status, status_json
from .task import TaskOptions

__all__ = ["update_command", "status_command", "MAX_WORKERS"]

#: Most workers of a local cluster (each is a process holding a store and its sampler).
MAX_WORKERS = 256


def _check_workers(workers, scheduler) -> int | None:
    if scheduler is not None and workers is not None:
        raise FleetError("--workers: the cluster at --scheduler has its own workers; give one of the two")
    if workers is None:
        return None
    if not 0 <= workers <= MAX_WORKERS:
        raise FleetError(f"--workers: expected 0 (no Dask: the stores one after another in this process) to "
                         f"{MAX_WORKERS}, got {workers}")
    return workers


def _default_workers(n_tasks: int) -> int:
    import os

    return max(1, min(n_tasks, os.cpu_count() or 1))


def update_command(source, *, workers=None, scheduler=None, json_path=None, lock_timeout=None,
                   accept_model_change=False, force=False, out=None, err=None) -> int:
    """Update every store of the fleet at ``source`` (a folder or a manifest) with its new datasets.

    Parameters
    ----------
    source : path-like
    workers : int, optional
        Workers of the local Dask cluster (default: the cores, at most one per store); 0 runs the stores one
        after another in this process, without Dask.
    scheduler : str, optional
        Address of a running Dask scheduler, instead of a local cluster.
    json_path : path-like, optional
        Also write the fleet's outcome (the record's JSON) here.
    lock_timeout : float, optional
        Seconds to wait for a store another update holds (:class:`~seqbayes.fleet.task.TaskOptions`).
    accept_model_change : bool
        As ``seqbayes update --accept-model-change``, for every store.
    force : bool
        ``--json`` may replace an existing file that is not a fleet outcome (never an input or a store).
    out, err : text streams
        Where the lines go (default: stdout and stderr).

    Returns
    -------
    int
        The exit status (module docstring).

    Raises
    ------
    FleetError, seqbayes.store.targets.OutputError
        The command refused to start; no store was touched.
    """
    from ..store.locks import lock_timeout as check_timeout, now
    from ..store.targets import OutputError

    out, err = out or sys.stdout, err or sys.stderr
    workers = _check_workers(workers, scheduler)
    if lock_timeout is not None:
        check_timeout(lock_timeout)
    plan = plan_fleet(source)
    if not plan.tasks:
        raise FleetError(f"{source}: no run stores in this fleet (a fleet folder holds stores NAME.nc, each beside "
                         f"a folder NAME/ of its new datasets; a manifest lists [[store]] entries; docs/fleet.md)")
    options = TaskOptions(lock_timeout=lock_timeout, accept_model_change=accept_model_change)
    size = outcome_size(plan)
    targets = check_targets(plan, json_path, force)
    reserved = []
    try:
        for path, what in targets:
            reserved.append(reserve_room(path, size, what))
        if workers is None and scheduler is None:
            workers = _default_workers(len(plan.tasks))

        def show(outcome):
            print(outcome.line(), file=out, flush=True)
            for line in outcome.warnings + tuple(w for s in outcome.steps for w in s.warnings):
                print(f"seqbayes update: warning: {outcome.name}: {line}", file=err, flush=True)

        started, clock = now(), time.perf_counter()
        if workers == 0:
            driver = "serial, in this process"
            outcomes = run_serial(plan.tasks, options, show)
        else:
            driver = (f"dask scheduler {scheduler}" if scheduler is not None
                      else f"dask LocalCluster of {workers} worker{'s' * (workers != 1)}")
            with dask_client(workers, scheduler) as client:
                clock = time.perf_counter()     # the cluster's start-up is not the fleet's work
                outcomes = run_dask(plan.tasks, client, options, show)
        fleet = collect(plan.tasks, outcomes, source=str(plan.source), driver=driver, started=started,
                        seconds=time.perf_counter() - clock)
    except BaseException:
        for output in reserved:
            output.abandon()
        raise
    text = json.dumps(fleet.to_json(), indent=1, allow_nan=False) + "\n"
    for output in reserved:
        try:
            output.commit(text)
        except OutputError as error:
            from ..store.datasets import printable

            for other in reserved:
                other.abandon()
            print(f"seqbayes update: error: {printable(str(error))}; the stores were updated as the lines above "
                  f"say", file=err)
            return 2
    print(fleet.summary(), file=out, flush=True)
    for outcome in fleet.failed:
        print(f"seqbayes update: error: {outcome.line()}", file=err, flush=True)
    return fleet.exit_code


def status_command(source, *, as_json=False, out=None) -> int:
    """Print the status of every store of the fleet at ``source``; 1 when some store has errors, else 0.

    Raises
    ------
    FleetError
        The fleet's folder or manifest is unusable.
    OSError
        The output could not be written (a full disk behind stdout).
    """
    out = out or sys.stdout
    plan = plan_fleet(source)
    record, problem = read_record(plan)
    statuses = fleet_status(plan, record)
    if as_json:
        text = json.dumps(status_json(plan, statuses, problem), indent=1, allow_nan=False)
    else:
        text = format_status(plan, statuses, problem)
    print(text, file=out)
    out.flush()                 # a full disk behind stdout is one line here, not a traceback at exit
    return 1 if any(s.errors for s in statuses) or problem else 0
