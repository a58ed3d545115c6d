"""The errors and warnings a user of the run stores catches."""

__all__ = ["StoreError", "DuplicateDatasetError", "ModelChangedError", "BoundWarning", "StoreLockTimeout",
           "StoreWarning"]


class StoreError(ValueError):
    """A run store is missing, damaged, of another format version or for another model, or cannot do what
    was asked of it (e.g. a forecast of a run whose kind has none)."""


class DuplicateDatasetError(StoreError):
    """The dataset has already been assimilated in this run."""


class ModelChangedError(StoreError):
    """The likelihood module's file no longer has the content the run recorded (or is missing)."""


class BoundWarning(UserWarning):
    """Most of a step's posterior lies at a bound of the prior (wrong units? too narrow a prior?)."""


class StoreLockTimeout(StoreError):
    """Another process held the run store's lock longer than the lock timeout (the message says who)."""


class StoreWarning(UserWarning):
    """Something about a run store the user should know that does not stop the command (e.g. a step that
    could not be written into a read-only store)."""
