"""The stiffness-drop path model of :mod:`~seqbayes.structural.stiffness_drop`: the stiffness acting
after a drop, the exact likelihood of a path, a simulated record with a drop, and the exact evidence
of a one-storey building (the monitor's reference).

A *path* of member ``i`` is ``(theta_i, delta_i, tau_i)``: ratios ``theta_i`` up to step ``tau_i - 1``
and ``theta_i (1 - delta_i e_storey)`` from the transition into step ``tau_i`` on, the structure's
state continuous through the change.
"""

from __future__ import annotations

import numpy as np

from ..rng import as_generator
from ..weights import logsumexp
from .filters.kalman import kalman_filter, kalman_log_likelihood, measurement_covariance
from .structures.shear_building import ShearBuilding, discretise, simulate

__all__ = ["effective_theta", "path_log_likelihood", "simulate_drop", "grid_log_evidence"]


def effective_theta(theta, delta, tau, storey: int) -> np.ndarray:
    """The stiffness ratios acting after the change: ``theta (N, d)`` with
    ``theta_j (1 - delta)`` for the particles that have dropped (``tau >= 0``)."""
    theta = np.array(theta, float)
    if storey > 0:
        dropped = np.asarray(tau) >= 0
        theta[dropped, storey - 1] *= 1.0 - np.asarray(delta)[dropped]
    return theta


def path_log_likelihood(building: ShearBuilding, dt: float, theta, delta, tau, storey: int, ground_acceleration,
                        measurements, measurement_noise, process_noise_std: float = 0.0,
                        channels: str = "absolute_acceleration", return_state: bool = False):
    """Exact ``log p(y_{0:T-1} | theta, delta, tau)`` of a stiffness path per member.

    Member ``i`` has ratios ``theta_i`` up to step ``tau_i - 1`` and
    ``theta_i (1 - delta_i e_storey)`` from the transition into step ``tau_i`` on
    (``tau_i < 0`` or ``>= T``: no change). Members are grouped by change step;
    each group is one batched Kalman pass before the change
    (:func:`~seqbayes.structural.filters.kalman.kalman_log_likelihood`, from rest) and one
    after it, started from the filtered state predicted through the new matrices.

    Parameters
    ----------
    building : ShearBuilding
    dt : float
    theta : (M, d) array
    delta : (M,) array
    tau : (M,) int array
    storey : int
        1-based storey of the drop (0: no change for anyone).
    ground_acceleration : (T,) array
    measurements : (T, p) array
    measurement_noise, process_noise_std, channels
        As :class:`~seqbayes.structural.sgenmcmc.SGEnMCMC`.
    return_state : bool
        Also return the filtered mean ``(M, m)`` and covariance ``(M, m, m)`` at ``T - 1``.

    Returns
    -------
    log_likelihood : (M,) array
    """
    theta = np.atleast_2d(np.asarray(theta, float))
    M = theta.shape[0]
    delta = np.broadcast_to(np.asarray(delta, float), (M,))
    tau = np.broadcast_to(np.asarray(tau, int), (M,))
    u = np.asarray(ground_acceleration, float)
    y = np.asarray(measurements, float)
    T = u.size
    if not 0 <= storey <= building.n_storeys:
        raise ValueError(f"storey: expected 0..{building.n_storeys}, got {storey}")
    tau = np.where((tau < 0) | (tau >= T) | (storey == 0), -1, tau)
    if np.any(tau == 0):
        raise ValueError("tau: a change at step 0 is the same as a different initial theta; use tau >= 1")
    after = discretise(building, effective_theta(theta, delta, tau, storey), dt, channels=channels)
    m = after.A.shape[1]
    loglik, mean, cov = np.empty(M), np.empty((M, m)), np.empty((M, m, m))
    for t in np.unique(tau):  # loop over distinct change steps (groups), not members
        idx = np.flatnonzero(tau == t)
        model = after.take(idx)
        if t < 0:
            out = kalman_log_likelihood(model, u, y, measurement_noise, process_noise_std, return_state=True)
        else:
            before = discretise(building, theta[idx], dt, channels=channels)
            ll, m0, P0 = kalman_log_likelihood(before, u[:t], y[:t], measurement_noise, process_noise_std,
                                               return_state=True)
            b = model.B0 + model.B1
            x0 = np.einsum("nij,nj->ni", model.A, m0) + model.B0 * u[t - 1] + model.B1 * u[t]
            P_pred = model.A @ P0 @ np.swapaxes(model.A, 1, 2) + process_noise_std**2 * b[:, :, None] * b[:, None, :]
            out = kalman_log_likelihood(model, u[t:], y[t:], measurement_noise, process_noise_std, x0=x0,
                                        P0=0.5 * (P_pred + np.swapaxes(P_pred, 1, 2)), return_state=True)
            out = (out[0] + ll,) + tuple(out[1:])
        loglik[idx], mean[idx], cov[idx] = out
    return (loglik, mean, cov) if return_state else loglik


