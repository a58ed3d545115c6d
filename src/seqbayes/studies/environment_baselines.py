"""The two baselines of issue 25: the field's novelty detection and an EKF with no environment.

Both read the rows of a monitoring data file (``day, temperature, f1 .. fn``, several rows a
day), learn on the first ``train_days`` days, compute one statistic per day, and alarm when the
statistic exceeds its threshold on ``consecutive`` days in a row (the rule shape of the Bayesian
workflow). The threshold is the ``1 - false_alarm_rate`` quantile of the statistic over the
training days.

**Novelty detection** (:func:`novelty_detection`; Peeters & De Roeck 2001, Sohn 2007), on the log
frequencies of every row:

- ``method="regression"``: each log frequency regressed on ``[1, T, min(T, 0)]`` (the freezing
  term) by least squares (scikit-learn ``LinearRegression``); the residuals are the features;
- ``method="pca"``: the standardised log frequencies projected off their first ``n_components``
  principal components (scikit-learn ``PCA``), which carry the temperature; the residual is what
  the kept components do not explain, expressed in the remaining components.

The covariance ``Sigma`` of the training residuals is scikit-learn's ``EmpiricalCovariance``; the
statistic of day ``d`` is the Mahalanobis distance of its mean residual, scaled by its row count,
``n_d rbar_d^T Sigma^-1 rbar_d`` (chi-square with ``n`` degrees of freedom for independent
Gaussian residuals).

Storey localisation (novelty detection has none by itself): a stiffness loss ``delta`` in storey
``j`` moves the log frequencies by ``-delta s_j``, with ``s_j = d ln f / d ln k_j`` the
eigen-derivative sensitivities of the undamaged building (:func:`frequency_sensitivities`). The
storey is the ``j`` whose ``-s_j``, passed through the same residual map (the regression leaves it
as is, the PCA variant projects it off the removed components), has the largest cosine with the
mean residual of the ``consecutive`` days that raised the alarm (:func:`localise`).

**EKF** (:func:`ekf_tracking`): the state is the vector of storey stiffness ratios ``theta``
(a random walk, ``process_std`` per row), the observation the frequencies of the row, with
relative noise ``measurement_std``; the observation Jacobian is the eigen-derivative
``d f_i / d theta_j = k_j (phi_i,j - phi_i,j-1)^2 / (8 pi^2 f_i)`` for mass-normalised shapes.
No environmental model: temperature moves ``theta``. The statistic of day ``d`` is the largest,
over storeys, of the drop of the day's mean ``theta_j`` below its training mean divided by the
storey's threshold (the ``1 - false_alarm_rate / n`` quantile of the training drops, Bonferroni
over storeys), so 1 is the threshold; the storey is the one with the largest ratio on the alarm
day. The library's EKF (``structural.filters.ekf``) filters accelerations through the building's
state space; here the measurement is a frequency set, a four-dimensional static problem, so the
filter is the twenty lines below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..structural.environment import held_for
from ..structural.structures import ShearBuilding

__all__ = ["BaselineResult", "novelty_detection", "ekf_tracking", "frequency_sensitivities", "localise",
           "alarm_days", "daily_means", "check_rows", "ekf_track"]


@dataclass(frozen=True)
class BaselineResult:
    """One baseline's verdict on one data file.

    Attributes
    ----------
    days : (D,) int array
        The whole days of the file (``floor(day)``), ascending.
    statistic : (D,) array
        The daily statistic (NaN on a day without rows).
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
    """

    days: np.ndarray
    statistic: np.ndarray
    threshold: float
    alarm_days: list
    storeys: list
    alarm_day: float | None
    storey: int | None


def check_rows(day, temperature, frequencies, n_modes: int | None = None):
    """Validated ``day (R,)``, ``temperature (R,)``, ``frequencies (R, n)`` (``ValueError`` naming the argument)."""
    day = np.asarray(day, dtype=float).reshape(-1)
    temperature = np.asarray(temperature, dtype=float).reshape(-1)
    frequencies = np.asarray(frequencies, dtype=float)
    if frequencies.ndim != 2 or frequencies.shape[0] != day.size:
        raise ValueError(f"frequencies: expected shape ({day.size}, n), one row per day value, got {frequencies.shape}")
    if temperature.size != day.size:
        raise ValueError(f"temperature: expected {day.size} values (one per row), got {temperature.size}")
    if n_modes is not None and frequencies.shape[1] != n_modes:
        raise ValueError(f"frequencies: expected {n_modes} columns (one per mode of the building), got {frequencies.shape[1]}")
    for name, values in (("day", day), ("temperature", temperature), ("frequencies", frequencies)):
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name}: contains NaN or inf")
    if np.any(frequencies <= 0):
        raise ValueError("frequencies: must be positive")
    if np.any(np.diff(day) < 0):
        raise ValueError("day: rows must be in time order")
    return day, temperature, frequencies


def daily_means(day: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whole days ``(D,)`` from the first to the last, the mean of ``values (R, q)`` on each ``(D, q)``
    (NaN without rows) and the row count of each ``(D,)``."""
    whole = np.floor(day).astype(int)
    days = np.arange(whole[0], whole[-1] + 1)
    index = whole - whole[0]
    counts = np.bincount(index, minlength=days.size)
    sums = np.zeros((days.size, values.shape[1]))
    np.add.at(sums, index, values)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts[:, None]
    return days, means, counts


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


