"""Batched stochastic ensemble Kalman filter (Lin et al. 2024, Eqs. 6-10 and
21-25), vectorised over ensemble members (no loop over members).

Building blocks, each a pure function of arrays:

* :func:`ensemble_moments` -- sample mean and covariance (Eq. 9), optionally
  *conditional* on member covariates (e.g. each member's parameter ``theta``):
  the anomalies are then the residuals of a least-squares regression on the
  covariates, so the covariance estimates the spread of the state *given*
  ``theta`` rather than the spread between parameter values;
* :func:`predictive_log_likelihood` -- the EnKF predictive density of the
  observation (Eq. 25): for the ensemble, ``N(y; mean(Y), C_yy + R)``; per
  member, ``N(y; Y_i, C_yy + R)``;
* :func:`perturbed_observation_update` -- Kalman gain from sample moments
  (``K = C_xy (C_yy + R)^-1``, the cross-covariance form that also handles a
  member-dependent observation operator) and the perturbed-observation update
  (Eqs. 10, 22);
* :func:`enkf_filter` -- the whole filter for the linear shear-building model
  (one parameter vector), returning the ensemble log-likelihood
  ``sum_k log N(y_k; mean(Y_k), C_yy,k + R)`` and the state means; for a large
  ensemble these converge to the Kalman filter's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...rng import as_generator
from ..structures.shear_building import DiscreteModel
from .kalman import check_filter_inputs, measurement_covariance

__all__ = [
    "ensemble_moments",
    "predictive_log_likelihood",
    "perturbed_observation_update",
    "forecast",
    "EnKFResult",
    "enkf_filter",
    "EnKFBank",
    "enkf_log_likelihood",
]

_LOG_2PI = np.log(2 * np.pi)


def _anomalies(values: np.ndarray, covariates: np.ndarray | None) -> np.ndarray:
    """Centred values, or residuals of a linear regression on ``covariates`` (N, q)."""
    centred = values - values.mean(axis=0)
    if covariates is None:
        return centred
    Z = covariates - covariates.mean(axis=0)
    beta, *_ = np.linalg.lstsq(Z, centred, rcond=None)
    return centred - Z @ beta


def ensemble_moments(X: np.ndarray, covariates: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Sample mean ``(m,)`` and covariance ``(m, m)`` of an ensemble ``X (N, m)`` (Eq. 9).

    With ``covariates (N, q)``, the covariance is that of the regression
    residuals on the covariates (divisor ``N - 1 - q``).

    Examples
    --------
    >>> mean, cov = ensemble_moments(np.array([[0.0], [2.0]]))
    >>> float(mean[0]), float(cov[0, 0])
    (1.0, 2.0)
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 2 or X.shape[0] < 2:
        raise ValueError(f"X: expected shape (N >= 2, m), got {X.shape}")
    q = 0 if covariates is None else np.shape(covariates)[1]
    E = _anomalies(X, covariates)
    return X.mean(axis=0), E.T @ E / (X.shape[0] - 1 - q)


def _gaussian_logpdf(residuals: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``log N(r; 0, S)`` for residual rows ``r (N, p)`` with one ``S (p, p)``."""
    L = np.linalg.cholesky(S)
    # p is small: invert the p x p factor once, then one matrix product (a LAPACK
    # triangular solve on a (p, N) right-hand side is far slower for N >> p)
    z = np.linalg.inv(L) @ residuals.T
    p = S.shape[0]
    return -0.5 * (p * _LOG_2PI + 2 * np.log(np.diag(L)).sum() + (z**2).sum(axis=0))


