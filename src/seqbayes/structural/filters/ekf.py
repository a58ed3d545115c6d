"""Augmented-state extended Kalman filter: the paper's baseline (Lin et al.
2024, Eqs. 2-5) for joint estimation of the state ``X = [x, x']`` and the
stiffness ratios ``theta``, with ``theta`` a slow random walk.

Augmented state ``Z = [X, theta]`` (size ``m + d``)::

    X_{k+1}     = A(theta) X_k + B0(theta) u_k + B1(theta) u_{k+1} + b(theta) eta_k
    theta_{k+1} = theta_k + zeta_k,            zeta_k ~ N(0, s_theta^2 I)
    y_k         = H(theta_k) X_k + v_k

``A, B0, B1`` are the exact FOH discretisation (a better transition than the
Euler step of Eq. 3). ``A_c(theta)`` and ``H(theta)`` are affine in ``theta``
(``K`` and the Rayleigh ``C`` are), so their ``d`` slopes are computed once;
a step builds the augmented FOH matrix ``Phi = [[A_c dt, b_c dt, 0], [0, 0, 1],
[0, 0, 0]]`` from them and takes one exponential with its exact derivatives
along ``E_j = dPhi/dtheta_j`` (the first block row of ``expm([[Phi, E], [0,
Phi]])``, Van Loan 1978; :func:`~seqbayes.structural.structures.shear_building.expm_and_derivatives`)
-- the Jacobian with respect to ``theta`` without finite differences and
without re-discretising the building ``2d + 1`` times per step (the previous
version: ~3 ms a step for 4 storeys). The observation is bilinear, so its
Jacobian is exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..structures.shear_building import Sensors, ShearBuilding, batched_expm, expm_and_derivatives
from ..summaries import convergence_step
from .kalman import measurement_covariance

__all__ = ["AugmentedModel", "JointFilterResult", "ekf", "joint_initial_state", "check_joint_inputs", "drift_moments"]

_LOG_2PI = np.log(2 * np.pi)


@dataclass(frozen=True)
class JointFilterResult:
    """Histories of a joint state-parameter filter over ``T`` steps.

    Attributes
    ----------
    theta_mean : (T, d) array
    theta_var : (T, d) array
        Marginal variances (diagonal of the parameter block).
    state_mean : (T, m) array
    drift_mean, drift_std : (T, n) arrays
        Inter-storey drifts of the filtered state.
    log_likelihood : float
        Sum of the Gaussian predictive log-densities.
    final_covariance : (m + d, m + d) array
    elapsed : float
    """

    theta_mean: np.ndarray
    theta_var: np.ndarray
    state_mean: np.ndarray
    drift_mean: np.ndarray
    drift_std: np.ndarray
    log_likelihood: float
    final_covariance: np.ndarray
    elapsed: float

    def convergence_step(self, truth: ArrayLike, tol: float = 0.01) -> np.ndarray:
        return convergence_step(self.theta_mean, truth, tol)


class AugmentedModel:
    """Transition and observation of ``Z = [X, theta]`` for a shear building.

    Parameters
    ----------
    building : ShearBuilding
    dt : float
    process_noise_std : float
        Std of the unmeasured ground-acceleration noise.
    theta_walk_std : float
        Std of the random-walk step of ``theta`` per time step.
    channels : str or Sensors
        ``"absolute_acceleration"``, ``"drift"`` or a sensor layout (:class:`~seqbayes.structural.structures.Sensors`).
    fd_step : float
        Unused (the ``theta`` Jacobian is now exact); kept for compatibility.
    theta_floor : float
        Stiffness ratios below this are clamped (keeps the stiffness positive).
    """

    def __init__(self, building: ShearBuilding, dt: float, process_noise_std: float = 0.0,
                 theta_walk_std: float = 1e-5, channels: str = "absolute_acceleration",
                 fd_step: float = 1e-6, theta_floor: float = 0.05):
        if theta_walk_std < 0 or process_noise_std < 0:
            raise ValueError("theta_walk_std, process_noise_std: must be non-negative")
        self.building, self.dt = building, float(dt)
        self.n = building.n_storeys
        self.m = building.state_dim
        self.d = self.n
        self.process_noise_std = float(process_noise_std)
        self.theta_walk_std = float(theta_walk_std)
        self.channels = channels
        self.fd_step = float(fd_step)
        self.theta_floor = float(theta_floor)
        if not isinstance(channels, Sensors) and channels not in ("absolute_acceleration", "drift"):
            raise ValueError(f"channels: expected 'absolute_acceleration', 'drift' or a Sensors layout, "
                             f"got {channels!r}")
        building.check_sampling(dt)
        # affine pieces: A_c(theta) = A_c0 + sum_j theta_j A_cj, H(theta) = H0 + sum_j theta_j H_j
        d, m = self.d, self.m
        basis = np.vstack([np.zeros(d), np.eye(d)])  # theta = 0 and the unit vectors
        A_c, b_c = building.continuous_state_space(np.maximum(basis, 1e-300))
        self._Ac0 = A_c[0]
        self._Ac_slopes = A_c[1:] - A_c[0]  # (d, m, m)
        H = building.observation_matrix(np.maximum(basis, 1e-300), channels)
        self._H0, self._H_slopes = H[0], H[1:] - H[0]  # (p, m), (d, p, m)
        size = m + 2
        self._phi0 = np.zeros((size, size))
        self._phi0[:m, m] = b_c * self.dt
        self._phi0[m, m + 1] = 1.0  # (1/dt) * dt: the first-order hold
        self._directions = np.zeros((d, size, size))  # E_j = dPhi / dtheta_j
        self._directions[:, :m, :m] = self._Ac_slopes * self.dt

    def _phi(self, theta):
        """Augmented FOH matrices ``(K, m + 2, m + 2)`` for a batch ``theta (K, d)``."""
        m = self.m
        phi = np.broadcast_to(self._phi0, (theta.shape[0],) + self._phi0.shape).copy()
        phi[:, :m, :m] = (self._Ac0 + np.tensordot(theta, self._Ac_slopes, axes=1)) * self.dt
        return phi

    def _transition(self, theta):
        """``E = expm(Phi)`` for a batch ``(K, d)``: ``A = E[:m, :m]``, ``X' = E[:m] @ [X, u_k, u_{k+1} - u_k]``."""
        return batched_expm(self._phi(theta))

    def _H(self, theta):
        """``H (K, p, m)`` for a batch ``theta (K, d)``."""
        return self._H0 + np.tensordot(theta, self._H_slopes, axes=1)

    def _safe(self, theta):
        return np.maximum(theta, self.theta_floor)  # keep stiffness positive

    def propagate(self, Z: np.ndarray, u_now: float, u_next: float) -> tuple[np.ndarray, np.ndarray]:
        """``f(Z)`` for a batch ``Z (K, m + d)``; also returns ``b(theta) (K, m)``."""
        m = self.m
        E = self._transition(self._safe(Z[:, m:]))
        drive = np.concatenate([Z[:, :m], np.full((Z.shape[0], 1), u_now), np.full((Z.shape[0], 1), u_next - u_now)],
                               axis=1)
        Xn = np.einsum("kij,kj->ki", E[:, :m, :], drive)
        return np.concatenate([Xn, Z[:, m:]], axis=1), E[:, :m, m]  # b = B0 + B1 = e12

    def observe(self, Z: np.ndarray) -> np.ndarray:
        """``h(Z) = H(theta) X`` for a batch ``(K, m + d)`` -> ``(K, p)``."""
        return np.einsum("kpm,km->kp", self._H(self._safe(Z[:, self.m :])), Z[:, : self.m])

    def process_covariance(self, b: np.ndarray) -> np.ndarray:
        """``Q_aug``: ``s_w^2 b b^T`` on the state block, ``s_theta^2 I`` on theta."""
        size = self.m + self.d
        Q = np.zeros((size, size))
        Q[: self.m, : self.m] = self.process_noise_std**2 * np.outer(b, b)
        Q[self.m :, self.m :] = self.theta_walk_std**2 * np.eye(self.d)
        return Q

    def linearise(self, z: np.ndarray, u_now: float, u_next: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``f(z)``, ``F = df/dZ``, ``b`` at one augmented state ``z (m + d,)``: one
        exponential with its derivatives along every ``theta_j`` (module docstring)."""
        m, d = self.m, self.d
        theta = self._safe(z[m:])
        E, dE = expm_and_derivatives(self._phi(theta[None, :])[0], self._directions)
        drive = np.concatenate([z[:m], [u_now, u_next - u_now]])
        Xn = E[:m] @ drive
        F = np.eye(m + d)
        F[:m, :m] = E[:m, :m]
        F[:m, m:] = (dE[:, :m] @ drive).T * (z[m:] > self.theta_floor)  # d X' / d theta_j; clamped: 0
        return np.concatenate([Xn, z[m:]]), F, E[:m, m]

    def observation_jacobian(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``h(z)`` and ``Hz = dh/dZ`` (exact: ``H`` is affine in theta)."""
        m, d = self.m, self.d
        H = self._H(self._safe(z[m:])[None, :])[0]
        J = np.empty((H.shape[0], m + d))
        J[:, :m] = H
        J[:, m:] = (self._H_slopes @ z[:m]).T * (z[m:] > self.theta_floor)
        return H @ z[:m], J


def joint_initial_state(model: AugmentedModel, theta0, theta0_var):
    """The joint state at rest: mean ``z = [0 (m,), theta0]`` and covariance ``P (m + d, m + d)``
    with ``theta0_var`` on the parameters' diagonal."""
    d, m = model.d, model.m
    theta0 = np.broadcast_to(np.asarray(theta0, float), (d,))
    var = np.broadcast_to(np.asarray(theta0_var, float), (d,))
    z = np.concatenate([np.zeros(m), theta0])
    P = np.zeros((m + d, m + d))
    P[m:, m:] = np.diag(var)
    return z, P


def check_joint_inputs(model: AugmentedModel, u, y):
    """``ground_acceleration (T,)`` and ``measurements (T, p)`` as finite float arrays of matching shapes."""
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    if u.ndim != 1 or not np.all(np.isfinite(u)):
        raise ValueError("ground_acceleration: expected a finite 1-D series")
    p = model.channels.n_channels if isinstance(model.channels, Sensors) else model.building.n_storeys
    if y.ndim != 2 or y.shape[0] != u.size or y.shape[1] != p:
        raise ValueError(f"measurements: expected shape ({u.size}, {p}), got {y.shape}")
    if not np.all(np.isfinite(y)):
        raise ValueError("measurements: contains NaN or inf")
    return u, y


def drift_moments(z, P, n):
    drift_op = np.eye(n) - np.eye(n, k=-1)
    drift = drift_op @ z[:n]
    drift_var = np.einsum("ij,jk,ik->i", drift_op, P[:n, :n], drift_op)
    return drift, np.sqrt(np.maximum(drift_var, 0))


def ekf(model: AugmentedModel, ground_acceleration: ArrayLike, measurements: ArrayLike, measurement_noise: ArrayLike,
        theta0: ArrayLike = 0.85, theta0_var: ArrayLike = 0.3**2 / 12) -> JointFilterResult:
    """Run the augmented-state EKF (Eqs. 2-5) from rest.

    Parameters
    ----------
    model : AugmentedModel
    ground_acceleration : (T,) array
    measurements : (T, p) array
    measurement_noise : (p,) stds or (p, p)
    theta0, theta0_var : float or (d,)
        Initial mean and variance of ``theta`` (default: those of U(0.7, 1)).
    """
    import time

    start = time.perf_counter()
    u, y = check_joint_inputs(model, ground_acceleration, measurements)
    m, d, n = model.m, model.d, model.n
    R = measurement_covariance(measurement_noise, y.shape[1])
    z, P = joint_initial_state(model, theta0, theta0_var)
    T = u.size
    th_mean, th_var = np.empty((T, d)), np.empty((T, d))
    x_mean, dr_mean, dr_std = np.empty((T, m)), np.empty((T, n)), np.empty((T, n))
    loglik = 0.0
    for k in range(T):  # loop over time only
        if k > 0:  # forecast (Eq. 3) with the linearised covariance
            z, F, b = model.linearise(z, u[k - 1], u[k])
            P = F @ P @ F.T + model.process_covariance(b)
        y_pred, J = model.observation_jacobian(z)
        S = J @ P @ J.T + R
        S = 0.5 * (S + S.T)
        innov = y[k] - y_pred
        gain = np.linalg.solve(S, J @ P).T  # Eq. 5
        sign, logdet = np.linalg.slogdet(S)
        loglik += -0.5 * (len(innov) * _LOG_2PI + logdet + innov @ np.linalg.solve(S, innov))
        z = z + gain @ innov
        IKH = np.eye(m + d) - gain @ J
        P = IKH @ P @ IKH.T + gain @ R @ gain.T  # Joseph form
        th_mean[k], th_var[k] = z[m:], np.diag(P)[m:]
        x_mean[k] = z[:m]
        dr_mean[k], dr_std[k] = drift_moments(z, P, n)
    return JointFilterResult(th_mean, th_var, x_mean, dr_mean, dr_std, float(loglik), P,
                             time.perf_counter() - start)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
