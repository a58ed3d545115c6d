"""Settings chosen from the record: the band, the decimation, the block rows, the model orders, the blocks.

:func:`choose_settings` looks at the record (its sampling rate, length and channels) and at its
spectrum, and returns the settings as a value (:class:`Settings`), with the warnings it has for the
user; :func:`normalise` (detrend, one common scale) comes before, :func:`decimate` after. The rules,
each measured in docs/oma.md:

- **Band.** Given, or derived from the spectrum: the sum over channels of each channel's Welch
  spectrum divided by its variance. The band runs from half the frequency of its lowest peak (a
  prominence of ``PEAK_DB``) to 1.25 times the highest frequency where it stands 10 dB above its
  floor (the 20th percentile of the upper half of the spectrum), and never below the frequency of
  which the record holds ``MIN_CYCLES`` cycles.
- **Decimation.** By the largest integer factor that keeps the band below 0.8 of the new Nyquist
  frequency (scipy's polyphase FIR filter, zero phase).
- **Block rows.** Lags up to ``2 s - 1`` span two periods of the band's lowest frequency, with at
  least ``max_order / p + 1`` rows; ``s p`` at most 720 (the SVD's cost), ``s`` at most 150.
- **Model orders.** ``2 .. max_order`` in steps of 2, ``max_order = min(100, max(40, 20 p), (s - 1) p)``.
- **Blocks for the standard errors.** 20 contiguous blocks, fewer when a block would hold fewer
  than 10 times ``2 s`` lags; none below 5.

Checks that refuse the record (one ``ValueError`` line): fewer than ``MIN_CYCLES`` cycles of the
band's lowest frequency; a band outside ``(0, Nyquist)``; a constant channel. Checks that warn
(:class:`OMAWarning`): energy up to the Nyquist frequency (the record may be aliased or its stated
rate too low).
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass

import numpy as np
from scipy import signal

__all__ = ["OMAWarning", "Settings", "choose_settings", "spectrum", "normalise", "decimate", "warn", "MIN_CYCLES"]

#: Fewest cycles of the band's lowest frequency a record must hold (the frequency's standard error is about
#: ``sqrt(2 zeta / (2 pi n))`` after ``n`` cycles: 0.8 % at 1 % damping and 50 cycles; comment-ok: the closed form's value).
MIN_CYCLES = 50
#: Largest Toeplitz dimension ``s p`` and block rows chosen automatically.
MAX_TOEPLITZ, MAX_BLOCK_ROWS = 720, 150
#: Share of the Nyquist frequency that the band may reach after decimation.
BAND_SHARE = 0.8
#: The top of the spectrum (share of Nyquist) that the aliasing check looks at, and the level (dB below
#: the spectrum's peak) above which energy there is reported: measured -16 to -19 dB on records decimated
#: without a filter, -29 dB at most on records sampled right (docs/oma.md, "Bad records").
ALIAS_SHARE, ALIAS_DB = 0.9, 24.0
#: Prominence [dB] of a spectral peak that sets the derived band's lower edge (half its frequency).
PEAK_DB = 6.0


class OMAWarning(UserWarning):
    """A result that needs the user's attention: partial, empty, or a record that may be aliased."""


@dataclass(frozen=True)
class Settings:
    """What :func:`choose_settings` chose (all also in the JSON the command writes).

    Attributes
    ----------
    band : (float, float)
        Frequencies sought [Hz].
    band_given : bool
    decimation : int
        Factor applied to the record (1: none).
    dt : float
        Sampling step after decimation [s].
    block_rows : int
    max_order : int
    n_blocks : int
        Blocks for the standard errors (0: none).
    samples : int
        Samples after decimation.
    channels : int
    """

    band: tuple
    band_given: bool
    decimation: int
    dt: float
    block_rows: int
    max_order: int
    n_blocks: int
    samples: int
    channels: int

    def as_dict(self) -> dict:
        return asdict(self)


