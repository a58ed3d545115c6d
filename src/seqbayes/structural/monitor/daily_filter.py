"""The exact per-mode Kalman filter of the monitor's linear-Gaussian part, batched over particles and modes.

Given a particle's static parameters, each mode ``i``'s log-frequency (centred at its reference) is::

    y_it = c_i + u_i,day + a_i (Ts_t - T_ref) + b_i knee_t + sum_r g_ir (z_tr - z_ref,r) + e_it

- ``c_i`` the mode's level: a random walk from day to day (variance ``q`` per day), constant within a day (the
  slowly varying discrepancy);
- ``u_i,day`` the day effect, ``N(0, s_d^2)`` afresh each day (weather the law misses, lasting a day);
- ``a_i, b_i, g_ir`` static coefficients with Gaussian priors;
- ``e_it ~ N(0, s_OMA,it^2 + s_i^2)``: the OMA's own error and the mode's set noise.

The state ``x = (c, u, a, b, g...)`` (``p = 4 + r``) is Gaussian given the data; the modes are independent given
the static parameters. A *chunk* is the sets of one day that arrive together (a whole day, or a record of it); it
is assimilated in information form, ``Lambda = sum_t w_t h_t h_t^T``, ``eta = sum_t w_t h_t y_t`` (``w = 1 /
variance``, 0 for a missing mode), so a day of any length costs a handful of ``p x p`` operations per particle and
mode (:func:`chunk_update`); a missing mode skips its update. At a new day the level's variance grows by ``q``
per day passed and the day effect restarts (:func:`new_day`).

For the change bank (:mod:`~seqbayes.structural.monitor.change`) each chunk also gives ``G^-1 = (I + P
Lambda)^-1``, ``beta = G^-T (eta - Lambda m)`` and ``Omega = G^-T Lambda``: the response of the filter to a unit
step in the level is carried by ``G^-1`` and its log-likelihood terms are ``beta`` and ``Omega``.

Hand-written because the filters needed are ``p <= 6`` dimensional and many (particles x modes), where a batched
information-form update in numpy is a few array operations; the general filters of
:mod:`seqbayes.structural.filters` run one model's state sequence per time step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["FilterState", "chunk_statistics", "chunk_update", "new_day", "initial_state", "LEVEL", "DAY"]

#: Indices of the level and of the day effect in the state.
LEVEL, DAY = 0, 1
_LOG_2PI = float(np.log(2 * np.pi))


@dataclass(frozen=True, eq=False)
class FilterState:
    """The per-mode filters of ``N`` particles.

    Attributes
    ----------
    mean : (N, n, p) array
    cov : (N, n, p, p) array
    """

    mean: np.ndarray
    cov: np.ndarray

    def take(self, index) -> "FilterState":
        return FilterState(self.mean[index], self.cov[index])


def initial_state(n_particles: int, n_modes: int, level_sd: float, day_var, static_sds) -> FilterState:
    """The filters before the first set: zero mean; variances ``level_sd^2``, the particles' day variance
    ``day_var (N,)`` and the static coefficients' ``static_sds^2``."""
    static_sds = np.asarray(static_sds, dtype=float)
    p = 2 + static_sds.size
    cov = np.zeros((n_particles, n_modes, p, p))
    cov[:, :, LEVEL, LEVEL] = level_sd ** 2
    cov[:, :, DAY, DAY] = np.asarray(day_var, dtype=float).reshape(-1, 1)
    idx = np.arange(2, p)
    cov[:, :, idx, idx] = static_sds ** 2
    return FilterState(np.zeros((n_particles, n_modes, p)), cov)


def new_day(state: FilterState, days_passed, level_var, day_var) -> FilterState:
    """The filters at the start of a new day: the level's variance grows by ``level_var (N,)`` per day passed
    (``days_passed >= 1``) and the day effect restarts at ``N(0, day_var (N,))``, uncorrelated."""
    mean = state.mean.copy()
    cov = state.cov.copy()
    mean[:, :, DAY] = 0.0
    cov[:, :, DAY, :] = 0.0
    cov[:, :, :, DAY] = 0.0
    cov[:, :, DAY, DAY] = np.asarray(day_var, dtype=float).reshape(-1, 1)
    cov[:, :, LEVEL, LEVEL] += float(days_passed) * np.asarray(level_var, dtype=float).reshape(-1, 1)
    return FilterState(mean, cov)


