"""The jump posterior of a step under the transition mixture of a kernel with :class:`~seqbayes.kernels.Jump`
components: the :class:`~seqbayes.results.StepInfo` fields of :func:`~seqbayes.kernels.jump_posterior` and the
Monte Carlo standard error of the (Rao-Blackwellised) jump probability, :func:`jump_probability_se`."""

from __future__ import annotations

import numpy as np

from ..kernels import jump_posterior
from ..priors import as_samples
from ..weights import normalise
from .mixture import grouped_sums, label_groups
from .lineage import mixture_chain, posterior_labels
from .mixture import GaussianMixture, MixtureSum, backward_masses

__all__ = ["jump_probability_se", "jump_step_fields", "jump_fields"]

#: Largest (points x branches x components) block of responsibilities held at once, in floats.
_BLOCK_FLOATS = 8_000_000


def _branch_responsibilities(prior, theta: np.ndarray):
    """Blocks ``(rows, r)`` of the exact responsibilities ``r (b, C, N)`` of every (branch, component) of a
    :class:`MixtureSum` (``C = 1`` for a :class:`GaussianMixture`) for the points ``theta (m, d)``; never m x N x d."""
    mixtures, log_v = (prior.mixtures, prior.log_weights) if isinstance(prior, MixtureSum) else ((prior,), [0.0])
    n = mixtures[0].centres.shape[0]
    block = max(1, _BLOCK_FLOATS // max(1, 2 * n * len(mixtures)))
    for start in range(0, theta.shape[0], block):
        x = theta[start:start + block]
        logits = np.stack([lv + m.log_weights[None, :] - np.sum(np.log(m.bandwidth))
                           - 0.5 * np.sum(((x[:, None, :] - m.centres[None]) / m.bandwidth) ** 2, axis=2)
                           for lv, m in zip(log_v, mixtures)], axis=1)
        logits -= logits.max(axis=(1, 2), keepdims=True)
        r = np.exp(logits)
        r /= r.sum(axis=(1, 2), keepdims=True)
        yield slice(start, start + x.shape[0]), r


def jump_probability_se(kernel: MarkovKernel, prior: MixtureSum, posterior: np.ndarray, log_weights: np.ndarray,
                        labels: np.ndarray | None = None, ancestor_labels: np.ndarray | None = None,
                        ancestors: np.ndarray | None = None, earlier_prior=None,
                        earlier_labels: np.ndarray | None = None, deeper=(), mixture_target: bool = True) -> float:
    """Monte Carlo standard error of the Rao-Blackwellised jump probability ``P = sum_k v_k s_k``.

    ``s_k = sum_{c jumped} sum_i r_kci`` is the exact probability that particle ``k`` came through a jump
    branch, ``r_kci = V_c W_i N_c(theta_k; centre_ci, h_c^2) / pi(theta_k)`` its responsibility for ancestor
    ``i`` and branch ``c`` (:func:`~seqbayes.kernels.jump_posterior`). Up to three terms, each a sum of squared
    influences over groups of dependent particles (copies of one draw, as for the evidence's se):

    - the posterior sample's, ``sum_e (sum_{k in e} v_k (s_k - P))^2`` over ``labels``;
    - the ancestors', ``sum_g (sum_{i in g} f_i)^2`` over ``ancestor_labels``, ``f_i = b_i - P a_i``, with
      ``a_i = sum_k v_k sum_c r_kci`` the posterior's mass on ancestor ``i`` and ``b_i`` its part through a
      jump branch: ``P`` is the ratio ``sum_i b_i / sum_i a_i`` of two sums over the N ancestors, whose
      first-order (delta-method) variance this is. Without ``mixture_target`` (a path-space step: the posterior
      was drawn from the exact target, which does not rest on the ancestors) only each ``s_k`` moves with them,
      ``f_i = b_i - sum_k v_k s_k sum_c r_kci``, the influence of ancestor ``i`` on ``s_k``'s ratio, averaged;
    - with ``ancestors`` and ``earlier_prior`` (the previous step's posterior particles, i.e. the components
      of ``prior``, and the mixture prior they were drawn under): the ancestors' own prior's, ``u = f R`` with
      ``R`` that mixture's responsibilities for the ancestors, summed over ``earlier_labels`` (the two-step
      term of the evidence's se, :meth:`GaussianMixture.backward_spread`: the ancestors are not independent
      draws of the exact previous posterior but of a mixture of N earlier particles);
    - with ``deeper``, the same for every earlier step the mixtures rest on: ``u`` carried back one step per
      ``(prior, points)`` pair (:func:`~seqbayes.predictive.mixture.backward_masses`, each particle its own
      group), until a step adds less than 1 % of the variance. A drift that carries the jump's evidence over
      several steps tilts those posteriors too (as the remedy's trigger,
      :func:`~seqbayes.predictive.lineage.lagged_ancestor_variance`).

    Parameters
    ----------
    kernel : MarkovKernel
        With Jump components.
    prior : MixtureSum
        The step's predictive prior.
    posterior : (m, d) array
    log_weights : (m,) array
    labels : (m,) int array, optional
        Groups of dependent posterior particles (distinct if omitted).
    ancestor_labels : (N,) int array, optional
        Groups of dependent ancestors (the previous posterior's labels; distinct if omitted).
    ancestors : (N, d) array, optional
    earlier_prior : GaussianMixture or MixtureSum, optional
    earlier_labels : (M,) int array, optional
    deeper : sequence of (prior, points)
        Going back from ``earlier_prior``'s components: ``points (M, d)`` are those components (a posterior's
        particles) and ``prior`` the mixture they were drawn under (only with ``earlier_prior``).
    mixture_target : bool
        Whether the posterior sample's target is ``prior``'s posterior (a mixture step), whose weights move with the
        ancestors, or one that does not rest on them (the path-space step's exact target).

    Returns
    -------
    float
    """
    posterior = as_samples(posterior, prior.dim, "posterior")
    v = np.exp(normalise(np.asarray(log_weights, dtype=float)))
    jumped = kernel.branches.jumped.any(axis=1)
    n = prior.mixtures[0].centres.shape[0]
    s = np.empty(posterior.shape[0])
    a, b = np.zeros(n), np.zeros(n)
    for rows, r in _branch_responsibilities(prior, posterior):
        s[rows] = r[:, jumped].sum(axis=(1, 2))
        # the mixture's posterior moves its mass a_i with the ancestors; the exact target leaves each s_k to them
        a += (v[rows] if mixture_target else v[rows] * s[rows]) @ r.sum(axis=1)
        b += v[rows] @ r[:, jumped].sum(axis=1)
    p = float(v @ s)
    post = grouped_sums(v * (s - p), label_groups(labels, v.size))
    influence = b - (p * a if mixture_target else a)
    anc = grouped_sums(influence, label_groups(ancestor_labels, n))
    variance = post @ post + anc @ anc
    if ancestors is not None and earlier_prior is not None:
        ancestors = as_samples(ancestors, prior.dim, "ancestors")
        m = (earlier_prior.mixtures[0] if isinstance(earlier_prior, MixtureSum) else earlier_prior).centres.shape[0]
        u = np.zeros(m)
        for rows, r in _branch_responsibilities(earlier_prior, ancestors):
            u += influence[rows] @ r.sum(axis=1)
        grouped = grouped_sums(u, label_groups(earlier_labels, m))
        variance += grouped @ grouped
        for earlier_prior, points in deeper:
            u = backward_masses(earlier_prior, points, u)[0]
            term = float(u @ u)
            variance += term
            if term < 0.01 * variance:
                break
    return float(np.sqrt(variance))


def jump_step_fields(kernel: MarkovKernel, prior, posterior, log_weights, labels: np.ndarray | None = None,
                     ancestor_labels: np.ndarray | None = None, mixture_target: bool = True, **earlier: Any) -> dict:
    """The :class:`~seqbayes.results.StepInfo` fields of :func:`~seqbayes.kernels.jump_posterior` (``jump_probability``,
    ``jump_parameter``, ``jump_size``, ``jump_size_sd``) and the jump probability's standard error
    (:func:`jump_probability_se`, ``jump_probability_se``; ``mixture_target`` and ``earlier``: its ``ancestors``,
    ``earlier_prior``, ``earlier_labels`` and ``deeper``) when ``prior`` is the step's :class:`MixtureSum` of a
    jump kernel; ``{}`` otherwise (step 1, no jumps)."""
    if not (kernel.has_jumps and isinstance(prior, MixtureSum)):
        return {}
    fields = jump_posterior(kernel, prior, posterior, log_weights).step_fields()
    fields["jump_probability_se"] = jump_probability_se(kernel, prior, posterior, log_weights, labels, ancestor_labels,
                                                        mixture_target=mixture_target, **earlier)
    return fields


def jump_fields(kernel: MarkovKernel, state, cloud, mixture_target: bool = True) -> dict:
    """:func:`jump_step_fields` of a step from ``state`` (its predictive prior ``state.prior``) whose posterior is
    ``cloud`` (a :class:`~seqbayes.core.state.Cloud` in the model's parameters), with every term of the se the state
    knows: the ancestors' labels and, where the ancestors are the last stored step's posterior drawn under its
    mixture prior (not a path-space step's), that prior and the window's chain of mixtures before it.
    ``mixture_target=False`` for a path-space step (:func:`jump_probability_se`)."""
    earlier = {}
    last = state.memory.window[-1] if state.memory.window else None
    # a path-space posterior rests on its window's start, not on its mixture prior (negligible: docs/jump_kernels.md)
    if (last is not None and not last.path_space and isinstance(last.prior, (GaussianMixture, MixtureSum))
            and state.posterior is not None and np.array_equal(last.posterior, state.posterior)):
        earlier = dict(ancestors=state.posterior, earlier_prior=last.prior, earlier_labels=posterior_labels(state, 1),
                       deeper=mixture_chain(state.memory.window[:-1]))
    return jump_step_fields(kernel, state.prior, cloud.particles, cloud.log_weights, cloud.labels,
                            posterior_labels(state), mixture_target=mixture_target, **earlier)


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any

    from ..kernels import MarkovKernel