def simulate_drop(building: ShearBuilding, dt: float, theta, storey: int, fraction: float, drop_step: int,
                  ground_acceleration, process_noise_std: float = 0.0, rng=None,
                  channels: str = "absolute_acceleration"):
    """Response of ``building`` whose storey ``storey`` (1-based) loses ``fraction`` of
    its stiffness from the transition into step ``drop_step`` on, the state continuous
    through the change (the model of :class:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor`).

    Returns
    -------
    y : (T, p) array
        Clean channels.
    drifts : (T, n) array
        Inter-storey drifts.
    """
    theta = np.asarray(theta, float)
    u = np.asarray(ground_acceleration, float)
    if not 1 <= drop_step < u.size:
        raise ValueError(f"drop_step: expected 1..{u.size - 1}, got {drop_step}")
    if not 1 <= storey <= building.n_storeys:
        raise ValueError(f"storey: expected 1..{building.n_storeys}, got {storey}")
    if not 0 <= fraction < 1:
        raise ValueError(f"fraction: expected [0, 1), got {fraction}")
    rng = as_generator(rng)
    after = theta.copy()
    after[storey - 1] *= 1 - fraction
    drift_H = building.observation_matrix(theta, "drift")
    pre = discretise(building, theta, dt, channels=channels)
    post = discretise(building, after, dt, channels=channels)
    y1, X1, d1 = simulate(pre, u[:drop_step], process_noise_std=process_noise_std, rng=rng,
                          extra_observations=[drift_H])
    # continue from the last pre-change state through the new matrices (one step of u[drop_step - 1 : ])
    y2, X2, d2 = simulate(post, u[drop_step - 1:], x0=X1[0, -1], process_noise_std=process_noise_std, rng=rng,
                          extra_observations=[drift_H])
    return np.concatenate([y1[0], y2[0, 1:]]), np.concatenate([d1[0], d2[0, 1:]])


def _switched_increments(building, dt, theta, delta, tau, u, y, R, sw):
    """Per-step increments ``(M, T)`` of the plain Kalman filter of a one-storey path
    with the matrices switched at step ``tau`` (common to all members)."""
    after = theta * (1 - delta)[:, None]
    pre, post = discretise(building, theta, dt), discretise(building, after, dt)
    first = kalman_filter(pre, u[:tau], y[:tau], R, sw, store=True)
    A, b = post.A, post.B0 + post.B1
    x0 = np.einsum("nij,nj->ni", A, first.filtered_means[:, -1]) + post.B0 * u[tau - 1] + post.B1 * u[tau]
    P0 = A @ first.filtered_covariances @ np.swapaxes(A, 1, 2) + sw**2 * b[:, :, None] * b[:, None, :]
    second = kalman_filter(post, u[tau:], y[tau:], R, sw, x0=x0, P0=P0, store=True)
    return np.concatenate([first.log_likelihood_increments, second.log_likelihood_increments], axis=1)


def grid_log_evidence(building: ShearBuilding, dt: float, ground_acceleration, measurements, measurement_noise,
                      process_noise_std: float, ends, change_every: int, hazard: float, box=(0.7, 1.0),
                      drop_range=(0.02, 0.5), grid=(151, 101)):
    """The exact evidence of the two classes of a **one-storey** building, the
    reference for :class:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor`: ``log p(y_{0:e} | M_0)`` and
    ``log p(y_{0:e} | M_1)`` at each step ``e`` in ``ends``.

    Trapezoid rule on a ``grid = (n_theta, n_delta)`` grid of the uniform priors of
    ``theta`` over ``box = (lower, upper)`` and ``delta`` over ``drop_range`` (on the tests' case within 5e-5 of
    a grid twice as fine), and the sum over the change boundaries with their geometric prior
    ``h (1 - h)^(b - 1)``; every term is the plain :func:`~seqbayes.structural.filters.kalman.kalman_filter`
    (no steady-state shortcut), independent of :func:`path_log_likelihood`.

    Returns
    -------
    log_z0, log_z1 : (len(ends),) arrays
    """
    if building.n_storeys != 1:
        raise ValueError(f"building: the grid reference is for one storey, got {building.n_storeys}")
    u = np.asarray(ground_acceleration, float)
    y = np.asarray(measurements, float)
    ends = np.asarray(ends, int)
    R = measurement_covariance(measurement_noise, 1)
    n_theta, n_delta = grid
    theta = np.linspace(*box, n_theta)
    delta = np.linspace(*drop_range, n_delta)
    w_theta, w_delta = np.ones(n_theta), np.ones(n_delta)
    w_theta[[0, -1]] = w_delta[[0, -1]] = 0.5
    w_theta, w_delta = w_theta / w_theta.sum(), w_delta / w_delta.sum()
    log_w = np.log(np.outer(w_theta, w_delta).ravel())
    no_change = np.cumsum(kalman_filter(discretise(building, theta[:, None], dt), u, y, R, process_noise_std,
                                        store=True).log_likelihood_increments, axis=1)
    log_z0 = np.array([logsumexp(np.log(w_theta) + no_change[:, e]) for e in ends])
    grid_theta, grid_delta = np.repeat(theta, n_delta)[:, None], np.tile(delta, n_theta)
    boundaries = np.arange(change_every, u.size, change_every)
    terms = []
    for i, tau in enumerate(boundaries):  # loop over change boundaries
        cum = np.cumsum(_switched_increments(building, dt, grid_theta, grid_delta, tau, u, y, R, process_noise_std),
                        axis=1)
        log_prior = np.log(hazard) + i * np.log1p(-hazard)  # P(tau = i-th boundary)
        terms.append([log_prior + logsumexp(log_w + cum[:, e]) if e >= tau else -np.inf for e in ends])
    terms = np.array(terms).reshape(len(boundaries), len(ends))
    n_before = np.array([np.sum(boundaries <= e) for e in ends])
    log_z1 = np.array([logsumexp(np.concatenate([[n_before[j] * np.log1p(-hazard) + log_z0[j]], terms[:, j]]))
                       for j in range(len(ends))])
    return log_z0, log_z1