def chunk_statistics(h, y, oma_var, noise_var):
    """The information of one chunk's sets for every particle and mode.

    Parameters
    ----------
    h : (N, S, p) array
        The regressors of the sets (:func:`seqbayes.structural.monitor.law.design`, with the day effect's 1 as
        column 1).
    y : (S, n) array
        Centred log-frequencies; NaN where a mode is missing.
    oma_var : (S, n) array
        The OMA's variance of each log-frequency (0 where not given).
    noise_var : (N, n) array
        Each particle's set noise variance per mode.

    Returns
    -------
    info : (N, n, p, p) array
        ``Lambda = sum_t w_t h_t h_t^T``.
    score : (N, n, p) array
        ``eta = sum_t w_t h_t y_t``.
    square : (N, n) array
        ``sum_t w_t y_t^2``.
    log_det : (N, n) array
        ``sum_t log(variance_t)`` over the observed sets.
    n_obs : (n,) array
        Observed sets per mode.
    """
    h = np.asarray(h, dtype=float)
    n_particles, n_sets, p = h.shape
    observed = np.isfinite(y)
    y0 = np.where(observed, y, 0.0)
    outer = (h[:, :, :, None] * h[:, :, None, :]).reshape(n_particles, n_sets, p * p)
    if not np.any(oma_var):
        # w = observed / noise_var factorises: one matrix product over the sets for every particle and mode
        obs = observed.astype(float)
        scale = 1.0 / noise_var                                            # (N, n)
        info = (outer.transpose(0, 2, 1).reshape(-1, n_sets) @ obs).reshape(n_particles, p * p, -1)
        info = (info * scale[:, None, :]).transpose(0, 2, 1).reshape(n_particles, -1, p, p)
        score = (h.transpose(0, 2, 1).reshape(-1, n_sets) @ y0).reshape(n_particles, p, -1)
        score = (score * scale[:, None, :]).transpose(0, 2, 1)
        square = (y0 * y0).sum(axis=0)[None, :] * scale
        n_obs = obs.sum(axis=0)
        log_det = n_obs[None, :] * np.log(noise_var)
        return info, score, square, log_det, n_obs
    variance = oma_var[None, :, :] + noise_var[:, None, :]            # (N, S, n)
    w = np.where(observed[None], 1.0 / variance, 0.0)
    info = np.matmul(outer.transpose(0, 2, 1), w).transpose(0, 2, 1).reshape(n_particles, -1, p, p)
    wy = w * y0[None]
    score = np.matmul(h.transpose(0, 2, 1), wy).transpose(0, 2, 1)
    square = np.einsum("nsi,si->ni", wy, y0)
    log_det = np.einsum("nsi,si->ni", np.log(variance), observed.astype(float))
    return info, score, square, log_det, observed.sum(axis=0)


def chunk_update(state: FilterState, info, score, square, log_det, n_obs):
    """Assimilate one chunk (information form) into every particle's and mode's filter.

    Returns
    -------
    state : FilterState
        The filters after the chunk.
    loglike : (N, n) array
        ``log p(chunk | earlier sets)`` per particle and mode.
    g_inv : (N, n, p, p) array
        ``(I + P Lambda)^-1``: the map of the filter's response to a level step through the chunk.
    beta : (N, n, p) array
        ``G^-T (eta - Lambda m)``.
    omega : (N, n, p, p) array
        ``G^-T Lambda`` (symmetric).
    """
    m, P = state.mean, state.cov
    p = m.shape[-1]
    g = P @ info
    g[..., np.arange(p), np.arange(p)] += 1.0                              # G = I + P Lambda
    g_inv = np.linalg.inv(g)
    _, log_det_g = np.linalg.slogdet(g)
    lam_m = (info @ m[..., None])[..., 0]
    residual = score - lam_m                                               # r = eta - Lambda m
    step = (g_inv @ (P @ residual[..., None]))[..., 0]                     # G^-1 P r
    mean = m + step
    cov = g_inv @ P
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    quadratic = square + ((lam_m - 2 * score) * m).sum(axis=-1) - (residual * step).sum(axis=-1)
    loglike = -0.5 * (n_obs[None, :] * _LOG_2PI + log_det + log_det_g + quadratic)
    g_inv_t = np.swapaxes(g_inv, -1, -2)
    beta = (g_inv_t @ residual[..., None])[..., 0]
    omega = info @ g_inv                                                   # = G^-T Lambda, symmetric
    omega = 0.5 * (omega + np.swapaxes(omega, -1, -2))
    return FilterState(mean, cov), loglike, g_inv, beta, omega
