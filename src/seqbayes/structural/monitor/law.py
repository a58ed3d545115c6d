"""The environmental law's nonlinear part: the structure's temperature through a first-order lag of the air's,
the smooth freezing knee, and the prior of the static parameters the sampler moves.

Per identified set ``t`` the law's regressors are (:func:`design`)::

    h_t = (1, 1, Ts_t - T_ref, knee(Ts_t) - knee(T_ref), z_t,1 - z_ref,1, ...)

(the level's and the day effect's coefficients, then the temperature's, the knee's and the covariates')

- ``Ts`` the structure's temperature: ``Ts_t = Ts_{t-1} + (1 - exp(-dt_t / tau)) (T_t - Ts_{t-1})`` with ``T`` the
  recorded air temperature, ``dt_t`` the time since the previous set and ``tau`` the thermal time constant
  (:func:`lagged`; the first set starts at ``Ts = T``; ``tau`` near its lower bound is no lag).
- ``knee(T) = w log(1 + exp((T0 - T) / w))``: a smooth ``max(T0 - T, 0)`` (freezing stiffens below ``T0``),
  with location ``T0`` and sharpness ``w`` learned.
- ``z`` further covariates by name (humidity, a traffic or wind proxy), entering linearly.

Their coefficients per mode are linear and marginalised exactly by the per-mode Kalman filter
(:mod:`~seqbayes.structural.monitor.daily_filter`); the static parameters here, with the discrepancy's and the
noise's scales, are what the particles carry (:class:`MonitorPrior`, in the coordinates the moves use: a box,
uniform in each).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MonitorPrior", "lagged", "knee", "design", "PARAMETERS"]

#: The static parameters in the order of the sampler's coordinates (per-mode noise scales last).
PARAMETERS = ("log_tau_h", "knee_location", "log_knee_width", "log_level_sd", "log_day_sd")


@dataclass(frozen=True)
class MonitorPrior:
    """Priors of the monitor's static parameters and of the linear coefficients it marginalises.

    The particles' coordinates ``u`` are uniform in a box: ``log tau`` [h] (thermal time constant), ``T0``
    [degC], ``log w`` [degC], ``log`` of the discrepancy's random-walk sd per day, ``log`` of the day effect's sd
    (both in log-frequency units), then ``log`` of each mode's set noise sd (added to the OMA's own).

    Attributes
    ----------
    tau_hours : (2,) tuple
        Bounds of the lag's time constant [h]; the lower one stands for no lag.
    knee_location : (2,) tuple
        Bounds of ``T0`` [degC].
    knee_width : (2,) tuple
        Bounds of ``w`` [degC].
    level_sd : (2,) tuple
        Bounds of the per-mode discrepancy's random-walk sd per day (log-frequency).
    day_sd : (2,) tuple
        Bounds of the per-mode day effect's sd (log-frequency).
    noise_sd : (2,) tuple
        Bounds of each mode's set noise sd (relative frequency error).
    level0_sd : float
        Prior sd of each mode's level at the first set about its reference log-frequency.
    temperature_sd, knee_sd : float
        Prior sds of the per-mode coefficients of ``Ts - T_ref`` and of the knee [log-frequency per degC].
    covariate_sd : float
        Prior sd of a further covariate's coefficient, per unit of the covariate.
    reference_temperature : float
        ``T_ref`` [degC].
    """

    tau_hours: tuple = (0.05, 48.0)
    knee_location: tuple = (-4.0, 4.0)
    knee_width: tuple = (0.2, 4.0)
    level_sd: tuple = (1e-6, 3e-3)
    day_sd: tuple = (1e-6, 1e-2)
    noise_sd: tuple = (1e-4, 0.05)
    level0_sd: float = 0.1
    temperature_sd: float = 0.005
    knee_sd: float = 0.03
    covariate_sd: float = 0.01
    reference_temperature: float = 10.0

    def __post_init__(self):
        for name in ("tau_hours", "knee_width", "level_sd", "day_sd", "noise_sd", "knee_location"):
            bounds = getattr(self, name)
            if (not isinstance(bounds, (tuple, list)) or len(bounds) != 2
                    or not all(isinstance(b, (int, float)) and math.isfinite(b) for b in bounds)):
                raise ValueError(f"{name}: expected two finite numbers (low, high), got {bounds!r}")
            low, high = bounds
            if not low < high or (name != "knee_location" and low <= 0):
                raise ValueError(f"{name}: expected {'' if name == 'knee_location' else '0 < '}low < high, "
                                 f"got {bounds!r}")
            object.__setattr__(self, name, (float(low), float(high)))
        for name in ("level0_sd", "temperature_sd", "knee_sd", "covariate_sd"):
            value = getattr(self, name)
            if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
        if not math.isfinite(self.reference_temperature):
            raise ValueError(f"reference_temperature: expected a finite number, got {self.reference_temperature!r}")

    def box(self, n_modes: int) -> np.ndarray:
        """The ``(5 + n_modes, 2)`` box of the coordinates ``u`` (lower, upper)."""
        rows = [np.log(self.tau_hours), self.knee_location, np.log(self.knee_width), np.log(self.level_sd),
                np.log(self.day_sd)] + [np.log(self.noise_sd)] * int(n_modes)
        return np.array(rows, dtype=float)

    def names(self, n_modes: int) -> tuple:
        """The coordinates' names (``log_noise_sd_1`` ... per mode last)."""
        return PARAMETERS + tuple(f"log_noise_sd_{i + 1}" for i in range(int(n_modes)))

    def sample(self, size: int, n_modes: int, rng: np.random.Generator) -> np.ndarray:
        """``(size, 5 + n_modes)`` draws of ``u`` from the prior (uniform in :meth:`box`)."""
        box = self.box(n_modes)
        return box[:, 0] + (box[:, 1] - box[:, 0]) * rng.random((int(size), box.shape[0]))

    def logpdf(self, u: np.ndarray, n_modes: int) -> np.ndarray:
        """``(N,)`` log prior density of ``u (N, 5 + n_modes)``: constant inside the box, ``-inf`` outside."""
        box = self.box(n_modes)
        inside = np.all((u > box[:, 0]) & (u < box[:, 1]), axis=1)
        return np.where(inside, -float(np.sum(np.log(box[:, 1] - box[:, 0]))), -np.inf)

    def static_sds(self, n_covariates: int) -> np.ndarray:
        """Prior sds of the static coefficients (temperature, knee, covariates), ``(2 + n_covariates,)``."""
        return np.array([self.temperature_sd, self.knee_sd] + [self.covariate_sd] * int(n_covariates))


