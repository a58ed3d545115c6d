"""The monitor's record of the data so far: every set's time, air temperature, covariates, centred
log-frequencies and OMA variances, grouped into *chunks* (the sets of one calendar day that arrived together).

A pass over the history (:mod:`~seqbayes.structural.monitor.sampler`) needs all of it: a move of a particle's
static parameters re-weighs it against every set since the first. The run store keeps the same arrays
(:mod:`seqbayes.store.monitor`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["History", "prepare_sets"]


def prepare_sets(model, times, temperature, frequencies, std_frequencies=None, covariates=None):
    """The arrays of a history's new sets: ``(times, air, covariates (S, r), y (S, n), oma_var (S, n))``.

    ``y = log f - log f_ref`` (NaN where a mode is missing); ``oma_var = (s_f / f)^2``, the OMA's variance of the
    log-frequency (0 where not given). Raises ValueError naming what is wrong.
    """
    times = np.asarray(times, dtype=float).reshape(-1)
    s = times.size
    air = np.asarray(temperature, dtype=float).reshape(-1)
    f = np.asarray(frequencies, dtype=float).reshape(s, -1) if s else np.zeros((0, model.n_modes))
    if f.shape[1] != model.n_modes:
        raise ValueError(f"frequencies: expected {model.n_modes} modes per set, got {f.shape[1]}")
    if air.size != s:
        raise ValueError(f"temperature: expected {s} values (one per set), got {air.size}")
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(air))):
        raise ValueError("day, temperature: every set needs a finite time and air temperature")
    if s > 1 and np.any(np.diff(times) <= 0):
        raise ValueError("day: the sets' times must increase")
    bad = np.isfinite(f) & ~(f > 0)
    if bad.any():
        raise ValueError(f"frequencies: expected positive values [Hz] (empty where missing), got {f[bad][0]!r}")
    y = np.log(np.where(f > 0, f, np.nan)) - np.log(model.reference_frequencies)[None, :]
    oma = np.zeros_like(y)
    if std_frequencies is not None:
        sf = np.asarray(std_frequencies, dtype=float).reshape(s, -1)
        if sf.shape != f.shape:
            raise ValueError(f"std_frequencies: expected shape {f.shape}, got {sf.shape}")
        if np.any(np.isfinite(sf) & (sf < 0)):
            raise ValueError("std_frequencies: expected standard errors >= 0 (empty where not given)")
        oma = np.where(np.isfinite(sf) & np.isfinite(y), (np.nan_to_num(sf) / np.where(f > 0, f, 1.0)) ** 2, 0.0)
    r = len(model.covariates)
    z = np.zeros((s, r)) if covariates is None else np.asarray(covariates, dtype=float).reshape(s, r)
    if not np.all(np.isfinite(z)):
        raise ValueError(f"covariates {', '.join(model.covariates)}: every set needs finite values")
    return times, air, z, y, oma


@dataclass(frozen=True, eq=False)
class History:
    """The sets so far (``S`` of them) in ``K`` chunks.

    Attributes
    ----------
    times, air : (S,) arrays
        Set times [days] and air temperatures [degC].
    covariates : (S, r) array
    y, oma_var : (S, n) arrays
        Centred log-frequencies (NaN: missing) and the OMA's variances of them.
    chunk_end : (K,) int array
        One past each chunk's last set.
    chunk_day : (K,) int array
        Each chunk's calendar day, counted from the first set's (0).
    origin : float
        The first set's calendar day (``floor`` of its time).
    """

    times: np.ndarray
    air: np.ndarray
    covariates: np.ndarray
    y: np.ndarray
    oma_var: np.ndarray
    chunk_end: np.ndarray
    chunk_day: np.ndarray
    origin: float = math.nan

    @classmethod
    def empty(cls, n_modes: int, n_covariates: int) -> "History":
        return cls(np.zeros(0), np.zeros(0), np.zeros((0, n_covariates)), np.zeros((0, n_modes)),
                   np.zeros((0, n_modes)), np.zeros(0, dtype=int), np.zeros(0, dtype=int))

    @property
    def n_chunks(self) -> int:
        return int(self.chunk_end.size)

    @property
    def n_sets(self) -> int:
        return int(self.times.size)

    def rows(self, k: int) -> slice:
        return slice(int(self.chunk_end[k - 1]) if k else 0, int(self.chunk_end[k]))

    def new_day(self, k: int) -> bool:
        """Whether chunk ``k`` opens a calendar day."""
        return k == 0 or self.chunk_day[k] != self.chunk_day[k - 1]

    def days_passed(self, k: int) -> int:
        return 0 if k == 0 else int(self.chunk_day[k] - self.chunk_day[k - 1])

    def candidate(self, k: int) -> int:
        """The calendar day a loss could start at with chunk ``k`` (its day, from day 1), or -1."""
        return int(self.chunk_day[k]) if self.new_day(k) and self.chunk_day[k] >= 1 else -1

    def candidates(self) -> np.ndarray:
        return np.array([self.candidate(k) for k in range(self.n_chunks)], dtype=int)

    def extended(self, times, air, covariates, y, oma_var) -> "History":
        """This history with new sets (later than every set so far), split into chunks by calendar day."""
        times = np.asarray(times, dtype=float)
        if times.size == 0:
            raise ValueError("the dataset holds no set")
        if self.n_sets and times[0] <= self.times[-1]:
            raise ValueError(f"day: the new sets start at {times[0]:.6g}, not after the last set so far "
                             f"({self.times[-1]:.6g}); sets arrive in time order, each once")
        origin = math.floor(times[0]) if not self.n_sets else self.origin
        day = np.floor(times).astype(int) - int(origin)
        breaks = np.flatnonzero(np.diff(day)) + 1
        ends = np.append(breaks, times.size) + self.n_sets
        return History(np.concatenate([self.times, times]), np.concatenate([self.air, air]),
                       np.concatenate([self.covariates, covariates]), np.concatenate([self.y, y]),
                       np.concatenate([self.oma_var, oma_var]), np.concatenate([self.chunk_end, ends]),
                       np.concatenate([self.chunk_day, day[np.append(0, breaks)]]), float(origin))
