"""The transition-mixture prior for the moves, evaluated exactly or by a pseudo-marginal estimate from a
subsample of its components (:class:`SubsampledPrior`)."""

from __future__ import annotations

import numpy as np

from .mixture import GaussianMixture, systematic_selection

__all__ = ["SubsampledPrior", "SUBSAMPLE_VARIANCE", "SUBSAMPLE_MAX_VARIANCE"]


#: Relative variance of the subsample estimate that :class:`SubsampledPrior` aims at, at the pilot's 90th
#: percentile (the sd of its log ~0.6 there, less in the bulk; Doucet et al. 2015 find ~1-1.7 optimal when the
#: cost grows with M: here part of it does not, the proposal over the clusters).
SUBSAMPLE_VARIANCE = 0.5


#: ... and beyond which (at the particles of a later tempering stage) the step falls back to exact evaluation.
SUBSAMPLE_MAX_VARIANCE = 2.0


#: Fewest terms of a subsample estimate.
_MIN_TERMS = 8


#: Most terms, as a fraction of the centres: beyond, the exact evaluation is the cheaper (a term of the
#: subsample costs ~20 pairs of the dense sum at N = 16,000, measured: a gather and a double-precision
#: exponential against part of a single-precision matrix product).
_MAX_TERM_FRACTION = 1.0 / 32.0


#: Points at which the estimate's variance is computed exactly before it is used.
_PILOT = 128