def lagged(times, air, tau_hours, start=None, start_time=None) -> np.ndarray:
    """The structure's temperature ``(N, S)`` at the sets ``times (S,)`` [days] from the air temperature ``air (S,)``.

    Parameters
    ----------
    times, air : (S,) arrays
        Set times [days], increasing, and the air temperatures there [degC].
    tau_hours : (N,) array
        Each particle's time constant [h].
    start : (N,) array, optional
        The structure's temperature at ``start_time`` (the last set before these); without it the first set
        starts at ``Ts = T``.
    start_time : float, optional
        Time of ``start`` [days].

    Examples
    --------
    >>> lagged(np.array([0.0, 1 / 24]), np.array([0.0, 10.0]), np.array([1.0])).round(3).tolist()
    [[0.0, 6.321]]
    """
    times = np.asarray(times, dtype=float)
    air = np.asarray(air, dtype=float)
    tau = np.asarray(tau_hours, dtype=float).reshape(-1)
    out = np.empty((tau.size, times.size))
    if times.size == 0:
        return out
    gaps = np.diff(times, prepend=times[0] if start_time is None else start_time) * 24.0
    # keep = exp(-dt / tau): the share of the previous structure temperature kept over each gap
    keep = np.exp(-gaps[None, :] / tau[:, None])
    current = air[0] + np.zeros(tau.size) if start is None else np.asarray(start, dtype=float).copy()
    for s in range(times.size):   # a short recursion over the sets, vectorised over the particles
        current = air[s] + keep[:, s] * (current - air[s])
        out[:, s] = current
    return out


def knee(temperature, location, width) -> np.ndarray:
    """``w log(1 + exp((T0 - T) / w))``, a smooth ``max(T0 - T, 0)``; broadcasts.

    >>> float(np.round(knee(-10.0, 0.0, 0.5), 6)), float(np.round(knee(10.0, 0.0, 0.5), 6))
    (10.0, 0.0)
    """
    width = np.asarray(width, dtype=float)
    return width * np.logaddexp(0.0, (np.asarray(location, dtype=float) - np.asarray(temperature, dtype=float))
                                / width)


def design(structure_temperature, location, width, covariates, reference_temperature: float,
           covariate_reference) -> np.ndarray:
    """The regressors ``h (N, S, 4 + r)`` of the sets: ``1, 1, Ts - T_ref, knee(Ts) - knee(T_ref), z - z_ref``.

    Parameters
    ----------
    structure_temperature : (N, S) array
    location, width : (N,) arrays
        The knee's ``T0`` and ``w`` per particle.
    covariates : (S, r) array
        Further covariates (``r`` may be 0).
    reference_temperature : float
    covariate_reference : (r,) array
    """
    ts = np.asarray(structure_temperature, dtype=float)
    n, s = ts.shape
    covariates = np.asarray(covariates, dtype=float).reshape(s, -1)
    r = covariates.shape[1]
    h = np.empty((n, s, 4 + r))
    h[:, :, :2] = 1.0
    h[:, :, 2] = ts - reference_temperature
    loc, wid = np.asarray(location, dtype=float)[:, None], np.asarray(width, dtype=float)[:, None]
    h[:, :, 3] = knee(ts, loc, wid) - knee(reference_temperature, loc, wid)
    if r:
        h[:, :, 4:] = (covariates - np.asarray(covariate_reference, dtype=float)[None, :])[None, :, :]
    return h