def predictive_log_likelihood(y: np.ndarray, Y: np.ndarray, R: np.ndarray, covariates: np.ndarray | None = None,
                              centre: str = "member") -> tuple[np.ndarray, np.ndarray]:
    """EnKF predictive log-density of observation ``y`` (Eq. 25).

    Parameters
    ----------
    y : (p,) array
        The observation.
    Y : (N, p) array
        Predicted observations of the forecast members, ``h(X_i, theta_i)``.
    R : (p, p) array
        Measurement-noise covariance.
    covariates : (N, q) array, optional
        Condition the spread on member covariates (see module docstring).
    centre : {"member", "regression"}
        Centre of each member's predictive density: its own prediction
        ``Y_i``, or (with covariates) the regression fit ``mean(Y) + beta^T
        (z_i - mean(z))`` -- the ensemble's estimate of ``E[y | z_i]``, free of
        the member's own state noise.

    Returns
    -------
    ensemble : float
        ``log N(y; mean(Y), C_yy + R)``.
    members : (N,) array
        ``log N(y; centre_i, C_yy + R)`` per member.
    """
    Y = np.asarray(Y, dtype=float)
    if centre not in ("member", "regression"):
        raise ValueError(f"centre: expected 'member' or 'regression', got {centre!r}")
    mean, C_yy = ensemble_moments(Y, covariates)
    S = C_yy + R
    S = 0.5 * (S + S.T)
    ens = float(_gaussian_logpdf((y - mean)[None, :], S)[0])
    if centre == "regression" and covariates is not None:
        centres = Y - _anomalies(Y, covariates)  # fitted values
    else:
        centres = Y
    return ens, _gaussian_logpdf(y[None, :] - centres, S)


