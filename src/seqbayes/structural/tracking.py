"""Mode tracking: each record's poles assigned to tracked modes, record after record (docs/modal.md).

An automated OMA gives, per record, a handful of poles: unsorted, some modes missing, some poles
spurious (noise, harmonics, a mode found twice). Monitoring needs the same physical mode in the same
column of every record. The tracker keeps one *track* per mode, a local-level model of its frequency::

    x_{t+1} = x_t + w_t,    w_t ~ N(0, Q dt)
    f_{i,t} = x_{j,t} + v,  v ~ N(0, s_j^2 + (c_j sigma_i)^2)

with ``sigma_i`` the pole's own standard error (the SSI's), ``c_j`` a calibration of it, ``s_j`` the
track's scatter beyond it and ``dt`` the time since the last record in record spacings. Each record:

1. predict the tracks (``P + Q dt``);
2. assign its poles to tracks (:func:`assign`): the optimal one-to-one assignment
   (:func:`scipy.optimize.linear_sum_assignment`) of the cost ``z^2 / 2`` (``z`` the innovation in sds)
   plus, where poles and tracks have shapes, a MAC term; a pair is allowed only inside the gate
   (``|z| < gate``, MAC above ``mac_gate``); leaving a pole unassigned (spurious) or a track without a
   pole (missing) costs ``gate^2 / 4`` each, so a pair is made exactly when it is inside the gate and no
   better pairing uses its pole or track. Two close modes get two tracks, and a record holding both
   assigns the lower pole to the lower track (crossing costs more); a record holding one assigns it to
   the nearer prediction and marks the other mode *missing*, never shifting columns;
3. update the tracks with the assigned poles (a Kalman update of all tracks: with drift correlations a
   mode seen also moves the prediction of a mode not seen);
4. update each track's reference shape (MAC-aligned running mean).

Without a given reference (:func:`reference_from_poles`) the modes are found in the first
``initial_days`` of data: poles are grouped into frequency bands (gaps wider than ``band_gap``), a band
seen in at least ``min_presence`` of the records holds as many modes as the poles per record it shows
in at least that share of the records (poles of one record closer than ``merge`` counted once), and
its modes start at the medians of the sorted poles of the records that show exactly that many. The
noise of each track (``Q_jj``, ``s_j``, ``c_j``) is then fitted by maximum likelihood to the tracked
first days. The drifts are taken as independent: their correlations cannot be learned from a few days,
because the record-to-record change of a track is mostly its scatter (from ``n`` pairs of consecutive
poles the estimate's standard error is about ``(1 + 2 s^2 / q) / sqrt(n)``, 0.2 to 1.5 for the mast's
first four modes over three days, docs/modal.md); give ``correlation`` to use known ones.

Written here because no maintained library does it: pyoma-2 clusters one record's stabilisation
diagram but does not track across records; the assignment itself is SciPy's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment, minimize

from .modes_table import PoleTable, write_modes_table

__all__ = ["TrackerSettings", "ReferenceModes", "TrackState", "TrackedModes", "assign", "track_step",
           "track_poles", "reference_from_poles", "shape_mac", "covariates_at"]

_UNMATCHED = 1e9      # the cost of a forbidden pair (finite: linear_sum_assignment needs a feasible matrix)


@dataclass(frozen=True)
class TrackerSettings:
    """Settings of the tracker and of the reference found from the data.

    Attributes
    ----------
    gate : float
        A pole joins a track only within this many sds of its prediction.
    mac_gate : float
        ... and, where both have shapes, with a MAC of at least this.
    shape_memory : float
        Weight of a new pole's shape in its track's reference shape.
    initial_days : float
        Days of data the reference is found in (:func:`reference_from_poles`).
    min_presence : float
        A band (and each of its modes) must be seen in at least this share of those records.
    band_gap : float
        Relative frequency gap that separates two bands.
    merge : float
        Poles of one record closer than this (relative) count once when the modes of a band are counted.
    """

    gate: float = 3.5
    mac_gate: float = 0.8
    shape_memory: float = 0.2
    initial_days: float = 3.0
    min_presence: float = 0.25
    band_gap: float = 0.015
    merge: float = 0.003

    def __post_init__(self):
        for name in ("gate", "initial_days", "band_gap"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name}: expected a positive number, got {getattr(self, name)!r}")
        for name in ("mac_gate", "shape_memory", "min_presence", "merge"):
            if not 0 <= getattr(self, name) < 1:
                raise ValueError(f"{name}: expected a number in [0, 1), got {getattr(self, name)!r}")


@dataclass(frozen=True)
class ReferenceModes:
    """The tracked modes and their noise model (module docstring).

    Attributes
    ----------
    frequencies : (m,) array
        Starting frequencies [Hz], ascending.
    initial_sd : (m,) array
        Their uncertainty [Hz].
    drift : (m,) array
        sd of a track's change per record spacing [Hz] (``sqrt(Q_jj)``).
    scatter : (m,) array
        ``s_j`` [Hz].
    std_scale : (m,) array
        ``c_j``.
    spacing : float
        Record spacing [days] (``dt = 1`` between consecutive records).
    correlation : (m, m) array, optional
        Correlations of the drifts (default: independent).
    shapes : (p, m) array or None
        Reference shapes at ``channels``.
    channels : tuple of str
    """

    frequencies: np.ndarray
    initial_sd: np.ndarray
    drift: np.ndarray
    scatter: np.ndarray
    std_scale: np.ndarray
    spacing: float = 1.0
    correlation: np.ndarray | None = None
    shapes: np.ndarray | None = None
    channels: tuple = ()

    def __post_init__(self):
        f = np.asarray(self.frequencies, dtype=float).reshape(-1)
        m = f.size
        if m == 0 or not np.all(np.isfinite(f) & (f > 0)):
            raise ValueError(f"frequencies: expected at least one positive frequency, got {self.frequencies!r}")
        object.__setattr__(self, "frequencies", f)
        for name in ("initial_sd", "drift", "scatter", "std_scale"):
            value = np.broadcast_to(np.asarray(getattr(self, name), dtype=float), (m,)).copy()
            if not np.all(np.isfinite(value) & (value >= 0)):
                raise ValueError(f"{name}: expected {m} finite values >= 0, got {getattr(self, name)!r}")
            object.__setattr__(self, name, value)
        corr = np.eye(m) if self.correlation is None else np.asarray(self.correlation, dtype=float)
        if corr.shape != (m, m) or not np.allclose(corr, corr.T) or np.any(np.abs(np.diag(corr) - 1) > 1e-12):
            raise ValueError(f"correlation: expected a symmetric ({m}, {m}) matrix with unit diagonal")
        object.__setattr__(self, "correlation", corr)
        if not self.spacing > 0:
            raise ValueError(f"spacing: expected a positive number of days, got {self.spacing!r}")
        if self.shapes is not None:
            shapes = np.asarray(self.shapes, dtype=float)
            if shapes.ndim != 2 or shapes.shape[1] != m or shapes.shape[0] != len(self.channels):
                raise ValueError(f"shapes: expected ({len(self.channels)}, {m}) for the channels, got {shapes.shape}")
            object.__setattr__(self, "shapes", shapes)

    @property
    def n_modes(self) -> int:
        return int(self.frequencies.size)

    @property
    def drift_covariance(self) -> np.ndarray:
        """``Q (m, m)``."""
        return self.drift[:, None] * self.correlation * self.drift[None, :]

    def initial_state(self, day: float = np.nan) -> TrackState:
        return TrackState(self.frequencies.copy(), np.diag(self.initial_sd ** 2), self.shapes, float(day))


@dataclass(frozen=True)
class TrackState:
    """The tracks after a record: ``mean (m,)`` [Hz], ``cov (m, m)``, ``shapes (p, m)`` or None, ``day``."""

    mean: np.ndarray
    cov: np.ndarray
    shapes: np.ndarray | None
    day: float


def shape_mac(pole_shapes: np.ndarray, track_shapes: np.ndarray) -> np.ndarray:
    """MAC of every pole shape ``(k, p)`` with every track shape ``(p, m)``: ``(k, m)``; NaN where a pole's
    shape has a NaN component."""
    a = np.asarray(pole_shapes, dtype=float)
    b = np.asarray(track_shapes, dtype=float)
    num = (a @ b) ** 2
    den = np.einsum("kp,kp->k", a, a)[:, None] * np.einsum("pm,pm->m", b, b)[None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


def assign(frequency, variance, mean, gate: float = 3.5, mac=None, mac_gate: float = 0.8) -> np.ndarray:
    """The optimal one-to-one assignment of ``k`` poles to ``m`` tracks inside the gate.

    Parameters
    ----------
    frequency : (k,) array
        The record's poles [Hz].
    variance : (k, m) array
        Variance of the innovation of pole ``i`` against track ``j``.
    mean : (m,) array
        The tracks' predictions [Hz].
    gate : float
    mac : (k, m) array, optional
        MAC of the poles' shapes with the tracks' (NaN: no shape, no MAC term).
    mac_gate : float

    Returns
    -------
    (k,) int array
        The track of each pole (0-based), -1 for a pole left unassigned.

    Examples
    --------
    >>> assign([0.3505, 0.355, 0.40], np.full((3, 2), 0.001 ** 2), [0.351, 0.354]).tolist()
    [0, 1, -1]
    """
    f = np.asarray(frequency, dtype=float).reshape(-1)
    mean = np.asarray(mean, dtype=float).reshape(-1)
    k, m = f.size, mean.size
    variance = np.broadcast_to(np.asarray(variance, dtype=float), (k, m))
    z2 = (f[:, None] - mean[None, :]) ** 2 / variance
    cost = 0.5 * z2
    allowed = z2 < gate ** 2
    if mac is not None:
        mac = np.asarray(mac, dtype=float)
        known = np.isfinite(mac)
        allowed &= ~known | (mac >= mac_gate)
        cost = cost + np.where(known, 0.5 * gate ** 2 * (1 - mac) / max(1 - mac_gate, 1e-12), 0.0)
        allowed &= cost < 0.5 * gate ** 2
    full = np.full((k + m, m + k), _UNMATCHED)
    full[:k, :m] = np.where(allowed, cost, _UNMATCHED)
    full[np.arange(k), m + np.arange(k)] = 0.25 * gate ** 2      # pole i left out (spurious)
    full[k + np.arange(m), np.arange(m)] = 0.25 * gate ** 2      # track j without a pole (missing)
    full[k:, m:] = 0.0
    rows, cols = linear_sum_assignment(full)
    out = np.full(k, -1)
    pairs = (rows < k) & (cols < m)
    ok = pairs.copy()
    ok[pairs] = allowed[rows[pairs], cols[pairs]]
    out[rows[ok]] = cols[ok]
    return out


def _pole_variance(reference: ReferenceModes, std: np.ndarray, predicted_var: np.ndarray) -> np.ndarray:
    """``(k, m)`` innovation variances: the track's predictive variance, its scatter and the scaled pole sd."""
    std = np.where(np.isfinite(std), std, 0.0)
    measurement = reference.scatter[None, :] ** 2 + (reference.std_scale[None, :] * std[:, None]) ** 2
    return predicted_var[None, :] + measurement, measurement


