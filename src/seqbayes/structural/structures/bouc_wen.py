"""A shear building whose storeys follow the Bouc-Wen hysteretic law (the
nonlinear storey model behind Lin et al. 2024's case for an EnKF and a
surrogate of the state recursion), batched over stiffness ratios ``theta``
and ensemble members.

Model. Storey ``i`` (drift ``delta_i = x_i - x_{i-1}``, ``x_0 = 0``) carries
the restoring force::

    r_i = theta_i k_i^u (alpha_i delta_i + (1 - alpha_i) z_i)
    z_i' = A_i delta_i' - beta_i |delta_i'| |z_i|^(e - 1) z_i - gamma_i delta_i' |z_i|^e

(``z_i`` is the hysteretic displacement, ``e`` the exponent; for ``A = 1``
the storey yields at a drift of about ``(beta + gamma)^(-1/e)``). Damping is
the linear building's Rayleigh ``C = a0 M + a1 K(theta)`` with ``K`` the
elastic storey stiffness ``theta_i k_i^u``. Floor equations::

    M x'' + C x' + D^T r = -M 1 a_g,     D the drift operator (delta = D x)

State ``X = [x, x', z]`` (length ``3n``). Measured channels are linear in
``X``: floor absolute accelerations ``x'' + a_g = -M^-1 (C x' + D^T r)``
and drifts ``D x``. With ``alpha = 1`` the model is the linear
:class:`~seqbayes.structural.structures.ShearBuilding` (``z`` has no effect).

Two transitions over a sampling step ``dt`` (ground acceleration linear
between samples, first-order hold, as :func:`~seqbayes.structural.structures.discretise`;
process noise a constant extra ground acceleration over the step, as there):

* :class:`BoucWenRK4` (``integrator="rk4"``): classical 4th-order Runge-Kutta
  on the whole state with ``substeps`` sub-steps per sample -- the reference.
* :class:`BoucWenExponential` (``integrator="exponential"``): an exponential
  integrator. The linear part ``[x, x']`` with inputs ``w = [a_g, z]`` is
  discretised exactly (FOH in ``w``: ``s_{k+1} = A s_k + G0 w_k + G1 w_{k+1}``,
  one matrix exponential per ``theta``); ``z`` is advanced by RK4 on its own
  equation with the drift velocity linear in time between the step's ends
  (predictor: ``z`` held; corrector: the new ``z``). The matrices depend on
  ``theta`` only, so they can be interpolated over ``theta`` by a sparse grid
  (Lin et al. Eq. 18: the state recursion interpolated over the parameters)
  -- ``level`` -- or computed exactly per ``theta`` (``level=None``).
  Second order in ``dt`` in the hysteretic coupling; exact (to round-off)
  for ``alpha = 1``.

Both act on states of shape ``(N, m)`` or ensembles ``(N, M, m)`` with one
``theta`` per leading index (no loop over members).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...rng import as_generator
from .. import sparsegrid
from .shear_building import Sensors, ShearBuilding, batched_expm, check_dt, check_theta, sensor_rows

__all__ = ["BoucWenBuilding", "BoucWenModel", "BoucWenRK4", "BoucWenExponential", "bouc_wen_transition",
           "simulate_bouc_wen", "INTEGRATORS"]

INTEGRATORS = ("rk4", "exponential")


def _per_storey(value, n: int, name: str) -> np.ndarray:
    arr = np.broadcast_to(np.asarray(value, dtype=float), (n,)) if np.ndim(value) == 0 else np.asarray(value, float)
    if arr.shape != (n,):
        raise ValueError(f"{name}: expected a scalar or shape ({n},), got {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: must be finite")
    return arr.copy()


@dataclass(frozen=True)
class BoucWenBuilding:
    """An n-storey shear building with Bouc-Wen hysteretic storeys (module docstring).

    Parameters
    ----------
    linear : ShearBuilding
        Masses, elastic storey stiffnesses ``k^u`` and the Rayleigh damping.
    alpha : float or (n,)
        Post-yield to elastic stiffness ratio, in ``[0, 1]`` (1: linear).
    beta, gamma : float or (n,)
        Bouc-Wen shape parameters [m^-e]; ``beta + gamma > 0`` for a bounded ``z``.
    A : float or (n,)
        Bouc-Wen ``A`` (default 1: ``z`` has units of drift).
    exponent : float
        ``e >= 1`` (default 1).

    Examples
    --------
    >>> lin = ShearBuilding([1e3, 1e3], [1e6, 1e6])
    >>> bw = BoucWenBuilding.from_yield_drift(lin, 0.005, alpha=0.2)
    >>> bw.n_storeys, bw.state_dim
    (2, 6)
    >>> float(bw.beta[0] + bw.gamma[0]) * 0.005
    1.0
    """

    linear: ShearBuilding
    alpha: np.ndarray = 0.1
    beta: np.ndarray = 100.0
    gamma: np.ndarray = 100.0
    A: np.ndarray = 1.0
    exponent: float = 1.0
    drift_operator: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        if not isinstance(self.linear, ShearBuilding):
            raise TypeError(f"linear: expected a ShearBuilding, got {type(self.linear).__name__}")
        n = self.linear.n_storeys
        alpha = _per_storey(self.alpha, n, "alpha")
        if np.any(alpha < 0) or np.any(alpha > 1):
            raise ValueError(f"alpha: must be in [0, 1], got {alpha}")
        beta, gamma = _per_storey(self.beta, n, "beta"), _per_storey(self.gamma, n, "gamma")
        if np.any(beta + gamma <= 0):
            raise ValueError("beta, gamma: need beta + gamma > 0 (bounded hysteretic displacement)")
        A = _per_storey(self.A, n, "A")
        if np.any(A <= 0):
            raise ValueError(f"A: must be positive, got {A}")
        e = float(self.exponent)
        if not np.isfinite(e) or e < 1:
            raise ValueError(f"exponent: must be >= 1, got {self.exponent}")
        for name, value in (("alpha", alpha), ("beta", beta), ("gamma", gamma), ("A", A), ("exponent", e)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, "drift_operator", np.eye(n) - np.eye(n, k=-1))

    @classmethod
    def from_yield_drift(cls, linear: ShearBuilding, yield_drift, alpha=0.1, exponent: float = 1.0,
                         beta_fraction: float = 0.5) -> "BoucWenBuilding":
        """Bouc-Wen storeys that yield at ``yield_drift`` [m] (``A = 1``,
        ``beta + gamma = yield_drift^-e``, ``beta = beta_fraction (beta + gamma)``)."""
        n = linear.n_storeys
        uy = _per_storey(yield_drift, n, "yield_drift")
        if np.any(uy <= 0):
            raise ValueError(f"yield_drift: must be positive, got {uy}")
        total = uy ** (-float(exponent))
        return cls(linear, alpha, beta_fraction * total, (1 - beta_fraction) * total, 1.0, exponent)

    @property
    def n_storeys(self) -> int:
        return self.linear.n_storeys

    @property
    def state_dim(self) -> int:
        return 3 * self.linear.n_storeys

    def check_sampling(self, dt: float, theta=None) -> None:
        """As :meth:`ShearBuilding.check_sampling` (elastic modes)."""
        self.linear.check_sampling(dt, theta)

    # ---------------------------------------------------------------- dynamics
    def derivative(self, theta_b: np.ndarray, X: np.ndarray, ground_acceleration) -> np.ndarray:
        """``X'`` of states ``X (..., 3n)`` with stiffness ratios ``theta_b`` broadcastable
        to ``(..., n)`` and ground acceleration broadcastable to ``X.shape[:-1]``."""
        return self._derivative(self._coefficients(theta_b), X, ground_acceleration)

    def _coefficients(self, theta_b):
        k = np.asarray(theta_b, float) * self.linear.stiffnesses
        a1 = self.linear.rayleigh[1]
        return k * self.alpha, k * (1 - self.alpha), a1 * k

    def _derivative(self, coefficients, X, ground_acceleration):
        n = self.n_storeys
        k_elastic, k_hysteretic, k_damping = coefficients
        x, v, z = X[..., :n], X[..., n:2 * n], X[..., 2 * n:]
        out = np.empty_like(X)
        out[..., :n] = v
        drift = x.copy()
        drift[..., 1:] -= x[..., :-1]
        rate = v.copy()
        rate[..., 1:] -= v[..., :-1]
        storey = k_elastic * drift  # r_i + a1 k_i delta_i' (Rayleigh stiffness part)
        storey += k_hysteretic * z
        storey += k_damping * rate
        storey /= self.linear.masses
        acc = out[..., n:2 * n]
        np.negative(storey, out=acc)
        acc[..., :-1] += storey[..., 1:] * (self.linear.masses[1:] / self.linear.masses[:-1])  # -M^-1 D^T s
        acc -= self.linear.rayleigh[0] * v
        acc -= np.asarray(ground_acceleration)[..., None]
        out[..., 2 * n:] = self.z_rate(z, rate)
        return out

    def _component_major(self, theta_c, ndim: int) -> tuple:
        """Per-storey constants shaped ``(n, 1, ...)`` for states ``(3n, ...)`` of ``ndim`` axes,
        and the stiffness terms of ``theta_c (n, ...)``."""
        n = self.n_storeys
        col = (n,) + (1,) * (ndim - 1)
        k = theta_c * self.linear.stiffnesses.reshape(col)
        alpha = self.alpha.reshape(col)
        masses = self.linear.masses.reshape(col)
        return (k * alpha, k * (1 - alpha), self.linear.rayleigh[1] * k, masses, None, self.A.reshape(col),
                self.beta.reshape(col), self.gamma.reshape(col))

    def _derivative_cm(self, params, Xc, ground_acceleration):
        """:meth:`derivative` in the component-major layout ``Xc (3n, ...)``."""
        n = self.n_storeys
        k_elastic, k_hysteretic, k_damping, masses, _, A, beta, gamma = params
        x, v, z = Xc[:n], Xc[n:2 * n], Xc[2 * n:]
        out = np.empty_like(Xc)
        out[:n] = v
        drift = x.copy()
        drift[1:] -= x[:-1]
        rate = v.copy()
        rate[1:] -= v[:-1]
        storey = k_elastic * drift  # r_i + a1 k_i delta_i' (Rayleigh stiffness part)
        storey += k_hysteretic * z
        storey += k_damping * rate
        acc = out[n:2 * n]
        np.negative(storey, out=acc)
        acc[:-1] += storey[1:]  # -D^T s
        acc /= masses
        acc -= self.linear.rayleigh[0] * v
        acc -= ground_acceleration
        if self.exponent == 1.0:
            zr = out[2 * n:]
            np.multiply(A, rate, out=zr)
            zr -= beta * np.abs(rate) * z
            zr -= gamma * rate * np.abs(z)
        else:
            abs_z = np.abs(z)
            out[2 * n:] = (A * rate - beta * np.abs(rate) * abs_z ** (self.exponent - 1) * z
                           - gamma * rate * abs_z**self.exponent)
        return out

    def z_rate(self, z: np.ndarray, drift_rate: np.ndarray) -> np.ndarray:
        """Bouc-Wen ``z' (..., n)`` from ``z`` and the drift velocities."""
        if self.exponent == 1.0:  # beta |d'| z + gamma d' |z|
            out = self.A * drift_rate
            out -= self.beta * np.abs(drift_rate) * z
            out -= self.gamma * drift_rate * np.abs(z)
            return out
        abs_z = np.abs(z)
        abs_z_e = abs_z**self.exponent
        return (self.A * drift_rate - self.beta * np.abs(drift_rate) * abs_z ** (self.exponent - 1) * z
                - self.gamma * drift_rate * abs_z_e)

    def storey_forces(self, theta, X) -> np.ndarray:
        """Hysteretic restoring forces ``r (..., n)`` [N] (without damping) of states ``X (..., 3n)``."""
        n = self.n_storeys
        theta = np.asarray(theta, float)
        k = theta * self.linear.stiffnesses
        drift = np.diff(X[..., :n], axis=-1, prepend=0.0)
        return k * (self.alpha * drift + (1 - self.alpha) * X[..., 2 * n:])

    def observation_matrix(self, theta, channels="absolute_acceleration") -> np.ndarray:
        """``H (N, p, 3n)`` of the channels (linear in ``X = [x, x', z]``):
        ``"absolute_acceleration"``, ``"drift"`` or a :class:`Sensors` layout."""
        n = self.n_storeys
        theta = check_theta(theta, n)
        if isinstance(channels, Sensors):
            return sensor_rows(self.observation_matrix, theta, channels, n)
        D = self.drift_operator
        N = theta.shape[0]
        if channels == "drift":
            H = np.zeros((N, n, 3 * n))
            H[:, :, :n] = D
            return H
        if channels != "absolute_acceleration":
            raise ValueError(f"channels: expected 'absolute_acceleration', 'drift' or Sensors, got {channels!r}")
        a0, a1 = self.linear.rayleigh
        k = theta * self.linear.stiffnesses  # (N, n)
        minv = 1 / self.linear.masses
        DT = D.T
        H = np.empty((N, n, 3 * n))
        H[:, :, :n] = -minv[:, None] * (DT @ ((k * self.alpha)[:, :, None] * D))  # -M^-1 D^T diag(alpha k) D
        H[:, :, n:2 * n] = -a0 * np.eye(n) - minv[:, None] * (DT @ ((a1 * k)[:, :, None] * D))
        H[:, :, 2 * n:] = -minv[:, None] * (DT[None] * (k * (1 - self.alpha))[:, None, :])
        return H

    # ------------------------------------------------- linear part (exponential)
    def linear_part(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """Continuous ``A_c (N, 2n, 2n)``, ``B_c (N, 2n, 1 + n)`` of
        ``s' = A_c s + B_c [a_g, z]`` for ``s = [x, x']``."""
        n = self.n_storeys
        theta = check_theta(theta, n)
        N = theta.shape[0]
        C = self.linear.damping_matrix(theta)
        D = self.drift_operator
        minv = (1 / self.linear.masses)[None, :, None]
        k = theta * self.linear.stiffnesses
        Ac = np.zeros((N, 2 * n, 2 * n))
        Ac[:, :n, n:] = np.eye(n)
        Ac[:, n:, :n] = -minv * (D.T @ ((k * self.alpha)[:, :, None] * D))  # -M^-1 D^T diag(alpha k) D
        Ac[:, n:, n:] = -minv * C
        Bc = np.zeros((N, 2 * n, 1 + n))
        Bc[:, n:, 0] = -1.0
        Bc[:, n:, 1:] = -minv * (D.T[None] * (k * (1 - self.alpha))[:, None, :])
        return Ac, Bc

    def exponential_matrices(self, theta, dt: float) -> np.ndarray:
        """FOH matrices of the linear part, flattened ``(N, 2n*2n + 2 * 2n*(1+n))``:
        ``A``, ``G0``, ``G1`` of ``s_{k+1} = A s_k + G0 w_k + G1 w_{k+1}`` (one
        batched matrix exponential of the augmented matrix, as
        :func:`~seqbayes.structural.structures.discretise`)."""
        dt = check_dt(dt)
        Ac, Bc = self.linear_part(theta)
        N, s = Ac.shape[:2]
        q = Bc.shape[2]
        aug = np.zeros((N, s + 2 * q, s + 2 * q))
        aug[:, :s, :s] = Ac * dt
        aug[:, :s, s:s + q] = Bc * dt
        aug[:, s:s + q, s + q:] = np.eye(q)  # (1/dt) * dt
        E = batched_expm(aug)
        A = E[:, :s, :s]
        e12, e13 = E[:, :s, s:s + q], E[:, :s, s + q:]
        return np.concatenate([A.reshape(N, -1), (e12 - e13).reshape(N, -1), e13.reshape(N, -1)], axis=1)


@dataclass(frozen=True)
class BoucWenModel:
    """The Bouc-Wen transition of ``N`` parameter vectors over one sampling step:
    what the filters need (duck-typed with
    :class:`~seqbayes.structural.structures.DiscreteModel` for ``H``, ``dt`` and ``take``).

    Attributes
    ----------
    theta : (N, n) array
    H : (N, p, 3n) array
        Observation matrix (linear in the state).
    dt : float
    step : object
        The integrator (:class:`BoucWenRK4` or :class:`BoucWenExponential`)
        with ``propagate(theta, X, u_prev, u_now, eta)``.
    matrices : (N, K) array or None
        The exponential integrator's per-``theta`` matrices.
    """

    theta: np.ndarray
    H: np.ndarray
    dt: float
    step: object
    matrices: np.ndarray | None = None
    hold: str = "foh"

    @property
    def n_members(self) -> int:
        return self.H.shape[0]

    def propagate(self, X: np.ndarray, u_prev: float, u_now: float, eta: np.ndarray | None = None) -> np.ndarray:
        """Advance states ``X (N, m)`` or ensembles ``X (N, M, m)`` one step, with
        ground acceleration ``u_prev -> u_now`` (linear) plus a constant ``eta``
        (shape ``X.shape[:-1]``; the unmeasured input noise)."""
        return self.step.propagate(self, X, u_prev, u_now, eta)

    def take(self, index) -> "BoucWenModel":
        return BoucWenModel(self.theta[index], self.H[index], self.dt, self.step,
                            None if self.matrices is None else self.matrices[index])


class BoucWenRK4:
    """Reference transition: RK4 with ``substeps`` sub-steps per sampling step.

    Parameters
    ----------
    building : BoucWenBuilding
    dt : float
    substeps : int
        RK4 steps per sample (default 4; RK4 is stable for ``omega h < 2.8``).
    channels : str or Sensors
    """

    name = "rk4"

    def __init__(self, building: BoucWenBuilding, dt: float, substeps: int = 4,
                 channels="absolute_acceleration"):
        if not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise ValueError(f"substeps: expected an integer >= 1, got {substeps!r}")
        self.building, self.dt, self.substeps, self.channels = building, check_dt(dt), int(substeps), channels

    def __call__(self, theta) -> BoucWenModel:
        theta = check_theta(theta, self.building.n_storeys)
        return BoucWenModel(theta, self.building.observation_matrix(theta, self.channels), self.dt, self)

    def propagate(self, model: BoucWenModel, X, u_prev, u_now, eta=None):
        b = self.building
        # component-major layout (3n, N[, M]): every operation below is on contiguous
        # (N[, M]) blocks rather than on strided slices of the last axis
        Xc = np.ascontiguousarray(np.moveaxis(X, -1, 0))
        theta_c = model.theta.T if X.ndim == 2 else model.theta.T[:, :, None]
        params = b._component_major(theta_c, Xc.ndim)
        eta = 0.0 if eta is None else eta
        h = self.dt / self.substeps
        du = (u_now - u_prev) / self.substeps
        for j in range(self.substeps):  # loop over sub-steps only
            a_start = u_prev + j * du + eta
            k1 = b._derivative_cm(params, Xc, a_start)
            k2 = b._derivative_cm(params, Xc + 0.5 * h * k1, a_start + 0.5 * du)
            k3 = b._derivative_cm(params, Xc + 0.5 * h * k2, a_start + 0.5 * du)
            k4 = b._derivative_cm(params, Xc + h * k3, a_start + du)
            Xc = Xc + (h / 6) * (k1 + 2 * k2 + 2 * k3 + k4)
        return np.ascontiguousarray(np.moveaxis(Xc, 0, -1))


class BoucWenExponential:
    """Exponential-integrator transition (module docstring): exact FOH matrices of
    the linear part per ``theta`` (``level=None``, one matrix exponential of size
    ``4n + 2`` each) or interpolated over ``theta`` by a level-``level`` sparse grid
    on the box ``[lower, upper]``; ``z`` by RK4 with ``z_substeps`` sub-steps.
    """

    name = "exponential"

    def __init__(self, building: BoucWenBuilding, dt: float, level: int | None = None, lower=None, upper=None,
                 z_substeps: int = 1, channels="absolute_acceleration", basis: str = "modified",
                 substeps: int = 1, corrections: int = 0):
        self.building, self.dt, self.channels = building, check_dt(dt), channels
        if not isinstance(substeps, (int, np.integer)) or substeps < 1:
            raise ValueError(f"substeps: expected an integer >= 1, got {substeps!r}")
        if not isinstance(corrections, (int, np.integer)) or corrections < 0:
            raise ValueError(f"corrections: expected an integer >= 0, got {corrections!r}")
        self.substeps, self.corrections = int(substeps), int(corrections)
        h = self.dt / self.substeps
        self.level = level
        n = building.n_storeys
        self.z_substeps = int(z_substeps)
        if self.z_substeps < 1:
            raise ValueError(f"z_substeps: expected an integer >= 1, got {z_substeps!r}")
        self.interpolant = None
        if level is not None:
            if lower is None or upper is None:
                raise ValueError("lower, upper: the sparse grid needs the parameter box")
            lower = np.broadcast_to(np.asarray(lower, float), (n,)).copy()
            upper = np.broadcast_to(np.asarray(upper, float), (n,)).copy()
            building.check_sampling(dt, upper)
            self.interpolant = sparsegrid.interpolate(lambda t: building.exponential_matrices(t, h), n, level,
                                                      lower, upper, basis=basis)

    @property
    def n_points(self) -> int:
        return 0 if self.interpolant is None else self.interpolant.grid.n_points

    def matrices(self, theta) -> np.ndarray:
        if self.interpolant is None:
            return self.building.exponential_matrices(theta, self.dt / self.substeps)
        return self.interpolant(theta)

    def __call__(self, theta) -> BoucWenModel:
        theta = check_theta(theta, self.building.n_storeys)
        return BoucWenModel(theta, self.building.observation_matrix(theta, self.channels), self.dt, self,
                            self.matrices(theta))

    def unpack(self, flat):
        n = self.building.n_storeys
        s, q = 2 * n, 1 + n
        N = flat.shape[0]
        A = flat[:, : s * s].reshape(N, s, s)
        G0 = flat[:, s * s : s * s + s * q].reshape(N, s, q)
        G1 = flat[:, s * s + s * q :].reshape(N, s, q)
        return A, G0, G1

    def propagate(self, model: BoucWenModel, X, u_prev, u_now, eta=None):
        b = self.building
        n = b.n_storeys
        A, G0, G1 = self.unpack(model.matrices)
        ensemble = X.ndim == 3
        if ensemble:  # (N, M, m): matrices act on the last axis per leading index
            def lin(M_, V):
                return np.matmul(V, np.swapaxes(M_, 1, 2))
        else:
            def lin(M_, V):
                return np.einsum("nij,nj->ni", M_, V)
        eta = 0.0 if eta is None else np.asarray(eta)[..., None]
        shape = X.shape[:-1] + (1,)
        du = (u_now - u_prev) / self.substeps
        for j in range(self.substeps):  # loop over sub-steps only
            s_k, z_k = X[..., : 2 * n], X[..., 2 * n:]
            a_prev = np.broadcast_to(u_prev + j * du + eta, shape)
            a_now = np.broadcast_to(u_prev + (j + 1) * du + eta, shape)
            base = lin(A, s_k) + lin(G0, np.concatenate([a_prev, z_k], axis=-1))
            s_next = base + lin(G1, np.concatenate([a_now, z_k], axis=-1))  # predictor: z held
            rate_k = np.diff(s_k[..., n:], axis=-1, prepend=0.0)
            for _ in range(1 + self.corrections):
                z = self._advance_z(z_k, rate_k, np.diff(s_next[..., n:], axis=-1, prepend=0.0))
                s_next = base + lin(G1, np.concatenate([a_now, z], axis=-1))  # corrector
            X = np.concatenate([s_next, z], axis=-1)
        return X

    def _advance_z(self, z, rate_k, rate_next):
        """RK4 on ``z'`` over one sub-step, drift rate linear in time between its ends
        (in the component-major layout, contiguous per storey)."""
        b = self.building
        n = b.n_storeys
        col = (n,) + (1,) * (z.ndim - 1)
        A, beta, gamma = b.A.reshape(col), b.beta.reshape(col), b.gamma.reshape(col)

        def rate_of(zc, rc):
            if b.exponent == 1.0:
                out = A * rc
                out -= beta * np.abs(rc) * zc
                out -= gamma * rc * np.abs(zc)
                return out
            abs_z = np.abs(zc)
            return A * rc - beta * np.abs(rc) * abs_z ** (b.exponent - 1) * zc - gamma * rc * abs_z**b.exponent

        zc = np.ascontiguousarray(np.moveaxis(z, -1, 0))
        r_k = np.ascontiguousarray(np.moveaxis(rate_k, -1, 0))
        slope = np.ascontiguousarray(np.moveaxis(rate_next, -1, 0)) - r_k
        h = 1.0 / self.z_substeps
        dt = self.dt / self.substeps
        for j in range(self.z_substeps):  # loop over z sub-steps only (t in units of the sub-step)
            t0 = j * h
            r0, rm, r1 = r_k + t0 * slope, r_k + (t0 + 0.5 * h) * slope, r_k + (t0 + h) * slope
            k1 = rate_of(zc, r0)
            k2 = rate_of(zc + 0.5 * h * dt * k1, rm)
            k3 = rate_of(zc + 0.5 * h * dt * k2, rm)
            k4 = rate_of(zc + h * dt * k3, r1)
            zc = zc + (h * dt / 6) * (k1 + 2 * k2 + 2 * k3 + k4)
        return np.moveaxis(zc, 0, -1)


def bouc_wen_transition(building: BoucWenBuilding, dt: float, integrator: str = "exponential",
                        level: int | None = None, lower=None, upper=None, substeps: int = 4,
                        channels="absolute_acceleration"):
    """The transition of ``building`` at step ``dt``: :class:`BoucWenRK4` or
    :class:`BoucWenExponential` (exact matrices, or a sparse grid of ``level``),
    each with ``substeps`` sub-steps per sample (default 4: one sub-step is
    too coarse for the exponential integrator beyond yield; errors in
    docs/benchmarks.md, section surrogate)."""
    if integrator == "rk4":
        if level is not None:
            raise ValueError("level: the RK4 transition has no sparse grid (use integrator='exponential')")
        return BoucWenRK4(building, dt, substeps, channels)
    if integrator == "exponential":
        return BoucWenExponential(building, dt, level, lower, upper, channels=channels, substeps=substeps)
    raise ValueError(f"integrator: expected one of {INTEGRATORS}, got {integrator!r}")


def simulate_bouc_wen(transition, theta, ground_acceleration, process_noise_std: float = 0.0,
                      rng: int | np.random.Generator | None = None, return_states: bool = False):
    """Simulate ``N`` Bouc-Wen buildings (one per row of ``theta (N, n)``) from rest.

    Parameters
    ----------
    transition : BoucWenRK4 or BoucWenExponential
    theta : (N, n) or (n,) array
    ground_acceleration : (T,) array
    process_noise_std : float
        Std of an unmeasured white ground acceleration, constant over each step.
    rng : seed or Generator
        Used only when ``process_noise_std > 0``.
    return_states : bool

    Returns
    -------
    y : (N, T, p) array
        Channels ``H X_k``; with ``return_states`` also ``X (N, T, 3n)``.
    """
    u = np.asarray(ground_acceleration, dtype=float)
    if u.ndim != 1 or u.size < 2 or not np.all(np.isfinite(u)):
        raise ValueError(f"ground_acceleration: expected a finite 1-D series of length >= 2, got shape {u.shape}")
    if process_noise_std < 0:
        raise ValueError(f"process_noise_std: must be non-negative, got {process_noise_std}")
    model = transition(theta)
    N, m = model.H.shape[0], model.H.shape[2]
    T = u.size
    noise = as_generator(rng).standard_normal((T, N)) * process_noise_std if process_noise_std > 0 else None
    states = np.empty((T, N, m))
    X = np.zeros((N, m))
    for k in range(T):  # loop over time only
        states[k] = X
        if k + 1 < T:
            X = model.propagate(X, u[k], u[k + 1], None if noise is None else noise[k])
    states = np.swapaxes(states, 0, 1)
    y = np.einsum("npm,ntm->ntp", model.H, states)
    return (y, states) if return_states else y
