"""Priors: a product of independent :mod:`scipy.stats` frozen distributions with
parameter names, vectorised over samples ``(N, d)``.

Any object with ``logpdf(theta (N, d)) -> (N,)`` and ``sample(n, rng) -> (n, d)``
is accepted as a prior by the samplers; ``JointPrior`` is the usual one.

The moves work in unconstrained coordinates of the prior's box (:class:`BoxTransform`).Moves in unconstrained coordinates.

MCMC moves propose in ``u = T(theta)``: identity for an unbounded parameter,
``log(theta - lo)`` (or ``log(hi - theta)``) for a half-bounded one and
``logit((theta - lo) / (hi - lo))`` for a bounded one, and target
``pi(theta(u)) |d theta / d u|``. A bounded scale parameter (a noise std with a
uniform prior over three decades) then moves multiplicatively, which is what
lets a tempered sampler reach the small-scale end; in the parameter's own
coordinates a random walk or stretch move tuned on the bulk never gets there
and the evidence comes out several nats low (Coulomb-friction study, s = 1).
The transform is a bijection of the open box, so detailed balance in ``u`` is
detailed balance in ``theta``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from .rng import as_generator

__all__ = ["JointPrior", "as_samples", "support_of", "check_distribution", "inside_support", "inside_space", "BoxTransform"]


def as_samples(theta, dim: int | None = None, name: str = "theta") -> np.ndarray:
    """Validate and return ``theta`` as a float array of shape ``(N, d)``."""
    theta = np.asarray(theta, dtype=float)
    if theta.ndim != 2:
        raise ValueError(f"{name}: expected shape (N, d), got {theta.shape}")
    if dim is not None and theta.shape[1] != dim:
        raise ValueError(f"{name}: expected {dim} columns (parameters), got shape {theta.shape}")
    return theta


def inside_support(points, support) -> np.ndarray:
    """``(N,)`` bool: the rows of ``points (N, d)`` inside the ``(d, 2)`` box ``support`` (NaN is outside)."""
    return ((points >= support[:, 0]) & (points <= support[:, 1])).all(axis=1)


def inside_space(points, support) -> np.ndarray:
    """:func:`inside_support`, with every row inside when the box is unbounded (no comparison made)."""
    if np.isneginf(support[:, 0]).all() and np.isposinf(support[:, 1]).all():
        return np.ones(points.shape[0], dtype=bool)
    return inside_support(points, support)


class JointPrior:
    """Independent product prior ``p(theta) = prod_j p_j(theta_j)``.

    Parameters
    ----------
    distributions : mapping name -> frozen distribution, or sequence of them
        Frozen :mod:`scipy.stats` distributions, one per parameter (e.g.
        ``scipy.stats.uniform(0.01, 99.99)``).
    names : sequence of str, optional
        Parameter names when ``distributions`` is a sequence
        (default ``theta_0, theta_1, ...``).

    Examples
    --------
    >>> from scipy import stats
    >>> prior = JointPrior({"k": stats.uniform(0, 2), "c": stats.norm(0, 1)})
    >>> prior.sample(5, rng=0).shape
    (5, 2)
    """

    def __init__(self, distributions: Mapping[str, Any] | Sequence[Any], names: Sequence[str] | None = None):
        if isinstance(distributions, Mapping):
            if names is not None:
                raise TypeError("names: give names either as mapping keys or as names=, not both")
            names = list(distributions.keys())
            distributions = list(distributions.values())
        else:
            distributions = list(distributions)
            names = [f"theta_{j}" for j in range(len(distributions))] if names is None else list(names)
        if not distributions:
            raise ValueError("distributions: at least one parameter is needed")
        if len(names) != len(distributions):
            raise ValueError(f"names: {len(names)} names for {len(distributions)} distributions")
        if len(set(names)) != len(names):
            raise ValueError(f"names: duplicate parameter names in {names}")
        for name, dist in zip(names, distributions):
            check_distribution(dist, f"distributions[{name!r}]")
        self.names = tuple(str(n) for n in names)
        self.distributions = tuple(distributions)
        self._logpdfs = tuple(_fast_logpdf(dist) for dist in self.distributions)
        self._samplers = tuple(_fast_sampler(dist) for dist in self.distributions)
        support = np.array([dist.support() for dist in self.distributions], dtype=float)
        support.setflags(write=False)
        self._support = support

    @property
    def dim(self) -> int:
        return len(self.distributions)

    @property
    def support(self) -> np.ndarray:
        """``(d, 2)`` array of lower and upper bounds of each marginal (read-only)."""
        return self._support

    def logpdf(self, theta: ArrayLike) -> np.ndarray:
        """Log density at ``theta (N, d)``; ``-inf`` outside the support. Returns ``(N,)``."""
        theta = as_samples(theta, self.dim)
        total = np.zeros(theta.shape[0])
        for j, logpdf in enumerate(self._logpdfs):
            total += logpdf(theta[:, j])
        total[np.isnan(total)] = -np.inf
        return total

    def marginal_logpdf(self, j: int, values: ArrayLike) -> np.ndarray:
        """Log density of parameter ``j`` alone at ``values (N,)``; ``-inf`` outside its support."""
        out = np.asarray(self._logpdfs[j](np.asarray(values, dtype=float)), dtype=float)
        return np.where(np.isnan(out), -np.inf, out)

    def sample(self, n: int, rng: int | np.random.Generator | None = None) -> np.ndarray:
        """``n`` independent draws, shape ``(n, d)``."""
        if int(n) < 1:
            raise ValueError(f"n: must be at least 1, got {n}")
        rng = as_generator(rng)
        return np.column_stack([draw(int(n), rng) for draw in self._samplers])

    def describe(self) -> list[dict]:
        """Name, scipy.stats name and parameters of each marginal (for records)."""
        out = []
        for name, dist in zip(self.names, self.distributions):
            out.append({"name": name, "dist": dist.dist.name, "args": list(map(float, dist.args)),
                        "kwds": {k: float(v) for k, v in dist.kwds.items()}})
        return out

    def __repr__(self) -> str:
        parts = ", ".join(f"{d['name']}~{d['dist']}{tuple(d['args'])}{d['kwds'] or ''}" for d in self.describe())
        return f"JointPrior({parts})"


def check_distribution(dist, label: str = "distribution") -> None:
    """Refuse what would fail later: an unfrozen scipy distribution, a non-positive scale, invalid
    shape parameters or a zero-width support. Objects that are not scipy's need ``logpdf`` and ``rvs``.

    Raises
    ------
    TypeError
        Not a (frozen) distribution.
    ValueError
        Invalid parameters; the message names ``label`` and the parameter.
    """
    from scipy import stats

    if isinstance(dist, (stats.rv_continuous, stats.rv_discrete)):
        raise TypeError(f"{label}: scipy.stats.{dist.name} is not frozen; give its parameters, e.g. "
                        f"scipy.stats.{dist.name}(loc=0, scale=1)")
    if isinstance(dist, type) or not (hasattr(dist, "logpdf") and hasattr(dist, "rvs")):
        raise TypeError(f"{label}: expected a frozen scipy.stats distribution, got {dist!r}")
    base = getattr(dist, "dist", None)
    if isinstance(base, stats.rv_discrete):
        raise ValueError(f"{label}: scipy.stats.{base.name} is discrete; parameters need a continuous distribution")
    if not isinstance(base, stats.rv_continuous):
        return
    try:
        shapes, loc, scale = base._parse_args(*dist.args, **dist.kwds)
    except TypeError as err:
        raise ValueError(f"{label}: scipy.stats.{base.name}: {err}") from None
    if not np.all(np.isfinite(loc)):
        raise ValueError(f"{label}: scipy.stats.{base.name}: loc must be finite, got {loc}")
    if not np.all(np.asarray(scale) > 0) or not np.all(np.isfinite(scale)):
        raise ValueError(f"{label}: scipy.stats.{base.name}: scale must be positive and finite, got {scale}")
    if not np.all(base._argcheck(*shapes)):
        raise ValueError(f"{label}: scipy.stats.{base.name}: invalid shape parameter(s) {tuple(map(float, shapes))}")
    lower, upper = map(float, dist.support())
    if not lower < upper or not np.isfinite(dist.logpdf(dist.median())):
        raise ValueError(f"{label}: scipy.stats.{base.name}: zero-width or invalid distribution "
                         f"(support [{lower}, {upper}])")


def _location_scale(dist):
    """``(name, loc, scale)`` of a frozen ``norm`` or ``uniform`` (no shape parameters), else ``(None, 0, 1)``."""
    name = getattr(getattr(dist, "dist", None), "name", None)
    if name not in ("norm", "uniform") or len(dist.args) > 2 or set(dist.kwds) - {"loc", "scale"}:
        return None, 0.0, 1.0
    args = list(dist.args) + [None, None]
    loc = dist.kwds.get("loc", 0.0 if args[0] is None else args[0])
    scale = dist.kwds.get("scale", 1.0 if args[1] is None else args[1])
    if np.ndim(loc) or np.ndim(scale):
        return None, 0.0, 1.0
    return name, float(loc), float(scale)


def _fast_logpdf(dist):
    """``dist.logpdf`` for a frozen distribution; plain numpy for ``norm`` and ``uniform``.

    scipy's frozen ``logpdf`` spends ~0.1 ms per call on argument checks, as much as the
    whole step of a cheap model; the two commonest priors are evaluated directly (same
    values to rounding, checked against scipy in the tests)."""
    name, loc, scale = _location_scale(dist)
    if name == "norm":
        const = -np.log(scale) - 0.5 * np.log(2.0 * np.pi)

        def norm_logpdf(x):
            z = (x - loc) / scale
            return const - 0.5 * z * z
        return norm_logpdf
    if name == "uniform":
        lower, upper = map(float, dist.support())
        log_density = -np.log(scale)

        def uniform_logpdf(x):
            return np.where((x >= lower) & (x <= upper), log_density, -np.inf)
        return uniform_logpdf
    return dist.logpdf


def _fast_sampler(dist):
    """``dist.rvs(size=n, random_state=rng)`` as a function of ``(n, rng)``; for ``norm`` and
    ``uniform`` the same draws without scipy's per-call checks (bit-identical, tested)."""
    name, loc, scale = _location_scale(dist)
    if name == "norm":
        return lambda n, rng: rng.standard_normal(n) * scale + loc
    if name == "uniform":
        return lambda n, rng: rng.uniform(0.0, 1.0, n) * scale + loc
    return lambda n, rng: dist.rvs(size=n, random_state=rng)