def _aligned(new, old):
    """``new`` with its sign turned towards ``old``."""
    s = np.sign(np.nansum(new * old))
    return new * (s if s != 0 else 1.0)


def track_step(state: TrackState, reference: ReferenceModes, record: PoleTable,
               settings: TrackerSettings = TrackerSettings()) -> tuple[TrackState, np.ndarray]:
    """One record through the tracker (module docstring, steps 1-4).

    Parameters
    ----------
    state : TrackState
        After the previous record (:meth:`ReferenceModes.initial_state` before the first).
    reference : ReferenceModes
    record : PoleTable
        The record's poles (one ``day``).
    settings : TrackerSettings

    Returns
    -------
    state : TrackState
    assignment : (k,) int array
        Each pole's track (0-based) or -1 (spurious).
    """
    day = float(record.day[0]) if record.n_rows else state.day
    dt = 1.0 if not np.isfinite(state.day) else max((day - state.day) / reference.spacing, 0.0)
    cov = state.cov + reference.drift_covariance * dt                              # step 1
    if not record.n_rows:
        return TrackState(state.mean, cov, state.shapes, day), np.zeros(0, dtype=int)
    variance, measurement = _pole_variance(reference, record.std_frequency, np.diag(cov))
    mac = None
    if state.shapes is not None and record.shapes is not None and record.channels == reference.channels:
        mac = shape_mac(record.shapes, state.shapes)
    a = assign(record.frequency, variance, state.mean, settings.gate, mac, settings.mac_gate)   # step 2
    mean, shapes = state.mean, state.shapes
    chosen = np.flatnonzero(a >= 0)
    if chosen.size:                                                                  # step 3
        tracks = a[chosen]
        H = np.eye(mean.size)[tracks]
        R = np.diag(measurement[chosen, tracks])
        S = H @ cov @ H.T + R
        gain = np.linalg.solve(S, H @ cov).T
        mean = mean + gain @ (record.frequency[chosen] - mean[tracks])
        I_KH = np.eye(mean.size) - gain @ H
        cov = I_KH @ cov @ I_KH.T + gain @ R @ gain.T                               # Joseph form: stays PSD
        if mac is not None:                                                          # step 4
            shapes = shapes.copy()
            for i, j in zip(chosen, tracks):
                if np.all(np.isfinite(record.shapes[i])):
                    new = _aligned(record.shapes[i], shapes[:, j])
                    blend = (1 - settings.shape_memory) * shapes[:, j] + settings.shape_memory * new
                    shapes[:, j] = blend / np.max(np.abs(blend))
    return TrackState(mean, 0.5 * (cov + cov.T), shapes, day), a


