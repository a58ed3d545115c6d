"""A fleet of run stores updated together: one task per store, on a Dask cluster or one after another.

An operator monitors many structures, each with its own run store updated as data arrive. A fleet is
a folder of stores beside folders of their new datasets, or a manifest listing stores and their
datasets (:mod:`seqbayes.fleet.plan`). ``seqbayes update FLEET`` runs one task per store (a store's
datasets are sequential, the stores independent) through the same path as ``seqbayes update`` of that
store (:mod:`seqbayes.fleet.task`), so each store ends bit-identical to the same store updated alone;
one store's bad file, raising likelihood, damage or lock is that store's one-line outcome
(:mod:`seqbayes.fleet.records`) and does not stop the others. The drivers (:mod:`seqbayes.fleet.drivers`)
are the same tasks serially here or as ``distributed`` tasks on a local cluster or a scheduler.
``seqbayes status FLEET`` lists each store's last step, alarm and errors (:mod:`seqbayes.fleet.status`).

The layer sits between the command line and the stores: it imports :mod:`seqbayes.store` (and
:mod:`seqbayes.parallel` for the cluster), and only the CLI imports it (docs/fleet.md).
"""

from .command import status_command, update_command
from .drivers import dask_client, run_dask, run_serial
from .plan import FleetError, FleetPlan, StoreTask, is_fleet, plan_fleet
from .records import FleetOutcome, StepOutcome, StoreOutcome, collect
from .status import StoreStatus, fleet_status
from .task import TaskOptions, describe_failure, pending_datasets, run_task

__all__ = ["plan_fleet", "is_fleet", "FleetPlan", "StoreTask", "FleetError", "TaskOptions", "run_task",
           "pending_datasets", "describe_failure", "StepOutcome", "StoreOutcome", "FleetOutcome", "collect",
           "run_serial", "run_dask", "dask_client", "StoreStatus", "fleet_status", "update_command",
           "status_command"]
