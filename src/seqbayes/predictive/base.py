"""Which predictive prior a run uses, and the one a step goes through (:func:`predictive_for`)."""

from __future__ import annotations

from ..core.state import SamplerState
from ..kernels import MarkovKernel
from .history import ExactHistory
from .smc2 import JointFirstStep, NestedPredictive, NestedState, nested_split
from .transition import TransitionMixture

__all__ = ["resolve_predictive", "predictive_for"]


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


def predictive_for(state, problem, config):
    """``(predictive, state)``: the predictive of the step after ``state`` (a
    :class:`~seqbayes.predictive.particle.Predictive`) and the state it starts from.

    SMC^2's first dataset with ``joint_first_step`` starts from a :class:`~seqbayes.core.state.SamplerState`
    over every parameter (:class:`~seqbayes.predictive.smc2.JointFirstStep`)."""
    if isinstance(state, NestedState):
        if state.step > 0 or not problem.inner_filter.joint_first_step:
            return NestedPredictive(problem, config), state
        joint = SamplerState(0, state.particles, state.log_weights, problem.prior, 0.0, state.step_size)
        return JointFirstStep(problem, config, "joint"), joint
    method = resolve_predictive(config.predictive, problem.kernel)
    if method == "history":
        return ExactHistory(problem, config, method), state
    return TransitionMixture(problem, config, method), state