class SubsampledPrior:
    """A step's transition-mixture prior (Eq. A3) for the moves: exact, or pseudo-marginal with a subsample.

    Called on ``theta (m, d)`` it returns ``log p(theta)`` (exact, :meth:`GaussianMixture.logpdf`,
    ``O(m N)``) or, once :meth:`start` has chosen ``M = n_terms``, the log of the unbiased estimate
    ``p_hat = (1/M) sum_m W_a T(theta | c_a) / q_a`` with ``a_1..a_M`` drawn afresh from an ancestor
    proposal ``q(theta)`` (:meth:`GaussianMixture.subsample_logpdf`, ``O(m (K + M))``, ``K ~ sqrt(N) / 2``). The moves cache the prior value of every
    particle (column 1 of their components) and evaluate it afresh at every proposal only, so a
    random estimate makes them pseudo-marginal Metropolis-Hastings moves on an extended target whose
    ``theta``-marginal is exactly ``L^beta p`` (Andrieu & Roberts 2009). That needs the cached values
    to be draws of the extended target, which :meth:`start` provides: the step's particles are the
    predictive draws ``theta_i ~ T(. | c_i)`` with weights ``W_i`` (:meth:`GaussianMixture.draw_one_per_component`),
    so ``(theta_i, i)`` is a draw of ``W_j T(theta | c_j)`` and ``i`` one of the exact responsibilities
    given ``theta_i``: ``a_1 = i`` and ``a_2..a_M ~ q(theta_i)`` is a draw of the extended target
    ``p_hat(theta; a) prod_m q_{a_m}(theta)`` (the estimate is symmetric in the ``a_m``). The step's
    particles must therefore be the mixture's per-component draws in their order (as
    :func:`predictive_density` returns them and the run store keeps them); the moves must never
    re-evaluate a current particle's prior value (only proposals). Tempering reweights
    by ``L^delta`` alone and resampling carries the cached values, so both keep the extended target;
    the importance-sampling evidence (:func:`~seqbayes.predictive.evidence.importance_step`) is linear in the
    prior, stays unbiased with the estimate, and its ESS (hence the stated standard error) includes
    the estimate's noise.

    The choice between exact evaluation and ``M`` is automatic (:meth:`start`): the estimate's relative
    variance at ``theta`` is known exactly, ``(E_q[w^2] / p^2 - 1) / M``
    (:meth:`GaussianMixture.log_second_moment`, ``O(N)`` per point), so it is computed at a pilot of
    ``_PILOT`` particles selected by the prior weights and as many by the weights times the likelihood
    (where the posterior lies), and ``M`` is set for ``SUBSAMPLE_VARIANCE`` at the pilot's 90th
    percentile; where that needs more than ``N / 32`` terms (prior-data conflict: the posterior in
    the mixture's tail, where few components carry it) the step evaluates exactly. Before each
    move, :meth:`refreshed` checks the current particles again and falls back to exact evaluation
    for the rest of the step (recomputing the cached values: the particles' ``theta`` are draws of
    the exact target, whatever ``M`` was) if the variance exceeds ``SUBSAMPLE_MAX_VARIANCE``.

    Parameters
    ----------
    mixture : GaussianMixture
        The step's prior, whose centre ``i`` is the ancestor of the step's particle ``i``.
    rng : numpy.random.Generator
        The step's generator (the draws of ``a`` interleave with the step's other draws).
    """

    def __init__(self, mixture: GaussianMixture, rng: np.random.Generator):
        self.mixture, self.rng = mixture, rng
        self.n_terms = None      # None: exact evaluation
        self.fell_back = False   # a later stage's check switched the step to exact evaluation

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        """``log p`` or its estimate at ``theta (m, d)``, returns ``(m,)``."""
        if self.n_terms is None:
            return self.mixture.logpdf(theta)
        return self.mixture.subsample_logpdf(theta, self.n_terms, self.rng)

    def _relative_variance(self, points) -> float:
        """The 90th percentile over ``points (k, d)`` of the one-term estimate's relative variance."""
        return float(np.quantile(np.expm1(self.mixture.log_second_moment(points)), 0.9))

    def start(self, particles: np.ndarray, log_weights: np.ndarray, loglike: np.ndarray,
              own_draws: bool = True) -> np.ndarray:
        """Choose exact evaluation or ``M`` and return the prior values of the step's particles.

        Parameters
        ----------
        particles : (N, d) array
            The step's particles; with ``own_draws`` particle ``i`` is a draw of component ``i``.
        log_weights, loglike : (N,) arrays
            Their log-weights and log-likelihoods (``-inf`` allowed: such rows get ``-inf``).
        own_draws : bool
            False when the particles are not the mixture's per-component draws (a restart from
            the restricted prior): the step then evaluates exactly.

        Returns
        -------
        (N,) array
        """
        n = particles.shape[0]
        carried = np.isfinite(loglike)
        values = np.full(n, -np.inf)
        self.n_terms = None
        if own_draws and n == self.mixture.centres.shape[0] and carried.any():
            posterior = np.where(carried, log_weights + np.where(carried, loglike, 0.0), -np.inf)
            pilot = np.concatenate([systematic_selection(log_weights, _PILOT), systematic_selection(posterior, _PILOT)])
            n_terms = max(_MIN_TERMS, int(np.ceil(self._relative_variance(particles[pilot]) / SUBSAMPLE_VARIANCE)))
            if n_terms <= _MAX_TERM_FRACTION * n:
                self.n_terms = n_terms
        if self.n_terms is None:
            values[carried] = self.mixture.logpdf(particles[carried])
        else:
            values[carried] = self.mixture.subsample_logpdf(particles[carried], self.n_terms, self.rng,
                                                            first=np.flatnonzero(carried))
        return values

    def refreshed(self, particles: np.ndarray, components: np.ndarray) -> np.ndarray:
        """Before a move: the components ``(N, k)``, with column 1 recomputed exactly (and exact evaluation
        from then on) if the estimate's relative variance at the equally weighted ``particles (N, d)``
        exceeds ``SUBSAMPLE_MAX_VARIANCE``; else unchanged."""
        if self.n_terms is None:
            return components
        n = particles.shape[0]
        pilot = np.linspace(0, n - 1, min(n, _PILOT)).astype(int)   # evenly spaced: no random draw
        if self._relative_variance(particles[pilot]) / self.n_terms <= SUBSAMPLE_MAX_VARIANCE:
            return components
        self.n_terms, self.fell_back = None, True
        components = components.copy()
        alive = np.isfinite(components[:, 0])
        components[alive, 1] = self.mixture.logpdf(particles[alive])
        return components