def _result(days, statistic, threshold, consecutive, end_of_training, storey_at) -> BaselineResult:
    alarms = alarm_days(days, statistic, threshold, consecutive, end_of_training)
    storeys = [storey_at(d) for d in alarms]
    return BaselineResult(days, statistic, float(threshold), [d + 1 for d in alarms], storeys,
                          alarms[0] + 1 if alarms else None, storeys[0] if storeys else None)


def novelty_detection(day: ArrayLike, temperature: ArrayLike, frequencies: ArrayLike, building: ShearBuilding,
                      method: str = "regression", train_days: float = 90, false_alarm_rate: float = 0.01,
                      consecutive: int = 2, n_components: int = 1) -> BaselineResult:
    """Temperature removed by regression or PCA, then a daily Mahalanobis distance (module docstring).

    Parameters
    ----------
    day, temperature : (R,) arrays
        Time [days] and temperature [degrees C] of each row, in time order.
    frequencies : (R, n) array
        The identified frequencies [Hz] of each row (``n`` = the building's storeys).
    building : ShearBuilding
        The nominal building, for the localisation's sensitivities.
    method : {"regression", "pca"}
    train_days : float
        Learn on the days before ``floor(day[0]) + train_days``.
    false_alarm_rate : float
        Share of training days whose statistic exceeds the threshold.
    consecutive : int
        Days in a row above the threshold that make an alarm.
    n_components : int
        Principal components removed (``method="pca"``).

    Returns
    -------
    BaselineResult
    """
    from sklearn.covariance import EmpiricalCovariance
    from sklearn.decomposition import PCA
    from sklearn.linear_model import LinearRegression

    day, temperature, frequencies = check_rows(day, temperature, frequencies, building.n_storeys)
    end = _check_settings(train_days, false_alarm_rate, consecutive, day)
    train = day < end
    logf = np.log(frequencies)
    patterns = -frequency_sensitivities(building).T  # (storey, mode): a loss lowers ln f by delta s_j
    if method == "regression":
        covariates = np.column_stack([temperature, np.minimum(temperature, 0.0)])
        fit = LinearRegression().fit(covariates[train], logf[train])
        residual = logf - fit.predict(covariates)
    elif method == "pca":
        n = logf.shape[1]
        if not 1 <= int(n_components) < n:
            raise ValueError(f"n_components: expected 1 .. {n - 1}, got {n_components}")
        centre, scale = logf[train].mean(axis=0), logf[train].std(axis=0)
        pca = PCA().fit((logf[train] - centre) / scale)
        kept = pca.components_[int(n_components):]  # (n - n_components, n)
        residual = ((logf - centre) / scale) @ kept.T
        patterns = (patterns / scale) @ kept.T
    else:
        raise ValueError(f"method: expected 'regression' or 'pca', got {method!r}")
    precision = EmpiricalCovariance().fit(residual[train]).precision_
    days, means, counts = daily_means(day, residual)
    statistic = counts * np.einsum("di,ij,dj->d", means, precision, means)
    statistic[counts == 0] = np.nan
    training_days = (days < end) & (counts > 0)
    threshold = np.quantile(statistic[training_days], 1 - false_alarm_rate)

    def storey_at(alarm: float) -> int:
        # the mean residual of the days that raised the alarm (within a long run, the latest ones)
        i = int(np.searchsorted(days, alarm))
        return localise(np.nanmean(means[i + 1 - int(consecutive): i + 1], axis=0), patterns)

    return _result(days, statistic, threshold, consecutive, end, storey_at)