def spectrum(y: np.ndarray, dt: float, resolution: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies and the sum over channels of each channel's Welch spectrum divided by its variance."""
    T = y.shape[0]
    nperseg = int(min(T // 4, 2 ** int(np.log2(max(T // 8, 16)))))
    if resolution is not None:
        nperseg = int(min(nperseg, max(16, 2 ** int(np.ceil(np.log2(1.0 / (resolution * dt)))))))
    freqs, psd = signal.welch(y, fs=1.0 / dt, nperseg=max(nperseg, 8), axis=0, detrend="constant")
    with np.errstate(divide="ignore", invalid="ignore"):
        total = np.nansum(psd / np.var(y, axis=0), axis=1)
    return freqs, total


def _derived_band(freqs: np.ndarray, total: np.ndarray, duration: float, nyquist: float) -> tuple[float, float]:
    upper = freqs >= nyquist / 2
    floor = np.percentile(total[upper], 20) if upper.sum() >= 4 else np.min(total)
    lowest = max(MIN_CYCLES / duration, 2 * freqs[1])
    above = np.flatnonzero((total > 10 * floor) & (freqs >= lowest))
    hi = BAND_SHARE * nyquist if above.size == 0 else min(BAND_SHARE * nyquist, freqs[above[-1]] * 1.25)
    level = 10 * np.log10(np.maximum(total, 1e-300))
    peaks, _ = signal.find_peaks(level, prominence=PEAK_DB)
    peaks = peaks[(freqs[peaks] >= lowest) & (freqs[peaks] <= hi)]
    lo = lowest if peaks.size == 0 else max(lowest, freqs[peaks[0]] / 2)
    return lo, max(hi, min(BAND_SHARE * nyquist, 2 * lo))


def _aliasing(freqs: np.ndarray, total: np.ndarray, nyquist: float) -> str | None:
    top = freqs >= ALIAS_SHARE * nyquist
    if top.sum() < 2:
        return None
    level = 10 * np.log10(np.median(total[top]) / np.max(total[freqs > 0]))
    if level > -ALIAS_DB:
        return (f"the spectrum holds energy up to the Nyquist frequency {nyquist:.4g} Hz ({level:.0f} dB of its peak "
                f"above {ALIAS_SHARE * nyquist:.4g} Hz): the record may be aliased or its stated sampling rate too low; "
                f"check the rate, or record with an anti-aliasing filter below {nyquist:.4g} Hz")
    return None


def choose_settings(y: np.ndarray, dt: float, band=None, max_order: int | None = None,
                    block_rows: int | None = None, n_blocks: int | None = None) -> tuple[Settings, list[str]]:
    """The settings for record ``y (T, p)`` at step ``dt`` (see the module docstring), and the warnings.

    ``band``, ``max_order``, ``block_rows`` and ``n_blocks`` override the automatic choice.
    """
    T, p = y.shape
    duration, nyquist = T * dt, 0.5 / dt
    notes = []
    freqs, total = spectrum(y, dt)
    alias = _aliasing(freqs, total, nyquist)
    if alias:
        notes.append(alias)
    if band is None:
        lo, hi = _derived_band(freqs, total, duration, nyquist)
    else:
        try:
            lo, hi = (float(v) for v in band)
        except (TypeError, ValueError):
            raise ValueError(f"band: expected two frequencies (lo, hi) in Hz, got {band!r}") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo < hi <= nyquist):
            raise ValueError(f"band: expected 0 <= lo < hi <= the Nyquist frequency {nyquist:.4g} Hz, got ({lo:g}, {hi:g})")
    cycles = duration * lo if lo > 0 else np.inf
    if band is not None and cycles < MIN_CYCLES:
        raise ValueError(f"y: the record ({duration:.4g} s) is too short for the band: it holds {cycles:.3g} cycles of "
                         f"the band's lowest frequency {lo:g} Hz, and OMA needs at least {MIN_CYCLES} (record at least "
                         f"{MIN_CYCLES / max(lo, 1e-300):.4g} s, or start the band at {MIN_CYCLES / duration:.3g} Hz or above)")
    if band is None and duration * BAND_SHARE * nyquist < MIN_CYCLES:
        raise ValueError(f"y: the record ({duration:.4g} s, {T} samples) is too short: it holds fewer than "
                         f"{MIN_CYCLES} cycles of any frequency below {BAND_SHARE:g} of the Nyquist frequency "
                         f"{nyquist:.4g} Hz; record longer")
    factor = max(1, int(np.floor(BAND_SHARE * nyquist / hi))) if hi > 0 else 1
    dt_new = dt * factor
    samples = T // factor
    floor_lo = max(lo, 1.0 / (dt_new * MAX_BLOCK_ROWS))
    if block_rows is None:
        wanted_order = min(100, max(40, 20 * p)) if max_order is None else int(max_order)
        block_rows = int(np.ceil(1.0 / (floor_lo * dt_new)))
        block_rows = max(block_rows, int(np.ceil(wanted_order / p)) + 1, 4)
        block_rows = min(block_rows, MAX_BLOCK_ROWS, max(MAX_TOEPLITZ // p, int(np.ceil(40 / p)) + 1))
    block_rows = int(block_rows)
    if block_rows < 2 or 2 * block_rows >= samples:
        raise ValueError(f"block_rows: expected 2 <= block_rows < samples / 2 = {samples // 2} (after decimation by "
                         f"{factor}), got {block_rows}; the record is too short for its band")
    if max_order is None:
        max_order = min(100, max(40, 20 * p), (block_rows - 1) * p)
        max_order -= max_order % 2
    max_order = int(max_order)
    if max_order < 4 or max_order % 2 or max_order > (block_rows - 1) * p:
        raise ValueError(f"max_order: expected an even order 4 .. (block_rows - 1) * p = {(block_rows - 1) * p}, "
                         f"got {max_order}")
    if n_blocks is None:
        n_blocks = int(min(20, samples // (10 * 2 * block_rows)))
        n_blocks = n_blocks if n_blocks >= 5 else 0
    settings = Settings((float(lo), float(hi)), band is not None, factor, dt_new, block_rows, max_order,
                        int(n_blocks), samples, p)
    return settings, notes


def normalise(y: np.ndarray) -> np.ndarray:
    """Detrended and scaled to unit overall RMS (one factor for all channels: no overflow in LAPACK at any
    amplitude, and the shapes keep their units); a constant channel is refused."""
    peak = np.max(np.abs(y))
    if peak == 0:
        raise ValueError("y: every channel is constant (or a straight line): there is no vibration to identify")
    y = signal.detrend(y / peak, axis=0, type="linear")
    rms = np.sqrt(np.mean(y**2, axis=0))
    flat = np.flatnonzero(rms <= 1e-10)  # the record is scaled to a peak of 1: below this is round-off of a constant
    if rms.max() == 0 or flat.size == y.shape[1]:
        raise ValueError("y: every channel is constant (or a straight line): there is no vibration to identify")
    if flat.size:
        raise ValueError(f"y: channel{'s' if flat.size > 1 else ''} {', '.join(map(str, flat))} "
                         f"{'are' if flat.size > 1 else 'is'} constant (or a straight line); remove "
                         f"{'them' if flat.size > 1 else 'it'} before OMA")
    return y / np.sqrt(np.mean(y**2))


def decimate(y: np.ndarray, settings: Settings) -> np.ndarray:
    """The normalised record decimated to the band (zero-phase polyphase FIR), or itself."""
    if settings.decimation > 1:
        y = signal.resample_poly(y, 1, settings.decimation, axis=0)
    return y


def warn(notes) -> None:
    """Emit each note as an :class:`OMAWarning` (the command prints each as one line)."""
    for note in notes:
        warnings.warn(note, OMAWarning, stacklevel=3)
