"""An n-storey shear building: matrices, modes, state space and its exact
discretisation, batched over many stiffness-ratio vectors ``theta``.

Model (Lin et al. 2024, Eq. 1 and Eq. 11)::

    M x'' + C(theta) x' + K(theta) x = -M 1 a_g(t)

with ``x`` the floor displacements relative to the ground, storey stiffness
``k_i = theta_i k_i^u`` and Rayleigh damping ``C = a0 M + a1 K(theta)``. The
Rayleigh coefficients are fixed from the *undamaged* structure (``theta = 1``)
so that the damping coefficients are a property of the specimen and ``C`` is
affine in ``theta`` (the usual convention when stiffness degrades).

State ``X = [x, x']`` (length ``2n``)::

    X' = A_c(theta) X + b_c a_g,   A_c = [[0, I], [-M^-1 K, -M^-1 C]],  b_c = [0, -1]

Measured channels (rows of ``H``):

* ``"absolute_acceleration"``: ``x'' + 1 a_g = -M^-1 (K x + C x')`` -- linear in
  ``X`` with no feed-through, the accelerometer reading;
* ``"drift"``: inter-storey drifts ``x_i - x_{i-1}``.

Discretisation at step ``dt`` is exact for the stated input hold: zero-order
hold (input constant over a step) or first-order hold (input linear between
samples, the default). With FOH::

    X_{k+1} = A_d X_k + G0 u_k + G1 u_{k+1}

computed from one matrix exponential of an augmented matrix (``u`` is the
ground acceleration). Units are SI (kg, N/m, s, m/s^2).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...rng import as_generator

__all__ = [
    "ShearBuilding",
    "DiscreteModel",
    "discretise",
    "simulate",
    "add_measurement_noise",
    "HOLDS",
    "batched_expm",
    "expm_and_derivatives",
    "CHANNELS",
    "Sensors",
]

HOLDS = ("foh", "zoh")
CHANNELS = ("absolute_acceleration", "drift")


@dataclass(frozen=True)
class Sensors:
    """Sensor layout: which floors carry an accelerometer and which storeys a
    drift sensor (1-based, bottom to top). Accepted wherever ``channels`` is (in
    place of ``"absolute_acceleration"``, every floor, or ``"drift"``, every
    storey); the observation matrix has the acceleration rows first, in the
    order given, then the drift rows.

    Examples
    --------
    >>> b = ShearBuilding([1e3, 1e3, 1e3], [1e6, 1e6, 1e6])
    >>> b.observation_matrix([1.0, 1.0, 1.0], Sensors(accelerations=(1, 3), drifts=(2,))).shape
    (1, 3, 6)
    """

    accelerations: tuple = ()
    drifts: tuple = ()

    def __post_init__(self):
        for name in ("accelerations", "drifts"):
            values = tuple(int(v) for v in np.atleast_1d(getattr(self, name)))
            if any(v < 1 for v in values) or len(set(values)) != len(values):
                raise ValueError(f"{name}: expected distinct 1-based floor numbers, got {getattr(self, name)}")
            object.__setattr__(self, name, values)
        if not self.accelerations and not self.drifts:
            raise ValueError("accelerations, drifts: a layout needs at least one sensor")

    @property
    def n_channels(self) -> int:
        return len(self.accelerations) + len(self.drifts)

    def check(self, n_storeys: int) -> None:
        """Raise if a sensor sits above the top floor."""
        top = max(self.accelerations + self.drifts)
        if top > n_storeys:
            raise ValueError(f"sensors: floor {top} does not exist in a {n_storeys}-storey building")


def check_theta(theta, n: int, name: str = "theta") -> np.ndarray:
    """Stiffness ratios ``theta`` as a validated ``(N, n)`` float array; a single vector ``(n,)``
    becomes ``(1, n)`` (``ValueError`` naming ``name`` for a wrong shape, NaN/inf or a ratio <= 0)."""
    theta = np.asarray(theta, dtype=float)
    if theta.ndim == 1:
        theta = theta[None, :]
    if theta.ndim != 2 or theta.shape[1] != n:
        raise ValueError(f"{name}: expected shape (N, {n}) or ({n},), got {theta.shape}")
    if not np.all(np.isfinite(theta)):
        raise ValueError(f"{name}: contains NaN or inf")
    if np.any(theta <= 0):
        raise ValueError(f"{name}: stiffness ratios must be positive (a non-positive storey stiffness)")
    return theta


@dataclass(frozen=True)
class DiscreteModel:
    """Discrete-time matrices for a batch of ``N`` parameter vectors.

    ``X_{k+1} = A X_k + B0 u_k + B1 u_{k+1} (+ w_k)``, ``y_k = H X_k (+ v_k)``.

    Attributes
    ----------
    A : (N, m, m) array
    B0, B1 : (N, m) arrays
        Input columns for ``u_k`` and ``u_{k+1}`` (``B1 = 0`` under ZOH).
    H : (N, p, m) array
        Observation matrix of the measured channels.
    dt : float
    hold : str
    """

    A: np.ndarray
    B0: np.ndarray
    B1: np.ndarray
    H: np.ndarray
    dt: float
    hold: str

    @property
    def n_members(self) -> int:
        return self.A.shape[0]

    def pack(self) -> np.ndarray:
        """All matrices flattened to ``(N, m*m + 2m + p*m)`` (for interpolation)."""
        n = self.A.shape[0]
        return np.concatenate(
            [self.A.reshape(n, -1), self.B0, self.B1, self.H.reshape(n, -1)], axis=1
        )

    @staticmethod
    def unpack(flat: np.ndarray, m: int, p: int, dt: float, hold: str) -> "DiscreteModel":
        """Inverse of :meth:`pack` for a state size ``m`` and ``p`` channels."""
        flat = np.asarray(flat, dtype=float)
        n = flat.shape[0]
        i = m * m
        A = flat[:, :i].reshape(n, m, m)
        B0 = flat[:, i : i + m]
        B1 = flat[:, i + m : i + 2 * m]
        H = flat[:, i + 2 * m : i + 2 * m + p * m].reshape(n, p, m)
        return DiscreteModel(A, B0, B1, H, float(dt), hold)

    def take(self, index: ArrayLike) -> "DiscreteModel":
        """The members ``index`` (fancy indexing on the batch axis)."""
        return DiscreteModel(self.A[index], self.B0[index], self.B1[index], self.H[index],
                             self.dt, self.hold)


def sensor_rows(observation_matrix, theta: np.ndarray, sensors: "Sensors", n_storeys: int) -> np.ndarray:
    """``H (N, p, .)`` of a :class:`Sensors` layout: the rows of ``observation_matrix(theta, kind)``
    (every floor's ``"absolute_acceleration"``, every storey's ``"drift"``) at its floors, the
    accelerations first (shared by the linear and the Bouc-Wen building)."""
    sensors.check(n_storeys)
    rows = []
    if sensors.accelerations:
        rows.append(observation_matrix(theta, "absolute_acceleration")[:, [f - 1 for f in sensors.accelerations]])
    if sensors.drifts:
        rows.append(observation_matrix(theta, "drift")[:, [f - 1 for f in sensors.drifts]])
    return np.concatenate(rows, axis=1)


@dataclass(frozen=True)
class ShearBuilding:
    """An n-storey shear building with storey stiffness ``theta_i * k_i^u``.

    Parameters
    ----------
    masses : (n,) array_like
        Floor masses [kg], bottom to top; all positive.
    stiffnesses : (n,) array_like
        Undamaged storey stiffnesses ``k^u`` [N/m]; all positive.
    damping_ratios : (2,) tuple
        Modal damping ratios of the two modes that fix the Rayleigh coefficients.
    damping_modes : (2,) tuple of int
        The (1-based) modes that carry ``damping_ratios`` (default 1 and 2).

    Examples
    --------
    >>> b = ShearBuilding([1e3, 1e3], [1e6, 1e6])
    >>> b.n_storeys
    2
    >>> b.stiffness_matrix([1.0, 1.0])[0] / 1e6
    array([[ 2., -1.],
           [-1.,  1.]])
    """

    masses: np.ndarray
    stiffnesses: np.ndarray
    damping_ratios: tuple = (0.05, 0.05)
    damping_modes: tuple = (1, 2)
    rayleigh: tuple = field(init=False, repr=False)

    def __post_init__(self):
        masses = np.asarray(self.masses, dtype=float).reshape(-1)
        stiffnesses = np.asarray(self.stiffnesses, dtype=float).reshape(-1)
        if masses.size == 0:
            raise ValueError("masses: at least one storey is needed")
        if stiffnesses.shape != masses.shape:
            raise ValueError(
                f"stiffnesses: expected shape {masses.shape} (one per storey), got {stiffnesses.shape}")
        if not np.all(np.isfinite(masses)) or np.any(masses <= 0):
            raise ValueError(f"masses: must be finite and positive, got {masses}")
        if not np.all(np.isfinite(stiffnesses)) or np.any(stiffnesses <= 0):
            raise ValueError(f"stiffnesses: must be finite and positive, got {stiffnesses}")
        ratios = tuple(float(z) for z in self.damping_ratios)
        modes = tuple(int(j) for j in self.damping_modes)
        if len(ratios) != 2 or any(not (0 <= z < 1) for z in ratios):
            raise ValueError(f"damping_ratios: expected two ratios in [0, 1), got {self.damping_ratios}")
        n = masses.size
        if len(modes) != 2 or any(not (1 <= j <= n) for j in modes) or (n > 1 and modes[0] == modes[1]):
            if not (n == 1 and modes[0] == 1):
                raise ValueError(f"damping_modes: expected two distinct modes in 1..{n}, got {self.damping_modes}")
        object.__setattr__(self, "masses", masses)
        object.__setattr__(self, "stiffnesses", stiffnesses)
        object.__setattr__(self, "damping_ratios", ratios)
        object.__setattr__(self, "damping_modes", modes)
        object.__setattr__(self, "rayleigh", self._rayleigh_coefficients())

    # ------------------------------------------------------------------ matrices
    @property
    def n_storeys(self) -> int:
        return self.masses.size

    @property
    def state_dim(self) -> int:
        return 2 * self.masses.size

    def mass_matrix(self) -> np.ndarray:
        """``M``, shape ``(n, n)`` (lumped, diagonal)."""
        return np.diag(self.masses)

    def stiffness_matrix(self, theta: ArrayLike) -> np.ndarray:
        """``K(theta)`` for a batch, shape ``(N, n, n)`` (tridiagonal)."""
        n = self.n_storeys
        theta = check_theta(theta, n)
        k = theta * self.stiffnesses  # (N, n) storey stiffnesses k_i = theta_i k_i^u
        K = np.zeros((theta.shape[0], n, n))
        idx = np.arange(n)
        K[:, idx, idx] = k
        K[:, idx[:-1], idx[:-1]] += k[:, 1:]
        K[:, idx[:-1], idx[1:]] = -k[:, 1:]
        K[:, idx[1:], idx[:-1]] = -k[:, 1:]
        return K

    def _rayleigh_coefficients(self) -> tuple:
        """``(a0, a1)`` from ``zeta_r = a0 / (2 w_r) + a1 w_r / 2`` on the two modes at theta = 1."""
        w = 2 * np.pi * self.modes(np.ones(self.n_storeys))[0][0]
        if self.n_storeys == 1:
            z = self.damping_ratios[0]
            return (0.0, 2 * z / w[0])
        i, j = (m - 1 for m in self.damping_modes)
        design = np.array([[1 / (2 * w[i]), w[i] / 2], [1 / (2 * w[j]), w[j] / 2]])
        a0, a1 = np.linalg.solve(design, np.array(self.damping_ratios))
        return (float(a0), float(a1))

    def damping_matrix(self, theta: ArrayLike) -> np.ndarray:
        """Rayleigh ``C = a0 M + a1 K(theta)``, shape ``(N, n, n)``."""
        a0, a1 = self.rayleigh
        return a0 * self.mass_matrix()[None] + a1 * self.stiffness_matrix(theta)

    def modes(self, theta: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Natural frequencies [Hz] ``(N, n)`` ascending and mass-normalised shapes ``(N, n, n)``.

        Solves ``K phi = w^2 M phi`` through the symmetric ``M^-1/2 K M^-1/2``.
        """
        K = self.stiffness_matrix(theta)
        s = 1 / np.sqrt(self.masses)
        w2, v = np.linalg.eigh(s[None, :, None] * K * s[None, None, :])
        return np.sqrt(np.clip(w2, 0, None)) / (2 * np.pi), s[None, :, None] * v

    def modal_damping_ratios(self, theta: ArrayLike) -> np.ndarray:
        """Damping ratio of every mode, ``(N, n)``: ``a0 / (2 w) + a1 w / 2``."""
        a0, a1 = self.rayleigh
        w = 2 * np.pi * self.modes(theta)[0]
        return a0 / (2 * w) + a1 * w / 2

    def continuous_state_space(self, theta: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """``A_c (N, 2n, 2n)`` and ``b_c (2n,)`` of ``X' = A_c X + b_c a_g`` (Eq. 11)."""
        n = self.n_storeys
        K = self.stiffness_matrix(theta)
        C = self.damping_matrix(theta)
        minv = (1 / self.masses)[None, :, None]
        A = np.zeros((K.shape[0], 2 * n, 2 * n))
        A[:, :n, n:] = np.eye(n)
        A[:, n:, :n] = -minv * K
        A[:, n:, n:] = -minv * C
        b = np.concatenate([np.zeros(n), -np.ones(n)])
        return A, b

    def observation_matrix(self, theta: ArrayLike, channels: str = "absolute_acceleration") -> np.ndarray:
        """``H (N, p, 2n)`` of the measured channels (see module docstring):
        ``"absolute_acceleration"`` (every floor), ``"drift"`` (every storey) or a
        :class:`Sensors` layout (some floors)."""
        n = self.n_storeys
        theta = check_theta(theta, n)
        if isinstance(channels, Sensors):
            return sensor_rows(self.observation_matrix, theta, channels, n)
        if channels == "absolute_acceleration":
            A, _ = self.continuous_state_space(theta)
            return A[:, n:, :].copy()  # x'' + a_g = -M^-1 (K x + C x')
        if channels == "drift":
            D = np.eye(n) - np.eye(n, k=-1)
            H = np.zeros((theta.shape[0], n, 2 * n))
            H[:, :, :n] = D
            return H
        raise ValueError(f"channels: expected one of {CHANNELS}, got {channels!r}")

    def check_sampling(self, dt: float, theta: ArrayLike | None = None) -> None:
        """Raise if ``dt`` is too coarse for the highest mode (above Nyquist).

        The highest natural frequency (at ``theta``, default 1) must be below
        ``0.5 / dt``; otherwise the discrete response aliases.
        """
        dt = check_dt(dt)
        theta = np.ones(self.n_storeys) if theta is None else theta
        f_max = float(np.max(self.modes(theta)[0]))
        if f_max >= 0.5 / dt:
            raise ValueError(
                f"dt: sampling step {dt} s is too coarse for the highest mode ({f_max:.2f} Hz >= "
                f"Nyquist {0.5 / dt:.2f} Hz)")


def batched_expm(M: np.ndarray) -> np.ndarray:
    """Matrix exponential of a batch ``(N, m, m)`` by scaling and squaring with a
    degree-18 Taylor polynomial, fully vectorised (for the small, moderately
    normed matrices of a discretisation; agrees with :func:`scipy.linalg.expm`
    to round-off, checked in the tests)."""
    M = np.asarray(M, dtype=float)
    norm = np.abs(M).sum(axis=-2).max(axis=-1).max(initial=0.0)  # largest 1-norm in the batch
    s = int(max(0, np.ceil(np.log2(norm / 0.25)))) if norm > 0 else 0
    X = M / 2.0**s
    eye = np.broadcast_to(np.eye(M.shape[-1]), M.shape)
    result = eye.copy()
    for j in range(18, 0, -1):  # Horner: I + X/1 (I + X/2 (I + ...))
        result = eye + (X @ result) / j
    for _ in range(s):
        result = result @ result
    return result


def expm_and_derivatives(M: np.ndarray, directions: np.ndarray, degree: int = 14):
    """``expm(M)`` and its Frechet derivatives ``L(M, E_j)`` along ``directions (d, m, m)``.

    Scaling and squaring of a degree-``degree`` Taylor polynomial (norm scaled
    to <= 0.25, truncation error ~1e-20), differentiated term by term (Horner:
    ``dR <- (E R + M dR) / j``) and squared blockwise (``d(P^2) = P dP + dP P``):
    the first block row of ``expm([[M, E], [0, M]])`` (Van Loan 1978) at
    ``(1 + 2d) m^3`` flops per product instead of ``((d + 1) m)^3``.

    Returns
    -------
    expm : (m, m) array
    derivatives : (d, m, m) array

    Examples
    --------
    >>> E, L = expm_and_derivatives(np.array([[0.5]]), np.array([[[1.0]]]))
    >>> bool(np.isclose(E[0, 0], np.exp(0.5)) and np.isclose(L[0, 0, 0], np.exp(0.5)))
    True
    """
    M = np.asarray(M, dtype=float)
    directions = np.asarray(directions, dtype=float)
    norm = np.abs(M).sum(axis=0).max() + np.abs(directions).sum(axis=-2).max(initial=0.0)
    s = int(max(0, np.ceil(np.log2(norm / 0.25)))) if norm > 0 else 0
    X, E = M / 2.0**s, directions / 2.0**s
    eye = np.eye(M.shape[0])
    R, dR = eye.copy(), np.zeros_like(E)
    for j in range(degree, 0, -1):  # Horner for the polynomial and its derivative
        dR = (E @ R + X @ dR) / j
        R = eye + (X @ R) / j
    for _ in range(s):
        dR = R @ dR + dR @ R
        R = R @ R
    return R, dR


def check_dt(dt) -> float:
    """The sampling step ``dt`` as a positive finite float (``TypeError`` / ``ValueError`` otherwise)."""
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise TypeError(f"dt: expected a number, got {type(dt).__name__}") from None
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt: must be positive and finite, got {dt}")
    return dt


def discretise(building: ShearBuilding, theta: ArrayLike, dt: float, hold: str = "foh",
               channels: str = "absolute_acceleration") -> DiscreteModel:
    """Exact discretisation at step ``dt`` for a batch of ``theta``.

    Parameters
    ----------
    building : ShearBuilding
    theta : (N, n) or (n,) array
        Stiffness ratios.
    dt : float
        Sampling step [s]; must resolve the highest mode (below Nyquist).
    hold : {"foh", "zoh"}
        Input interpolation between samples.
    channels : {"absolute_acceleration", "drift"} or Sensors
        Every floor's acceleration, every storey's drift, or a sensor layout.

    Returns
    -------
    DiscreteModel
        Batched matrices; ``B1`` is zero for ZOH.

    Notes
    -----
    One batched :func:`scipy.linalg.expm` of the augmented matrix
    ``[[A_c, b_c, 0], [0, 0, 1/dt], [0, 0, 0]] * dt`` gives ``A_d`` (block 11),
    ``E12`` and ``E13``; then ``B0 = E12 - E13`` and ``B1 = E13`` (FOH), or
    ``B0 = E12`` (ZOH).
    """
    dt = check_dt(dt)
    if hold not in HOLDS:
        raise ValueError(f"hold: expected one of {HOLDS}, got {hold!r}")
    theta = check_theta(theta, building.n_storeys)
    building.check_sampling(dt, theta)
    A_c, b_c = building.continuous_state_space(theta)
    N, m = theta.shape[0], A_c.shape[1]
    aug = np.zeros((N, m + 2, m + 2))
    aug[:, :m, :m] = A_c * dt
    aug[:, :m, m] = b_c * dt
    aug[:, m, m + 1] = 1.0  # (1/dt) * dt
    E = batched_expm(aug)
    A = E[:, :m, :m]
    e12, e13 = E[:, :m, m], E[:, :m, m + 1]
    if hold == "foh":
        B0, B1 = e12 - e13, e13
    else:
        B0, B1 = e12, np.zeros_like(e12)
    H = building.observation_matrix(theta, channels)
    return DiscreteModel(A, B0, B1, H, dt, hold)


def _as_ground_motion(ground_acceleration) -> np.ndarray:
    u = np.asarray(ground_acceleration, dtype=float)
    if u.ndim != 1 or u.size < 2:
        raise ValueError(f"ground_acceleration: expected a 1-D series of length >= 2, got shape {u.shape}")
    if not np.all(np.isfinite(u)):
        raise ValueError("ground_acceleration: contains NaN or inf")
    return u


def simulate(model: DiscreteModel, ground_acceleration: ArrayLike, x0: ArrayLike | None = None,
             process_noise_std: float = 0.0, rng: int | np.random.Generator | None = None,
             extra_observations: Sequence[str] = ()) -> np.ndarray | tuple:
    """Simulate a batch of discrete models driven by one ground motion.

    Parameters
    ----------
    model : DiscreteModel
        ``N`` members (e.g. from :func:`discretise` at ``N`` thetas).
    ground_acceleration : (T,) array
        Ground acceleration [m/s^2] at the model's step; ``u_0`` is the first sample.
    x0 : (N, m) or (m,) array, optional
        Initial state (default at rest).
    process_noise_std : float
        Standard deviation of an unmeasured white-noise ground acceleration
        added to the input at each step (enters through ``B0 + B1``);
        0 for a deterministic response.
    rng : seed or Generator
        Only used when ``process_noise_std > 0``.
    extra_observations : sequence of (N, q, m) arrays
        Further observation matrices evaluated on the same states.

    Returns
    -------
    y : (N, T, p) array
        The channels ``H X_k`` for ``k = 0 .. T-1``; or a tuple
        ``(y, X, *extra)`` with states ``X (N, T, m)`` when extra observations
        are requested.
    """
    u = _as_ground_motion(ground_acceleration)
    T = u.size
    N, m = model.A.shape[0], model.A.shape[1]
    X = np.zeros((N, m)) if x0 is None else np.broadcast_to(np.asarray(x0, float), (N, m)).copy()
    if process_noise_std < 0:
        raise ValueError(f"process_noise_std: must be non-negative, got {process_noise_std}")
    noise = None
    if process_noise_std > 0:
        noise = as_generator(rng).standard_normal((T, N)) * process_noise_std
    b = model.B0 + model.B1
    states = np.empty((T, N, m))
    At = np.swapaxes(model.A, 1, 2)
    for k in range(T):  # loop over time only; all members at once
        states[k] = X
        if k + 1 < T:
            X = np.einsum("nj,nji->ni", X, At) + model.B0 * u[k] + model.B1 * u[k + 1]
            if noise is not None:
                X += b * noise[k][:, None]
    states = np.swapaxes(states, 0, 1)  # (N, T, m)
    y = np.einsum("npm,ntm->ntp", model.H, states)
    if not extra_observations:
        return y
    extras = [np.einsum("npm,ntm->ntp", np.broadcast_to(H, (N,) + np.shape(H)[-2:]), states)
              for H in extra_observations]
    return (y, states, *extras)


def add_measurement_noise(y: ArrayLike, fraction: float, rng: int | np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Add white noise with std ``fraction * RMS`` of each channel.

    Parameters
    ----------
    y : (T, p) array
        Clean channels.
    fraction : float
        Noise level relative to each channel's RMS (0.05 for 5 %).
    rng : seed or Generator

    Returns
    -------
    noisy : (T, p) array
    noise_std : (p,) array
        The per-channel noise standard deviations used.
    """
    y = np.asarray(y, dtype=float)
    if y.ndim != 2:
        raise ValueError(f"y: expected shape (T, p), got {y.shape}")
    if not np.isfinite(fraction) or fraction < 0:
        raise ValueError(f"fraction: must be non-negative, got {fraction}")
    std = fraction * np.sqrt(np.mean(y**2, axis=0))
    noisy = y + as_generator(rng).standard_normal(y.shape) * std
    return noisy, std

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Sequence
    from numpy.typing import ArrayLike
