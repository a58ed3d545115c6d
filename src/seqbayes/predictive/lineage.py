"""Ancestry of a step's posterior among the last posterior's particles: the exact transition's
responsibilities, the particles' labels (:attr:`~seqbayes.core.state.RemedyMemory.lineage`) and the
parts of the evidence's standard error that come from them."""

from __future__ import annotations

import numpy as np

from .mixture import AncestorSpread, grouped_ancestor_variance
from .mixture import GaussianMixture, MixtureSum, backward_masses

__all__ = ["ancestor_draws", "ancestor_mass", "mass_spread", "ancestor_terms", "lineage_after", "posterior_labels",
           "lagged_ancestor_variance", "mixture_chain", "remedy_window", "variance_before"]


def lineage_after(state, labels) -> np.ndarray:
    """``(N, 2)`` :attr:`RemedyMemory.lineage` after a step whose posterior particles descend from the
    initial draws ``labels (N,)``: those, and the labels of the last posterior (distinct without lineage)."""
    labels = np.asarray(labels, dtype=np.intp)
    previous = posterior_labels(state)
    return np.column_stack([labels, np.arange(labels.shape[0]) if previous is None else previous])


def posterior_labels(state, column=0):
    """Column ``column`` of ``state``'s lineage (0: the last posterior's labels, 1: the one's before), or
    ``None`` (every particle its own) without lineage of the posterior's size."""
    if state.memory.lineage is None or state.posterior is None or state.memory.lineage.shape[0] != state.posterior.shape[0]:
        return None
    return state.memory.lineage[:, column]


def mass_spread(state, mass) -> AncestorSpread:
    """The :class:`~seqbayes.predictive.mixture.AncestorSpread` of the last posterior's particles from the mass ``a (N,)``
    that this step's posterior gives them (the exact transition's responsibilities, :func:`ancestor_mass`)."""
    return AncestorSpread(float(1.0 / np.dot(mass, mass)),
                          grouped_ancestor_variance(mass, np.exp(state.posterior_log_weights), posterior_labels(state)),
                          mass=mass)


def ancestor_terms(state, spread):
    """``(variance, covariance)`` of the step's increment error from the ancestors of :func:`step_standard_errors`:
    the last posterior's (``spread``, an :class:`~seqbayes.predictive.mixture.AncestorSpread` or None) and, through the
    mixture the last step used, the posterior's before (:meth:`GaussianMixture.backward_spread`)."""
    if spread is None:
        return float("nan"), 0.0
    variance, covariance = spread.variance, 0.0
    if isinstance(state.previous_prior, GaussianMixture) and state.posterior is not None:
        backward, covariance = state.previous_prior.backward_spread(state.posterior, state.posterior_log_weights,
                                                                    spread, posterior_labels(state, 1))
        variance += backward
    return variance, covariance


def lagged_ancestor_variance(state, spread, floor: float) -> float:
    """How uncertain the step's increment is from every earlier posterior the mixtures rest on (relative
    variance): ``sum_t sum_j (a^t_j - b^t_j)^2`` over the window's steps ``t = s - 1, s - 2, ...``.

    ``a^t`` is the mass the step's posterior gives to the particles of step ``t`` (the exact responsibilities
    of each step's mixture prior, backwards from ``spread.mass`` on step ``s - 1``'s), ``b^t`` the same from
    step ``s - 1``'s posterior (``b^{s-1} = W``). The increment's estimate depends on step ``t``'s N particles
    through ``sum_j W_j h_j / sum_j W_j g_j`` (``h``, ``g``: the evidence of steps ``t+1..s`` and ``t+1..s-1``
    through particle ``j``), whose relative variance for independent particles is that term: the tilt the new
    data give step ``t`` times that step's sampling error. Lag 1 is ``spread.variance`` (grouped by the
    particles' labels), lag 2 :meth:`GaussianMixture.backward_spread`'s variance; a drift that carries a change
    over several steps tilts the earlier posteriors as well (docs/jump_kernels.md, moderate damage).

    Behind a path-space step (the chain of mixtures ends at its posterior) ``b^t`` is step ``t``'s own weights
    ``W^t``: the term is then the variance of the increments of steps ``t+1..s`` together, all of which rest on
    step ``t``'s particles. After a conflict the data keep pulling the posterior the same way, onto the same
    tail of those particles, so the errors of these steps share a sign (their covariances) and add up, and a
    path-space step now estimates them afresh (its bridge replaces the window's stored increments); counted one
    increment at a time, each stayed just under the threshold while their sum did not. The sum stops at the
    window's first step, once a lag adds less than ``floor``, or after lag 1 when ``spread`` has no mass (large N).

    Parameters
    ----------
    state : SamplerState
        The state before the step (its window ends with step ``s - 1``).
    spread : AncestorSpread
        The step's posterior over step ``s - 1``'s particles.
    floor : float

    Returns
    -------
    float
    """
    total = spread.variance
    if spread.mass is None or not state.memory.window:
        return float(total)
    mass = np.stack([spread.mass, np.exp(state.posterior_log_weights)])
    chain = mixture_chain(state.memory.window)
    since_path_step = state.memory.window[-1 - len(chain)].path_states > 0
    for lag, (prior, posterior) in enumerate(chain, 2):
        if posterior.shape[0] != mass.shape[1]:
            break
        mass = backward_masses(prior, posterior, mass)
        if since_path_step:
            mass[1] = np.exp(state.memory.window[-lag].log_weights)
        term = float(np.sum((mass[0] - mass[1]) ** 2))
        total += term
        if term < floor:
            break
    return float(total)


