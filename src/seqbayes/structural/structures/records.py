"""Multichannel response records from measurements: CSV and HDF5 loaders with
units and sampling rate, baseline correction, band-pass filtering and
decimation (the path from a shake-table or monitoring record
to the identifiers).

A :class:`ResponseRecord` holds ``T`` samples of ``c`` named channels in SI
units at a uniform step. The processing methods return new records::

    record = read_csv("test.csv", sampling_rate=200.0, units={"ground": "g", "floor1": "g"})
    record = record.baseline_corrected().band_passed(0.2, 20.0).decimated(4)   # 200 Hz -> 50 Hz
    u, y = record.channel("ground"), record.select(["floor1", "floor2"])
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .ground_motion import G

__all__ = ["ResponseRecord", "read_csv", "read_hdf5", "UNITS"]

#: factor to SI of each accepted unit (accelerations to m/s^2, displacements to m, velocities to m/s)
UNITS = {"g": G, "m/s2": 1.0, "m/s^2": 1.0, "cm/s2": 0.01, "cm/s^2": 0.01, "gal": 0.01, "mm/s2": 1e-3,
         "mm/s^2": 1e-3, "m": 1.0, "cm": 0.01, "mm": 1e-3, "m/s": 1.0, "cm/s": 0.01, "mm/s": 1e-3}
_SI = {"g": "m/s^2", "gal": "m/s^2", "m": "m", "cm": "m", "mm": "m", "m/s": "m/s", "cm/s": "m/s", "mm/s": "m/s"}


def _si_unit(unit: str) -> str:
    return _SI.get(unit, "m/s^2" if "s2" in unit or "s^2" in unit else unit)


@dataclass(frozen=True)
class ResponseRecord:
    """Uniformly sampled channels in SI units.

    Attributes
    ----------
    data : (T, c) array
    dt : float
        Sampling step [s].
    channels : tuple of str
        Channel names (``c``).
    units : tuple of str
        SI unit of each channel after conversion (``"m/s^2"``, ``"m"``, ``"m/s"``).
    """

    data: np.ndarray
    dt: float
    channels: tuple
    units: tuple

    def __post_init__(self):
        data = np.asarray(self.data, float)
        if data.ndim != 2 or data.shape[0] < 2:
            raise ValueError(f"data: expected shape (T, c) with T >= 2, got {data.shape}")
        if not np.all(np.isfinite(data)):
            raise ValueError("data: contains NaN or inf")
        if not np.isfinite(self.dt) or self.dt <= 0:
            raise ValueError(f"dt: must be positive and finite, got {self.dt}")
        channels, units = tuple(str(c) for c in self.channels), tuple(str(u) for u in self.units)
        if len(channels) != data.shape[1] or len(units) != data.shape[1]:
            raise ValueError(f"channels, units: expected {data.shape[1]} names and units, got {len(channels)} "
                             f"and {len(units)}")
        if len(set(channels)) != len(channels):
            raise ValueError(f"channels: names must be unique, got {channels}")
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "dt", float(self.dt))
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "units", units)

    @property
    def sampling_rate(self) -> float:
        return 1.0 / self.dt

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.data.shape[0]) * self.dt

    def _index(self, name: str) -> int:
        if name not in self.channels:
            raise ValueError(f"channel: {name!r} is not one of {self.channels}")
        return self.channels.index(name)

    def channel(self, name: str) -> np.ndarray:
        """One channel, ``(T,)``."""
        return self.data[:, self._index(name)].copy()

    def select(self, names: Sequence[str]) -> np.ndarray:
        """Channels ``names`` in that order, ``(T, len(names))`` (e.g. the measurements ``y``)."""
        return self.data[:, [self._index(n) for n in names]].copy()

    def baseline_corrected(self, order: int = 1) -> "ResponseRecord":
        """Each channel minus its least-squares polynomial of degree ``order`` in time
        (0: the mean; 1: mean and linear drift, the usual baseline correction)."""
        if not isinstance(order, (int, np.integer)) or order < 0:
            raise ValueError(f"order: expected a non-negative integer, got {order!r}")
        t = np.linspace(-1.0, 1.0, self.data.shape[0])
        basis = np.polynomial.legendre.legvander(t, int(order))  # well conditioned on [-1, 1]
        coef, *_ = np.linalg.lstsq(basis, self.data, rcond=None)
        return ResponseRecord(self.data - basis @ coef, self.dt, self.channels, self.units)

    def band_passed(self, low: float, high: float, order: int = 4) -> "ResponseRecord":
        """Zero-phase Butterworth band-pass ``[low, high]`` Hz of every channel
        (``scipy.signal.sosfiltfilt``; ``low = 0``: low-pass only)."""
        from scipy import signal

        nyquist = 0.5 / self.dt
        if not (0 <= low < high < nyquist):
            raise ValueError(f"low, high: need 0 <= low < high < Nyquist ({nyquist:g} Hz), got {low}, {high}")
        if low > 0:
            sos = signal.butter(order, [low, high], btype="bandpass", fs=1 / self.dt, output="sos")
        else:
            sos = signal.butter(order, high, btype="lowpass", fs=1 / self.dt, output="sos")
        return ResponseRecord(signal.sosfiltfilt(sos, self.data, axis=0), self.dt, self.channels, self.units)

    def decimated(self, factor: int) -> "ResponseRecord":
        """Every ``factor``-th sample after a zero-phase anti-aliasing FIR filter
        (``scipy.signal.decimate``); the step becomes ``factor * dt``."""
        from scipy import signal

        if not isinstance(factor, (int, np.integer)) or factor < 1:
            raise ValueError(f"factor: expected a positive integer, got {factor!r}")
        if factor == 1:
            return self
        if self.data.shape[0] < 4 * factor:
            raise ValueError(f"factor: the record ({self.data.shape[0]} samples) is too short to decimate by {factor}")
        data = signal.decimate(self.data, int(factor), ftype="fir", axis=0, zero_phase=True)
        return ResponseRecord(data, self.dt * factor, self.channels, self.units)


def _factors(names, units) -> tuple[np.ndarray, tuple]:
    """SI factors and SI unit names per channel; ``units`` a string for all or a dict per name."""
    per = {n: units for n in names} if isinstance(units, str) else dict(units)
    missing = [n for n in names if n not in per]
    if missing:
        raise ValueError(f"units: no unit given for channels {missing}")
    unknown = {per[n] for n in names} - set(UNITS)
    if unknown:
        raise ValueError(f"units: unknown {sorted(unknown)}; known: {sorted(UNITS)}")
    return np.array([UNITS[per[n]] for n in names]), tuple(_si_unit(per[n]) for n in names)


def _step_from(time, name: str) -> float:
    steps = np.diff(np.asarray(time, float))
    if steps.size == 0 or np.any(steps <= 0) or np.ptp(steps) > 1e-6 * steps.mean():
        raise ValueError(f"{name}: the time column must increase with a uniform step")
    return float(steps.mean())


def _rate(sampling_rate, dt_from_time):
    if sampling_rate is None and dt_from_time is None:
        raise ValueError("sampling_rate: not in the file; give sampling_rate= (Hz) or a time column")
    if sampling_rate is not None:
        if not np.isfinite(sampling_rate) or sampling_rate <= 0:
            raise ValueError(f"sampling_rate: must be positive, got {sampling_rate}")
        dt = 1.0 / float(sampling_rate)
        if dt_from_time is not None and abs(dt - dt_from_time) > 1e-6 * dt:
            raise ValueError(f"sampling_rate: {sampling_rate} Hz disagrees with the time column "
                             f"({1 / dt_from_time:g} Hz)")
        return dt
    return dt_from_time


def read_csv(path: str | os.PathLike, units: str | Sequence[str] = "m/s2", sampling_rate: float | None = None,
             time_column: str | None = None, channels: Sequence[str] | None = None,
             delimiter: str = ",") -> ResponseRecord:
    """Read a multichannel CSV file with a header row of channel names.

    Parameters
    ----------
    path : str or Path
    units : str or dict
        Unit of every channel, or ``{name: unit}`` (keys of :data:`UNITS`).
    sampling_rate : float, optional
        [Hz]; needed unless ``time_column`` is given (then they must agree).
    time_column : str, optional
        Name of a time column [s] (uniform step), not a channel.
    channels : list of str, optional
        Channels to keep (default all but the time column).
    delimiter : str

    Returns
    -------
    ResponseRecord
    """
    path = Path(path)
    with path.open(newline="") as f:
        header = next(csv.reader(f, delimiter=delimiter))
    header = [h.strip() for h in header]
    table = np.loadtxt(path, delimiter=delimiter, skiprows=1, ndmin=2)
    if table.shape[1] != len(header):
        raise ValueError(f"path: {path} has {len(header)} names in the header but {table.shape[1]} columns")
    dt_time = None
    if time_column is not None:
        if time_column not in header:
            raise ValueError(f"time_column: {time_column!r} is not in the header {header}")
        dt_time = _step_from(table[:, header.index(time_column)], "time_column")
    names = [h for h in header if h != time_column] if channels is None else list(channels)
    absent = [n for n in names if n not in header]
    if absent:
        raise ValueError(f"channels: {absent} not in the header {header}")
    factors, si = _factors(names, units)
    data = table[:, [header.index(n) for n in names]] * factors
    return ResponseRecord(data, _rate(sampling_rate, dt_time), tuple(names), si)


def read_hdf5(path: str | os.PathLike, group: str = "/", channels: Sequence[str] | None = None,
              units: str | Sequence[str] | None = None, sampling_rate: float | None = None) -> ResponseRecord:
    """Read channels stored as 1-D datasets of one HDF5 group.

    Each dataset is a channel named by its key; its unit is the dataset's
    ``units`` attribute unless ``units`` is given (a string or ``{name: unit}``);
    the sampling rate [Hz] is the group's (or else the first dataset's)
    ``sampling_rate`` attribute unless given. A dataset named ``time`` is used
    as a time column (uniform step) and is not a channel.

    Returns
    -------
    ResponseRecord
    """
    import h5py

    with h5py.File(path, "r") as f:
        if group not in f:
            raise ValueError(f"group: {group!r} not in {path}")
        g = f[group]
        keys = [k for k in g.keys() if isinstance(g[k], h5py.Dataset) and k != "time"]
        names = keys if channels is None else list(channels)
        absent = [n for n in names if n not in keys]
        if absent:
            raise ValueError(f"channels: {absent} not datasets of {group!r} ({keys})")
        if not names:
            raise ValueError(f"group: {group!r} holds no channel datasets")
        columns = [np.asarray(g[n][...], float) for n in names]
        if any(c.ndim != 1 or c.size != columns[0].size for c in columns):
            raise ValueError("channels: every channel must be a 1-D dataset of the same length")
        if units is None:
            stored = {}
            for n in names:
                unit = g[n].attrs.get("units")
                if unit is None:
                    raise ValueError(f"units: dataset {n!r} has no 'units' attribute; give units=")
                stored[n] = unit.decode() if isinstance(unit, bytes) else str(unit)
            units = stored
        rate = sampling_rate
        if rate is None:
            rate = g.attrs.get("sampling_rate", g[names[0]].attrs.get("sampling_rate"))
            rate = None if rate is None else float(rate)
        dt_time = _step_from(g["time"][...], "time") if "time" in g else None
    factors, si = _factors(names, units)
    return ResponseRecord(np.column_stack(columns) * factors, _rate(rate, dt_time), tuple(names), si)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    import os
    from collections.abc import Sequence
