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
           "check_filter_inputs", "KalmanBank"]

_LOG_2PI = np.log(2 * np.pi)
_STEADY_BLOCK = 256  # time steps per block of the steady-state phase of kalman_log_likelihood


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


def kalman_filter(model: DiscreteModel, ground_acceleration: ArrayLike, measurements: ArrayLike, measurement_noise: ArrayLike,
                  process_noise_std: float = 0.0, x0: ArrayLike | None = None, P0: ArrayLike | None = None,
                  store: bool = False) -> KalmanResult:
    """Batched Kalman filter: one independent filter per member of ``model``.

    Parameters
    ----------
    model : DiscreteModel
        ``N`` members (e.g. :func:`~seqbayes.structural.structures.discretise` at ``N`` thetas).
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


def _sequential_update(mean, P, H, Ht, yw_k):
    """Kalman update with whitened channels ``y_w = H X + v``, ``v ~ N(0, I)``,
    processed one scalar at a time, but with one batched product before and
    one after: the channel-``j`` columns ``P_j h_l`` of the later channels are
    downdated as vectors, and ``P - sum_j g_j (P_j h_j)^T`` is one product.

    Returns the updated ``mean (N, m)``, ``P (N, m, m)`` and the increment
    ``-0.5 sum_j (log s_j + e_j^2 / s_j)`` (without the constant).
    """
    PH = P @ Ht  # (N, m, p), column j becomes P_j h_j once channels < j are processed
    HPH = H @ PH  # (N, p, p): h_l . P h_j
    p = H.shape[1]
    gains = np.empty_like(PH)
    increment = np.zeros(mean.shape[0])
    innov = yw_k - np.einsum("npm,nm->np", H, mean)  # e_l w.r.t. the current mean; yw_k (p,) or (N, p)
    for j in range(p):  # loop over channels only
        c = PH[:, :, j]
        s = HPH[:, j, j] + 1.0
        e = innov[:, j]
        g = c / s[:, None]
        gains[:, :, j] = g
        mean = mean + g * e[:, None]
        increment -= 0.5 * (np.log(s) + e * e / s)
        if j + 1 < p:  # downdate the later channels' columns, cross terms and innovations
            hc = HPH[:, j + 1 :, j] / s[:, None]  # (N, p - j - 1): h_l . g
            PH[:, :, j + 1 :] -= g[:, :, None] * HPH[:, None, j, j + 1 :]
            HPH[:, j + 1 :, j + 1 :] -= hc[:, :, None] * HPH[:, None, j, j + 1 :]
            innov[:, j + 1 :] -= hc * e[:, None]
    P = P - gains @ np.swapaxes(PH, 1, 2)
    return mean, P, increment


def _chandrasekhar_transient(model, H, yw, u, mean, loglik, process_noise_std, steady_tol):
    """Predicted-form Kalman recursion from a known initial state with the
    Riccati equation in Chandrasekhar form (see :func:`kalman_log_likelihood`).

    Returns ``(k, mean, P, loglik, steady)``: if the covariance increments
    fell below ``steady_tol`` at step ``k < T``, ``mean`` and ``P`` are the
    *predicted* moments of step ``k`` and ``steady = k`` (the data of step
    ``k`` not yet processed); otherwise ``k = T - 1``, ``steady = T`` and
    ``mean``, ``P`` are *filtered* at the last step, as the sequential loop leaves them.
    """
    A, B0, B1 = model.A, model.B0, model.B1
    N, m = mean.shape
    p = H.shape[1]
    T = yw.shape[0]
    # W = [mean, L]: the two vectors share every product with A, H, S^-1 and K_bar
    W = np.stack([mean, B0 + B1], axis=2)  # L_0 = b: P_1 - P_0 = Q = s_w^2 b b^T
    M = np.full(N, float(process_noise_std) ** 2)
    S_inv = np.broadcast_to(np.eye(p), (N, p, p)).copy()  # S_0 = H P_0 H^T + I = I
    logdet = np.zeros(N)
    K_bar = np.zeros((N, m, p))  # A P_k H^T (the unnormalised predicted-form gain)
    increments_L, increments_M = [], []  # P_k = sum_{j<k} M_j L_j L_j^T, summed once at the end
    diag_P = np.zeros((N, m))  # for the steady test: max |P_ij| = max P_ii (P is PSD)

    def covariance():
        if not increments_L:
            return np.zeros((N, m, m))
        Ls, Ms = np.array(increments_L), np.array(increments_M)  # (k, N, m), (k, N)
        return np.einsum("kn,kni,knj->nij", Ms, Ls, Ls)

    for k in range(T):  # loop over time only
        HW = H @ W  # (N, p, 2): H mean, v = H L
        HW[:, :, 0] = yw[k] - HW[:, :, 0]  # innovation e
        SE = S_inv @ HW  # S^-1 e, S^-1 v
        e, Se = HW[:, :, 0], SE[:, :, 0]
        loglik -= 0.5 * (logdet + (e * Se).sum(axis=1))
        if k + 1 == T:  # filter the last step: m + P H^T S^-1 e, P - P H^T S^-1 H P
            P = covariance()
            PHt = P @ np.swapaxes(H, 1, 2)
            mean = W[:, :, 0] + (PHt @ Se[:, :, None])[:, :, 0]
            P = P - PHt @ S_inv @ np.swapaxes(PHt, 1, 2)
            return k, mean, 0.5 * (P + np.swapaxes(P, 1, 2)), loglik, T
        AW = A @ W
        KS = K_bar @ SE  # K_bar S^-1 e, K_bar S^-1 v
        v, Sv, L = HW[:, :, 1], SE[:, :, 1], W[:, :, 1]
        W = np.stack([AW[:, :, 0] + B0 * u[k] + B1 * u[k + 1] + KS[:, :, 0],  # predicted mean of k + 1
                      AW[:, :, 1] - KS[:, :, 1]], axis=2)  # L_{k+1} = (A - K_k H) L_k
        K_bar = K_bar + (M[:, None] * AW[:, :, 1])[:, :, None] * v[:, None, :]
        denominator = 1.0 + M * (v * Sv).sum(axis=1)
        S_inv = S_inv - (M / denominator)[:, None, None] * Sv[:, :, None] * Sv[:, None, :]  # Sherman-Morrison
        logdet = logdet + np.log(denominator)
        increments_L.append(L)
        increments_M.append(M)
        L2 = L * L
        diag_P += M[:, None] * L2
        M = M / denominator
        if steady_tol > 0 and k > 0:
            change = increments_M[-1] * L2.max(axis=1) / diag_P.max(axis=1).clip(1e-300)
            if np.all(change < steady_tol):
                return k + 1, W[:, :, 0].copy(), covariance(), loglik, k + 1
    raise AssertionError("unreachable")  # pragma: no cover


def kalman_log_likelihood(model: DiscreteModel, ground_acceleration: ArrayLike, measurements: ArrayLike,
                          measurement_noise: ArrayLike, process_noise_std: float = 0.0, x0: ArrayLike | None = None,
                          P0: ArrayLike | None = None, steady_tol: float = 1e-11, return_steady_step: bool = False,
                          return_state: bool = False, chandrasekhar: bool = True) -> np.ndarray | tuple:
    """``log p(y_{0:T-1} | theta_i)`` for every member: the same numbers as
    :func:`kalman_filter`, computed fast for the many-``theta`` batches of a sampler.

    Two phases, looping over time only:

    1. *Transient.* The channels are whitened (``R = I``). From a known
       initial state (``P0=None``) the predicted covariance grows by rank-1
       increments ``P_{k+1} - P_k = M_k L_k L_k^T`` (``P_1 = Q = s_w^2 b b^T``),
       so the Riccati recursion runs in Chandrasekhar form (Morf, Sidhu and
       Kailath 1974): ``L_{k+1} = (A - K_k H) L_k``, ``M_{k+1} = M_k / (1 +
       M_k v^T S_k^-1 v)``, ``v = H L_k``, the innovation covariance ``S`` and
       its inverse by rank-1 (Sherman-Morrison) updates -- vector operations
       instead of ``m x m`` products per step. Otherwise (or
       ``chandrasekhar=False``) the channels are processed one scalar at a
       time while the full covariance recursion runs.
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
    chandrasekhar : bool
        Use the Chandrasekhar transient when ``P0`` is None (default).
    return_state : bool
        Also return the filtered mean ``(N, m)`` and covariance ``(N, m, m)`` of
        ``X_{T-1}`` given ``y_{0:T-1}`` (to continue the filter, e.g. with
        :class:`KalmanBank`), after the steady step if both are asked for.

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
    Ht = np.swapaxes(H, 1, 2).copy()
    if P0 is None and chandrasekhar:  # (1) transient from a known state: rank-1 covariance increments
        k, mean, P, loglik, steady = _chandrasekhar_transient(model, H, yw, u, mean, loglik, process_noise_std,
                                                              steady_tol)
    while k < T and steady == T and not (P0 is None and chandrasekhar):  # (1) transient, channels one at a time
        mean, P, increment = _sequential_update(mean, P, H, Ht, yw[k])
        loglik += increment
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
        logdet = 2 * np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        loglik -= 0.5 * n_left * logdet
        G_flat = G.reshape(N * m, p)
        for start in range(k, T, _STEADY_BLOCK):  # blocks of time bound the memory (T x N x m at once before)
            stop = min(start + _STEADY_BLOCK, T)
            n = stop - start
            # inputs of the frozen recursion, laid out (time, member, state) for contiguous steps
            drive = u[start : stop - 1, None, None] * model.B0[None] + u[start + 1 : stop, None, None] * model.B1[None]
            drive += (G_flat @ yw[start : stop - 1].T).reshape(N, m, n - 1).transpose(2, 0, 1)
            means = np.empty((n, N, m))
            means[0] = mean
            for t in range(1, n):  # loop over time only
                np.add(np.einsum("nij,nj->ni", F, means[t - 1]), drive[t - 1], out=means[t])
            # innovations and their whitened norms for the block's steps at once: (N, p, n)
            innov = yw[start:stop].T[None] - H @ means.transpose(1, 2, 0)
            z = L_inv @ innov
            loglik -= 0.5 * (z * z).sum(axis=(1, 2))
            if stop < T:  # the prediction of the next block's first step
                mean = (np.einsum("nij,nj->ni", F, means[-1]) + model.B0 * u[stop - 1] + model.B1 * u[stop]
                        + (G_flat @ yw[stop - 1]).reshape(N, m))
        if return_state:  # filter the last prediction: m + K_f e, P - K_f S K_f^T with K_f = P H^T S^-1
            filter_gain = P @ np.swapaxes(H, 1, 2) @ S_inv
            mean = means[-1] + np.einsum("nmp,np->nm", filter_gain, innov[:, :, -1])
            P = P - filter_gain @ S @ np.swapaxes(filter_gain, 1, 2)
            P = 0.5 * (P + np.swapaxes(P, 1, 2))
    out = (loglik,)
    if return_steady_step:
        out += (steady,)
    if return_state:
        out += (mean, P)
    return out if len(out) > 1 else loglik


