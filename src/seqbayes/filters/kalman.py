"""The exact Kalman filter for the linear shear-building model, batched over
many parameter vectors: the marginal likelihood ``p(y_{1:T} | theta)`` that is
the gold standard for SG-EnMCMC, and the oracle for the EnKF.

Model (per member ``i``; ``u`` is the known ground acceleration)::

    X_{k+1} = A_i X_k + B0_i u_k + B1_i u_{k+1} + b_i eta_k,   eta_k ~ N(0, s_w^2)
    y_k     = H_i X_k + v_k,                                  v_k ~ N(0, R)

with ``b_i = B0_i + B1_i`` (an unmeasured white-noise ground acceleration of
std ``s_w``, held over one step), so ``Q_i = s_w^2 b_i b_i^T``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..structures.shear_building import DiscreteModel

__all__ = ["KalmanResult", "kalman_filter", "kalman_log_likelihood", "measurement_covariance", "process_covariance",
           "check_filter_inputs"]

_LOG_2PI = np.log(2 * np.pi)


@dataclass(frozen=True)
class KalmanResult:
    """Output of :func:`kalman_filter` for ``N`` members.

    Attributes
    ----------
    log_likelihood : (N,) array
        ``log p(y_{0:T-1} | theta_i)``.
    log_likelihood_increments : (N, T) array or None
        ``log p(y_k | y_{0:k-1}, theta_i)``.
    filtered_means : (N, T, m) array or None
        ``E[X_k | y_{0:k}]``.
    filtered_covariances : (N, m, m) array
        Covariance at the last step.
    """

    log_likelihood: np.ndarray
    log_likelihood_increments: np.ndarray | None
    filtered_means: np.ndarray | None
    filtered_covariances: np.ndarray


def measurement_covariance(noise_std, p: int) -> np.ndarray:
    """``R (p, p)`` from per-channel std ``(p,)``, a scalar, or a full ``(p, p)`` matrix."""
    noise_std = np.asarray(noise_std, dtype=float)
    if noise_std.ndim == 2:
        if noise_std.shape != (p, p):
            raise ValueError(f"measurement_noise: expected ({p}, {p}), got {noise_std.shape}")
        return noise_std
    std = np.broadcast_to(noise_std, (p,)) if noise_std.ndim == 0 else noise_std
    if std.shape != (p,):
        raise ValueError(f"measurement_noise: expected {p} channel stds, got shape {noise_std.shape}")
    if np.any(std <= 0) or not np.all(np.isfinite(std)):
        raise ValueError("measurement_noise: standard deviations must be positive and finite")
    return np.diag(std**2)


def process_covariance(model: DiscreteModel, process_noise_std: float) -> np.ndarray:
    """``Q_i = s_w^2 b_i b_i^T`` per member, shape ``(N, m, m)``."""
    if not np.isfinite(process_noise_std) or process_noise_std < 0:
        raise ValueError(f"process_noise_std: must be non-negative, got {process_noise_std}")
    b = model.B0 + model.B1
    return process_noise_std**2 * b[:, :, None] * b[:, None, :]


def check_filter_inputs(model: DiscreteModel, ground_acceleration, measurements):
    """Validate ``u (T,)`` and ``y (T, p)`` against the model; returns them as arrays."""
    u = np.asarray(ground_acceleration, dtype=float)
    y = np.asarray(measurements, dtype=float)
    if u.ndim != 1:
        raise ValueError(f"ground_acceleration: expected shape (T,), got {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ValueError("ground_acceleration: contains NaN or inf")
    if y.ndim != 2 or y.shape[0] != u.size:
        raise ValueError(f"measurements: expected shape ({u.size}, p) to match the ground motion, got {y.shape}")
    p = model.H.shape[1]
    if y.shape[1] != p:
        raise ValueError(f"measurements: {y.shape[1]} channels but the model observes {p}")
    if not np.all(np.isfinite(y)):
        raise ValueError("measurements: contains NaN or inf")
    return u, y


def kalman_filter(model: DiscreteModel, ground_acceleration, measurements, measurement_noise,
                  process_noise_std: float = 0.0, x0=None, P0=None, store: bool = False) -> KalmanResult:
    """Batched Kalman filter: one independent filter per member of ``model``.

    Parameters
    ----------
    model : DiscreteModel
        ``N`` members (e.g. :func:`~seqbayes.structures.discretise` at ``N`` thetas).
    ground_acceleration : (T,) array
    measurements : (T, p) array
        ``y_k`` for ``k = 0..T-1``.
    measurement_noise : (p,) stds, scalar, or (p, p) covariance
    process_noise_std : float
        Std of the unmeasured input noise (see module docstring).
    x0 : (m,) array, optional
        Mean of ``X_0`` (default at rest).
    P0 : (m, m) array, optional
        Covariance of ``X_0`` (default 0: known initial state).
    store : bool
        Keep increments and filtered means (memory ``N * T * m``).

    Returns
    -------
    KalmanResult
    """
    u, y = check_filter_inputs(model, ground_acceleration, measurements)
    N, m = model.A.shape[:2]
    p = model.H.shape[1]
    R = measurement_covariance(measurement_noise, p)
    Q = process_covariance(model, process_noise_std)
    mean = np.zeros((N, m)) if x0 is None else np.broadcast_to(np.asarray(x0, float), (N, m)).copy()
    P = np.zeros((N, m, m)) if P0 is None else np.broadcast_to(np.asarray(P0, float), (N, m, m)).copy()
    A, H = model.A, model.H
    At, Ht = np.swapaxes(A, 1, 2), np.swapaxes(H, 1, 2)
    T = u.size
    loglik = np.zeros(N)
    incs = np.empty((N, T)) if store else None
    means = np.empty((N, T, m)) if store else None
    for k in range(T):  # loop over time only
        y_pred = np.einsum("npm,nm->np", H, mean)
        PHt = P @ Ht  # (N, m, p)
        S = H @ PHt + R  # innovation covariance
        S = 0.5 * (S + np.swapaxes(S, 1, 2))
        L = np.linalg.cholesky(S)
        innov = y[k] - y_pred
        z = np.linalg.solve(L, innov[:, :, None])[:, :, 0]
        logdet = 2 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        inc = -0.5 * (p * _LOG_2PI + logdet + (z**2).sum(axis=1))
        loglik += inc
        gain = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, 1, 2)), 1, 2)  # P H^T S^-1
        mean = mean + np.einsum("nmp,np->nm", gain, innov)
        P = P - gain @ np.swapaxes(PHt, 1, 2)
        if store:
            incs[:, k] = inc
            means[:, k] = mean
        if k + 1 < T:
            mean = np.einsum("nij,nj->ni", A, mean) + model.B0 * u[k] + model.B1 * u[k + 1]
            P = A @ P @ At + Q
            P = 0.5 * (P + np.swapaxes(P, 1, 2))
    return KalmanResult(loglik, incs, means, P)


def kalman_log_likelihood(model: DiscreteModel, ground_acceleration, measurements, measurement_noise,
                          process_noise_std: float = 0.0, x0=None, P0=None, steady_tol: float = 1e-11,
                          return_steady_step: bool = False):
    """``log p(y_{0:T-1} | theta_i)`` for every member: the same numbers as
    :func:`kalman_filter`, computed fast for the many-``theta`` batches of a sampler.

    Two phases, looping over time only:

    1. *Transient.* The channels are whitened (``R = I``) and processed one
       scalar at a time (sequential processing: exact, and no ``p x p``
       factorisation per step), while the covariance recursion runs.
    2. *Steady state.* The predicted covariance does not depend on the data;
       once it has stopped changing for every member (max relative change
       below ``steady_tol``), the gain and innovation covariance are frozen
       and the mean follows the time-invariant recursion
       ``m_{k+1} = A (I - K H) m_k + A K y_k + B0 u_k + B1 u_{k+1}``, one
       batched product per step; the innovation terms are summed at the end.

    The difference from :func:`kalman_filter` is of order ``T * steady_tol``
    in the log-likelihood (checked in the tests).

    Parameters
    ----------
    model, ground_acceleration, measurements, measurement_noise, process_noise_std, x0, P0
        As :func:`kalman_filter`.
    steady_tol : float
        Relative change of the predicted covariance below which it is frozen
        (``0`` disables the steady-state phase).
    return_steady_step : bool
        Also return the step at which the steady state was reached (``T`` if never).

    Returns
    -------
    log_likelihood : (N,) array
    """
    u, y = check_filter_inputs(model, ground_acceleration, measurements)
    N, m = model.A.shape[:2]
    p = model.H.shape[1]
    T = u.size
    R = measurement_covariance(measurement_noise, p)
    chol_R = np.linalg.cholesky(R)
    white = np.linalg.inv(chol_R)
    H = np.einsum("ij,njm->nim", white, model.H)  # whitened: y_w = H_w X + v, v ~ N(0, I)
    yw = y @ white.T
    Q = process_covariance(model, process_noise_std)
    A = model.A
    At = np.swapaxes(A, 1, 2)
    mean = np.zeros((N, m)) if x0 is None else np.broadcast_to(np.asarray(x0, float), (N, m)).copy()
    P = np.zeros((N, m, m)) if P0 is None else np.broadcast_to(np.asarray(P0, float), (N, m, m)).copy()
    loglik = np.full(N, -0.5 * T * (p * _LOG_2PI + 2 * np.log(np.diag(chol_R)).sum()))
    k = 0
    steady = T
    P_prior = None  # the previous step's predicted covariance (steady-state test)
    while k < T:  # (1) transient: time-varying covariance, channels one at a time
        for j in range(p):
            h = H[:, j, :]
            Ph = np.einsum("nab,nb->na", P, h)
            s = np.einsum("na,na->n", h, Ph) + 1.0
            e = yw[k, j] - np.einsum("na,na->n", h, mean)
            gain = Ph / s[:, None]
            mean = mean + gain * e[:, None]
            P = P - gain[:, :, None] * Ph[:, None, :]
            loglik -= 0.5 * (np.log(s) + e * e / s)
        if k + 1 == T:
            break
        mean = np.einsum("nij,nj->ni", A, mean) + model.B0 * u[k] + model.B1 * u[k + 1]
        P_new = A @ P @ At + Q
        P_new = 0.5 * (P_new + np.swapaxes(P_new, 1, 2))
        k += 1
        if steady_tol > 0 and k > 1:
            change = np.abs(P_new - P_prior).max(axis=(1, 2)) / np.abs(P_new).max(axis=(1, 2)).clip(1e-300)
            if np.all(change < steady_tol):
                P = P_new
                steady = k
                break
        P = P_prior = P_new
    if steady < T:  # (2) steady state from step k: frozen gain, one product per step
        S = H @ P @ np.swapaxes(H, 1, 2) + np.eye(p)
        S = 0.5 * (S + np.swapaxes(S, 1, 2))
        L = np.linalg.cholesky(S)
        L_inv = np.linalg.inv(L)
        S_inv = np.swapaxes(L_inv, 1, 2) @ L_inv
        gain = P @ np.swapaxes(H, 1, 2) @ S_inv  # (N, m, p)
        F = A - A @ gain @ H  # A (I - K H)
        G = A @ gain
        n_left = T - k
        # inputs of the frozen recursion, laid out (time, member, state) for contiguous steps
        drive = u[k:-1, None, None] * model.B0[None] + u[k + 1 :, None, None] * model.B1[None]
        drive += (G.reshape(N * m, p) @ yw[k:-1].T).reshape(N, m, n_left - 1).transpose(2, 0, 1)
        means = np.empty((n_left, N, m))
        means[0] = mean
        for t in range(1, n_left):  # loop over time only
            np.add(np.einsum("nij,nj->ni", F, means[t - 1]), drive[t - 1], out=means[t])
        # innovations and their whitened norms for all remaining steps at once: (N, p, T - k)
        innov = yw[k:].T[None] - H @ means.transpose(1, 2, 0)
        z = L_inv @ innov
        logdet = 2 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        loglik -= 0.5 * (n_left * logdet + (z * z).sum(axis=(1, 2)))
    return (loglik, steady) if return_steady_step else loglik
