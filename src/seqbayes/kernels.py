"""Markov transition kernels ``T(theta_{s+1} | theta_s)``: ``theta_{s+1} =
Gamma(theta_s) + nu`` with Gaussian process noise ``nu`` (Eq. A2 of Lye et al.
2023), built one component per parameter.

A component maps one column ``(N,)`` to ``(N,)`` and carries its own noise std
(0 for a time-invariant parameter). :class:`MarkovKernel` stacks them; a user
with a coupled evolution model passes ``nominal=callable((N, d)) -> (N, d)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields

import numpy as np

from .priors import as_samples

__all__ = ["Static", "Drift", "Decay", "Custom", "MarkovKernel"]


def _check_noise(noise_std):
    noise_std = float(noise_std)
    if not np.isfinite(noise_std) or noise_std < 0:
        raise ValueError(f"noise_std: must be finite and >= 0, got {noise_std}")
    return noise_std


@dataclass(frozen=True)
class _Component:
    """One parameter's evolution ``Gamma`` and noise std; fields are validated on construction."""

    noise_std: float = field(default=0.0, kw_only=True)

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "noise_std":
                value = _check_noise(value)
            elif f.type in ("float", float):
                value = float(value)
                if not np.isfinite(value):
                    raise ValueError(f"{f.name}: must be finite, got {value}")
            object.__setattr__(self, f.name, value)

    def describe(self) -> dict:
        out = {"type": type(self).__name__.lower()}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = getattr(value, "__qualname__", repr(value)) if callable(value) else value
        return out


@dataclass(frozen=True)
class Static(_Component):
    """Time-invariant parameter: ``theta_{s+1} = theta_s`` (no noise)."""

    noise_std: float = field(default=0.0, init=False)

    def nominal(self, x: np.ndarray) -> np.ndarray:
        return x


@dataclass(frozen=True)
class Drift(_Component):
    """Additive drift: ``theta_{s+1} = theta_s + rate + nu`` (e.g. Eq. 21, ``rate = -0.375``)."""

    rate: float

    def nominal(self, x: np.ndarray) -> np.ndarray:
        return x + self.rate


@dataclass(frozen=True)
class Decay(_Component):
    """Multiplicative decay: ``theta_{s+1} = exp(-rate) theta_s + nu`` (e.g. Eq. 22, ``rate = 0.470``)."""

    rate: float

    def nominal(self, x: np.ndarray) -> np.ndarray:
        return np.exp(-self.rate) * x


@dataclass(frozen=True)
class Custom(_Component):
    """A user function of one parameter, ``theta_{s+1} = func(theta_s) + nu``; ``func`` maps ``(N,) -> (N,)``."""

    func: Callable[[np.ndarray], np.ndarray]

    def __post_init__(self):
        if not callable(self.func):
            raise TypeError("func: expected a callable mapping (N,) -> (N,)")
        super().__post_init__()

    def nominal(self, x: np.ndarray) -> np.ndarray:
        out = np.asarray(self.func(x), dtype=float)
        if out.shape != x.shape:
            raise ValueError(f"Custom.func: returned shape {out.shape} for input {x.shape}")
        return out


@dataclass(frozen=True, eq=False)
class MarkovKernel:
    """``T(theta_{s+1} | theta_s)`` of Eq. (A2), vectorised over samples ``(N, d)``.

    Parameters
    ----------
    components : sequence of Static / Drift / Decay / Custom, optional
        One per parameter, in the prior's order.
    nominal_function : callable ``(N, d) -> (N, d)``, optional
        A coupled evolution model ``Gamma``; give ``noise_std`` with it.
    noise_std : sequence of float, optional
        Process-noise std per parameter, only with ``nominal_function``.

    Examples
    --------
    >>> kernel = MarkovKernel([Drift(-0.375, noise_std=0.04), Static()])
    >>> kernel.propagate(np.array([[1.0, 2.0]]), np.random.default_rng(0)).shape
    (1, 2)
    """

    components: tuple = ()
    nominal_function: Callable | None = None
    noise_std: np.ndarray = field(default=None)

    def __init__(self, components: Sequence | None = None, *, nominal_function=None, noise_std=None):
        if (components is None) == (nominal_function is None):
            raise TypeError("MarkovKernel: give either components or nominal_function (with noise_std)")
        if components is not None:
            components = tuple(components)
            if not components:
                raise ValueError("components: at least one parameter is needed")
            for j, c in enumerate(components):
                if not (hasattr(c, "nominal") and hasattr(c, "noise_std")):
                    raise TypeError(f"components[{j}]: expected Static, Drift, Decay or Custom, got {c!r}")
            if noise_std is not None:
                raise TypeError("noise_std: set it on each component instead")
            noise = np.array([c.noise_std for c in components], dtype=float)
        else:
            if not callable(nominal_function):
                raise TypeError("nominal_function: expected a callable (N, d) -> (N, d)")
            if noise_std is None:
                raise TypeError("noise_std: required with nominal_function")
            noise = np.atleast_1d(np.asarray(noise_std, dtype=float))
            if noise.ndim != 1 or not np.all(np.isfinite(noise)) or np.any(noise < 0):
                raise ValueError(f"noise_std: expected a 1-D array of finite values >= 0, got {noise_std!r}")
            components = ()
        noise.setflags(write=False)
        object.__setattr__(self, "components", components)
        object.__setattr__(self, "nominal_function", nominal_function)
        object.__setattr__(self, "noise_std", noise)

    @property
    def dim(self) -> int:
        return self.noise_std.size

    @property
    def static_mask(self) -> np.ndarray:
        """``(d,)`` bool: parameters without process noise."""
        return self.noise_std == 0

    @property
    def is_static(self) -> bool:
        """Every parameter is :class:`Static`: the kernel is the identity (no evolution, no noise)."""
        return bool(self.components) and all(isinstance(c, Static) for c in self.components)

    def nominal(self, theta) -> np.ndarray:
        """``Gamma(theta)``: the noise-free evolution, ``(N, d) -> (N, d)``."""
        theta = as_samples(theta, self.dim)
        if self.nominal_function is not None:
            out = np.asarray(self.nominal_function(theta), dtype=float)
            if out.shape != theta.shape:
                raise ValueError(f"nominal_function: returned shape {out.shape} for input {theta.shape}")
            return out
        return np.column_stack([c.nominal(theta[:, j]) for j, c in enumerate(self.components)])

    def propagate(self, theta, rng: np.random.Generator) -> np.ndarray:
        """One draw from ``T(. | theta)`` for each row: ``Gamma(theta) + nu`` (Eq. A2)."""
        mean = self.nominal(theta)
        return mean + rng.standard_normal(mean.shape) * self.noise_std

    def logpdf(self, new, old) -> np.ndarray:
        """``log T(new | old)`` over the noisy parameters; static ones must be equal (else ``-inf``)."""
        new = as_samples(new, self.dim, "new")
        mean = self.nominal(as_samples(old, self.dim, "old"))
        noisy = ~self.static_mask
        z = (new[:, noisy] - mean[:, noisy]) / self.noise_std[noisy]
        out = -0.5 * np.sum(z**2, axis=1) - np.sum(np.log(self.noise_std[noisy])) - 0.5 * noisy.sum() * np.log(2 * np.pi)
        out[np.any(new[:, ~noisy] != mean[:, ~noisy], axis=1)] = -np.inf
        return out

    def describe(self) -> list[dict] | dict:
        if self.components:
            return [c.describe() for c in self.components]
        return {"type": "function", "func": getattr(self.nominal_function, "__qualname__", "?"),
                "noise_std": self.noise_std.tolist()}