class KalmanBank:
    """``N`` exact Kalman filters advanced together one time step at a time: the
    on-line likelihood of a particle filter over parameters (resample-move SMC).

    Built from the discrete models of the ``N`` parameter vectors; the
    channels are whitened by ``R`` once and processed one scalar at a time
    (sequential processing, as :func:`kalman_log_likelihood`), so a step costs
    a handful of batched products and no small factorisation. The bank is
    immutable in spirit: :meth:`step` returns new arrays, and a bank of a
    subset or a re-ordering of the members is :meth:`take`.

    Parameters
    ----------
    model : DiscreteModel
        ``N`` members.
    measurement_noise : (p,) stds, scalar, or (p, p) covariance
    process_noise_std : float
    member_noise_std : (N, p) array, optional
        Per-member channel noise stds (independent channels), in place of
        ``measurement_noise`` (which is then ignored): each filter has its own
        ``R_i = diag(member_noise_std[i]^2)`` (noise levels as parameters).
    """

    def __init__(self, model: DiscreteModel, measurement_noise: ArrayLike, process_noise_std: float = 0.0,
                 member_noise_std: ArrayLike | None = None):
        p = model.H.shape[1]
        self.model = model
        if member_noise_std is None:
            self.R = measurement_covariance(measurement_noise, p)
            chol_R = np.linalg.cholesky(self.R)
            self.white = np.linalg.inv(chol_R)
            self.member_white = None
            self.H = np.einsum("ij,njm->nim", self.white, model.H)  # whitened observation (N, p, m)
            self.constant = -0.5 * (p * _LOG_2PI + 2 * np.log(np.diag(chol_R)).sum())
        else:
            std = np.asarray(member_noise_std, dtype=float)
            if std.shape != (model.H.shape[0], p) or not np.all(np.isfinite(std)) or np.any(std <= 0):
                raise ValueError(f"member_noise_std: expected positive finite stds of shape "
                                 f"({model.H.shape[0]}, {p}), got shape {std.shape}")
            self.R = None
            self.white = None
            self.member_white = 1.0 / std  # (N, p)
            self.H = model.H * self.member_white[:, :, None]
            self.constant = -0.5 * p * _LOG_2PI - np.log(std).sum(axis=1)  # (N,)
        self.Ht = np.swapaxes(self.H, 1, 2).copy()
        self.Q = process_covariance(model, process_noise_std)
        self.At = np.swapaxes(model.A, 1, 2)
        self.process_noise_std = float(process_noise_std)
        self.frozen = None  # (gain, S^-1, log det S / 2) once steady: see freeze()

    can_freeze = True

    @property
    def n_members(self) -> int:
        return self.model.A.shape[0]

    def moments(self, mean: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(N, m)`` and covariance ``(N, m, m)`` of each filter's state (as they are)."""
        return mean, P

    def initial_state(self, x0: ArrayLike | None = None, P0: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(N, m)`` and covariance ``(N, m, m)`` of ``X_0`` (default at rest, known)."""
        N, m = self.model.A.shape[:2]
        mean = np.zeros((N, m)) if x0 is None else np.broadcast_to(np.asarray(x0, float), (N, m)).copy()
        P = np.zeros((N, m, m)) if P0 is None else np.broadcast_to(np.asarray(P0, float), (N, m, m)).copy()
        return mean, P

    def step(self, mean: np.ndarray, P: np.ndarray, y_k: np.ndarray, u_prev: float | None = None,
             u_now: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step: predict from the filtered ``(mean, P)`` of step ``k - 1`` with
        inputs ``u_prev = u_{k-1}``, ``u_now = u_k`` (skip the prediction when both
        are ``None``: the first step), then update with ``y_k (p,)``.

        Returns
        -------
        mean : (N, m), P : (N, m, m)
            Filtered at step ``k``.
        increment : (N,)
            ``log p(y_k | y_{0:k-1}, theta_i)``.
        """
        model = self.model
        y_k = np.asarray(y_k, float)
        yw = self.white @ y_k if self.member_white is None else self.member_white * y_k
        if self.frozen is not None and u_prev is not None:  # steady state: P and the gain are fixed
            gain, S_inv, half_logdet = self.frozen
            mean = np.einsum("nij,nj->ni", model.A, mean) + model.B0 * u_prev + model.B1 * u_now
            e = yw - np.einsum("npm,nm->np", self.H, mean)
            Se = np.einsum("npq,nq->np", S_inv, e)
            mean = mean + np.einsum("nmp,np->nm", gain, e)
            return mean, P, self.constant - half_logdet - 0.5 * np.einsum("np,np->n", e, Se)
        if u_prev is not None:
            mean = np.einsum("nij,nj->ni", model.A, mean) + model.B0 * u_prev + model.B1 * u_now
            P = model.A @ P @ self.At + self.Q
            P = 0.5 * (P + np.swapaxes(P, 1, 2))
        mean, P, increment = _sequential_update(mean, P, self.H, self.Ht, yw)
        return mean, P, increment + self.constant

    def freeze(self, P: np.ndarray) -> "KalmanBank":
        """A bank whose covariance is in its steady state: from the filtered ``P``
        (steady), the predicted ``P^- = A P A^T + Q``, ``S = H P^- H^T + I`` and
        the gain ``P^- H^T S^-1`` are fixed, and :meth:`step` only moves the
        mean (four batched products), returning ``P`` unchanged. Exact to the
        tolerance at which ``P`` was declared steady."""
        new = self.take(slice(None))
        prior = self.model.A @ P @ self.At + self.Q
        PHt = prior @ self.Ht
        S = self.H @ PHt + np.eye(self.H.shape[1])
        L = np.linalg.cholesky(0.5 * (S + np.swapaxes(S, 1, 2)))
        L_inv = np.linalg.inv(L)
        S_inv = np.swapaxes(L_inv, 1, 2) @ L_inv
        new.frozen = (PHt @ S_inv, S_inv, np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1))
        return new

    def take(self, index: ArrayLike) -> "KalmanBank":
        """The bank of members ``index``."""
        new = object.__new__(KalmanBank)
        new.model = self.model.take(index)
        new.R, new.white, new.constant = self.R, self.white, self.constant
        new.member_white = None if self.member_white is None else self.member_white[index]
        if np.ndim(self.constant):
            new.constant = self.constant[index]
        new.process_noise_std = self.process_noise_std
        new.H, new.Ht, new.Q, new.At = self.H[index], self.Ht[index], self.Q[index], self.At[index]
        new.frozen = None if self.frozen is None else tuple(x[index] for x in self.frozen)
        return new

    @staticmethod
    def concatenate(banks: Sequence[KalmanBank]) -> "KalmanBank":
        """One bank of the members of ``banks`` in order (same noise levels)."""
        first = banks[0]
        if any(b.member_white is not None for b in banks):
            raise ValueError("banks: concatenate needs shared noise levels (no member_noise_std)")
        new = object.__new__(KalmanBank)
        models = [b.model for b in banks]
        new.model = DiscreteModel(*(np.concatenate([getattr(mo, f) for mo in models]) for f in ("A", "B0", "B1", "H")),
                                  first.model.dt, first.model.hold)
        new.R, new.white, new.constant = first.R, first.white, first.constant
        new.member_white = None
        new.process_noise_std = first.process_noise_std
        new.H = np.concatenate([b.H for b in banks])
        new.Ht = np.concatenate([b.Ht for b in banks])
        new.Q = np.concatenate([b.Q for b in banks])
        new.At = np.concatenate([b.At for b in banks])
        new.frozen = None
        return new

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Sequence
    from numpy.typing import ArrayLike
