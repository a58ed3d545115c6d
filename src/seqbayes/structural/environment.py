"""Damage against environment as model selection: identified natural frequencies under temperature.

Model (issue 25). Every storey stiffness follows the temperature ``T`` through one factor::

    k_i(T) = theta_i k_i^u c(T),   c(T) = 1 + alpha (T - T_ref) + beta min(T, 0)

with ``k^u`` the nominal stiffnesses of the :class:`ShearBuilding` and ``theta`` the reference
stiffness ratios. With one factor on all storeys ``K(T) = c(T) K(theta)``, so every natural
frequency scales by ``sqrt(c(T))``: one eigenproblem per particle serves every hourly set. An
identified set ``y_h`` (log frequencies, ascending) is::

    y_hr = log f_r(theta) + 0.5 log c(T_h) + e_hr,   e_hr ~ N(0, sigma^2)

(``sigma`` is the relative frequency error). The models:

- ``M0``, no damage: ``(log theta, alpha, beta, log sigma)`` all static.
- ``Mj``, a loss in storey ``j``: ``theta_j`` becomes ``theta_j (1 - delta)`` from an unknown day
  ``tau`` with a geometric prior ``P(tau = d) = p (1 - p)^(d - 1)``, ``d = 1, 2, ...`` (``p`` the
  daily hazard; day 0 is the first monitored day). ``tau`` is summed out exactly for each particle
  from the per-day likelihoods under both states, so the sampler's parameters stay static and the
  likelihood of days ``0..t`` is::

      Z_t = sum_{d=1}^{t} P(tau=d) prod_{s<d} p0_s prod_{d<=s<=t} p1_s  +  P(tau>t) prod_{s<=t} p0_s

  ``P(tau <= t | phi, data)`` is its first part over ``Z_t`` (Rao-Blackwellised).

Each model is sampled by IBIS (resample-move SMC over a growing history, one update per day,
tempered within a day by :func:`seqbayes.core.tempering.temper`) with random-walk Metropolis moves on
the full history. Per day the likelihood needs only per-day sums of the data and of
``g_h = 0.5 log c(T_h)`` (``Sigma g``, ``Sigma g^2``, ``Sigma g Y``), so a move costs one pass over the
hourly temperatures per particle and one 4x4 eigenproblem (two under ``Mj``).

``P(damage by t) = sum_j P(Mj | data) P(tau <= t | Mj, data)`` with the model probabilities from
the IBIS log-evidences and the prior model probabilities. The alarm rule
(:func:`alarm_days`): ``P(damage) > threshold`` on ``consecutive`` days in a row.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..weights import resample
from ..core.tempering import TargetESS, between_stages, temper
from ..moves.base import metropolis_accept
from ..weights import logsumexp, normalise
from .structures import ShearBuilding

__all__ = ["EnvironmentPrior", "ModelDay", "MonitorDay", "ChangeModelSampler", "EnvironmentMonitor", "alarm_days",
           "split_days", "FrequencyLikelihood", "monitor_year", "held_for"]

_FLOOR = -1e250  # stands in for -inf in the tempering increments, which must be finite


@dataclass(frozen=True)
class EnvironmentPrior:
    """Priors and the damage prior of the monitor.

    Attributes
    ----------
    stiffness_sd : float
        Standard deviation of ``log theta_i`` (mean 0: the nominal stiffnesses).
    alpha_sd, beta_sd : float
        Standard deviations of the zero-mean normal priors of ``alpha`` and ``beta`` [1/degC].
    noise_bounds : (2,) tuple
        Log-uniform prior bounds of the relative frequency error ``sigma``.
    damage_bounds : (2,) tuple
        Uniform prior bounds of the loss ``delta``; ``delta`` below the lower bound is not damage.
    daily_hazard : float
        ``p`` of the geometric prior of the damage day under ``Mj``.
    no_damage_probability : float
        Prior probability of ``M0``; the storeys share the rest equally.
    reference_temperature : float
        ``T_ref`` [degC].
    """

    stiffness_sd: float = 0.1
    alpha_sd: float = 0.005
    beta_sd: float = 0.03
    noise_bounds: tuple = (1e-4, 0.05)
    damage_bounds: tuple = (0.01, 0.25)
    daily_hazard: float = 1.0 / 365.0
    no_damage_probability: float = 0.5
    reference_temperature: float = 10.0

    def __post_init__(self):
        for name in ("stiffness_sd", "alpha_sd", "beta_sd"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ValueError(f"{name}: expected a positive finite value, got {getattr(self, name)}")
        lo, hi = self.noise_bounds
        if not 0 < lo < hi:
            raise ValueError(f"noise_bounds: expected 0 < low < high, got {self.noise_bounds}")
        lo, hi = self.damage_bounds
        if not 0 < lo < hi < 1:
            raise ValueError(f"damage_bounds: expected 0 < low < high < 1, got {self.damage_bounds}")
        if not 0 < self.daily_hazard < 1:
            raise ValueError(f"daily_hazard: expected a value in (0, 1), got {self.daily_hazard}")
        if not 0 < self.no_damage_probability < 1:
            raise ValueError(f"no_damage_probability: expected a value in (0, 1), got {self.no_damage_probability}")


@dataclass(frozen=True)
class ModelDay:
    """One model's posterior after one day.

    Attributes
    ----------
    log_evidence : float
        Running log-evidence ``log p(days 0..t | model)``.
    p_damage : float
        ``P(tau <= t | model, data)`` (0 under ``M0``).
    mean, sd : (d,) arrays
        Posterior mean and standard deviation of ``(theta_1..n, alpha, beta, sigma[, delta])``.
    damage_day : float
        Posterior mean of ``tau`` given ``tau <= t`` (NaN under ``M0`` or with no mass there).
    n_stages, n_moves : int
        Tempering stages and move sweeps of the day.
    acceptance : float
        Mean acceptance of the day's moves (NaN without moves).
    """

    log_evidence: float
    p_damage: float
    mean: np.ndarray
    sd: np.ndarray
    damage_day: float
    n_stages: int
    n_moves: int
    acceptance: float


@dataclass(frozen=True)
class MonitorDay:
    """The monitor after one day.

    Attributes
    ----------
    day : int
        Day index (0 = first monitored day).
    p_damage : float
        ``P(damage by the end of day) = sum_j P(Mj) P(tau <= day | Mj)``.
    model_probabilities : (n + 1,) array
        ``P(M0 | data), P(M1 | data), ...``.
    storey : int or None
        1-based storey with the largest ``P(Mj | data) P(tau <= day | Mj)``.
    damage_size : float
        Posterior mean loss ``delta`` of that storey's model.
    alarm : bool
        The alarm rule holds at this day.
    models : tuple of ModelDay
    """

    day: int
    p_damage: float
    model_probabilities: np.ndarray
    storey: int | None
    damage_size: float
    alarm: bool
    models: tuple = field(repr=False)


def alarm_days(p_damage, threshold: float = 0.95, consecutive: int = 2) -> np.ndarray:
    """Indices of the days on which ``p_damage`` has exceeded ``threshold`` on ``consecutive`` days in a row.

    Examples
    --------
    >>> alarm_days([0.1, 0.99, 0.2, 0.97, 0.98, 0.99], 0.95, 2).tolist()
    [4, 5]
    """
    p = np.asarray(p_damage, float)
    if p.ndim != 1:
        raise ValueError(f"p_damage: expected a 1-d array, got shape {p.shape}")
    if not 0 < threshold < 1:
        raise ValueError(f"threshold: expected a value in (0, 1), got {threshold}")
    if int(consecutive) != consecutive or consecutive < 1:
        raise ValueError(f"consecutive: expected a positive integer, got {consecutive}")
    return np.flatnonzero(held_for(p > threshold, int(consecutive)))


def held_for(above, consecutive: int) -> np.ndarray:
    """``(D,)`` bool: whether ``above (D,)`` has held on the day and the ``consecutive - 1`` days before it.

    The alarm rule's run length, shared by the monitor and the baselines
    (:mod:`seqbayes.studies.environment_baselines`).

    Examples
    --------
    >>> held_for(np.array([False, True, True, False, True, True, True]), 2).tolist()
    [False, False, True, False, False, True, True]
    """
    above = np.asarray(above, bool)
    run = np.zeros(above.size, int)
    for i, a in enumerate(above):  # run length of exceedances ending at day i (a loop over days)
        run[i] = (run[i - 1] + 1) * a if i else int(a)
    return run >= consecutive


def split_days(day, temperature, frequencies) -> list:
    """Group frequency sets by whole day: a list of ``(day_index, temperature (S,), frequencies (S, n))``.

    ``day`` (S,) is the float time in days; rows are sorted by it and grouped by ``floor(day)``.
    """
    day = np.asarray(day, float)
    temperature = np.asarray(temperature, float)
    frequencies = np.asarray(frequencies, float)
    if day.ndim != 1 or temperature.shape != day.shape:
        raise ValueError(f"day, temperature: expected 1-d arrays of one length, got {day.shape}, {temperature.shape}")
    if frequencies.ndim != 2 or frequencies.shape[0] != day.size:
        raise ValueError(f"frequencies: expected shape ({day.size}, n), got {frequencies.shape}")
    if not (np.isfinite(day).all() and np.isfinite(temperature).all() and np.isfinite(frequencies).all()):
        raise ValueError("day, temperature, frequencies: contain NaN or inf")
    if np.any(frequencies <= 0):
        raise ValueError("frequencies: must be positive")
    order = np.argsort(day, kind="stable")
    whole = np.floor(day[order]).astype(int)
    starts = np.flatnonzero(np.r_[True, np.diff(whole) > 0])
    ends = np.r_[starts[1:], whole.size]
    return [(int(whole[s]), temperature[order][s:e], frequencies[order][s:e]) for s, e in zip(starts, ends)]


class FrequencyLikelihood:
    """The no-damage model's likelihood as a run-store likelihood: ``loglike(theta (N, n + 3), data) -> (N,)``.

    ``theta`` holds the stiffness ratios ``theta_1..n``, ``alpha``, ``beta`` [1/degC] and the relative
    frequency error ``sigma``; ``data`` is one dataset of identified frequency sets with their
    temperature covariate: the dict of columns ``temperature, f1..fn`` (the store's
    ``format = "columns"``) or an ``(S, n + 1)`` array with those columns in that order. Exactly the
    per-set density of :class:`ChangeModelSampler` under ``M0``. A user's module holds, for example::

        from seqbayes.structural.environment import FrequencyLikelihood
        loglike = FrequencyLikelihood([2e5, 2e5, 2e5, 1.6e5], [3e8, 2.6e8, 2.2e8, 1.8e8])

    Examples
    --------
    >>> like = FrequencyLikelihood([1e5], [4e7])
    >>> f = like.frequencies(np.array([[1.0, 0.0, 0.0, 0.01]]), np.array([10.0]))
    >>> like(np.array([[1.0, 0.0, 0.0, 0.01]]), {"temperature": np.array([10.0]), "f1": f[0, :, 0]}).round(3)
    array([3.686])
    """

    def __init__(self, masses, stiffnesses, reference_temperature: float = 10.0):
        self.building = ShearBuilding(masses, stiffnesses)
        if not np.isfinite(reference_temperature):
            raise ValueError(f"reference_temperature: expected a finite value, got {reference_temperature}")
        self.reference_temperature = float(reference_temperature)

    def _columns(self, data):
        n = self.building.n_storeys
        if isinstance(data, dict):
            missing = [c for c in ["temperature"] + [f"f{r + 1}" for r in range(n)] if c not in data]
            if missing:
                raise ValueError(f"data: expected the columns temperature, f1..f{n}; missing {missing}")
            temperature = np.asarray(data["temperature"], float)
            freqs = np.column_stack([np.asarray(data[f"f{r + 1}"], float) for r in range(n)])
        else:
            table = np.asarray(data, float)
            if table.ndim != 2 or table.shape[1] != n + 1:
                raise ValueError(f"data: expected an (S, {n + 1}) array of temperature, f1..f{n}, got {table.shape}")
            temperature, freqs = table[:, 0], table[:, 1:]
        return temperature, freqs

    def frequencies(self, theta, temperature) -> np.ndarray:
        """Model frequencies ``(N, S, n)`` [Hz] at the temperatures ``(S,)``."""
        theta = np.atleast_2d(np.asarray(theta, float))
        n = self.building.n_storeys
        if theta.shape[1] != n + 3:
            raise ValueError(f"theta: expected shape (N, {n + 3}) (theta_1..{n}, alpha, beta, sigma), "
                             f"got {theta.shape}")
        temperature = np.asarray(temperature, float)
        factor = (1.0 + theta[:, n:n + 1] * (temperature - self.reference_temperature)[None, :]
                  + theta[:, n + 1:n + 2] * np.minimum(temperature, 0.0)[None, :])
        base = self.building.modes(theta[:, :n])[0]  # (N, n)
        return np.sqrt(np.clip(factor, 0.0, None))[:, :, None] * base[:, None, :]

    def __call__(self, theta, data) -> np.ndarray:
        theta = np.atleast_2d(np.asarray(theta, float))
        temperature, freqs = self._columns(data)
        n = self.building.n_storeys
        model = self.frequencies(theta, temperature)  # (N, S, n)
        sigma = theta[:, n + 2]
        with np.errstate(divide="ignore"):
            resid = np.log(freqs)[None, :, :] - np.log(model)
        out = (-0.5 * resid[0].size * np.log(2 * np.pi * sigma ** 2)
               - 0.5 * np.sum(resid ** 2, axis=(1, 2)) / sigma ** 2)
        return np.where(np.all(np.isfinite(resid), axis=(1, 2)) & (sigma > 0), out, -np.inf)


class _History:
    """The assimilated sets, centred log frequencies, and their per-day sums."""

    def __init__(self, n_modes: int):
        self.n_modes = n_modes
        self.temperature = np.empty(0)
        self.y = np.empty((0, n_modes))
        self.starts: list = []
        self.sum_yy: list = []
        self.sum_y: list = []
        self.counts: list = []

    def append(self, temperature, y):
        self.starts.append(self.temperature.size)
        self.temperature = np.concatenate([self.temperature, temperature])
        self.y = np.concatenate([self.y, y])
        self.sum_yy.append(float(np.sum(y ** 2)))
        self.sum_y.append(y.sum(axis=0))
        self.counts.append(y.shape[0])

    def copy(self) -> "_History":
        other = _History(self.n_modes)
        other.temperature, other.y = self.temperature.copy(), self.y.copy()
        other.starts, other.sum_yy, other.sum_y, other.counts = (list(self.starts), list(self.sum_yy),
                                                                 list(self.sum_y), list(self.counts))
        return other

    def day_arrays(self, first_day: int):
        """Sets and per-day sums of days ``first_day..``: (T, y, starts relative, sum_yy, sum_y, counts)."""
        s0 = self.starts[first_day]
        starts = np.asarray(self.starts[first_day:]) - s0
        return (self.temperature[s0:], self.y[s0:], starts, np.asarray(self.sum_yy[first_day:]),
                np.asarray(self.sum_y[first_day:]), np.asarray(self.counts[first_day:]))


class ChangeModelSampler:
    """IBIS over the days for one model: ``M0`` (``storey=None``) or a loss in ``storey`` (1-based).

    Parameters ``phi (N, d)``: ``log theta_1..n, alpha, beta, log sigma`` and, under ``Mj``, ``delta``.
    """

    def __init__(self, building: ShearBuilding, storey: int | None, prior: EnvironmentPrior, n_particles: int,
                 rng: np.random.Generator, *, n_moves: int = 5, target_ess: float = 0.5):
        n = building.n_storeys
        if storey is not None and not (int(storey) == storey and 1 <= storey <= n):
            raise ValueError(f"storey: expected None or an integer in 1..{n}, got {storey}")
        if int(n_particles) != n_particles or n_particles < 10:
            raise ValueError(f"n_particles: expected an integer >= 10, got {n_particles}")
        if not 0 < target_ess < 1:
            raise ValueError(f"target_ess: expected a fraction in (0, 1), got {target_ess}")
        self.building, self.storey, self.prior, self.rng = building, storey, prior, rng
        self.n, self.n_particles, self.n_moves, self.target_ess = n, int(n_particles), int(n_moves), target_ess
        self.dim = n + 3 + (storey is not None)
        self.log_nominal = np.log(building.modes(np.ones(n))[0][0])
        self.history = _History(n)
        self.phi = self.sample_prior(self.n_particles)
        self.log_weights = np.zeros(self.n_particles)
        self.log_evidence = 0.0
        self.loglike0 = np.empty((self.n_particles, 0))  # (N, days) per-day log-likelihoods, undamaged
        self.loglike1 = np.empty((self.n_particles, 0))  # damaged (Mj only)
        self.scale = 2.38 / math.sqrt(self.dim)
        self.n_set_evaluations = 0  # particle x frequency-set likelihood terms evaluated
        self.n_particle_evaluations = 0  # particle likelihood calls (a day or a whole history each)

    # ---------------------------------------------------------------- prior
    def sample_prior(self, size: int) -> np.ndarray:
        p, n, rng = self.prior, self.n, self.rng
        columns = [rng.normal(0.0, p.stiffness_sd, (size, n)), rng.normal(0.0, p.alpha_sd, (size, 1)),
                   rng.normal(0.0, p.beta_sd, (size, 1)), rng.uniform(*np.log(p.noise_bounds), (size, 1))]
        if self.storey is not None:
            columns.append(rng.uniform(*p.damage_bounds, (size, 1)))
        return np.concatenate(columns, axis=1)

    def prior_logpdf(self, phi: np.ndarray) -> np.ndarray:
        p, n = self.prior, self.n
        out = (-0.5 * np.sum(phi[:, :n] ** 2, axis=1) / p.stiffness_sd ** 2 - 0.5 * (phi[:, n] / p.alpha_sd) ** 2
               - 0.5 * (phi[:, n + 1] / p.beta_sd) ** 2)
        lo, hi = np.log(p.noise_bounds)
        inside = (phi[:, n + 2] > lo) & (phi[:, n + 2] < hi)
        if self.storey is not None:
            inside &= (phi[:, n + 3] > p.damage_bounds[0]) & (phi[:, n + 3] < p.damage_bounds[1])
        return np.where(inside, out, -np.inf)

    # ---------------------------------------------------------------- likelihood
    def day_loglikes(self, phi: np.ndarray, first_day: int) -> tuple[np.ndarray, np.ndarray | None]:
        """Per-day log-likelihoods ``(N, D)`` of days ``first_day..`` undamaged and (``Mj``) damaged."""
        n, N = self.n, phi.shape[0]
        temperature, y, starts, sum_yy, sum_y, counts = self.history.day_arrays(first_day)
        self.n_set_evaluations += N * temperature.size
        self.n_particle_evaluations += N
        theta = np.exp(phi[:, :n])
        alpha, beta, sigma = phi[:, n:n + 1], phi[:, n + 1:n + 2], np.exp(phi[:, n + 2])
        factor = (1.0 + alpha * (temperature - self.prior.reference_temperature)[None, :]
                  + beta * np.minimum(temperature, 0.0)[None, :])  # c(T_h), (N, H)
        valid = np.all(factor > 0, axis=1)
        g = 0.5 * np.log(np.where(factor > 0, factor, 1.0))
        sum_g = np.add.reduceat(g, starts, axis=1)
        sum_gg = np.add.reduceat(g * g, starts, axis=1)
        sum_gy = np.add.reduceat(g * y.sum(axis=1)[None, :], starts, axis=1)
        base = sum_yy[None, :] - 2 * sum_gy + n * sum_gg  # sum_h sum_r (y_hr - g_h)^2
        norm = -0.5 * n * counts[None, :] * np.log(2 * np.pi * sigma[:, None] ** 2)

        def loglike(ratios):
            a = np.log(self.building.modes(ratios)[0]) - self.log_nominal  # (N, n) centred log f_r
            squares = (base - 2 * a @ sum_y.T + 2 * sum_g * a.sum(axis=1)[:, None]
                       + counts[None, :] * np.sum(a * a, axis=1)[:, None])
            return np.where(valid[:, None], norm - 0.5 * squares / sigma[:, None] ** 2, -np.inf)

        undamaged = loglike(theta)
        if self.storey is None:
            return undamaged, None
        damaged_theta = theta.copy()
        damaged_theta[:, self.storey - 1] *= 1.0 - phi[:, n + 3]
        return undamaged, loglike(damaged_theta)

    def log_marginal(self, loglike0: np.ndarray, loglike1: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``log Z_t (N,)`` over days ``0..t`` and ``log P(tau <= t | phi, data) (N,)`` (``-inf`` under ``M0``)."""
        c0 = np.cumsum(loglike0, axis=1)
        if loglike1 is None:
            return c0[:, -1], np.full(c0.shape[0], -np.inf)
        days = loglike0.shape[1]
        hazard = self.prior.daily_hazard
        c1 = np.cumsum(loglike1, axis=1)
        # tau = d in 1..t: days 0..d-1 undamaged, d..t damaged; P(tau = d) = p (1-p)^(d-1)
        d = np.arange(1, days)
        log_prior_tau = math.log(hazard) + (d - 1) * math.log1p(-hazard)
        changed = log_prior_tau[None, :] + c0[:, :-1] + (c1[:, -1:] - c1[:, :-1])
        unchanged = (days - 1) * math.log1p(-hazard) + c0[:, -1]  # P(tau > t) = (1-p)^t, t = days - 1
        if changed.shape[1] == 0:
            return unchanged, np.full(c0.shape[0], -np.inf)
        log_changed = logsumexp(changed, axis=1)
        total = np.logaddexp(log_changed, unchanged)
        return total, np.where(np.isfinite(total), log_changed - total, -np.inf)

    # ---------------------------------------------------------------- update
    def update(self, temperature: np.ndarray, frequencies: np.ndarray) -> ModelDay:
        """Assimilate one day's sets (``temperature (S,)``, ``frequencies (S, n)`` [Hz])."""
        y = np.log(frequencies) - self.log_nominal[None, :]
        self.history.append(np.asarray(temperature, float), y)
        day = len(self.history.starts) - 1
        previous, _ = (self.log_marginal(self.loglike0, self._damaged()) if day else
                       (np.zeros(self.n_particles), None))
        new0, new1 = self.day_loglikes(self.phi, day)
        self.loglike0 = np.concatenate([self.loglike0, new0], axis=1)
        if new1 is not None:
            self.loglike1 = np.concatenate([self.loglike1, new1], axis=1)
        current, _ = self.log_marginal(self.loglike0, self.loglike1 if new1 is not None else None)
        increments = np.maximum(np.nan_to_num(current - previous, nan=_FLOOR, neginf=_FLOOR), _FLOOR)
        self._stages = 0
        self._moves = []
        annealed = temper(None, increments, self.log_weights, TargetESS(self.target_ess * self.n_particles),
                          between_stages(self._resample_move), log_z=self.log_evidence)
        self.log_weights, self.log_evidence = annealed.log_weights, annealed.log_z
        return self.summary(day)

    def start_from(self, no_damage: "ChangeModelSampler") -> ModelDay:
        """Take ``M0``'s particles after its first day, each with a ``delta`` from the prior.

        On day 0 no damage can have happened (``tau >= 1``), so ``Mj``'s posterior there is
        ``M0``'s times the prior of ``delta``, and their evidences are equal: sharing the first
        day, where the posterior contracts most, keeps its Monte Carlo error out of the Bayes factors.
        """
        if self.storey is None or no_damage.storey is not None or len(no_damage.history.starts) != 1:
            raise ValueError("no_damage: expected the no-damage sampler after its first day, for a damage model")
        if len(self.history.starts):
            raise ValueError("start_from: this sampler has already assimilated data")
        self.history = no_damage.history.copy()
        delta = self.rng.uniform(*self.prior.damage_bounds, (no_damage.n_particles, 1))
        self.phi = np.concatenate([no_damage.phi, delta], axis=1)
        self.n_particles = self.phi.shape[0]
        self.loglike0, self.loglike1 = self.day_loglikes(self.phi, 0)
        self.log_weights = no_damage.log_weights.copy()
        self.log_evidence = no_damage.log_evidence
        self.scale = no_damage.scale
        self._stages, self._moves = 0, []
        return self.summary(0)

    def _resample_move(self, log_weights, increments, exponent, particles):
        """Resample by ``log_weights``, then ``n_moves`` random-walk sweeps toward
        ``prior * Z_{t-1}^(1 - exponent) * Z_t^exponent``; returns the new increments."""
        self._stages += 1
        index = resample("systematic", np.exp(normalise(log_weights)), self.rng)
        self.phi = self.phi[index]
        self.loglike0 = self.loglike0[index]
        if self.storey is not None:
            self.loglike1 = self.loglike1[index]
        loglike1 = self._damaged()
        current, _ = self.log_marginal(self.loglike0, loglike1)
        previous = self._previous(self.loglike0, loglike1)
        log_target = self.prior_logpdf(self.phi) + (1 - exponent) * previous + exponent * current
        cov = np.cov(self.phi, rowvar=False) + 1e-12 * np.eye(self.dim)
        chol = np.linalg.cholesky(cov)
        for _ in range(self.n_moves):
            proposal = self.phi + self.scale * self.rng.standard_normal(self.phi.shape) @ chol.T
            prior = self.prior_logpdf(proposal)
            inside = np.isfinite(prior)
            new0 = np.full_like(self.loglike0, -np.inf)
            new1 = np.full_like(self.loglike0, -np.inf) if loglike1 is not None else None
            if inside.any():
                l0, l1 = self.day_loglikes(proposal[inside], 0)
                new0[inside] = l0
                if new1 is not None:
                    new1[inside] = l1
            with np.errstate(invalid="ignore"):
                cur_new, _ = self.log_marginal(new0, new1)
                prev_new = self._previous(new0, new1)
                target_new = prior + (1 - exponent) * prev_new + exponent * cur_new
            accept = metropolis_accept(log_target, np.where(inside, target_new, -np.inf), 0.0, self.rng)
            self.phi[accept] = proposal[accept]
            self.loglike0[accept] = new0[accept]
            if loglike1 is not None:
                self.loglike1[accept] = new1[accept]
                loglike1 = self.loglike1
            log_target[accept] = target_new[accept]
            rate = accept.mean()
            self._moves.append(rate)
            self.scale *= math.exp(rate - 0.25)  # steer the acceptance toward about 1/4
        current, _ = self.log_marginal(self.loglike0, loglike1)
        increments = current - self._previous(self.loglike0, loglike1)
        return np.maximum(np.nan_to_num(increments, nan=_FLOOR, neginf=_FLOOR), _FLOOR), particles

    def _damaged(self):
        return self.loglike1 if self.storey is not None else None

    def _previous(self, loglike0, loglike1):
        if loglike0.shape[1] == 1:
            return np.zeros(loglike0.shape[0])
        return self.log_marginal(loglike0[:, :-1], None if loglike1 is None else loglike1[:, :-1])[0]

    def summary(self, day: int) -> ModelDay:
        w = np.exp(normalise(self.log_weights))
        loglike1 = self._damaged()
        _, log_p = self.log_marginal(self.loglike0, loglike1)
        p_damage = float(w @ np.exp(log_p))
        values = self.phi.copy()
        n = self.n
        values[:, :n] = np.exp(values[:, :n])
        values[:, n + 2] = np.exp(values[:, n + 2])
        mean = w @ values
        sd = np.sqrt(np.maximum(w @ (values - mean) ** 2, 0.0))
        damage_day = float("nan")
        if loglike1 is not None and day >= 1 and p_damage > 0:
            c0, c1 = np.cumsum(self.loglike0, axis=1), np.cumsum(loglike1, axis=1)
            d = np.arange(1, day + 1)
            hazard = self.prior.daily_hazard
            changed = math.log(hazard) + (d - 1) * math.log1p(-hazard) + c0[:, :-1] + (c1[:, -1:] - c1[:, :-1])
            post = np.exp(changed - logsumexp(changed, axis=1)[:, None])  # P(tau = d | tau <= t, phi)
            weights = w * np.exp(log_p)
            if weights.sum() > 0:
                damage_day = float((weights / weights.sum()) @ (post @ d))
        return ModelDay(float(self.log_evidence), p_damage, mean, sd, damage_day, self._stages, len(self._moves),
                        float(np.mean(self._moves)) if self._moves else float("nan"))