def mixture_chain(window) -> list:
    """``(prior, posterior)`` of the window's steps, latest first, while each step's posterior rests on its
    mixture prior over the step before with as many particles: the chain ends behind a path-space step, a
    prior that is not a mixture (the first step's) or a change of N."""
    out = []
    for later, earlier in zip(window[:0:-1], window[-2::-1]):
        if (later.path_states > 0 or not isinstance(later.prior, (GaussianMixture, MixtureSum))
                or earlier.posterior.shape[0] != later.posterior.shape[0]):
            break
        out.append((later.prior, later.posterior))
    return out


#: Most (query, ancestor) pairs of the transition density evaluated at once.
_PAIR_BLOCK = 250_000


def ancestor_draws(kernel, later, earlier, earlier_log_weights, rng=None, later_log_weights=None):
    """Ancestors of ``later`` among the weighted particles ``earlier`` under the exact transition.

    With ``p(theta) = sum_j W_j T(theta | earlier_j)`` (Eq. A3 with the kernel's own density), the
    ancestor of a point ``theta_i`` is ``j`` with probability ``r_ij = W_j T(theta_i | earlier_j) / p(theta_i)``.
    Evaluated in blocks of rows (memory ``O(block x M)``), sampled by the Gumbel-max trick.

    Parameters
    ----------
    kernel : MarkovKernel
        Its ``logpdf(new, old)`` is the transition density.
    later : (N, d) array
    earlier : (M, d) array
    earlier_log_weights : (M,) array
        Normalised log-weights ``log W_j``.
    rng : numpy.random.Generator, optional
        When given, one ancestor index per row of ``later`` is drawn.
    later_log_weights : (N,) array, optional
        When given, the ancestor ESS ``1 / sum_j a_j^2`` with ``a_j = sum_i v_i r_ij`` is returned:
        how many of the earlier particles carry the later (posterior) distribution.

    Returns
    -------
    index : (N,) int array or None
    ancestor_ess : float
        NaN without ``later_log_weights``.
    """
    index, mass = ancestor_mass(kernel, later, earlier, earlier_log_weights, rng, later_log_weights)
    return index, (float(1.0 / np.dot(mass, mass)) if mass is not None else float("nan"))


def ancestor_mass(kernel, later, earlier, earlier_log_weights, rng=None, later_log_weights=None):
    """:func:`ancestor_draws` with the mass ``a (M,)`` (None without ``later_log_weights``) in place of its ESS."""
    n, m = later.shape[0], earlier.shape[0]
    block = max(1, _PAIR_BLOCK // m)
    index = np.empty(n, dtype=np.intp) if rng is not None else None
    mass = np.zeros(m) if later_log_weights is not None else None
    for start in range(0, n, block):
        rows = later[start:start + block]
        b = rows.shape[0]
        log_r = kernel.logpdf(np.repeat(rows, m, axis=0), np.tile(earlier, (b, 1))).reshape(b, m)
        log_r += earlier_log_weights[None, :]
        peak = np.max(log_r, axis=1, keepdims=True)
        peak[~np.isfinite(peak)] = 0.0
        if rng is not None:
            index[start:start + b] = np.argmax(log_r + rng.gumbel(size=(b, m)), axis=1)
        if mass is not None:
            r = np.exp(log_r - peak)
            r /= np.maximum(r.sum(axis=1, keepdims=True), 1e-300)
            mass += np.exp(later_log_weights[start:start + b]) @ r
    return index, mass


def remedy_window(window: tuple, remedy_lag: int) -> tuple:
    """The past steps that the next path-space step's window takes: the last ``remedy_lag - 1``, or back to
    the first step of the last path-space step's window, while that is stored and the path at most
    ``2 remedy_lag`` states long.

    A path-space step replaces the cumulative evidence from its window's first step on by its own estimate,
    ``log Z_hat_{1:w-1} + log Z_hat_{w:s}``. A later window that starts inside it rests instead on the
    mixture prior over a filtered cloud that the new data tilt (and on the increments the earlier step
    superseded), whose error it brings back; consecutive remedies therefore share the earlier step's
    first prior (docs/jump_kernels.md, "The window's first prior").
    """
    keep = remedy_lag - 1
    for back, past in enumerate(reversed(window)):
        if past.path_states:
            anchored = back + past.path_states  # entries from that step's window start to the last one
            if keep < anchored <= len(window) and anchored <= 2 * remedy_lag - 1:
                keep = anchored
            break
    return window[-keep:]


def variance_before(state) -> float:
    """:attr:`PastStep.log_evidence_variance` of the step after ``state``: its cumulative variance, as the square of
    the se the last record reports, which is what a restored run rebuilds it from (:mod:`seqbayes.store.snapshot`), so that
    resumed runs stay bit-identical."""
    return float(np.sqrt(state.log_evidence_variance)) ** 2