@dataclass(frozen=True)
class TrackedModes:
    """The tracker's output over many records.

    Attributes
    ----------
    poles : PoleTable
        Every pole given.
    reference : ReferenceModes
        The reference the tracks started from.
    assignment : (n,) int array
        Each pole's tracked mode, 1-based; 0: spurious (assigned to no mode).
    day : (R,) array
        The records' start [days].
    rows : tuple of R arrays
        Each record's row indices in ``poles``.
    frequency, std_frequency : (R, m) arrays
        The tracked pole of each mode in each record [Hz] and its own standard error; NaN where missing.
    track_mean, track_sd : (R, m) arrays
        The tracks after each record (the filtered frequency and its sd).
    """

    poles: PoleTable
    reference: ReferenceModes
    assignment: np.ndarray
    day: np.ndarray
    rows: tuple
    frequency: np.ndarray
    std_frequency: np.ndarray
    track_mean: np.ndarray
    track_sd: np.ndarray

    @property
    def n_modes(self) -> int:
        return self.reference.n_modes

    @property
    def coverage(self) -> np.ndarray:
        """``(m,)``: share of the records in which each mode was found."""
        return np.mean(np.isfinite(self.frequency), axis=0)

    @property
    def spurious(self) -> np.ndarray:
        """``(R,)``: poles of each record assigned to no mode."""
        return np.array([int(np.sum(self.assignment[r] == 0)) for r in self.rows])

    def scatter(self) -> dict:
        """Per mode (``(m,)`` arrays): ``mean``, ``sd`` and ``range`` of the tracked frequencies [Hz], and
        ``step_sd``, the sd of their change between consecutive records where both hold the mode [Hz]."""
        def sd(values):
            values = values[np.isfinite(values)]
            return float(np.std(values, ddof=1)) if values.size > 1 else np.nan
        f = self.frequency
        seen = [col[np.isfinite(col)] for col in f.T]
        return {"mean": np.array([v.mean() if v.size else np.nan for v in seen]),
                "sd": np.array([sd(v) for v in seen]),
                "range": np.array([np.ptp(v) if v.size else np.nan for v in seen]),
                "step_sd": np.array([sd(col) for col in np.diff(f, axis=0).T])}

    def summary(self) -> str:
        """A markdown table, one row per mode: coverage, mean, sd and range of the tracked frequencies."""
        sc = self.scatter()
        lines = ["| mode | coverage | mean [Hz] | sd [Hz] | range [Hz] | record-to-record sd [Hz] |",
                 "|---|---|---|---|---|---|"]
        for j in range(self.n_modes):
            lines.append(f"| {j + 1} | {100 * self.coverage[j]:.1f} % | {sc['mean'][j]:.4f} | {sc['sd'][j]:.4f} | "
                         f"{sc['range'][j]:.4f} | {sc['step_sd'][j]:.4f} |")
        return "\n".join(lines)

    def datasets(self, covariates: tuple | None = None) -> list[PoleTable]:
        """One table per record holding at least one tracked mode: its tracked poles (column ``mode``, one row
        per mode found, in mode order) with the record's covariates.

        Parameters
        ----------
        covariates : (day (C,), {name: (C,) array}), optional
            As :func:`seqbayes.structural.modes_table.read_covariates`; each record takes the row of the
            nearest ``day`` within half a record spacing (NaN if none).
        """
        out = []
        for r, rows in enumerate(self.rows):
            rows = rows[self.assignment[rows] > 0]
            if not rows.size:
                continue
            rows = rows[np.argsort(self.assignment[rows], kind="stable")]
            table = self.poles.take(rows)
            extra = dict(table.covariates)
            if covariates is not None:
                extra.update(covariates_at(self.day[r], covariates, self.reference.spacing))
            out.append(replace(table, mode=self.assignment[rows],
                               covariates={k: np.broadcast_to(v, rows.shape) for k, v in extra.items()}))
        return out

    def write_datasets(self, folder, prefix: str = "record", covariates: tuple | None = None) -> list[Path]:
        """Write :meth:`datasets` as ``folder/<prefix>_<NNN>.csv`` (numbered in time order, from 1).

        Returns
        -------
        list of pathlib.Path
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        tables = self.datasets(covariates)
        width = max(3, len(str(len(tables))))
        return [write_modes_table(folder / f"{prefix}_{i + 1:0{width}d}.csv", t) for i, t in enumerate(tables)]


def covariates_at(day: float, covariates: tuple, spacing: float) -> dict:
    """The covariates ``(day (C,), {name: (C,)})`` of the row nearest ``day`` within half a record ``spacing``
    (NaN if none), as ``{name: 0-d array}``."""
    days, values = covariates
    i = int(np.argmin(np.abs(np.asarray(days) - day))) if len(days) else -1
    near = i >= 0 and abs(days[i] - day) <= 0.5 * spacing + 1e-9
    return {name: np.array(v[i] if near else np.nan) for name, v in values.items()}


def track_poles(poles: PoleTable, reference: ReferenceModes | None = None,
                settings: TrackerSettings = TrackerSettings()) -> TrackedModes:
    """Track every record of ``poles`` (module docstring): the thin driver over :func:`track_step`.

    Parameters
    ----------
    poles : PoleTable
        Poles of many records (grouped by ``day``).
    reference : ReferenceModes, optional
        Default: :func:`reference_from_poles` on the first ``settings.initial_days``.
    settings : TrackerSettings

    Returns
    -------
    TrackedModes
    """
    reference = reference_from_poles(poles, settings) if reference is None else reference
    records = poles.records()
    m = reference.n_modes
    state = reference.initial_state()
    assignment = np.zeros(poles.n_rows, dtype=int)
    R = len(records)
    freq, std, mean, sd = (np.full((R, m), np.nan) for _ in range(4))
    for r, rows in enumerate(records):
        state, a = track_step(state, reference, poles.take(rows), settings)
        assignment[rows] = a + 1
        hit = a >= 0
        freq[r, a[hit]] = poles.frequency[rows[hit]]
        std[r, a[hit]] = poles.std_frequency[rows[hit]]
        mean[r], sd[r] = state.mean, np.sqrt(np.diag(state.cov))
    return TrackedModes(poles, reference, assignment, np.array([poles.day[r[0]] for r in records]),
                        tuple(records), freq, std, mean, sd)


# ------------------------------------------------------------------ the reference from the data
def _bands(log_f: np.ndarray, gap: float) -> list[np.ndarray]:
    order = np.argsort(log_f)
    cuts = np.flatnonzero(np.diff(log_f[order]) > np.log1p(gap)) + 1
    return np.split(order, cuts)


def _merged(values: np.ndarray, merge: float) -> np.ndarray:
    """Sorted values with runs closer than ``merge`` (relative) replaced by their mean."""
    v = np.sort(values)
    groups = np.split(v, np.flatnonzero(np.diff(np.log(v)) > np.log1p(merge)) + 1)
    return np.array([g.mean() for g in groups])


def _local_level_nll(log_params, f, std, dt, x0, p0):
    """Negative log-likelihood of one track's series under the local-level model (NaN: missing)."""
    q, s2, c2 = np.exp(log_params)
    x, p, nll = x0, p0, 0.0
    for y, sig, step in zip(f, std, dt):
        p = p + q * step
        if np.isfinite(y):
            var = p + s2 + c2 * sig ** 2
            e = y - x
            nll += 0.5 * (np.log(2 * np.pi * var) + e * e / var)
            k = p / var
            x, p = x + k * e, (1 - k) * p
    return nll


