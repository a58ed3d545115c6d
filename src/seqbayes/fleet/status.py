"""A fleet's status: per store its last step, its alarm, what is pending and what is wrong, as text and JSON.

:func:`store_status` opens one store (a reader: it takes no lock an update would wait for and writes
nothing but a committed journal, as every seqbayes command does), reads the data files the plan gives it
to tell which are still to be assimilated and which cannot be (the errors an update would stop on), asks
the backend for its alarm (:meth:`~seqbayes.store.base.BaseStore.alarm_state`, None for kinds without
one) and takes the last fleet update's error for the store from the fleet's record
(:func:`seqbayes.fleet.outputs.read_record`).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["StoreStatus", "store_status", "fleet_status", "format_status", "status_json"]


@dataclass(frozen=True)
class StoreStatus:
    """One store of a fleet as it stands.

    Attributes
    ----------
    name, store : str
        Its name in the plan and its path.
    kind, model : str or None
        The run kind and the model's name (None: the store could not be opened).
    n_steps : int or None
        Its last step.
    last_dataset : str or None
        The file name of the dataset of its last step.
    alarm : AlarmState or None
        The backend's alarm; None when the kind has none.
    pending : int
        Data files of the plan it does not hold yet.
    errors : tuple of str
        What is wrong, one line each: the store does not open, a data file cannot be read, the last fleet
        update failed on it.
    last_update : dict or None
        The last fleet update's outcome of the store (``status``, ``error``, ``started``), from the record.
    """

    name: str
    store: str
    kind: str | None = None
    model: str | None = None
    n_steps: int | None = None
    last_dataset: str | None = None
    alarm: object = None
    pending: int = 0
    errors: tuple = ()
    last_update: dict | None = None

    def to_json(self) -> dict:
        alarm = self.alarm
        return {"name": self.name, "store": self.store, "kind": self.kind, "model": self.model,
                "steps": self.n_steps, "last_dataset": self.last_dataset,
                "alarm": None if alarm is None else {"raised": bool(alarm.raised), "step": alarm.step,
                                                     "text": alarm.text},
                "pending": self.pending, "errors": list(self.errors), "last_update": self.last_update}


def store_status(task, last: dict | None = None) -> StoreStatus:
    """The :class:`StoreStatus` of ``task``'s store (module docstring); ``last`` is its entry in the record."""
    from ..store import open_run
    from ..store.datasets import printable
    from .task import pending_datasets

    last_update = None
    if isinstance(last, dict) and last.get("status") in ("updated", "current", "failed"):
        n_steps = last.get("n_steps")
        last_update = {"status": last["status"], "error": printable(str(last["error"]))[:1000]
                       if last.get("error") is not None else None, "started": printable(str(last.get("started"))),
                       "n_steps": n_steps if isinstance(n_steps, int) else None}
    errors = [task.problem] if task.problem else []
    try:
        store = open_run(task.store)
    except Exception as err:   # damaged, missing, another version: the one line the store's open gives
        errors.insert(0, printable(str(err)))
        store = None
    if last_update is not None and last_update["error"] is not None:
        since = ("" if store is None or last_update["n_steps"] in (None, store.n_steps) else
                 f" (it had {last_update['n_steps']} steps then, {store.n_steps} now)")
        errors.append(f"the last fleet update ({last_update['started']}) failed{since}: {last_update['error']}")
    if store is None:
        return StoreStatus(task.name, str(task.store), errors=tuple(errors), last_update=last_update,
                           pending=len(task.datasets))
    readable, bad = [], []
    for path in task.datasets:
        try:
            readable.append((path, store.read_datafile(path)))
        except Exception as err:
            bad.append(printable(str(err)))
    pending = len(bad)
    try:
        pending += len(pending_datasets(store, [p for p, _ in readable], [t for _, t in readable])[0])
    except ValueError as err:
        bad.append(printable(str(err)))
        pending = len(task.datasets)
    return StoreStatus(task.name, str(task.store), store.kind, printable(str(store.config.name)), store.n_steps,
                       printable(store.sources[-1]) if store.n_steps else None, store.alarm_state(), pending,
                       tuple(errors + bad), last_update)


def fleet_status(plan, record: dict | None = None) -> tuple:
    """Every store's :class:`StoreStatus`, in the plan's order (``record``: the last update's outcomes by name)."""
    record = record or {}
    return tuple(store_status(task, record.get(task.name)) for task in plan.tasks)


def _alarm_text(alarm) -> str:
    if alarm is None:
        return "-"
    return f"ALARM (step {alarm.step})" if alarm.raised else "off"


def format_status(plan, statuses, problem: str | None = None) -> str:
    """The text of ``seqbayes status FLEET``: one row per store, then each store's errors, then a summary."""
    from ..store.datasets import printable

    rows = [("store", "kind", "steps", "last dataset", "pending", "alarm", "errors")]
    for s in statuses:
        rows.append((s.name, s.kind or "?", "?" if s.n_steps is None else str(s.n_steps), s.last_dataset or "-",
                     str(s.pending), _alarm_text(s.alarm), str(len(s.errors))))
    widths = [min(40, max(len(r[i]) for r in rows)) for i in range(len(rows[0]))]
    lines = [f"{printable(str(plan.source))} (a fleet {plan.kind}): {len(statuses)} stores"]
    lines += ["  ".join(cell[:40].ljust(w) if i in (0, 1, 3, 5) else cell.rjust(w)
                        for i, (cell, w) in enumerate(zip(row, widths))).rstrip() for row in rows]
    troubled = [s for s in statuses if s.errors or (s.alarm is not None and s.alarm.raised)]
    if troubled or problem:
        lines.append("")
    if problem:
        lines.append(f"record: {problem}")
    for s in troubled:
        if s.alarm is not None and s.alarm.raised:
            lines.append(f"{s.name}: alarm at step {s.alarm.step}: {printable(s.alarm.text)}")
        lines += [f"{s.name}: {error}" for error in s.errors]
    n_errors = sum(bool(s.errors) for s in statuses)
    n_alarms = sum(s.alarm is not None and bool(s.alarm.raised) for s in statuses)
    lines.append(f"{n_errors} store{'s' * (n_errors != 1)} with errors, {n_alarms} with an alarm raised, "
                 f"{sum(s.pending for s in statuses)} datasets pending")
    return "\n".join(lines)


def status_json(plan, statuses, problem: str | None = None) -> dict:
    """What ``seqbayes status FLEET --json`` prints."""
    return {"fleet": str(plan.source), "kind": plan.kind, "record_problem": problem,
            "stores": [s.to_json() for s in statuses],
            "with_errors": [s.name for s in statuses if s.errors],
            "alarms": [s.name for s in statuses if s.alarm is not None and s.alarm.raised]}
