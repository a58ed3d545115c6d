"""Identified modes as the measurement of a linear model: the modal likelihood (docs/modal.md).

A dataset is one record's tracked modes (:mod:`seqbayes.structural.tracking`): per measured mode
``r`` its frequency ``f_r`` with the OMA's standard error ``sigma_r`` and, optionally, its shape
``phi_r`` at some channels with standard errors ``sigma_phi``. A model
(:mod:`seqbayes.structural.structures.linear`) predicts, for each particle, the frequencies
``f_hat_k`` and shapes ``phi_hat_k`` of its lowest modes. With measured mode ``r`` paired with
predicted mode ``k = pi(r)``::

    log L = sum_r  log N(f_r; f_hat_k, (c sigma_r)^2 + (e_f f_hat_k)^2)
          + sum_r sum_c  log N(phi_rc; s_rk phi_hat_kc, sigma_phi_rc^2 + e_phi^2)

``c`` scales the OMA's standard errors (1: as reported), ``e_f`` is the relative frequency
prediction error and ``e_phi`` the shape prediction error, each set or learned (:class:`Fixed`,
:class:`Learned`); ``s_rk`` is the weighted least-squares scale of the predicted shape onto the
measured one (the shapes' normalisation and sign are not information). With equal variances the
shape term is ``-|phi_r|^2 (1 - MAC(phi_r, phi_hat_k)) / (2 var)`` plus a constant: the MAC
criterion as a Gaussian residual (Vanik, Beck & Au 2000).

The pairing ``pi`` (:class:`ByMode`, :class:`ByAssignment`) is made inside the likelihood, for each
particle: by the tracked mode's number, or by the one-to-one assignment of measured to predicted
modes that maximises the likelihood (frequency and shape terms), so that two predicted modes that
swap order as the parameters move are followed by their shapes. A mode missing from a record has no
row and no term. Everything is vectorised over the ``(N, d)`` particles; the assignment is solved per
particle only where the best predicted mode of two measured modes coincides.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["ModalData", "ModalLikelihood", "Fixed", "Learned", "ByMode", "ByAssignment", "modal_data"]

_LOG_2PI = float(np.log(2 * np.pi))


@dataclass(frozen=True)
class Fixed:
    """A prediction-error sd that is set: one value, or one per tracked mode (indexed by the mode's id)."""

    value: float | tuple = 0.0

    def __post_init__(self):
        v = np.asarray(self.value, dtype=float)
        if v.ndim > 1 or not np.all(np.isfinite(v) & (v >= 0)):
            raise ValueError(f"value: expected a sd >= 0 or one per mode, got {self.value!r}")

    def values(self, theta: np.ndarray, mode: np.ndarray) -> np.ndarray:
        """``(N, k)`` (or broadcastable) sd for the ``k`` measured modes ``mode (k,)`` (ids, 1-based)."""
        v = np.asarray(self.value, dtype=float)
        if v.ndim == 0:
            return v[None, None]
        if np.max(mode) > v.size:
            raise ValueError(f"error: {v.size} per-mode values, but the data hold mode {int(np.max(mode))}")
        return v[mode - 1][None, :]


@dataclass(frozen=True)
class Learned:
    """A prediction-error sd that is a parameter: column ``column`` of ``theta``."""

    column: int

    def values(self, theta: np.ndarray, mode: np.ndarray) -> np.ndarray:
        return theta[:, [self.column]]


@dataclass(frozen=True)
class ByMode:
    """Measured mode ``r`` (its tracked id) is predicted mode ``model_modes[r - 1]`` (1-based; default ``r``)."""

    model_modes: tuple | None = None

    def pair(self, cost: np.ndarray, mode: np.ndarray, n_predicted: int) -> np.ndarray:
        index = mode - 1 if self.model_modes is None else np.asarray(self.model_modes, dtype=int)[mode - 1] - 1
        if np.any(index >= n_predicted) or np.any(index < 0):
            raise ValueError(f"mode: the data hold mode {int(np.max(mode))}, but the model predicts {n_predicted} "
                             f"modes")
        return np.broadcast_to(index, cost.shape[:2])


@dataclass(frozen=True)
class ByAssignment:
    """Measured modes paired with predicted modes by the one-to-one assignment of least cost (the negative
    log-likelihood of the pair), per particle."""

    def pair(self, cost: np.ndarray, mode: np.ndarray, n_predicted: int) -> np.ndarray:
        N, k, q = cost.shape
        if k > q:
            raise ValueError(f"data: {k} measured modes, but the model predicts only {q}")
        best = np.argmin(cost, axis=2)                                # (N, k)
        ordered = np.sort(best, axis=1)
        clash = np.flatnonzero(np.any(ordered[:, 1:] == ordered[:, :-1], axis=1)) if k > 1 else []
        for n in clash:                                               # rare: two measured modes want one
            c = np.where(np.isfinite(cost[n]), cost[n], 1e300)
            rows, cols = linear_sum_assignment(c)
            best[n, rows] = cols
        return best


@dataclass(frozen=True)
class ModalData:
    """One record's measured modes (``k`` rows).

    Attributes
    ----------
    mode : (k,) int array
        Tracked ids (1-based).
    frequency, std_frequency : (k,) arrays
        [Hz]; an unknown sd is 0 (the prediction error alone).
    shapes, std_shapes : (k, p) arrays or None
        At ``channels``; NaN components are not measured.
    channels : tuple of str
    """

    mode: np.ndarray
    frequency: np.ndarray
    std_frequency: np.ndarray
    shapes: np.ndarray | None = None
    std_shapes: np.ndarray | None = None
    channels: tuple = ()


def modal_data(data) -> ModalData:
    """A :class:`ModalData` from a dict of columns (``mode``, ``frequency_hz``, ``std_frequency_hz``,
    ``phi_<channel>``, ``std_phi_<channel>``: a run store's ``format = "columns"``), a
    :class:`~seqbayes.structural.modes_table.PoleTable` with ``mode``, or a ``ModalData``."""
    if isinstance(data, ModalData):
        return data
    if hasattr(data, "frequency") and hasattr(data, "mode"):
        if data.mode is None:
            raise ValueError("data: a modes table without a mode column; track it first "
                             "(seqbayes.structural.tracking) or pair by ByAssignment with mode = 1..k")
        return _checked(data.mode, data.frequency, data.std_frequency, data.shapes, data.std_shapes, data.channels)
    if not isinstance(data, dict):
        raise TypeError(f"data: expected a dict of columns (mode, frequency_hz, std_frequency_hz, phi_<channel>...), "
                        f"a PoleTable or ModalData, got {type(data).__name__}")
    missing = [c for c in ("mode", "frequency_hz") if c not in data]
    if missing:
        raise ValueError(f"data: missing column(s) {', '.join(missing)}; a modal dataset has mode, frequency_hz, "
                         f"std_frequency_hz and optionally phi_<channel>, std_phi_<channel>")
    channels = tuple(c[4:] for c in data if c.startswith("phi_"))
    k = np.asarray(data["frequency_hz"]).size
    shapes = np.column_stack([data[f"phi_{c}"] for c in channels]) if channels else None
    std_shapes = (np.column_stack([data.get(f"std_phi_{c}", np.zeros(k)) for c in channels]) if channels else None)
    return _checked(data["mode"], data["frequency_hz"], data.get("std_frequency_hz", np.zeros(k)), shapes, std_shapes,
                    channels)


def _checked(mode, frequency, std, shapes, std_shapes, channels) -> ModalData:
    f = np.asarray(frequency, dtype=float).reshape(-1)
    mode = np.asarray(mode, dtype=float).reshape(-1)
    if f.size == 0:
        raise ValueError("data: no measured mode (an empty record carries no information; skip it)")
    if mode.shape != f.shape or not np.all(np.isfinite(mode) & (mode >= 1) & (mode == np.round(mode))):
        raise ValueError("mode: expected a positive integer (the tracked mode, 1-based) per row")
    mode = mode.astype(int)
    if np.unique(mode).size != mode.size:
        raise ValueError(f"mode: a record holds mode {int(mode[np.argmax(np.bincount(mode))])} twice")
    if not np.all(np.isfinite(f) & (f > 0)):
        raise ValueError("frequency_hz: expected positive numbers")
    std = np.nan_to_num(np.broadcast_to(np.asarray(std, dtype=float).reshape(-1), f.shape), nan=0.0)
    if np.any(std < 0):
        raise ValueError("std_frequency_hz: expected standard errors >= 0")
    if shapes is not None:
        shapes = np.asarray(shapes, dtype=float).reshape(f.size, -1)
        std_shapes = np.nan_to_num(np.asarray(std_shapes, dtype=float).reshape(shapes.shape), nan=0.0)
        if np.any(std_shapes < 0):
            raise ValueError("std_phi: expected standard errors >= 0")
    return ModalData(mode, f, std, shapes, std_shapes, tuple(channels))


class ModalLikelihood:
    """``loglike(theta (N, d), data) -> (N,)`` of identified modes under a linear model (module docstring).

    Parameters
    ----------
    model
        ``n_parameters``, ``channels`` and ``modes(theta) -> (frequencies (N, q), shapes (N, p, q) or None)``
        (:mod:`seqbayes.structural.structures.linear`); it takes ``theta[:, :model.n_parameters]``.
    frequency_error : Fixed or Learned or float
        ``e_f``, relative (a float is :class:`Fixed`).
    shape_error : Fixed or Learned or float or None
        ``e_phi`` (in the measured shapes' units: largest component 1); None: shapes are not used.
    std_scale : float
        ``c``, the factor on the OMA's standard errors (0: ignore them).
    pairing : ByMode or ByAssignment
        Default :class:`ByMode` without shapes, :class:`ByAssignment` with them.

    Examples
    --------
    >>> from seqbayes.structural.structures.linear import ModeLevel
    >>> like = ModalLikelihood(ModeLevel(2), frequency_error=0.01)
    >>> data = {"mode": [2], "frequency_hz": [0.5], "std_frequency_hz": [0.0]}
    >>> like(np.array([[0.3, 0.5], [0.3, 0.505]]), data).round(3)
    array([4.379, 3.879])
    """

    def __init__(self, model, frequency_error=0.01, shape_error=None, std_scale: float = 1.0, pairing=None):
        self.model = model
        self.frequency_error = frequency_error if hasattr(frequency_error, "values") else Fixed(float(frequency_error))
        self.shape_error = (None if shape_error is None else
                            shape_error if hasattr(shape_error, "values") else Fixed(float(shape_error)))
        if not (np.isfinite(std_scale) and std_scale >= 0):
            raise ValueError(f"std_scale: expected a factor >= 0, got {std_scale!r}")
        self.std_scale = float(std_scale)
        if self.shape_error is not None and not getattr(model, "channels", ()):
            raise ValueError("shape_error: the model gives no mode shapes (no channels); leave shape_error None")
        self.pairing = pairing if pairing is not None else (ByMode() if self.shape_error is None else ByAssignment())
        if isinstance(self.frequency_error, Fixed) and np.any(np.asarray(self.frequency_error.value) == 0) \
                and self.std_scale == 0:
            raise ValueError("frequency_error, std_scale: both zero leaves the frequencies without a variance")

    @property
    def n_parameters(self) -> int:
        """Columns of ``theta`` read: the model's and the learned errors'."""
        learned = [e.column + 1 for e in (self.frequency_error, self.shape_error) if isinstance(e, Learned)]
        return max([self.model.n_parameters, *learned])

    def _shape_rows(self, data: ModalData):
        """The model's channel index of each data channel."""
        channels = tuple(self.model.channels)
        unknown = [c for c in data.channels if c not in channels]
        if unknown:
            raise ValueError(f"data: shape channel(s) {', '.join(unknown)} are not among the model's channels "
                             f"{', '.join(channels)}")
        return np.array([channels.index(c) for c in data.channels], dtype=int)

    def predict(self, theta: np.ndarray) -> tuple:
        """The model's ``(frequencies (N, q), shapes (N, p, q) or None)`` at ``theta (N, d)``."""
        return self.model.modes(np.atleast_2d(np.asarray(theta, dtype=float))[:, :self.model.n_parameters])

    def pair_terms(self, theta: np.ndarray, data: ModalData, modes: tuple | None = None) -> np.ndarray:
        """``(N, k, q)``: the log-likelihood of measured mode ``r`` if it were predicted mode ``j``, per particle
        (``modes``: :meth:`predict` at ``theta``, to reuse one eigensolution for several datasets)."""
        freqs, shapes = self.predict(theta) if modes is None else modes                # (N, q), (N, p, q)
        sd_model = self.frequency_error.values(theta, data.mode)                     # (N or 1, k)
        var = (self.std_scale * data.std_frequency)[None, :, None] ** 2 + \
            (sd_model[:, :, None] * freqs[:, None, :]) ** 2                          # (N, k, q)
        resid = data.frequency[None, :, None] - freqs[:, None, :]
        with np.errstate(divide="ignore", invalid="ignore"):
            out = -0.5 * (_LOG_2PI + np.log(var) + resid ** 2 / var)
        if self.shape_error is not None and data.shapes is not None:
            out = out + self._shape_terms(theta, data, shapes)
        return np.where(np.isfinite(out), out, -np.inf)

    def _shape_terms(self, theta, data, shapes):
        rows = self._shape_rows(data)
        predicted = shapes[:, rows, :]                                                # (N, p, q)
        measured = np.nan_to_num(data.shapes)                                         # (k, p)
        seen = np.isfinite(data.shapes)
        e = self.shape_error.values(theta, data.mode)                                 # (N or 1, k)
        var = data.std_shapes[None, :, :] ** 2 + e[:, :, None] ** 2                   # (N, k, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(seen[None], 1.0 / var, 0.0)                                 # (N, k, p)
            # weighted least-squares scale of predicted mode j onto measured mode r
            num = np.einsum("nkp,kp,npq->nkq", w, measured, predicted)
            den = np.einsum("nkp,npq->nkq", w, predicted ** 2)
            scale = num / den
            # sum_p w (phi - s phi_hat)^2 = sum w phi^2 - 2 s num + s^2 den = sum w phi^2 - num^2 / den (comment-ok: the algebra)
            quad = np.einsum("nkp,kp->nk", w, measured ** 2)[:, :, None] - scale * num
            log_det = np.sum(np.where(seen[None], np.log(var), 0.0), axis=2)         # (N, k)
        n_seen = seen.sum(axis=1)                                                     # (k,)
        return -0.5 * ((n_seen * _LOG_2PI)[None, :, None] + log_det[:, :, None] + np.maximum(quad, 0.0))

    def __call__(self, theta, data, modes: tuple | None = None) -> np.ndarray:
        """``(N,)`` log-likelihood of ``theta (N, d)`` given one record's modes (``modes``: as :meth:`pair_terms`)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] < self.n_parameters:
            raise ValueError(f"theta: expected at least {self.n_parameters} columns, got shape {theta.shape}")
        data = modal_data(data)
        terms = self.pair_terms(theta, data, modes)                                   # (N, k, q)
        if not terms.shape[2]:
            raise ValueError("model: predicts no mode")
        pairs = self.pairing.pair(-terms, data.mode, terms.shape[2])                  # (N, k)
        chosen = np.take_along_axis(terms, pairs[:, :, None], axis=2)[:, :, 0]
        return np.sum(chosen, axis=1)

    def predicted(self, theta, data) -> tuple[np.ndarray, np.ndarray]:
        """``(frequencies (N, k), pairing (N, k))``: the predicted frequency of each measured mode and the model
        mode (0-based) it was paired with."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        data = modal_data(data)
        terms = self.pair_terms(theta, data)
        pairs = self.pairing.pair(-terms, data.mode, terms.shape[2])
        freqs, _ = self.model.modes(theta[:, :self.model.n_parameters])
        return np.take_along_axis(freqs, pairs, axis=1), pairs