def reference_from_poles(poles: PoleTable, settings: TrackerSettings = TrackerSettings(),
                         frequencies=None) -> ReferenceModes:
    """The tracked modes and their noise, found in the first ``settings.initial_days`` of ``poles``
    (module docstring).

    Parameters
    ----------
    poles : PoleTable
    settings : TrackerSettings
    frequencies : (m,) array, optional
        The modes to track [Hz], if known (their noise is still fitted to the first days).

    Raises
    ------
    ValueError
        Fewer than 5 records in that window without ``frequencies`` (with them, the noise takes defaults:
        0.3 % of each frequency), or no band seen often enough (the message says what to change).
    """
    records = poles.records()
    day = np.array([poles.day[r[0]] for r in records])
    spacing = float(np.median(np.diff(day))) if day.size > 1 else 1.0
    window = [r for r, d in zip(records, day) if d < day[0] + settings.initial_days]
    if frequencies is not None:
        freqs = np.sort(np.asarray(frequencies, dtype=float).reshape(-1))
        if freqs.size == 0 or not np.all(np.isfinite(freqs) & (freqs > 0)):
            raise ValueError(f"frequencies: expected positive frequencies [Hz], got {frequencies!r}")
        spreads = 0.003 * freqs
        if len(window) < 5:       # too little to fit the noise: a drift of half, a scatter of the whole default spread (comment-ok: the 0.003 above)
            return ReferenceModes(freqs, spreads, drift=0.5 * spreads, scatter=spreads, std_scale=0.0,
                                  spacing=spacing)
    elif len(window) < 5:
        raise ValueError(f"poles: {len(window)} record(s) in the first {settings.initial_days:g} days; the modes "
                         f"are found from at least 5 (raise initial_days, or give the modes to track)")
    rows = np.concatenate(window)
    if frequencies is None:
        freqs, spreads = _modes_in_window(poles, window, settings)
    spreads = np.maximum(spreads, 1e-4 * freqs)
    shapes, channels = _initial_shapes(poles, rows, freqs)
    first = ReferenceModes(freqs, spreads, drift=0.5 * spreads, scatter=spreads, std_scale=0.0, spacing=spacing,
                           shapes=shapes, channels=channels)
    return _fitted(first, poles, window, settings)