def support_of(prior, dim: int) -> np.ndarray:
    """The ``(d, 2)`` support box of ``prior``, or ``(-inf, inf)`` if it does not say."""
    support = getattr(prior, "support", None)
    if support is None:
        return np.tile([-np.inf, np.inf], (dim, 1))
    support = np.asarray(support, dtype=float)
    if support.shape != (dim, 2):
        raise ValueError(f"prior.support: expected shape ({dim}, 2), got {support.shape}")
    return support



def _softplus(x):
    return np.logaddexp(0.0, x)


@dataclass(frozen=True, eq=False)
class BoxTransform:
    """Per-dimension bijection from the open ``(d, 2)`` support box to ``R^d``."""

    support: np.ndarray

    def __post_init__(self):
        support = np.asarray(self.support, dtype=float)
        lo, hi = support[:, 0], support[:, 1]
        object.__setattr__(self, "support", support)
        object.__setattr__(self, "_both", np.isfinite(lo) & np.isfinite(hi))
        object.__setattr__(self, "_lower", np.isfinite(lo) & ~np.isfinite(hi))
        object.__setattr__(self, "_upper", ~np.isfinite(lo) & np.isfinite(hi))
        object.__setattr__(self, "_width", np.where(self._both, hi - lo, 1.0))
        object.__setattr__(self, "_log_width", np.log(self._width))

    def forward(self, theta) -> np.ndarray:
        """``u = T(theta)`` for ``theta (N, d)`` inside the box; points on the boundary are nudged in."""
        lo, hi = self.support[:, 0], self.support[:, 1]
        u = np.array(theta, dtype=float, copy=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            if self._both.any():
                x = np.clip((theta[:, self._both] - lo[self._both]) / self._width[self._both], 1e-15, 1 - 1e-15)
                u[:, self._both] = np.log(x) - np.log1p(-x)
            if self._lower.any():
                u[:, self._lower] = np.log(np.maximum(theta[:, self._lower] - lo[self._lower], 1e-300))
            if self._upper.any():
                u[:, self._upper] = np.log(np.maximum(hi[self._upper] - theta[:, self._upper], 1e-300))
        return u

    def inverse(self, u) -> np.ndarray:
        """``theta = T^{-1}(u)``, ``(N, d)``."""
        lo, hi = self.support[:, 0], self.support[:, 1]
        theta = np.array(u, dtype=float, copy=True)
        if self._both.any():
            theta[:, self._both] = lo[self._both] + self._width[self._both] / (1.0 + np.exp(-u[:, self._both]))
        if self._lower.any():
            theta[:, self._lower] = lo[self._lower] + np.exp(u[:, self._lower])
        if self._upper.any():
            theta[:, self._upper] = hi[self._upper] - np.exp(u[:, self._upper])
        return theta

    def log_jacobian(self, u) -> np.ndarray:
        """``log |d theta / d u|`` summed over dimensions, ``(N,)``."""
        out = np.zeros(u.shape[0])
        if self._both.any():
            ub = u[:, self._both]
            out += np.sum(self._log_width[self._both] - _softplus(-ub) - _softplus(ub), axis=1)
        half = self._lower | self._upper
        if half.any():
            out += np.sum(u[:, half], axis=1)
        return out

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Mapping
    from typing import Any
    from numpy.typing import ArrayLike
