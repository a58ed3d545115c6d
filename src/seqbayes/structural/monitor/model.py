"""What the monitor is told about a structure: its modes' reference frequencies, the pattern a loss leaves across
them (from a linear model's eigen-sensitivities, or none: the mode-level model), the covariates by name, the
priors, and the sampler's and the alarm's settings.

- :meth:`MonitorModel.shear_building`: floor masses and storey stiffnesses; a loss in a storey.
- :meth:`MonitorModel.linear`: any linear model of :mod:`seqbayes.structural.structures.linear` (``K0 + sum_j
  theta_j K_j`` with mass and influence matrices, a shear building, or a user eigen function); a loss in the
  element of a parameter.
- :meth:`MonitorModel.mode_level`: no structural model, only the tracked modes' reference frequencies (the mast);
  a loss is a lasting drop of one or more modes, and no location is reported.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .change import ElementLoss, LossPrior, ModeShift, sensitivities
from .law import MonitorPrior

__all__ = ["MonitorModel", "MonitorSettings", "AlarmRule"]


@dataclass(frozen=True, eq=False)
class MonitorModel:
    """The structure as the monitor knows it.

    Attributes
    ----------
    reference_frequencies : (n,) array
        Each mode's frequency [Hz] at the reference (the prior mean of its level), ascending.
    pattern : ElementLoss or ModeShift
        What a loss does to the modes.
    covariates : tuple of str
        Further covariates by name (columns of the data beside ``temperature``), entering linearly.
    covariate_reference : (r,) array
        The covariates' reference values (their coefficients are per unit from there).
    prior : MonitorPrior
    """

    reference_frequencies: np.ndarray
    pattern: object
    covariates: tuple = ()
    covariate_reference: np.ndarray = field(default_factory=lambda: np.zeros(0))
    prior: MonitorPrior = MonitorPrior()

    def __post_init__(self):
        f = np.asarray(self.reference_frequencies, dtype=float).reshape(-1)
        if f.size < 1 or not np.all(np.isfinite(f) & (f > 0)):
            raise ValueError(f"reference_frequencies: expected positive finite frequencies [Hz], got {f.tolist()}")
        if np.any(np.diff(f) < 0):
            raise ValueError(f"reference_frequencies: expected them ascending (mode 1 lowest), got {f.tolist()}")
        object.__setattr__(self, "reference_frequencies", f)
        if not isinstance(self.pattern, (ElementLoss, ModeShift)):
            raise TypeError(f"pattern: expected an ElementLoss or a ModeShift, got {type(self.pattern).__name__}")
        n_pattern = self.pattern.patterns.shape[0] if isinstance(self.pattern, ElementLoss) else self.pattern.n_modes
        if n_pattern != f.size:
            raise ValueError(f"pattern: it has {n_pattern} modes, the model {f.size}")
        names = tuple(str(c) for c in self.covariates)
        if len(set(names)) != len(names) or "temperature" in names:
            raise ValueError(f"covariates: expected distinct names other than 'temperature', got {list(names)}")
        object.__setattr__(self, "covariates", names)
        ref = np.asarray(self.covariate_reference, dtype=float).reshape(-1)
        if ref.size == 0 and names:
            ref = np.zeros(len(names))
        if ref.size != len(names) or not np.all(np.isfinite(ref)):
            raise ValueError(f"covariate_reference: expected {len(names)} finite values, got {ref.tolist()}")
        object.__setattr__(self, "covariate_reference", ref)
        if not isinstance(self.prior, MonitorPrior):
            raise TypeError(f"prior: expected a MonitorPrior, got {type(self.prior).__name__}")

    @property
    def n_modes(self) -> int:
        return int(self.reference_frequencies.size)

    @property
    def locates(self) -> bool:
        """Whether a loss has a location (an element) in this model."""
        return isinstance(self.pattern, ElementLoss)

    @classmethod
    def linear(cls, model, n_modes: int | None = None, names=None, *, loss: LossPrior | None = None, **options):
        """From a linear model (``n_parameters``, ``modes(theta) -> (f (N, q), shapes)``): its first ``n_modes``
        frequencies at ``theta = 1`` and the eigen-sensitivities of each parameter's element (``names``: one per
        parameter, default ``"1"``, ``"2"``, ...). ``options``: the other fields."""
        f, _ = model.modes(np.ones((1, model.n_parameters)))
        n_modes = f.shape[1] if n_modes is None else int(n_modes)
        g = sensitivities(model, n_modes)
        names = tuple(str(i + 1) for i in range(model.n_parameters)) if names is None else tuple(names)
        pattern = ElementLoss(g, names) if loss is None else ElementLoss(g, names, loss)
        return cls(np.asarray(f[0, :n_modes], dtype=float), pattern, **options)

    @classmethod
    def shear_building(cls, masses, stiffnesses, **options):
        """A shear building (floor masses [kg], storey stiffnesses [N/m], bottom to top): a loss in a storey."""
        from ..structures import ShearBuilding
        from ..structures.linear import ShearBuildingModel

        return cls.linear(ShearBuildingModel(ShearBuilding(masses, stiffnesses)), **options)

    @classmethod
    def mode_level(cls, reference_frequencies, *, probability: float = 0.5, loss: LossPrior | None = None,
                   **options):
        """No structural model: each mode's reference frequency [Hz]; a loss is a lasting drop of any of them."""
        f = np.asarray(reference_frequencies, dtype=float).reshape(-1)
        shift = ModeShift(f.size, probability) if loss is None else ModeShift(f.size, probability, loss)
        return cls(f, shift, **options)


