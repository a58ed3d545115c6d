"""What a fleet update did, store by store, as frozen records (and their JSON form).

:class:`StoreOutcome` is what one store's task returns, wherever it ran: the datasets it assimilated
(:class:`StepOutcome`, one line each, as ``seqbayes update`` prints them), the ones the store already
held, or the one line saying why it stopped. :func:`collect` puts the outcomes of a fleet's tasks in
the plan's order as a :class:`FleetOutcome`, whose exit code says whether some store failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["StepOutcome", "StoreOutcome", "FleetOutcome", "collect", "UPDATED", "CURRENT", "FAILED",
           "OUTCOME_MARKER"]

#: A store's task assimilated at least one dataset.
UPDATED = "updated"
#: A store's task found nothing new to assimilate.
CURRENT = "current"
#: A store's task stopped on an error; the store keeps every step committed before it.
FAILED = "failed"
#: The key that marks a JSON file as a fleet update's outcome (such a file may be replaced by the next one).
OUTCOME_MARKER = "seqbayes_fleet_outcome"


@dataclass(frozen=True)
class StepOutcome:
    """One dataset a store's task assimilated.

    Attributes
    ----------
    source : str
        The data file's name.
    step : int
        The store's step it became (1-based).
    summary : str
        The backend's one line on the step (:meth:`~seqbayes.store.base.BaseStore.step_summary`).
    warnings : tuple of str
        Warnings of the step, one line each (a posterior piled up at a prior bound, ...).
    """

    source: str
    step: int
    summary: str
    warnings: tuple = ()

    def to_json(self) -> dict:
        return {"source": self.source, "step": self.step, "summary": self.summary, "warnings": list(self.warnings)}


@dataclass(frozen=True)
class StoreOutcome:
    """What one store's task did.

    Attributes
    ----------
    name, store : str
        The store's name in the plan and its path.
    status : {"updated", "current", "failed"}
    steps : tuple of StepOutcome
        The datasets assimilated, in order (also on failure: those committed before it).
    skipped : tuple of str
        Data files the store already held (assimilated by an earlier update), by name.
    n_steps : int or None
        The store's steps after the task; None when it could not be opened.
    error : str or None
        One line (status "failed").
    warnings : tuple of str
        Warnings outside the steps (e.g. a store that could not be written into), one line each.
    seconds : float
        The task's wall time.
    worker : str
        Where it ran (host and process id).
    """

    name: str
    store: str
    status: str
    steps: tuple = ()
    skipped: tuple = ()
    n_steps: int | None = None
    error: str | None = None
    warnings: tuple = ()
    seconds: float = 0.0
    worker: str = ""

    def __post_init__(self):
        if self.status not in (UPDATED, CURRENT, FAILED):
            raise ValueError(f"status: expected {UPDATED!r}, {CURRENT!r} or {FAILED!r}, got {self.status!r}")
        if (self.status == FAILED) != (self.error is not None):
            raise ValueError("error: a failed outcome needs its error line" if self.status == FAILED
                             else f"error: an outcome of status {self.status!r} has no error line")
        if self.status == CURRENT and self.steps:
            raise ValueError("steps: a current store's task assimilated nothing")

    @property
    def ok(self) -> bool:
        return self.status != FAILED

    def line(self) -> str:
        """The one line a fleet update prints for the store."""
        if self.status == FAILED:
            kept = (f" ({len(self.steps)} dataset{'s' * (len(self.steps) != 1)} assimilated before it)"
                    if self.steps else "")
            return f"{self.name}: FAILED{kept}: {self.error}"
        if self.status == CURRENT:
            held = f", {len(self.skipped)} of its datasets already assimilated" if self.skipped else ""
            return f"{self.name}: up to date ({self.n_steps} steps{held})"
        first, last = self.steps[0].step, self.steps[-1].step
        span = f"step {first}" if first == last else f"steps {first}-{last}"
        return (f"{self.name}: {len(self.steps)} dataset{'s' * (len(self.steps) != 1)} assimilated ({span}) in "
                f"{self.seconds:.1f} s")

    def to_json(self) -> dict:
        return {"name": self.name, "store": self.store, "status": self.status,
                "steps": [s.to_json() for s in self.steps], "skipped": list(self.skipped),
                "n_steps": self.n_steps, "error": self.error, "warnings": list(self.warnings),
                "seconds": round(self.seconds, 6) if math.isfinite(self.seconds) else None, "worker": self.worker}


@dataclass(frozen=True)
class FleetOutcome:
    """A fleet update's outcomes, one per store in the plan's order.

    Attributes
    ----------
    source : str
        The fleet's folder or manifest.
    outcomes : tuple of StoreOutcome
    driver : str
        What ran the tasks ("serial", "dask LocalCluster of 2 workers", "dask scheduler tcp://...").
    started : str
        When the update started (UTC, ISO 8601).
    seconds : float
        Its wall time, from the first task sent to the last outcome.
    """

    source: str
    outcomes: tuple
    driver: str = ""
    started: str = ""
    seconds: float = 0.0

    @property
    def failed(self) -> tuple:
        return tuple(o for o in self.outcomes if not o.ok)

    @property
    def exit_code(self) -> int:
        """0 when every store's task succeeded, 1 when some failed (the others completed)."""
        return 1 if self.failed else 0

    def stores_per_minute(self) -> float:
        return 60.0 * len(self.outcomes) / self.seconds if self.seconds > 0 else float("nan")

    def summary(self) -> str:
        """One line: how many stores were updated, up to date and failed, and the time."""
        counts = {status: sum(o.status == status for o in self.outcomes) for status in (UPDATED, CURRENT, FAILED)}
        steps = sum(len(o.steps) for o in self.outcomes)
        text = (f"{len(self.outcomes)} stores of {self.source}: {counts[UPDATED]} updated ({steps} dataset"
                f"{'s' * (steps != 1)}), {counts[CURRENT]} up to date, {counts[FAILED]} failed; {self.seconds:.1f} s")
        if self.driver:
            text += f" ({self.driver})"
        return text

    def to_json(self) -> dict:
        return {OUTCOME_MARKER: 1, "source": self.source, "driver": self.driver, "started": self.started,
                "seconds": round(self.seconds, 6), "failed": [o.name for o in self.failed],
                "stores": [o.to_json() for o in self.outcomes]}


def collect(tasks, outcomes, **fields) -> FleetOutcome:
    """The :class:`FleetOutcome` of ``tasks`` (the plan's :class:`~seqbayes.fleet.plan.StoreTask` list) from
    their ``outcomes`` in any order: one per task, in the tasks' order; a task without an outcome (a driver
    stopped early) is reported failed, and an outcome of no task or a second one for a task is refused."""
    by_name = {}
    for outcome in outcomes:
        if outcome.name in by_name:
            raise ValueError(f"outcomes: two outcomes for the store {outcome.name!r}")
        by_name[outcome.name] = outcome
    names = [task.name for task in tasks]
    unknown = sorted(set(by_name) - set(names))
    if unknown:
        raise ValueError(f"outcomes: {unknown[0]!r} is not a store of the plan")
    ordered = tuple(by_name.get(task.name) or StoreOutcome(task.name, str(task.store), FAILED,
                                                           error="no outcome came back for it (the update was "
                                                                 "stopped); the store keeps every step committed")
                    for task in tasks)
    return FleetOutcome(outcomes=ordered, **fields)
