"""The baselines of issues 25 and 40: the field's novelty detection and an EKF, on years with missing modes.

Both read the rows of a monitoring data file (``day, temperature, f1 .. fn``, several rows a day, NaN where a
mode was not identified), learn on the first ``train_days`` days, compute one statistic per day, and alarm when
the statistic exceeds its threshold on ``consecutive`` days in a row (the rule shape of the Bayesian workflow).
The default threshold is the ``1 - false_alarm_rate`` quantile of the statistic over the training days; the
misspecification matrix replaces it by the rule calibrated on simulated healthy years, as for the monitor
(:mod:`seqbayes.studies.environment_alarms`), so :attr:`BaselineResult.statistic` is what is kept.

**Novelty detection** (:func:`novelty_detection`; Peeters & De Roeck 2001, Sohn 2007), on the log frequencies:

- ``method="regression"``: each log frequency regressed, over the training rows where the mode is present, on
  ``[1, T, min(T, 0), Tbar_w ...]`` with ``Tbar_w`` the trailing mean air temperature over ``w`` days for each
  ``w`` in ``temperature_windows`` (the static regression with delayed temperature inputs that stands in for
  thermal inertia; scikit-learn ``LinearRegression``); the residuals are the features;
- ``method="pca"``: the log frequencies standardised by the training rows, their first ``n_components``
  principal components (scikit-learn ``PCA`` on the complete training rows) removed; what is left is expressed
  in the remaining components.

The statistic of day ``d`` is the Mahalanobis distance ``rbar_d^T S^-1 rbar_d`` of the day's mean residual
(each mode's mean over the rows where it is present; the PCA variant projects the day's mean standardised log
frequencies, the same thing for complete rows), ``S`` the covariance of the training days' mean residuals
(scikit-learn ``EmpiricalCovariance``). A day-level ``S`` keeps what the temperature model misses within a day
(a lag, humidity's cycle) in the covariance instead of in the distance. Days on which some mode has no row have
no statistic (NaN).

Storey localisation (novelty detection has none by itself): a stiffness loss ``delta`` in storey ``j`` moves the
log frequencies by ``-delta s_j``, with ``s_j = d ln f / d ln k_j`` the eigen-derivative sensitivities of the
nominal building (:func:`frequency_sensitivities`). The storey of day ``d`` is the ``j`` whose ``-s_j``, passed
through the same residual map (the PCA variant projects it off the removed components), has the largest cosine
with the mean residual of the ``consecutive`` days ending at ``d`` (:func:`localise`).

**EKF** (:func:`ekf_tracking`): the state is the vector of storey stiffness ratios ``theta`` (a random walk,
``process_std`` per row), with ``temperature_law=True`` augmented by the static coefficients ``alpha, beta`` of
``c(T) = 1 + alpha (T - T_ref) + beta min(T, 0)`` on the air temperature (the frequencies are then
``sqrt(c(T)) f(theta)``); the observation is the row's present frequencies, with relative noise
``measurement_std`` or the row's own standard errors. The Jacobian in ``theta`` is the eigen-derivative
``d f_i / d theta_j = k_j (phi_i,j - phi_i,j-1)^2 / (8 pi^2 f_i)`` for mass-normalised shapes. The statistic of
day ``d`` is the largest, over storeys, of the drop of the day's mean ``theta_j`` below its mean over the second
half of the training days (the first half is the filter's convergence) divided by that storey's ``1 -
false_alarm_rate / n`` quantile of the training drops, so 1 is the default threshold; the storey is the one with
the largest ratio. The library's EKF (``structural.filters.ekf``) filters accelerations through the building's
state space; here a measurement is a frequency set, a small static problem, so the filter is the lines below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..structural.environment import held_for
from ..structural.structures import ShearBuilding

__all__ = ["BaselineResult", "novelty_detection", "ekf_tracking", "frequency_sensitivities", "localise",
           "alarm_days", "daily_means", "check_rows", "ekf_track", "trailing_mean"]


@dataclass(frozen=True)
class BaselineResult:
    """One baseline's verdict on one data file.

    Attributes
    ----------
    days : (D,) int array
        The whole days of the file (``floor(day)``), ascending.
    statistic : (D,) array
        The daily statistic (NaN on a day without a verdict).
    threshold : float
        Alarm when ``statistic > threshold`` on ``consecutive`` days in a row.
    alarm_days : list of float
        The times at which the rule holds, after the training days: each the end of the day whose
        data completed it (``floor(day) + 1``, the convention of ``benchmarks/bench_environment.py``).
    storeys : list of int
        The storey (1-based) the method attributes each alarm to.
    alarm_day : float or None
        The first alarm time.
    storey : int or None
        The storey of the first alarm.
    elements : (D,) int array
        The storey the method points to on each day (0 on a day without a statistic).
    first_day : float
        The first day monitored (the end of the training days).
    """

    days: np.ndarray
    statistic: np.ndarray
    threshold: float
    alarm_days: list
    storeys: list
    alarm_day: float | None
    storey: int | None
    elements: np.ndarray
    first_day: float


def check_rows(day, temperature, frequencies, n_modes: int | None = None, std_frequencies=None):
    """Validated ``day (R,)``, ``temperature (R,)``, ``frequencies (R, n)`` (NaN: a missing mode) and
    ``std_frequencies (R, n)`` or None (``ValueError`` naming the argument)."""
    day = np.asarray(day, dtype=float).reshape(-1)
    temperature = np.asarray(temperature, dtype=float).reshape(-1)
    frequencies = np.asarray(frequencies, dtype=float)
    if frequencies.ndim != 2 or frequencies.shape[0] != day.size:
        raise ValueError(f"frequencies: expected shape ({day.size}, n), one row per day value, got {frequencies.shape}")
    if temperature.size != day.size:
        raise ValueError(f"temperature: expected {day.size} values (one per row), got {temperature.size}")
    if n_modes is not None and frequencies.shape[1] != n_modes:
        raise ValueError(f"frequencies: expected {n_modes} columns (one per mode of the building), got {frequencies.shape[1]}")
    for name, values in (("day", day), ("temperature", temperature)):
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name}: contains NaN or inf")
    if np.any(np.isinf(frequencies)):
        raise ValueError("frequencies: contains inf (a missing mode is NaN)")
    if np.any(frequencies <= 0):
        raise ValueError("frequencies: must be positive")
    empty = np.flatnonzero(np.all(np.isnan(frequencies), axis=0))
    if empty.size:
        raise ValueError(f"frequencies: mode {empty[0] + 1} is missing from every row")
    if np.any(np.diff(day) < 0):
        raise ValueError("day: rows must be in time order")
    if std_frequencies is not None:
        std_frequencies = np.asarray(std_frequencies, dtype=float)
        if std_frequencies.shape != frequencies.shape:
            raise ValueError(f"std_frequencies: expected shape {frequencies.shape}, got {std_frequencies.shape}")
        present = ~np.isnan(frequencies)
        if not (np.all(np.isfinite(std_frequencies[present])) and np.all(std_frequencies[present] > 0)):
            raise ValueError("std_frequencies: expected a positive finite standard error for every present mode")
    return day, temperature, frequencies, std_frequencies


def daily_means(day: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whole days ``(D,)`` from the first to the last, the mean of ``values (R, q)`` on each ``(D, q)`` over the
    rows where a column is not NaN (NaN without any), and those row counts ``(D, q)``."""
    whole = np.floor(day).astype(int)
    days = np.arange(whole[0], whole[-1] + 1)
    index = whole - whole[0]
    present = ~np.isnan(values)
    counts = np.zeros((days.size, values.shape[1]), int)
    np.add.at(counts, index, present.astype(int))
    sums = np.zeros((days.size, values.shape[1]))
    np.add.at(sums, index, np.where(present, values, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts
    return days, means, counts


def trailing_mean(day: np.ndarray, values: np.ndarray, window: float) -> np.ndarray:
    """``(R,)``: the mean of ``values (R,)`` over the rows with ``day`` in ``(day_r - window, day_r]`` (rows in
    time order).

    Examples
    --------
    >>> trailing_mean(np.array([0.0, 0.5, 1.0, 1.5]), np.array([1.0, 2.0, 3.0, 4.0]), 1.0).tolist()
    [1.0, 1.5, 2.5, 3.5]
    """
    cumulative = np.concatenate([[0.0], np.cumsum(values)])
    start = np.searchsorted(day, day - window, side="right")
    end = np.arange(1, day.size + 1)
    return (cumulative[end] - cumulative[start]) / (end - start)


def alarm_days(days: np.ndarray, statistic: np.ndarray, threshold: float, consecutive: int, first_day: float) -> list:
    """The days ``>= first_day`` on which ``statistic > threshold`` has held for ``consecutive`` days in a row."""
    consecutive = int(consecutive)
    if consecutive < 1:
        raise ValueError(f"consecutive: expected a positive integer, got {consecutive}")
    held = held_for(np.nan_to_num(statistic, nan=-np.inf) > threshold, consecutive)
    return [float(d) for d, h in zip(days, held) if h and d >= first_day]


def frequency_sensitivities(building: ShearBuilding, theta: ArrayLike | None = None) -> np.ndarray:
    """``d ln f_i / d ln k_j`` at ``theta`` (default undamaged), shape ``(n modes, n storeys)``.

    With mass-normalised shapes, ``d w_i^2 / d k_j = (phi_i,j - phi_i,j-1)^2`` (``phi_i,0 = 0``), so
    ``d ln f_i / d ln k_j = k_j (phi_i,j - phi_i,j-1)^2 / (2 w_i^2)``; each row sums to 1/2.
    """
    theta = np.ones(building.n_storeys) if theta is None else np.asarray(theta, dtype=float)
    return _jacobian(building, theta)[1]


def _jacobian(building: ShearBuilding, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frequencies ``(n,)``, ``d ln f / d ln k (n, n)`` and ``d f / d theta (n, n)`` at one ``theta``."""
    frequencies, shapes = building.modes(theta)
    frequencies, shapes = frequencies[0], shapes[0]  # shapes[:, i] is mode i
    drifts = np.diff(np.vstack([np.zeros((1, shapes.shape[1])), shapes]), axis=0)  # (storey, mode)
    k = np.asarray(theta, dtype=float) * building.stiffnesses
    w2 = (2 * np.pi * frequencies) ** 2
    log_sens = (k[:, None] * drifts**2 / (2 * w2[None, :])).T  # (mode, storey)
    df_dtheta = frequencies[:, None] * log_sens / np.asarray(theta, dtype=float)[None, :]
    return frequencies, log_sens, df_dtheta


def localise(residual: np.ndarray, patterns: np.ndarray) -> int:
    """The storey (1-based) whose damage pattern (row ``j`` of ``patterns``, the residual a loss in
    storey ``j`` would leave) has the largest cosine with ``residual``."""
    residual = np.asarray(residual, dtype=float)
    norms = np.linalg.norm(patterns, axis=1) * max(np.linalg.norm(residual), 1e-300)
    return int(np.argmax(patterns @ residual / norms)) + 1


def _check_settings(train_days, false_alarm_rate, consecutive, day):
    if not 0 < false_alarm_rate < 1:
        raise ValueError(f"false_alarm_rate: expected a value in (0, 1), got {false_alarm_rate}")
    if int(consecutive) < 1:
        raise ValueError(f"consecutive: expected a positive integer, got {consecutive}")
    first = float(np.floor(day[0]))
    if not train_days > 0 or np.floor(day[-1]) < first + train_days:
        raise ValueError(f"train_days: expected a positive number of days shorter than the record "
                         f"({np.floor(day[-1]) - first + 1:g} days), got {train_days}")
    return first + float(train_days)


def _result(days, statistic, threshold, consecutive, end_of_training, elements) -> BaselineResult:
    alarms = alarm_days(days, statistic, threshold, consecutive, end_of_training)
    storeys = [int(elements[int(np.searchsorted(days, d))]) for d in alarms]
    return BaselineResult(days, statistic, float(threshold), [d + 1 for d in alarms], storeys,
                          alarms[0] + 1 if alarms else None, storeys[0] if storeys else None,
                          np.asarray(elements, int), float(end_of_training))


def _window_means(means: np.ndarray, width: int) -> np.ndarray:
    """``(D, q)``: the mean of the rows ``d - width + 1 .. d`` of ``means`` (fewer at the start; NaN ignored)."""
    out = np.empty_like(means)
    for d in range(means.shape[0]):  # a loop over days
        block = means[max(0, d + 1 - width): d + 1]
        out[d] = np.nan if np.all(np.isnan(block)) else np.nanmean(block, axis=0)
    return out


def novelty_detection(day: ArrayLike, temperature: ArrayLike, frequencies: ArrayLike, building: ShearBuilding,
                      method: str = "regression", train_days: float = 90, false_alarm_rate: float = 0.01,
                      consecutive: int = 2, n_components: int = 1,
                      temperature_windows: tuple = (0.25, 1.0)) -> BaselineResult:
    """Temperature removed by regression or PCA, then a daily Mahalanobis distance (module docstring).

    Parameters
    ----------
    day, temperature : (R,) arrays
        Time [days] and air temperature [degrees C] of each row, in time order.
    frequencies : (R, n) array
        The identified frequencies [Hz] of each row (``n`` = the building's storeys; NaN where missing).
    building : ShearBuilding
        The nominal building, for the localisation's sensitivities.
    method : {"regression", "pca"}
    train_days : float
        Learn on the days before ``floor(day[0]) + train_days``.
    false_alarm_rate : float
        Share of training days whose statistic exceeds the default threshold.
    consecutive : int
        Days in a row above the threshold that make an alarm, and the days whose residuals localise.
    n_components : int
        Principal components removed (``method="pca"``).
    temperature_windows : tuple of float
        Trailing windows [days] of the mean temperatures the regression adds (``()``: none).

    Returns
    -------
    BaselineResult
    """
    from sklearn.covariance import EmpiricalCovariance
    from sklearn.decomposition import PCA
    from sklearn.linear_model import LinearRegression

    day, temperature, frequencies, _ = check_rows(day, temperature, frequencies, building.n_storeys)
    end = _check_settings(train_days, false_alarm_rate, consecutive, day)
    train = day < end
    logf = np.log(frequencies)
    present = ~np.isnan(logf)
    patterns = -frequency_sensitivities(building).T  # (storey, mode): a loss lowers ln f by delta s_j
    if method == "regression":
        covariates = np.column_stack([temperature, np.minimum(temperature, 0.0)]
                                     + [trailing_mean(day, temperature, float(w)) for w in temperature_windows])
        residual = np.full_like(logf, np.nan)
        for j in range(logf.shape[1]):  # per mode, over the rows where it is present
            rows = train & present[:, j]
            fit = LinearRegression().fit(covariates[rows], logf[rows, j])
            residual[present[:, j], j] = logf[present[:, j], j] - fit.predict(covariates[present[:, j]])
        days, means, counts = daily_means(day, residual)
    elif method == "pca":
        n = logf.shape[1]
        if not 1 <= int(n_components) < n:
            raise ValueError(f"n_components: expected 1 .. {n - 1}, got {n_components}")
        complete = train & present.all(axis=1)
        centre, scale = logf[complete].mean(axis=0), logf[complete].std(axis=0)
        kept = PCA().fit((logf[complete] - centre) / scale).components_[int(n_components):]  # (n - c, n)
        days, means, counts = daily_means(day, (logf - centre) / scale)
        means = means @ kept.T  # projection is linear: the day's mean residual
        patterns = (patterns / scale) @ kept.T
    else:
        raise ValueError(f"method: expected 'regression' or 'pca', got {method!r}")
    judged = np.all(counts > 0, axis=1)
    training_days = (days < end) & judged
    precision = EmpiricalCovariance().fit(means[training_days]).precision_
    statistic = np.einsum("di,ij,dj->d", np.where(judged[:, None], means, 0.0), precision,
                          np.where(judged[:, None], means, 0.0))
    statistic[~judged] = np.nan
    threshold = np.quantile(statistic[training_days], 1 - false_alarm_rate)
    window = _window_means(np.where(judged[:, None], means, np.nan), int(consecutive))
    elements = np.array([localise(w, patterns) if np.all(np.isfinite(w)) else 0 for w in window])
    return _result(days, statistic, threshold, consecutive, end, elements)


def ekf_tracking(day: ArrayLike, temperature: ArrayLike, frequencies: ArrayLike, building: ShearBuilding,
                 train_days: float = 90, false_alarm_rate: float = 0.01, consecutive: int = 2,
                 process_std: float = 0.002, measurement_std: float = 0.004, initial_std: float = 0.2,
                 temperature_law: bool = False, std_frequencies: ArrayLike | None = None) -> BaselineResult:
    """Storey stiffness ratios tracked by an EKF, with or without a temperature law in its state (module docstring).

    Parameters
    ----------
    day, temperature, frequencies, building, train_days, false_alarm_rate, consecutive
        As :func:`novelty_detection` (``temperature`` is used only with ``temperature_law``).
    process_std : float
        Random-walk standard deviation of each stiffness ratio per row.
    measurement_std : float
        Frequency noise relative to the frequency (where ``std_frequencies`` does not give it).
    initial_std : float
        Prior standard deviation of each ratio around 1.
    temperature_law : bool
        Augment the state with ``alpha`` and ``beta`` (static; prior sds 0.005 and 0.03 /degC, ``T_ref`` 10 degC).
    std_frequencies : (R, n) array, optional
        Each row's standard errors [Hz] (an OMA's), used as the measurement noise.

    Returns
    -------
    BaselineResult
    """
    day, temperature, frequencies, std_frequencies = check_rows(day, temperature, frequencies, building.n_storeys,
                                                                std_frequencies)
    end = _check_settings(train_days, false_alarm_rate, consecutive, day)
    n = building.n_storeys
    track = ekf_track(frequencies, building, process_std, measurement_std, initial_std,
                      temperature=temperature if temperature_law else None, std_frequencies=std_frequencies)[:, :n]
    days, means, counts = daily_means(day, track)
    judged = counts[:, 0] > 0
    start = float(np.floor(day[0]))
    reference_days = (days >= start + (end - start) / 2) & (days < end) & judged
    drop = means[reference_days].mean(axis=0) - means  # (D, n), positive when softer than in training
    limits = np.quantile(drop[reference_days], 1 - false_alarm_rate / n, axis=0)
    ratio = drop / np.maximum(limits, 1e-12)
    statistic = np.where(judged, np.max(np.where(judged[:, None], ratio, -np.inf), axis=1), np.nan)
    elements = np.where(judged, np.argmax(np.where(judged[:, None], ratio, -np.inf), axis=1) + 1, 0)
    return _result(days, statistic, 1.0, consecutive, end, elements)


#: Prior standard deviations of the EKF's ``alpha`` and ``beta`` [1/degC], and the reference temperature.
LAW_PRIOR_STD = (0.005, 0.03)
LAW_REFERENCE_TEMPERATURE = 10.0


def ekf_track(frequencies: ArrayLike, building: ShearBuilding, process_std: float = 0.002,
              measurement_std: float = 0.004, initial_std: float = 0.2, *, temperature: ArrayLike | None = None,
              std_frequencies: ArrayLike | None = None) -> np.ndarray:
    """The EKF's filtered state after each row: ``(R, n)`` ratios, or ``(R, n + 2)`` ratios, ``alpha``, ``beta``
    when ``temperature (R,)`` is given (parameters of :func:`ekf_tracking`; NaN frequencies are not observed)."""
    frequencies = np.asarray(frequencies, dtype=float)
    if frequencies.ndim != 2 or frequencies.shape[1] != building.n_storeys:
        raise ValueError(f"frequencies: expected shape (R, {building.n_storeys}), got {frequencies.shape}")
    for name, value in (("process_std", process_std), ("measurement_std", measurement_std),
                        ("initial_std", initial_std)):
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name}: must be positive and finite, got {value}")
    n = building.n_storeys
    law = temperature is not None
    d = n + 2 if law else n
    state = np.concatenate([np.ones(n), np.zeros(d - n)])
    P = np.diag(np.concatenate([np.full(n, initial_std**2), np.square(LAW_PRIOR_STD)[: d - n]]))
    Q = np.diag(np.concatenate([np.full(n, process_std**2), np.zeros(d - n)]))
    track = np.empty((frequencies.shape[0], d))
    for r, observed in enumerate(frequencies):  # one update per frequency set, in time order
        P = P + Q
        present = ~np.isnan(observed)
        if not present.any():
            track[r] = state
            continue
        predicted, _, H = _jacobian(building, np.clip(state[:n], 1e-3, None))
        if law:
            t = temperature[r]
            covariates = np.array([t - LAW_REFERENCE_TEMPERATURE, min(t, 0.0)])
            c = max(1.0 + covariates @ state[n:], 1e-3)
            H = np.hstack([np.sqrt(c) * H, predicted[:, None] * covariates[None, :] / (2 * np.sqrt(c))])
            predicted = np.sqrt(c) * predicted
        H = H[present]
        noise = (measurement_std * observed[present]) if std_frequencies is None else std_frequencies[r, present]
        S = H @ P @ H.T + np.diag(noise**2)
        gain = np.linalg.solve(S, H @ P).T
        state = state + gain @ (observed[present] - predicted[present])
        P = (np.eye(d) - gain @ H) @ P
        P = (P + P.T) / 2
        track[r] = state
    return track


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