@dataclass(frozen=True)
class AlarmRule:
    """Alarm when ``P(damage) > threshold`` at the end of ``consecutive`` days in a row."""

    threshold: float = 0.95
    consecutive: int = 2

    def __post_init__(self):
        if not 0 < self.threshold < 1:
            raise ValueError(f"threshold: expected a probability in (0, 1), got {self.threshold!r}")
        if isinstance(self.consecutive, bool) or int(self.consecutive) != self.consecutive or self.consecutive < 1:
            raise ValueError(f"consecutive: expected an integer >= 1, got {self.consecutive!r}")

    def next(self, run: int, p_damage: float) -> int:
        """The days in a row above the threshold after a day with ``p_damage`` (``run``: before it)."""
        return run + 1 if p_damage > self.threshold else 0

    def raised(self, run: int) -> bool:
        return run >= self.consecutive


@dataclass(frozen=True)
class MonitorSettings:
    """The sampler's settings.

    Attributes
    ----------
    n_particles : int
        Particles over the static parameters.
    ess : float
        Fraction of ``n_particles`` the ESS is kept at by tempering a day's data (resample and move below it).
    min_sweeps, max_sweeps : int
        Random-walk sweeps per resample-move (each a pass over the history): at least ``min_sweeps``, then until
        ``moved_fraction`` of the particles have moved, at most ``max_sweeps``.
    moved_fraction : float
    hazard : float
        Daily probability of a loss (geometric prior of its day, from day 1).
    alarm : AlarmRule
    chunk_particles : int
        Particles per block of a pass over the history (memory: about ``chunk * chunks * modes * p^2 * 24``
        bytes).
    """

    n_particles: int = 256
    ess: float = 0.5
    min_sweeps: int = 2
    max_sweeps: int = 10
    moved_fraction: float = 0.8
    hazard: float = 1.0 / 365.0
    alarm: AlarmRule = AlarmRule()
    chunk_particles: int = 128

    def __post_init__(self):
        for name, low in (("n_particles", 10), ("min_sweeps", 1), ("max_sweeps", 1), ("chunk_particles", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < low:
                raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")
        if self.min_sweeps > self.max_sweeps:
            raise ValueError(f"min_sweeps: {self.min_sweeps} exceeds max_sweeps {self.max_sweeps}")
        if not 0 < self.ess < 1:
            raise ValueError(f"ess: expected a fraction in (0, 1), got {self.ess!r}")
        if not 0 <= self.moved_fraction <= 1:
            raise ValueError(f"moved_fraction: expected a fraction in [0, 1], got {self.moved_fraction!r}")
        if not (math.isfinite(self.hazard) and 0 < self.hazard < 1):
            raise ValueError(f"hazard: expected a probability in (0, 1), got {self.hazard!r}")
        if not isinstance(self.alarm, AlarmRule):
            raise TypeError(f"alarm: expected an AlarmRule, got {type(self.alarm).__name__}")
