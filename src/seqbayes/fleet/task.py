"""One store's task of a fleet update: its datasets, in order, through the path of ``seqbayes update``.

:func:`run_task` does what ``seqbayes update STORE D1 D2 ...`` does (``cli.cmd_update``): it takes the
store's lock, opens the store through the registry, reads and checks every data file before anything
runs, and assimilates them one by one with ``store.assimilate``, each step committed through the
store's journal. So a store updated in a fleet holds the same numbers, bit for bit, as the same store
updated alone (tests/unit/test_fleet.py). Three things differ, all because a fleet runs unattended:

* datasets the store already holds are skipped (a fleet update that was stopped is simply run again),
  provided they are the first ones of the list and in the store's order (:func:`pending_datasets`);
* a store whose lock another update holds is not waited for unless a lock timeout is given: it is
  reported as locked, with the holder;
* the likelihood is evaluated in the task's own process (a store's ``[parallel]`` section is not used:
  the fleet's parallelism is across stores, and the parallel evaluation gives the serial numbers).

Whatever goes wrong (a bad file, a raising likelihood, a damaged or locked store) becomes the outcome's
one-line error (:func:`describe_failure`, the line ``seqbayes update`` prints); the task itself raises only
on ``KeyboardInterrupt`` and ``SystemExit``.
"""

from __future__ import annotations

import os
import socket
import time
import traceback
import warnings
from dataclasses import dataclass
from pathlib import Path

from .records import CURRENT, FAILED, UPDATED, StepOutcome, StoreOutcome

__all__ = ["TaskOptions", "run_task", "pending_datasets", "describe_failure", "worker_label"]


@dataclass(frozen=True)
class TaskOptions:
    """How a store's task runs.

    Attributes
    ----------
    lock_timeout : float or None
        Seconds to wait for a store another update holds; None: ``$SEQBAYES_LOCK_TIMEOUT``, else 0 (a
        fleet does not wait: it reports the store locked and goes on with the others).
    accept_model_change : bool
        As ``seqbayes update --accept-model-change``, for every store.
    """

    lock_timeout: float | None = None
    accept_model_change: bool = False

    def timeout(self) -> float:
        if self.lock_timeout is not None:
            return self.lock_timeout
        from ..store.locks import LOCK_TIMEOUT_ENV, lock_timeout

        return lock_timeout() if os.environ.get(LOCK_TIMEOUT_ENV) else 0.0


def worker_label() -> str:
    """Where a task runs: host and process id."""
    return f"{socket.gethostname()} pid {os.getpid()}"


class _Stop(Exception):
    """The task stops with this one line as its error."""


def pending_datasets(store, paths, tables) -> tuple[list, list]:
    """``(pending, skipped)``: the ``(path, table)`` pairs ``store`` does not hold yet, in order, and the names
    of those it holds.

    The ones it holds must come first and lie in the store in the list's order (a stopped fleet update
    leaves exactly that); otherwise assimilating the rest would not give the order the list asks for.

    Raises
    ------
    ValueError
        A held dataset after one not held, held ones out of order, or one dataset twice in the list
        (nothing has been assimilated).
    """
    held = {digest: k for k, digest in enumerate(store.digests)}
    digests = [store.digest_of(table) for table in tables]
    pending, skipped, steps, first_new, seen = [], [], [], None, {}
    for path, table, digest in zip(paths, tables, digests):
        name = Path(path).name
        if digest in seen:
            raise ValueError(f"{path}: the same data as {seen[digest]}, earlier in the list; nothing was "
                             f"assimilated")
        seen[digest] = name
        if digest not in held:
            first_new = name if first_new is None else first_new
            pending.append((path, table))
            continue
        if first_new is not None:
            raise ValueError(f"{path}: already assimilated as step {held[digest] + 1}, although {first_new}, before "
                             f"it in the list, is not: the store's order differs from the list's; nothing was "
                             f"assimilated")
        if steps and held[digest] < steps[-1]:
            raise ValueError(f"{path}: assimilated as step {held[digest] + 1}, before {skipped[-1]} (step "
                             f"{steps[-1] + 1}), which the list puts first: the store's order differs from the "
                             f"list's; nothing was assimilated")
        steps.append(held[digest])
        skipped.append(name)
    return pending, skipped


