"""The engine's exceptions and warnings."""

__all__ = ["ZeroLikelihoodError", "TemperingLimitError", "PriorDataConflictWarning", "InnerFilterWarning"]


class ZeroLikelihoodError(RuntimeError):
    """Every sample has zero likelihood for a dataset."""


class PriorDataConflictWarning(RuntimeWarning):
    """A step's posterior lies far in the tail of its prior (``StepInfo.prior_data_conflict``)."""


class InnerFilterWarning(RuntimeWarning):
    """SMC^2's inner particle filters are degenerate (``StepInfo.inner_ess`` below 0.05)."""


class TemperingLimitError(RuntimeError):
    """Bridging to a dataset took more tempering stages than allowed (``max_stages``)."""