def ekf_tracking(day: ArrayLike, temperature: ArrayLike, frequencies: ArrayLike, building: ShearBuilding,
                 train_days: float = 90, false_alarm_rate: float = 0.01, consecutive: int = 2,
                 process_std: float = 0.002, measurement_std: float = 0.004,
                 initial_std: float = 0.2) -> BaselineResult:
    """Storey stiffness ratios tracked by an EKF with no environmental model (module docstring).

    Parameters
    ----------
    day, temperature, frequencies, building, train_days, false_alarm_rate, consecutive
        As :func:`novelty_detection` (``temperature`` is validated and not used: the baseline
        has no environmental model).
    process_std : float
        Random-walk standard deviation of each stiffness ratio per row.
    measurement_std : float
        Frequency noise relative to the frequency.
    initial_std : float
        Prior standard deviation of each ratio around 1.

    Returns
    -------
    BaselineResult
    """
    day, temperature, frequencies = check_rows(day, temperature, frequencies, building.n_storeys)
    end = _check_settings(train_days, false_alarm_rate, consecutive, day)
    n = building.n_storeys
    track = ekf_track(frequencies, building, process_std, measurement_std, initial_std)
    days, means, counts = daily_means(day, track)
    training_days = (days < end) & (counts > 0)
    drop = means[training_days].mean(axis=0) - means  # (D, n), positive when softer than in training
    limits = np.quantile(drop[training_days], 1 - false_alarm_rate / n, axis=0)
    ratio = drop / np.maximum(limits, 1e-12)
    statistic = np.max(ratio, axis=1)
    statistic[counts == 0] = np.nan

    def storey_at(alarm: float) -> int:
        return int(np.argmax(ratio[int(np.searchsorted(days, alarm))])) + 1

    return _result(days, statistic, 1.0, consecutive, end, storey_at)


def ekf_track(frequencies: ArrayLike, building: ShearBuilding, process_std: float = 0.002,
              measurement_std: float = 0.004, initial_std: float = 0.2) -> np.ndarray:
    """The EKF's filtered stiffness ratios after each row, ``(R, n)`` (parameters of :func:`ekf_tracking`)."""
    frequencies = np.asarray(frequencies, dtype=float)
    if frequencies.ndim != 2 or frequencies.shape[1] != building.n_storeys:
        raise ValueError(f"frequencies: expected shape (R, {building.n_storeys}), got {frequencies.shape}")
    for name, value in (("process_std", process_std), ("measurement_std", measurement_std),
                        ("initial_std", initial_std)):
        if not np.isfinite(value) or value <= 0:
            raise ValueError(f"{name}: must be positive and finite, got {value}")
    n = building.n_storeys
    theta, P = np.ones(n), np.eye(n) * initial_std**2
    Q = np.eye(n) * process_std**2
    track = np.empty((frequencies.shape[0], n))
    for r, observed in enumerate(frequencies):  # one update per frequency set, in time order
        P = P + Q
        predicted, _, H = _jacobian(building, np.clip(theta, 1e-3, None))
        S = H @ P @ H.T + np.diag((measurement_std * observed) ** 2)
        gain = np.linalg.solve(S, H @ P).T
        theta = theta + gain @ (observed - predicted)
        P = (np.eye(n) - gain @ H) @ P
        P = (P + P.T) / 2
        track[r] = theta
    return track


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
