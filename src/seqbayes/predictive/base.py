"""Which predictive prior a run uses."""

from __future__ import annotations

from ..kernels import MarkovKernel
from .history import HistoryPrior
from .mixture import predictive_density
from .smc2 import nested_split

__all__ = ["resolve_predictive", "propagate"]


def resolve_predictive(method: str, kernel: MarkovKernel) -> str:
    """The predictive construction to use: ``"auto"`` is ``"history"`` for a static kernel, ``"smc2"`` for
    one with both static and drifting components, else ``"transition"`` (always for a kernel with jumps)."""
    if kernel.has_jumps and method in ("auto", "smc2"):  # SMC^2's inner filters assume a Gaussian transition
        if method == "smc2":
            raise ValueError("predictive: 'smc2' does not support Jump components; use 'transition'")
        return "transition"
    if method == "auto":
        return "history" if kernel.is_static else "smc2" if nested_split(kernel) is not None else "transition"
    if method == "smc2" and nested_split(kernel) is None:
        raise ValueError("predictive: 'smc2' needs a kernel of components with both Static and drifting ones")
    if method == "history" and not kernel.is_static:
        raise ValueError("predictive: 'history' (the exact prior p_0 x past likelihoods) needs a kernel whose "
                         "every parameter is Static; with process noise use 'transition' or 'kde'")
    return method


def propagate(state, cloud, dataset, log_increment, log_evidence, method, problem, config, rng):
    """Stage 6: the next step's prior (Eq. A2-A3). Returns the density, its particles and their prior
    values (known for the history prior: the particles are the posterior itself)."""
    if method == "joint":
        return None, problem.kernel.propagate(cloud.particles, rng), None
    if method == "history":  # the next prior is this posterior, exactly: keep the particles and their weights
        density = state.prior.extended(dataset, log_evidence) if isinstance(state.prior, HistoryPrior) else \
            HistoryPrior.start(problem.prior, problem.history, dataset, log_evidence)
        next_log_prior = cloud.components[:, 0] + cloud.components[:, 1] - float(log_increment)  # no +inf: no NaN
        return density, cloud.particles, next_log_prior
    density, predictive = predictive_density(cloud.particles, cloud.log_weights, problem.kernel, rng, method,
                                             config.shrink_static)
    return density, predictive, None