class EnvironmentMonitor:
    """On-line damage detection under temperature: one :class:`ChangeModelSampler` per model.

    Parameters
    ----------
    building : ShearBuilding
        Masses and nominal storey stiffnesses.
    prior : EnvironmentPrior
    n_particles : int
        Particles per model.
    threshold, consecutive : float, int
        The alarm rule (:func:`alarm_days`).
    rng : numpy.random.Generator
    n_moves : int
        Random-walk sweeps per resample-move.

    Examples
    --------
    >>> from seqbayes.structural import ShearBuilding
    >>> monitor = EnvironmentMonitor(ShearBuilding([1e5], [4e7]), n_particles=50, rng=np.random.default_rng(0))
    >>> [m.storey for m in monitor.samplers]
    [None, 1]
    """

    def __init__(self, building: ShearBuilding, *, prior: EnvironmentPrior = EnvironmentPrior(),
                 n_particles: int = 128, threshold: float = 0.95, consecutive: int = 2,
                 rng: np.random.Generator, n_moves: int = 5):
        if not isinstance(building, ShearBuilding):
            raise TypeError(f"building: expected a ShearBuilding, got {type(building).__name__}")
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
        alarm_days([0.0], threshold, consecutive)  # validates threshold and consecutive
        self.building, self.prior, self.threshold, self.consecutive = building, prior, threshold, int(consecutive)
        n = building.n_storeys
        streams = rng.spawn(n + 1)
        self.samplers = [ChangeModelSampler(building, storey, prior, n_particles, stream, n_moves=n_moves)
                         for storey, stream in zip([None] + list(range(1, n + 1)), streams)]
        self.log_model_prior = np.log(np.r_[prior.no_damage_probability,
                                            np.full(n, (1 - prior.no_damage_probability) / n)])
        self.days: list = []

    @property
    def n_set_evaluations(self) -> int:
        return sum(s.n_set_evaluations for s in self.samplers)

    @property
    def n_particle_evaluations(self) -> int:
        return sum(s.n_particle_evaluations for s in self.samplers)

    def update(self, temperature, frequencies) -> MonitorDay:
        """Assimilate one whole day: ``temperature (S,)`` [degC] and ``frequencies (S, n)`` [Hz], ascending per row."""
        temperature = np.asarray(temperature, float)
        frequencies = np.asarray(frequencies, float)
        n = self.building.n_storeys
        if frequencies.ndim != 2 or frequencies.shape[1] != n or frequencies.shape[0] < 1:
            raise ValueError(f"frequencies: expected shape (S, {n}) with S >= 1, got {frequencies.shape}")
        if temperature.shape != (frequencies.shape[0],):
            raise ValueError(f"temperature: expected shape ({frequencies.shape[0]},), got {temperature.shape}")
        if not (np.isfinite(temperature).all() and np.isfinite(frequencies).all()) or np.any(frequencies <= 0):
            raise ValueError("temperature, frequencies: expected finite values and positive frequencies")
        if self.days:
            models = tuple(s.update(temperature, frequencies) for s in self.samplers)
        else:
            first = self.samplers[0].update(temperature, frequencies)
            models = (first,) + tuple(s.start_from(self.samplers[0]) for s in self.samplers[1:])
        log_post = self.log_model_prior + np.array([m.log_evidence for m in models])
        probabilities = np.exp(log_post - logsumexp(log_post))
        damage_by_model = probabilities[1:] * np.array([m.p_damage for m in models[1:]])
        p_damage = float(damage_by_model.sum())
        best = int(np.argmax(damage_by_model))
        history = [d.p_damage for d in self.days] + [p_damage]
        alarm = bool(alarm_days(history[-self.consecutive:], self.threshold, self.consecutive).size) \
            if len(history) >= self.consecutive else False
        record = MonitorDay(len(self.days), p_damage, probabilities, best + 1 if damage_by_model[best] > 0 else None,
                            float(models[best + 1].mean[n + 3]), alarm, models)
        self.days.append(record)
        return record


