"""Which predictive prior a run uses (:class:`Auto`, :func:`resolve_predictive`); each component's ``predictive(state,
problem, config)`` gives the one a step goes through."""

from __future__ import annotations

from dataclasses import dataclass

from .history import History
from .smc2 import SMC2, nested_split
from .transition import Transition

__all__ = ["Auto", "resolve_predictive"]


@dataclass(frozen=True)
class Auto:
    """The predictive the kernel calls for (the default, ``predictive=None``): ``history`` for a static kernel,
    ``smc2`` for one with both static and drifting components (and no jumps), else ``transition``; each with its
    own settings."""

    transition: Transition = Transition()
    history: History = History()
    smc2: SMC2 = SMC2()

    def resolve(self, kernel):
        if kernel.is_static:
            return self.history
        if not kernel.has_jumps and nested_split(kernel) is not None:
            return self.smc2
        return self.transition


def resolve_predictive(predictive, kernel):
    """The predictive component a run with ``kernel`` uses: ``predictive`` checked against it, or with ``None`` the
    choice of :class:`Auto`.

    Raises
    ------
    ValueError
        The predictive does not apply to the kernel (SMC^2 without static and drifting components, the history
        prior with process noise).
    """
    if predictive is None:
        predictive = Auto()
    if not hasattr(predictive, "resolve"):
        raise TypeError(f"predictive: expected a predictive component (Transition(), History(), SMC2(), ...), got "
                        f"{predictive!r}")
    return predictive.resolve(kernel)