def run_task(task, options: TaskOptions = TaskOptions()) -> StoreOutcome:
    """Assimilate ``task``'s datasets into its store (module docstring) and say what happened.

    Parameters
    ----------
    task : seqbayes.fleet.plan.StoreTask
    options : TaskOptions

    Returns
    -------
    StoreOutcome
        ``updated``, ``current`` (nothing new) or ``failed`` with one line; on failure the store keeps the
        steps committed before the error (listed in ``steps``), and is unchanged by the dataset that failed.
    """
    from ..store import BoundWarning, open_run
    from ..store.datasets import printable
    from ..store.locks import store_lock

    start = time.perf_counter()
    store, steps, skipped, done, error = None, [], [], [], None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            if task.problem is not None:
                raise _Stop(task.problem)
            with store_lock(task.store, timeout=options.timeout(), notify=None):
                store = open_run(task.store)
                tables = [store.read_datafile(path) for path in task.datasets]   # all files checked first
                pending, skipped = pending_datasets(store, task.datasets, tables)
                for path, table in pending:
                    with warnings.catch_warnings(record=True) as step_caught:
                        warnings.simplefilter("always", BoundWarning)
                        try:
                            info = store.assimilate(table, Path(path).name,
                                                    accept_model_change=options.accept_model_change)
                        except (KeyboardInterrupt, SystemExit):
                            raise
                        except Exception as err:
                            raise _Stop(f"{path}: {describe_failure(err, store, done)}") from err
                    name = Path(path).name
                    steps.append(StepOutcome(name, store.n_steps, printable(store.step_summary(info, name)),
                                             _warning_lines(step_caught, BoundWarning)))
                    done.append(f"{name} (step {store.n_steps})")
        except (KeyboardInterrupt, SystemExit):
            raise
        except _Stop as stop:
            error = printable(str(stop))
        except Exception as err:
            error = printable(describe_failure(err, store, done, prefix=False))
    status = FAILED if error is not None else UPDATED if steps else CURRENT
    return StoreOutcome(task.name, str(task.store), status, tuple(steps), tuple(skipped),
                        store.n_steps if store is not None else None, error,
                        _warning_lines(caught, BoundWarning),
                        time.perf_counter() - start, worker_label())


#: Warnings addressed to developers, which Python does not show a user by default: not an outcome's lines.
_NOT_SHOWN = (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning)


def _warning_lines(caught, quiet) -> tuple:
    """Caught warnings as ``seqbayes update`` prints them, one line each (the category named unless it is
    ``quiet``'s), without the ones Python does not show by default."""
    from ..store.datasets import printable

    return tuple(("" if issubclass(w.category, quiet) else f"{w.category.__name__}: ") + printable(w.message)
                 for w in caught if not issubclass(w.category, _NOT_SHOWN))


def _raised_in(err, files) -> bool:
    """Whether the exception passed through one of ``files`` (the user's likelihood module)."""
    files = {str(Path(f).resolve()) for f in files if f}
    return any(str(Path(frame.filename).resolve()) in files for frame in traceback.extract_tb(err.__traceback__))


def describe_failure(err, store, done=(), prefix: bool = True) -> str:
    """One line for an update that failed, saying what the run store holds now.

    Parameters
    ----------
    err : Exception
    store : BaseStore or None
        The store being updated (None: it was not opened).
    done : sequence of str
        The steps committed before the error (``"d3.csv (step 7)"``).
    prefix : bool
        Whether the error came while assimilating a dataset (False: while opening the store or reading
        the data files, where a seqbayes error's own message is the line).
    """
    from ..store import ConfigError, DataError, StoreError

    if done:
        unchanged = (f"the run store keeps the steps committed before it ({', '.join(done)}); this file and the "
                     f"ones after it were not assimilated")
    else:
        unchanged = "the run store is unchanged"
    text = str(err)
    if isinstance(err, (StoreError, ConfigError, DataError)):
        return text if "previous store is kept" in text or not prefix else f"{text}; {unchanged}"
    if isinstance(err, OSError):
        where = f" ({err.filename})" if err.filename else ""
        return f"{err.strerror or text}{where}; {unchanged}"
    user = store.user_code() if store is not None else None   # (module:function, file) of the likelihood
    if user is not None and isinstance(err, ValueError) and text.startswith("loglike"):
        return f"likelihood {user[0]}: {text}; {unchanged}"
    if user is not None and _raised_in(err, [user[1]]):
        return f"the likelihood {user[0]} raised {type(err).__name__}: {text}; {unchanged}"
    if isinstance(err, (ValueError, TypeError)) and not prefix:
        return text
    if isinstance(err, ValueError) or type(err).__name__ in ("ZeroLikelihoodError", "TemperingLimitError"):
        return f"{text}; {unchanged}"
    return (f"{type(err).__name__} in seqbayes: {text} (a bug: please report it with --traceback); "
            f"{unchanged}")