def monitor_year(building: ShearBuilding, table: dict, *, rng: np.random.Generator, damage_day: float | None = None,
                 truth_known: bool = False, **options) -> tuple[dict, EnvironmentMonitor, list, list]:
    """Run an :class:`EnvironmentMonitor` over a table (``day``, ``temperature``, ``f1..fn``), one update per whole day.

    Parameters
    ----------
    building : ShearBuilding
    table : dict
        Columns ``day``, ``temperature``, ``f1..fn`` of ``(S,)`` arrays (a year CSV as
        :func:`seqbayes.studies.environment.read_year_csv` reads it).
    rng : numpy.random.Generator
    damage_day, truth_known : float or None, bool
        The true damage day (``None``: no damage) when the truth is known, to sort the alarms.
    **options
        Keywords of :class:`EnvironmentMonitor` (``n_particles``, ``threshold``, ``consecutive``, ...).

    Returns
    -------
    summary : dict
        ``p_damage`` (one per day), ``alarm_days`` (each the end of the day whose update raised it,
        ``floor(day) + 1``), ``alarm_day`` and ``storey`` (the first alarm), ``false_alarm_days``
        (with the truth known: alarm days at or before the damage day, every one if there is no
        damage; else empty), ``detection_delay`` (first alarm after the damage day minus that day),
        ``storey_at_detection``, ``damage_size_at_detection``, the learned ``environment`` (the
        posterior mean of alpha, beta, sigma at the end under the most probable ``model``, 0 for
        ``M0``), ``wall_seconds``, ``cpu_seconds`` and the likelihood-evaluation counts.
    monitor : EnvironmentMonitor
    days : list of int
    records : list of MonitorDay
    """
    n = building.n_storeys
    frequencies = np.column_stack([np.asarray(table[f"f{r + 1}"], float) for r in range(n) if f"f{r + 1}" in table])
    if frequencies.shape[1] != n:
        raise ValueError(f"table: expected the frequencies f1..f{n} of a {n}-storey building, got "
                         f"{frequencies.shape[1]} columns")
    monitor = EnvironmentMonitor(building, rng=rng, **options)
    start, cpu_start = time.perf_counter(), time.process_time()
    days, records = [], []
    for day, temperature, freqs in split_days(table["day"], table["temperature"], frequencies):
        records.append(monitor.update(temperature, freqs))
        days.append(day)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    p_damage = [r.p_damage for r in records]
    alarms = alarm_days(p_damage, monitor.threshold, monitor.consecutive)
    alarm_times = [float(days[i] + 1) for i in alarms]
    false_alarms, delay, detection = [], None, None
    if truth_known:
        false_alarms = [t for t in alarm_times if damage_day is None or t <= damage_day]
        after = [i for i, t in zip(alarms, alarm_times) if damage_day is not None and t > damage_day]
        if after:
            detection = records[after[0]]
            delay = days[after[0]] + 1 - damage_day
    first = records[alarms[0]] if alarms.size else None
    best = int(np.argmax(records[-1].model_probabilities))
    final = records[-1].models[best]
    summary = {"alarm_day": alarm_times[0] if alarm_times else None,
               "storey": None if first is None else first.storey,
               "damage_size": None if first is None else first.damage_size,
               "false_alarm_days": false_alarms, "p_damage": p_damage, "alarm_days": alarm_times,
               "detection_delay": delay, "storey_at_detection": None if detection is None else detection.storey,
               "damage_size_at_detection": None if detection is None else detection.damage_size,
               "final_model_probabilities": records[-1].model_probabilities.tolist(),
               "environment": {"model": best, "alpha": float(final.mean[n]), "beta": float(final.mean[n + 1]),
                               "sigma": float(final.mean[n + 2])},
               "n_particles": monitor.samplers[0].n_particles, "wall_seconds": wall, "cpu_seconds": cpu,
               "n_particle_evaluations": monitor.n_particle_evaluations,
               "n_set_evaluations": monitor.n_set_evaluations}
    return summary, monitor, days, records
