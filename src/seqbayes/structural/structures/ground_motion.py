"""Ground motions: PEER NGA ``.AT2`` and two-column loaders, the bundled El
Centro 1940 record, Kanai-Tajimi synthetic accelerograms, band-limited white
noise, PGA scaling and resampling.

All functions return ``GroundMotion`` records with acceleration in m/s^2.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from ...rng import as_generator

__all__ = [
    "G",
    "GroundMotion",
    "read_at2",
    "read_two_column",
    "load_el_centro",
    "kanai_tajimi",
    "band_limited_white_noise",
    "resample",
    "scale_to_pga",
]

#: standard gravity [m/s^2]
G = 9.80665

_BUNDLED = {
    "180": "elcentro_1940_ELC180.AT2",
    "270": "elcentro_1940_ELC270.AT2",
}


@dataclass(frozen=True)
class GroundMotion:
    """A uniformly sampled ground acceleration.

    Attributes
    ----------
    acceleration : (T,) array
        Ground acceleration [m/s^2].
    dt : float
        Sampling step [s].
    name : str
    """

    acceleration: np.ndarray
    dt: float
    name: str = ""

    def __post_init__(self):
        a = np.asarray(self.acceleration, dtype=float)
        if a.ndim != 1 or a.size < 2:
            raise ValueError(f"acceleration: expected a 1-D series of length >= 2, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("acceleration: contains NaN or inf")
        if not np.isfinite(self.dt) or self.dt <= 0:
            raise ValueError(f"dt: must be positive, got {self.dt}")
        object.__setattr__(self, "acceleration", a)
        object.__setattr__(self, "dt", float(self.dt))

    @property
    def duration(self) -> float:
        return self.dt * (self.acceleration.size - 1)

    @property
    def time(self) -> np.ndarray:
        return np.arange(self.acceleration.size) * self.dt

    @property
    def pga(self) -> float:
        """Peak ground acceleration [m/s^2]."""
        return float(np.max(np.abs(self.acceleration)))

    def truncate(self, duration: float) -> "GroundMotion":
        """The first ``duration`` seconds."""
        n = int(round(duration / self.dt)) + 1
        return GroundMotion(self.acceleration[:n], self.dt, self.name)


def read_at2(path: str | os.PathLike) -> GroundMotion:
    """Read a PEER NGA ``.AT2`` file (acceleration in g) into m/s^2.

    Format: four header lines, the fourth holding ``NPTS=`` and ``DT=``, then
    the values (any number per line).
    """
    text = Path(path).read_text()
    lines = text.splitlines()
    if len(lines) < 5:
        raise ValueError(f"path: {path} is not an AT2 file (fewer than 5 lines)")
    header = lines[3].upper()
    npts = re.search(r"NPTS\s*=\s*(\d+)", header)
    dt = re.search(r"DT\s*=\s*([0-9.Ee+-]+)", header)
    if npts is None or dt is None:
        raise ValueError(f"path: {path}: fourth line lacks NPTS= and DT=: {lines[3]!r}")
    values = np.array(" ".join(lines[4:]).split(), dtype=float)
    n = int(npts.group(1))
    if values.size < n:
        raise ValueError(f"path: {path}: header says {n} points, found {values.size}")
    return GroundMotion(values[:n] * G, float(dt.group(1)), name=lines[1].strip())


def read_two_column(path: str | os.PathLike, units: str = "g", comments: str = "#") -> GroundMotion:
    """Read plain two-column text ``time acceleration`` (uniform time step).

    Parameters
    ----------
    units : {"g", "m/s2", "cm/s2"}
    """
    scale = {"g": G, "m/s2": 1.0, "cm/s2": 0.01}
    if units not in scale:
        raise ValueError(f"units: expected one of {sorted(scale)}, got {units!r}")
    data = np.loadtxt(path, comments=comments, ndmin=2)
    if data.shape[1] != 2:
        raise ValueError(f"path: expected two columns (time, acceleration), got {data.shape[1]}")
    t = data[:, 0]
    steps = np.diff(t)
    if steps.size == 0 or np.any(steps <= 0) or np.ptp(steps) > 1e-6 * max(abs(steps.mean()), 1e-12) + 1e-9:
        raise ValueError("path: the time column must be increasing with a uniform step")
    return GroundMotion(data[:, 1] * scale[units], float(steps.mean()), name=Path(path).stem)


def load_el_centro(component: str = "180") -> GroundMotion:
    """The bundled El Centro 1940 record (Imperial Valley, Array #9), dt = 0.01 s.

    Parameters
    ----------
    component : {"180", "270"}
        Horizontal component (N-S is 180). See ``data/PROVENANCE_ground_motion.md``.
    """
    if component not in _BUNDLED:
        raise ValueError(f"component: expected one of {sorted(_BUNDLED)}, got {component!r}")
    ref = resources.files("seqbayes") / "data" / _BUNDLED[component]
    with resources.as_file(ref) as path:
        record = read_at2(path)
    return GroundMotion(record.acceleration, record.dt, f"El Centro 1940 {component}")


def scale_to_pga(motion: GroundMotion, pga_g: float) -> GroundMotion:
    """Scale a motion linearly so that its peak is ``pga_g`` (in g)."""
    if not pga_g > 0:
        raise ValueError(f"pga_g: must be positive, got {pga_g}")
    return GroundMotion(motion.acceleration * (pga_g * G / motion.pga), motion.dt, motion.name)


def resample(motion: GroundMotion, dt: float) -> GroundMotion:
    """Resample to step ``dt`` with an anti-aliasing polyphase filter.

    Uses :func:`scipy.signal.resample_poly` when ``motion.dt / dt`` is a
    rational number with small terms (0.01 s -> 0.02 s is 1/2).
    """
    if not dt > 0:
        raise ValueError(f"dt: must be positive, got {dt}")
    from fractions import Fraction

    ratio = Fraction(motion.dt / dt).limit_denominator(1000)
    if abs(float(ratio) - motion.dt / dt) > 1e-9:
        raise ValueError(f"dt: {dt} is not a rational multiple of the record step {motion.dt}")
    if ratio == 1:
        return motion
    from scipy import signal  # imported here: scipy.signal alone doubles `import seqbayes`

    a = signal.resample_poly(motion.acceleration, ratio.numerator, ratio.denominator)
    return GroundMotion(a, dt, motion.name)


def _envelope(t: np.ndarray, duration: float) -> np.ndarray:
    """Jennings-type envelope: quadratic rise (first 10 %), plateau, exponential decay (last 50 %)."""
    t1, t2 = 0.1 * duration, 0.5 * duration
    env = np.ones_like(t)
    env[t < t1] = (t[t < t1] / t1) ** 2
    late = t > t2
    env[late] = np.exp(-3.0 * (t[late] - t2) / (duration - t2))
    return env


def kanai_tajimi(duration: float, dt: float, pga_g: float = 0.07, ground_frequency_hz: float = 2.5,
                 ground_damping: float = 0.6, rng: int | np.random.Generator | None = None, envelope: bool = True) -> GroundMotion:
    """Kanai-Tajimi filtered white noise with an envelope, scaled to a PGA.

    The white noise drives the ground filter
    ``H(s) = (2 zeta_g w_g s + w_g^2) / (s^2 + 2 zeta_g w_g s + w_g^2)``,
    discretised bilinearly; then a Jennings envelope and a baseline removal are
    applied and the record is scaled to ``pga_g``.
    """
    if not duration > 0 or not dt > 0:
        raise ValueError(f"duration, dt: must be positive, got {duration}, {dt}")
    if not ground_frequency_hz > 0 or not ground_damping > 0:
        raise ValueError("ground_frequency_hz, ground_damping: must be positive")
    rng = as_generator(rng)
    n = int(round(duration / dt)) + 1
    wg = 2 * np.pi * ground_frequency_hz
    zg = ground_damping
    from scipy import signal

    b, a = signal.bilinear([2 * zg * wg, wg**2], [1, 2 * zg * wg, wg**2], fs=1 / dt)
    a_g = signal.lfilter(b, a, rng.standard_normal(n))
    if envelope:
        a_g = a_g * _envelope(np.arange(n) * dt, duration)
    a_g = a_g - np.linspace(a_g[0], a_g[-1], n)  # start and end at zero
    motion = GroundMotion(a_g, dt, f"Kanai-Tajimi ({ground_frequency_hz} Hz, {zg})")
    return scale_to_pga(motion, pga_g)


def band_limited_white_noise(duration: float, dt: float, band: tuple[float, float] = (0.5, 50.0),
                             rms_g: float = 0.02, rng: int | np.random.Generator | None = None) -> GroundMotion:
    """Gaussian white noise band-passed to ``band`` Hz and scaled to an RMS (in g).

    The paper's identification input is 0.5-50 Hz noise. The upper edge is
    clipped to 0.45 / dt (below Nyquist); at 50 Hz sampling the band is
    0.5-22.5 Hz. A 4th-order zero-phase Butterworth filter is used.
    """
    if not duration > 0 or not dt > 0:
        raise ValueError(f"duration, dt: must be positive, got {duration}, {dt}")
    low, high = float(band[0]), float(band[1])
    high = min(high, 0.45 / dt)
    if not 0 < low < high:
        raise ValueError(f"band: need 0 < low < high (after clipping to Nyquist), got {band}")
    rng = as_generator(rng)
    n = int(round(duration / dt)) + 1
    from scipy import signal

    sos = signal.butter(4, [low, high], btype="bandpass", fs=1 / dt, output="sos")
    a_g = signal.sosfiltfilt(sos, rng.standard_normal(n))
    a_g *= rms_g * G / np.sqrt(np.mean(a_g**2))
    return GroundMotion(a_g, dt, f"white noise {low}-{high} Hz")

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    import os