def _modes_in_window(poles: PoleTable, window: list, settings: TrackerSettings) -> tuple:
    """The modes of the window's bands (module docstring): ``(frequencies (m,), spreads (m,))``."""
    rows = np.concatenate(window)
    record_of = np.concatenate([np.full(r.size, i) for i, r in enumerate(window)])
    f = poles.frequency[rows]
    freqs, spreads = [], []
    for band in _bands(np.log(f), settings.band_gap):
        per_record = [f[band][record_of[band] == i] for i in range(len(window))]
        counts = np.array([_merged(v, settings.merge).size if v.size else 0 for v in per_record])
        n_modes = 0
        while np.mean(counts >= n_modes + 1) >= settings.min_presence:
            n_modes += 1
        if n_modes == 0:
            continue
        ranked = np.array([_merged(v, settings.merge) for v, c in zip(per_record, counts) if c == n_modes])
        freqs += list(np.median(ranked, axis=0))
        spreads += list(1.4826 * np.median(np.abs(ranked - np.median(ranked, axis=0)), axis=0))
    if not freqs:
        raise ValueError(f"poles: no frequency band holds poles in at least {settings.min_presence:.0%} of the "
                         f"{len(window)} records of the first {settings.initial_days:g} days; lower min_presence or "
                         f"give the reference modes")
    return np.array(freqs), np.array(spreads)