def perturbed_observation_update(X: np.ndarray, Y: np.ndarray, y: np.ndarray, R: np.ndarray,
                                 rng: int | np.random.Generator | None, covariates: np.ndarray | None = None,
                                 gain_covariance: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Stochastic EnKF analysis (Eqs. 10, 22) for all members at once.

    Parameters
    ----------
    X : (N, m) array
        Forecast states.
    Y : (N, p) array
        Predicted observations ``h(X_i)``.
    y : (p,) array
    R : (p, p) array
    rng : Generator
    covariates : (N, q) array, optional
        Conditional moments (see :func:`ensemble_moments`).
    gain_covariance : tuple (C_xy, C_yy), optional
        Use these moments instead of the sample ones.

    Returns
    -------
    X_new : (N, m) array
        ``X_i + K (y + v_i - Y_i)``, ``v_i ~ N(0, R)``, ``K = C_xy (C_yy + R)^-1``.
    gain : (m, p) array
    """
    rng = as_generator(rng)
    N = X.shape[0]
    if gain_covariance is None:
        q = 0 if covariates is None else covariates.shape[1]
        Ex = _anomalies(X, covariates)
        Ey = _anomalies(Y, covariates)
        C_xy = Ex.T @ Ey / (N - 1 - q)
        C_yy = Ey.T @ Ey / (N - 1 - q)
    else:
        C_xy, C_yy = gain_covariance
    S = C_yy + R
    gain = C_xy @ np.linalg.inv(S)  # K = C_xy S^-1 (S is p x p, p small)
    L = np.linalg.cholesky(R)
    perturbed = y[None, :] + rng.standard_normal(Y.shape) @ L.T  # perturbed observations
    return X + (perturbed - Y) @ gain.T, gain


def forecast(model: DiscreteModel, X: np.ndarray, u_now: float, u_next: float, process_noise_std: float = 0.0,
             rng: int | np.random.Generator | None = None) -> np.ndarray:
    """One forecast step for every member (Eq. 7 / Eq. 21 with exact matrices).

    ``X_i <- A_i X_i + B0_i u_now + B1_i u_next + b_i eta_i``; ``model`` has one
    member (shared) or one per row of ``X``.
    """
    X_new = np.einsum("nij,nj->ni", model.A, X) if model.A.shape[0] == X.shape[0] else X @ model.A[0].T
    X_new = X_new + model.B0 * u_now + model.B1 * u_next
    if process_noise_std > 0:
        eta = as_generator(rng).standard_normal(X.shape[0]) * process_noise_std
        X_new = X_new + (model.B0 + model.B1) * eta[:, None]
    return X_new


@dataclass(frozen=True)
class EnKFResult:
    """Output of :func:`enkf_filter`.

    Attributes
    ----------
    log_likelihood : float
        ``sum_k log N(y_k; mean(Y_k), C_yy,k + R)``.
    log_likelihood_increments : (T,) array
    filtered_means : (T, m) array
    final_ensemble : (N, m) array
    """

    log_likelihood: float
    log_likelihood_increments: np.ndarray
    filtered_means: np.ndarray
    final_ensemble: np.ndarray


def enkf_filter(model: DiscreteModel, ground_acceleration: ArrayLike, measurements: ArrayLike, measurement_noise: ArrayLike,
                process_noise_std: float = 0.0, n_members: int = 500, x0: ArrayLike | None = None,
                P0: ArrayLike | None = None, rng: int | np.random.Generator | None = None) -> EnKFResult:
    """Stochastic EnKF for one linear model (a ``DiscreteModel`` with one member).

    Same model and conventions as :func:`seqbayes.structural.filters.kalman.kalman_filter`;
    ``X_0 ~ N(x0, P0)`` (default exactly at rest).
    """
    if model.A.shape[0] != 1:
        raise ValueError(f"model: expected a single member, got {model.A.shape[0]}")
    if not isinstance(n_members, (int, np.integer)) or n_members < 2:
        raise ValueError(f"n_members: expected an integer >= 2, got {n_members!r}")
    u, y = check_filter_inputs(model, ground_acceleration, measurements)
    rng = as_generator(rng)
    m, p = model.A.shape[1], model.H.shape[1]
    R = measurement_covariance(measurement_noise, p)
    mean0 = np.zeros(m) if x0 is None else np.asarray(x0, float)
    X = np.tile(mean0, (n_members, 1))
    if P0 is not None:
        X = X + rng.standard_normal((n_members, m)) @ np.linalg.cholesky(
            np.asarray(P0, float) + 1e-300 * np.eye(m)).T
    H = model.H[0]
    T = u.size
    incs = np.empty(T)
    means = np.empty((T, m))
    for k in range(T):  # loop over time only
        Y = X @ H.T
        incs[k], _ = predictive_log_likelihood(y[k], Y, R)
        X, _ = perturbed_observation_update(X, Y, y[k], R, rng)
        means[k] = X.mean(axis=0)
        if k + 1 < T:
            X = forecast(model, X, u[k], u[k + 1], process_noise_std, rng)
    return EnKFResult(float(incs.sum()), incs, means, X)


class EnKFBank:
    """``N`` stochastic ensemble Kalman filters of ``M`` members each, advanced
    together one step at a time (no loop over filters or members): the
    on-line EnKF likelihood of a particle filter over parameters, the
    counterpart of :class:`~seqbayes.structural.filters.kalman.KalmanBank` for models
    where an exact filter is not available.

    The state of the bank is the ensembles ``X (N, M, m)`` and their sample
    covariances ``(N, m, m)`` (for summaries). Each step: forecast every
    member with its filter's matrices and its own process noise; increment
    ``log N(y_k; mean(Y_i), C_yy,i + R)`` (Eq. 25 with the ensemble mean);
    perturbed-observation update with ``K_i = C_xy,i (C_yy,i + R)^-1``
    (Eq. 22). A model with a ``propagate(X, u_prev, u_now, eta)`` method (a
    nonlinear transition such as
    :class:`~seqbayes.structural.structures.bouc_wen.BoucWenModel`) forecasts its own
    ensembles; otherwise the linear matrices ``A, B0, B1`` are used. The increment is a random, biased estimate of the exact
    ``log p(y_k | y_{0:k-1}, theta_i)``; for a linear model it converges to
    the Kalman filter's as ``M`` grows.

    Parameters
    ----------
    model : DiscreteModel
        ``N`` filters.
    measurement_noise : (p,) stds, scalar, or (p, p) covariance
    process_noise_std : float
    members : int
        Ensemble size ``M`` per filter.
    rng : numpy.random.Generator
        Source of the process noise and the observation perturbations.
    """

    can_freeze = False
    frozen = None

    def __init__(self, model: DiscreteModel, measurement_noise: ArrayLike, process_noise_std: float, members: int,
                 rng: int | np.random.Generator | None):
        if not isinstance(members, (int, np.integer)) or members < 2:
            raise ValueError(f"members: expected an integer >= 2, got {members!r}")
        p = model.H.shape[1]
        self.model = model
        self.R = measurement_covariance(measurement_noise, p)
        self.chol_R = np.linalg.cholesky(self.R)
        self.process_noise_std = float(process_noise_std)
        self.members = int(members)
        self.rng = rng
        self.b = None if hasattr(model, "propagate") else model.B0 + model.B1

    def initial_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ensembles at rest ``(N, M, m)`` and zero covariances ``(N, m, m)``."""
        N, m = self.model.H.shape[0], self.model.H.shape[2]
        return np.zeros((N, self.members, m)), np.zeros((N, m, m))

    def moments(self, X: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean ``(N, m)`` and covariance ``(N, m, m)`` of each filter's state."""
        return X.mean(axis=1), cov

    def step(self, X: np.ndarray, cov: np.ndarray, y_k: np.ndarray, u_prev: float | None = None,
             u_now: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One step (prediction skipped when ``u_prev`` is None): returns the
        updated ensembles, their covariances and the increments ``(N,)``."""
        model, rng = self.model, self.rng
        N, M = X.shape[:2]
        p = model.H.shape[1]
        if u_prev is not None:
            noise = rng.standard_normal((N, M)) * self.process_noise_std
            if self.b is None:  # a nonlinear model (e.g. Bouc-Wen) advances its own states
                X = model.propagate(X, u_prev, u_now, noise)
            else:
                X = (np.einsum("nij,nkj->nki", model.A, X) + (model.B0 * u_prev + model.B1 * u_now)[:, None, :]
                     + self.b[:, None, :] * noise[:, :, None])
        Y = np.einsum("npm,nkm->nkp", model.H, X)
        X_anom = X - X.mean(axis=1, keepdims=True)
        Y_mean = Y.mean(axis=1)
        Y_anom = Y - Y_mean[:, None, :]
        C_yy = np.einsum("nkp,nkq->npq", Y_anom, Y_anom) / (M - 1)
        C_xy = np.einsum("nkm,nkp->nmp", X_anom, Y_anom) / (M - 1)
        S = C_yy + self.R
        L = np.linalg.cholesky(0.5 * (S + np.swapaxes(S, 1, 2)))
        L_inv = np.linalg.inv(L)
        z = np.einsum("npq,nq->np", L_inv, y_k - Y_mean)
        increment = -0.5 * (p * _LOG_2PI + (z * z).sum(axis=1)) - np.log(np.diagonal(L, axis1=1, axis2=2)).sum(axis=1)
        gain = C_xy @ (np.swapaxes(L_inv, 1, 2) @ L_inv)  # C_xy S^-1
        perturbed = y_k + rng.standard_normal((N, M, p)) @ self.chol_R.T
        X = X + np.einsum("nmp,nkp->nkm", gain, perturbed - Y)
        X_anom = X - X.mean(axis=1, keepdims=True)
        cov = np.einsum("nki,nkj->nij", X_anom, X_anom) / (M - 1)
        return X, cov, increment


def enkf_log_likelihood(model: DiscreteModel, ground_acceleration: ArrayLike, measurements: ArrayLike,
                        measurement_noise: ArrayLike, process_noise_std: float, members: int,
                        rng: int | np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """EnKF log-likelihood of ``y_{0:T-1}`` for each of the ``N`` filters of ``model``
    (:class:`EnKFBank`, ``members`` each), and the final ensembles and covariances.

    Returns
    -------
    log_likelihood : (N,) array
    X : (N, M, m) array
    cov : (N, m, m) array
    """
    u, y = check_filter_inputs(model, ground_acceleration, measurements)
    bank = EnKFBank(model, measurement_noise, process_noise_std, members, as_generator(rng))
    X, cov = bank.initial_state()
    total = np.zeros(model.H.shape[0])
    for k in range(u.size):  # loop over time only
        X, cov, increment = bank.step(X, cov, y[k], *((u[k - 1], u[k]) if k else (None, None)))
        total += increment
    return total, X, cov

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
