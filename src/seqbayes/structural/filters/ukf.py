"""Augmented-state unscented Kalman filter for joint state and stiffness
estimation (mentioned by Lin et al. 2024 as the other classical baseline).

Same augmented model as :mod:`seqbayes.structural.filters.ekf`; the ``2(m+d)+1`` sigma
points (scaled unscented transform, Wan and van der Merwe) are propagated
through the exact discretisation at their own ``theta`` in one batched call
per step, with no loop over sigma points.
"""

from __future__ import annotations

import numpy as np

from .ekf import AugmentedModel, JointFilterResult, check_joint_inputs, drift_moments, joint_initial_state
from .kalman import measurement_covariance

__all__ = ["ukf", "sigma_points"]

_LOG_2PI = np.log(2 * np.pi)


def sigma_points(mean: np.ndarray, cov: np.ndarray, alpha: float = 1.0, beta: float = 2.0,
                 kappa: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scaled sigma points ``(2L+1, L)`` and mean/covariance weights ``(2L+1,)``.

    Examples
    --------
    >>> pts, wm, wc = sigma_points(np.zeros(2), np.eye(2))
    >>> pts.shape, round(float(wm.sum()), 12)
    ((5, 2), 1.0)
    """
    L = mean.size
    lam = alpha**2 * (L + kappa) - L
    root = np.linalg.cholesky((L + lam) * cov)
    pts = np.vstack([mean, mean + root.T, mean - root.T])
    wm = np.full(2 * L + 1, 0.5 / (L + lam))
    wc = wm.copy()
    wm[0] = lam / (L + lam)
    wc[0] = wm[0] + 1 - alpha**2 + beta
    return pts, wm, wc


def _psd(P):
    P = 0.5 * (P + P.T)
    w, v = np.linalg.eigh(P)
    return (v * np.maximum(w, 1e-18 * max(w.max(), 1e-300))) @ v.T


def ukf(model: AugmentedModel, ground_acceleration: ArrayLike, measurements: ArrayLike, measurement_noise: ArrayLike,
        theta0: ArrayLike = 0.85, theta0_var: ArrayLike = 0.3**2 / 12, alpha: float = 1.0, beta: float = 2.0,
        kappa: float = 0.0) -> JointFilterResult:
    """Run the augmented-state UKF from rest (arguments as :func:`~seqbayes.structural.filters.ekf.ekf`)."""
    import time

    start = time.perf_counter()
    u, y = check_joint_inputs(model, ground_acceleration, measurements)
    m, d, n = model.m, model.d, model.n
    R = measurement_covariance(measurement_noise, y.shape[1])
    z, P = joint_initial_state(model, theta0, theta0_var)
    P[:m, :m] = 1e-16 * np.eye(m)  # at rest, but keep the Cholesky defined
    T = u.size
    th_mean, th_var = np.empty((T, d)), np.empty((T, d))
    x_mean, dr_mean, dr_std = np.empty((T, m)), np.empty((T, n)), np.empty((T, n))
    loglik = 0.0
    for k in range(T):  # loop over time only
        if k > 0:  # unscented forecast, all sigma points in one batch
            pts, wm, wc = sigma_points(z, _psd(P), alpha, beta, kappa)
            prop, b = model.propagate(pts, u[k - 1], u[k])
            z = wm @ prop
            dev = prop - z
            P = (wc * dev.T) @ dev + model.process_covariance(wm @ b)
        pts, wm, wc = sigma_points(z, _psd(P), alpha, beta, kappa)
        Yp = model.observe(pts)
        y_pred = wm @ Yp
        dy = Yp - y_pred
        dz = pts - z
        S = (wc * dy.T) @ dy + R
        C = (wc * dz.T) @ dy
        innov = y[k] - y_pred
        gain = np.linalg.solve(S, C.T).T
        sign, logdet = np.linalg.slogdet(S)
        loglik += -0.5 * (len(innov) * _LOG_2PI + logdet + innov @ np.linalg.solve(S, innov))
        z = z + gain @ innov
        P = _psd(P - gain @ S @ gain.T)
        th_mean[k], th_var[k] = z[m:], np.diag(P)[m:]
        x_mean[k] = z[:m]
        dr_mean[k], dr_std[k] = drift_moments(z, P, n)
    return JointFilterResult(th_mean, th_var, x_mean, dr_mean, dr_std, float(loglik), P,
                             time.perf_counter() - start)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
