"""The accept/reject step shared by every move (the sweeps count into :class:`~seqbayes.core.state.SweepStats`)."""

from __future__ import annotations

import numpy as np

from ..priors import inside_support

__all__ = ["metropolis_accept", "evaluate_inside", "combine"]


def metropolis_accept(current_log_prob, proposal_log_prob, log_hastings, rng: np.random.Generator) -> np.ndarray:
    """Vectorised Metropolis-Hastings decision, ``(n,)`` bool.

    Accept when ``log U < proposal - current + log_hastings``. A proposal with
    ``-inf`` or NaN log-probability is always rejected; a current point at
    ``-inf`` is left for any finite proposal.
    """
    current = np.asarray(current_log_prob, dtype=float)
    proposal = np.asarray(proposal_log_prob, dtype=float)
    log_u = np.log(rng.random(proposal.shape))
    if np.isfinite(current).all():  # the usual case: no -inf - -inf to guard against
        return log_u < proposal - current + log_hastings  # NaN compares False
    finite = np.isfinite(proposal)
    with np.errstate(invalid="ignore"):
        log_ratio = np.where(finite, proposal - current + log_hastings, -np.inf)
    log_ratio[finite & np.isneginf(current)] = np.inf
    return log_u < log_ratio


def evaluate_inside(component_fn, points, support, n_components: int) -> tuple[np.ndarray, int]:
    """``component_fn`` at the points inside the ``(d, 2)`` support box; ``-inf`` outside.

    ``support=None`` means unbounded. Returns the ``(n, k)`` log-target components
    and the number of points evaluated. Points outside are rejected, never redrawn.
    """
    if support is None:
        return np.asarray(component_fn(points), dtype=float).reshape(points.shape[0], n_components), points.shape[0]
    out = np.full((points.shape[0], n_components), -np.inf)
    inside = inside_support(points, support)
    n_inside = int(np.count_nonzero(inside))
    if n_inside == points.shape[0]:
        out[:] = component_fn(points)
    elif n_inside:
        out[inside] = component_fn(points[inside])
    return out, n_inside


def combine(components, coefficients) -> np.ndarray:
    """Log target ``sum_k c_k l_k`` of ``(n, k)`` components; any ``-inf`` component gives ``-inf``.

    Components are never ``+inf`` (the samplers reject it), so a NaN can only come
    from ``0 x -inf`` and is mapped to ``-inf``.
    """
    if components.shape[1] == 1 and coefficients[0] == 1.0:  # a plain log-density (AIES)
        return components[:, 0].copy()
    with np.errstate(invalid="ignore"):  # 0 x -inf (a zero tempering exponent at a rejected row)
        total = components @ np.asarray(coefficients, dtype=float)
    total[np.isnan(total)] = -np.inf
    return total