def _initial_shapes(poles, rows, freqs):
    if poles.shapes is None:
        return None, ()
    shapes = np.ones((len(poles.channels), freqs.size))
    for j, fj in enumerate(freqs):          # the shape of the window's pole nearest each mode
        near = rows[np.argmin(np.abs(poles.frequency[rows] - fj))]
        if np.all(np.isfinite(poles.shapes[near])):
            shapes[:, j] = poles.shapes[near] / np.max(np.abs(poles.shapes[near]))
    return shapes, poles.channels


def _fitted(first: ReferenceModes, poles: PoleTable, window: list, settings: TrackerSettings) -> ReferenceModes:
    """``first`` with each track's drift, scatter and pole-sd scale fitted by maximum likelihood to the tracked
    window (the drifts stay independent: see the module docstring)."""
    sub = poles.take(np.concatenate(window))
    tracked = track_poles(sub, first, settings)
    dt = np.r_[1.0, np.diff(tracked.day) / first.spacing]
    drift, scatter, scale = first.drift.copy(), first.scatter.copy(), first.std_scale.copy()
    for j in range(first.n_modes):
        f, std = tracked.frequency[:, j], np.nan_to_num(tracked.std_frequency[:, j])
        if np.isfinite(f).sum() < 5:
            continue
        start = np.log([first.initial_sd[j] ** 2 / 4, first.initial_sd[j] ** 2, 1e-4])
        fit = minimize(_local_level_nll, start, args=(f, std, dt, first.frequencies[j], first.initial_sd[j] ** 2),
                       method="L-BFGS-B", bounds=[(np.log(1e-12 * first.frequencies[j] ** 2),
                                                   np.log(1e-2 * first.frequencies[j] ** 2))] * 2
                       + [(np.log(1e-8), np.log(4.0))])
        q, s2, c2 = np.exp(fit.x)
        drift[j], scatter[j], scale[j] = np.sqrt(q), np.sqrt(s2), np.sqrt(c2)
    return replace(first, drift=drift, scatter=scatter, std_scale=scale)
