"""Simulated ambient records with known modes: a shear building's floors, or any modal model at named channels.

- :func:`ambient_record`: a (planar) shear building under white-noise ground acceleration, every floor
  measured (the record of the simulated years, docs/oma.md).
- :class:`ModalModel` and :func:`building_3d`: a 3-D shear building (rigid floors with two
  translations and a rotation; principal axes at an angle to the sensors, so that bending modes mix
  in every channel) seen at channels that name a floor, a plan position and a direction. Two
  bending directions of nearly equal stiffness give close modes with different shapes.
- :func:`modal_record`: the exact sampled response of a :class:`ModalModel`: each mode a
  single-degree-of-freedom oscillator (exact zero-order-hold discretisation, one ``lfilter`` per
  mode) driven by the modal projection of independent floor forces (white, or low-passed like
  wind), the accelerations summed at the channels, plus white measurement noise. The poles of the
  simulated process are exactly ``exp(lambda dt)`` of the model's modes, so its frequencies and
  damping ratios are the truth the identification is scored against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import linalg, signal

from ...rng import as_generator
from ..structures.shear_building import ShearBuilding, add_measurement_noise, check_dt, discretise, simulate

__all__ = ["ambient_record", "ModalModel", "building_3d", "modal_record"]


def ambient_record(building: ShearBuilding, theta: ArrayLike, duration: float, dt: float,
                   noise_fraction: float = 0.05, rng: int | np.random.Generator | None = None) -> np.ndarray:
    """A simulated ambient-vibration record: every floor's absolute acceleration under white-noise
    ground acceleration (unit variance per step, through the exact discretisation), plus white
    measurement noise of ``noise_fraction`` times each channel's RMS.

    Parameters
    ----------
    building : ShearBuilding
    theta : (n,) array
        Stiffness ratios of the record.
    duration : float
        Record length [s].
    dt : float
        Sampling step [s] (below the highest mode's Nyquist limit).
    noise_fraction : float
        Measurement noise relative to each channel's RMS.
    rng : seed or Generator

    Returns
    -------
    (T, n) array, ``T = round(duration / dt)``.
    """
    rng = as_generator(rng)
    dt = check_dt(dt)
    if not np.isfinite(duration) or duration < 10 * dt:
        raise ValueError(f"duration: expected at least 10 sampling steps ({10 * dt} s), got {duration}")
    theta = np.asarray(theta, dtype=float).reshape(1, -1)
    model = discretise(building, theta, dt)
    steps = int(round(duration / dt))
    clean = simulate(model, np.zeros(steps), process_noise_std=1.0, rng=rng)[0]
    return add_measurement_noise(clean, noise_fraction, rng)[0]


@dataclass(frozen=True)
class ModalModel:
    """Modes seen at named channels (mass-normalised, classically damped).

    Attributes
    ----------
    frequencies : (K,) array
        Natural frequencies [Hz], ascending.
    damping_ratios : (K,) array
    shapes : (p, K) array
        Each mode's displacement at the channels.
    forcing : (d, K) array
        The modal force of each mode per unit force at each of ``d`` loaded degrees of freedom
        (``Phi^T`` of the mass-normalised shapes).
    channels : tuple of str
    """

    frequencies: np.ndarray
    damping_ratios: np.ndarray
    shapes: np.ndarray
    forcing: np.ndarray
    channels: tuple

    def select(self, channels) -> "ModalModel":
        """The same modes seen at a subset of the channels (by name)."""
        index = [self.channels.index(c) for c in channels]
        return ModalModel(self.frequencies, self.damping_ratios, self.shapes[index], self.forcing, tuple(channels))


#: Plan position of each sensor corner, in half the plan's sides.
CORNERS = {"A": (1.0, 1.0), "B": (-1.0, 1.0), "C": (-1.0, -1.0), "D": (1.0, -1.0)}


def _storeys(k: np.ndarray) -> np.ndarray:
    """The stiffness matrix of a chain of storey springs ``k (n,)`` (storey 1 to the ground)."""
    n = k.size
    K = np.diag(k + np.append(k[1:], 0.0))
    K -= np.diag(k[1:], 1) + np.diag(k[1:], -1)
    return K


def building_3d(n_floors: int, first_frequencies=(1.23, 1.29, 1.45), damping=0.015, angle_deg: float = 30.0,
                plan=(20.0, 20.0), max_frequency: float | None = None, sensors=None) -> ModalModel:
    """A 3-D shear building with uniform floors and storeys, tuned to given first frequencies.

    Parameters
    ----------
    n_floors : int
    first_frequencies : (3,) floats
        First bending frequency along each principal axis and first torsional frequency [Hz].
    damping : float or (K,) array
        Modal damping ratio(s).
    angle_deg : float
        Angle of the principal axes to the sensors' X and Y [degrees].
    plan : (float, float)
        Floor plan size [m]; sensors sit at its corners.
    max_frequency : float, optional
        Keep the modes below this frequency [Hz] (a truncated modal model).
    sensors : list of (floor, corner, direction), optional
        ``floor`` 1..n, ``corner`` "A" (``+x/2, +y/2``), "B" (``-x/2, +y/2``), "C" (``-x/2, -y/2``) or "D"
        (``+x/2, -y/2``), ``direction`` "X" or
        "Y"; default two channels (X, Y) at corner A of every floor, top floor first. Channel names are
        ``"{floor}{corner}{direction}"``, e.g. ``"15AX"``.

    Returns
    -------
    ModalModel
    """
    n = int(n_floors)
    if n < 1:
        raise ValueError(f"n_floors: expected at least 1, got {n_floors}")
    fx, fy, ft = (float(v) for v in first_frequencies)
    unit = linalg.eigh(_storeys(np.ones(n)), eigvals_only=True)[0]  # omega_1^2 of unit storeys and masses
    kx, ky, kt = ((2 * np.pi * f) ** 2 / unit for f in (fx, fy, ft))
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    chain = _storeys(np.ones(n))
    K = np.zeros((3 * n, 3 * n))
    K[:n, :n] = chain * (kx * c * c + ky * s * s)
    K[n:2 * n, n:2 * n] = chain * (kx * s * s + ky * c * c)
    K[:n, n:2 * n] = K[n:2 * n, :n] = chain * (kx - ky) * s * c
    K[2 * n:, 2 * n:] = chain * kt  # unit polar inertia per floor: kt sets the torsional frequencies
    omega2, phi = linalg.eigh(K)  # unit masses and inertias: M = I
    frequencies = np.sqrt(np.clip(omega2, 0, None)) / (2 * np.pi)
    keep = frequencies < (np.inf if max_frequency is None else float(max_frequency))
    frequencies, phi = frequencies[keep], phi[:, keep]
    half_x, half_y = plan[0] / 2, plan[1] / 2
    if sensors is None:
        sensors = [(floor, "A", d) for floor in range(n, 0, -1) for d in "XY"]
    rows, names = [], []
    for floor, corner, direction in sensors:
        if not 1 <= int(floor) <= n or corner not in CORNERS or direction not in ("X", "Y"):
            raise ValueError(f"sensors: expected (floor 1..{n}, a corner A-D, 'X' or 'Y'), got {(floor, corner, direction)}")
        px, py = CORNERS[corner][0] * half_x, CORNERS[corner][1] * half_y
        row = np.zeros(3 * n)
        i = int(floor) - 1
        if direction == "X":
            row[i], row[2 * n + i] = 1.0, -py / max(half_x, half_y)
        else:
            row[n + i], row[2 * n + i] = 1.0, px / max(half_x, half_y)
        rows.append(row)
        names.append(f"{floor}{corner}{direction}")
    shapes = np.array(rows) @ phi
    damping = np.broadcast_to(np.asarray(damping, dtype=float), frequencies.shape).copy()
    return ModalModel(frequencies, damping, shapes, phi, tuple(names))


def _mode_filter(frequency: float, damping: float, dt: float):
    """``(b, a)`` of the exact ZOH discretisation of ``q'' + 2 zeta w q' + w^2 q = u``, output ``q''``."""
    w = 2 * np.pi * frequency
    A = np.array([[0.0, 1.0], [-w * w, -2 * damping * w]])
    B = np.array([[0.0], [1.0]])
    Ad = linalg.expm(A * dt)
    Bd = np.linalg.solve(A, (Ad - np.eye(2)) @ B)
    C = np.array([[-w * w, -2 * damping * w]])
    b, a = signal.ss2tf(Ad, Bd, C, np.array([[1.0]]))
    return b[0], a


def modal_record(model: ModalModel, duration: float, dt: float, noise_fraction: float = 0.05,
                 rng: int | np.random.Generator | None = None, force_corner_hz: float | None = None,
                 noise: str = "channel") -> np.ndarray:
    """Accelerations at the model's channels under random floor forces, plus measurement noise.

    Parameters
    ----------
    model : ModalModel
    duration : float
        Record length [s].
    dt : float
        Sampling step [s]; every mode must lie below 0.8 of the Nyquist frequency.
    noise_fraction : float
        Measurement-noise standard deviation relative to each channel's RMS (``noise="channel"``) or to
        the largest channel RMS (``noise="floor"``: one sensor noise level for all channels).
    rng : seed or Generator
    force_corner_hz : float, optional
        Low-pass the forces above this frequency (first order, like wind); default white.
    noise : {"channel", "floor"}

    Returns
    -------
    (T, p) array, ``T = round(duration / dt)``.
    """
    rng = as_generator(rng)
    dt = check_dt(dt)
    if np.max(model.frequencies) >= 0.4 / dt:
        raise ValueError(f"dt: the model's highest mode {np.max(model.frequencies):.4g} Hz is above 0.8 of the Nyquist "
                         f"frequency {0.5 / dt:g} Hz; keep fewer modes (max_frequency) or sample faster")
    if noise not in ("channel", "floor"):
        raise ValueError(f"noise: expected 'channel' or 'floor', got {noise!r}")
    steps = int(round(duration / dt))
    burn = int(np.ceil(10.0 / (np.min(model.damping_ratios * model.frequencies) * 2 * np.pi * dt)))
    forces = rng.standard_normal((steps + burn, model.forcing.shape[0]))
    if force_corner_hz is not None:
        pole = np.exp(-2 * np.pi * float(force_corner_hz) * dt)
        forces = signal.lfilter([1 - pole], [1, -pole], forces, axis=0)
    modal_forces = forces @ model.forcing
    response = np.empty((steps, model.frequencies.size))
    for j, (f, z) in enumerate(zip(model.frequencies, model.damping_ratios)):
        b, a = _mode_filter(f, z, dt)
        response[:, j] = signal.lfilter(b, a, modal_forces[:, j])[burn:]
    clean = response @ model.shapes.T
    rms = np.sqrt(np.mean(clean**2, axis=0))
    scale = rms if noise == "channel" else np.full_like(rms, rms.max())
    return clean + noise_fraction * scale * rng.standard_normal(clean.shape)


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
