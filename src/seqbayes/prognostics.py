"""Prognostics: when will a drifting parameter cross a threshold?

Given equal-weight posterior samples of ``theta_s`` and the Markov kernel
``T(theta_{s+1} | theta_s)`` (Eq. A2 of Lye et al. 2023), the time to a threshold is the
first future step ``h >= 1`` at which parameter ``j`` is beyond a level the user sets
(stiffness below 70 % of nominal, friction below a limit): NASA's progpy calls it the
"time of event". Its distribution is estimated by simulating one (or several) kernel
paths from every sample, vectorised over the samples, with Monte Carlo standard errors
computed from the per-sample crossing frequencies (valid for independent posterior
samples; correlated MCMC samples would need their effective size instead).

The current step is not checked: a sample already beyond the threshold counts at the
first future step at which it still is. :attr:`FirstPassage.beyond_now` reports the
posterior probability of being beyond it already.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .priors import as_samples
from .rng import as_generator

__all__ = ["FirstPassage", "Threshold", "parse_threshold", "time_to_threshold", "gaussian_first_passage"]


@dataclass(frozen=True)
class FirstPassage:
    """The distribution of the first step at which a parameter crosses a threshold.

    Attributes
    ----------
    probability : ndarray, shape (H,)
        ``P(first crossing at step h)``, ``h = 1..H``.
    standard_error : ndarray, shape (H,)
        Monte Carlo standard errors of ``probability``.
    not_crossed : float
        ``P(not crossed by step H) = 1 - probability.sum()``.
    not_crossed_standard_error : float
    cumulative : ndarray, shape (H,)
        ``P(crossed by step h)``.
    cumulative_standard_error : ndarray, shape (H,)
    beyond_now : float
        Fraction of the given samples already beyond the threshold.
    parameter : int
    threshold : float
    direction : {"below", "above"}
    n_paths : int
        Simulated paths (samples x paths per sample).
    left_support : float
        With ``support``: the share of paths that left the parameter space before crossing (and
        within the horizon; NaN without ``support``). The likelihood is zero outside, so under the
        model those paths have no weight; the probabilities here are the kernel's, unrestricted, and
        are the model's when this share is small.
    """

    probability: np.ndarray
    standard_error: np.ndarray
    not_crossed: float
    not_crossed_standard_error: float
    cumulative: np.ndarray
    cumulative_standard_error: np.ndarray
    beyond_now: float
    parameter: int
    threshold: float
    direction: str
    n_paths: int
    left_support: float = float("nan")

    @property
    def horizon(self) -> int:
        """``H``, the number of future steps simulated."""
        return self.probability.size

    def quantile(self, q: float) -> float:
        """Smallest step ``h`` with ``P(crossed by h) >= q``; ``inf`` if not reached by ``H``."""
        if not 0.0 < q <= 1.0:
            raise ValueError(f"q: expected a probability in (0, 1], got {q}")
        hit = np.flatnonzero(self.cumulative >= q)
        return float(hit[0] + 1) if hit.size else float("inf")


@dataclass(frozen=True)
class Threshold:
    """A threshold on one named parameter, as ``seqbayes predict --threshold "k<0.7"`` gives it.

    Attributes
    ----------
    name : str
        The parameter's name.
    direction : {"below", "above"}
        ``"below"`` for ``name<value``, ``"above"`` for ``name>value``.
    value : float
    """

    name: str
    direction: str
    value: float

    def __str__(self) -> str:
        return f"{self.name} {'<' if self.direction == 'below' else '>'} {self.value:g}"


_THRESHOLD = re.compile(r"^\s*(?P<name>[^<>\s]+)\s*(?P<op>[<>])\s*(?P<value>\S+)\s*$")


def parse_threshold(text: str, names: Sequence[str]) -> Threshold:
    """Parse ``"NAME<VALUE"`` or ``"NAME>VALUE"`` (spaces allowed) for one of ``names``.

    Parameters
    ----------
    text : str
        E.g. ``"k<0.7"`` (the event: ``k`` falls below 0.7) or ``"c > 0.05"``.
    names : sequence of str
        The run's parameter names.

    Returns
    -------
    Threshold

    Raises
    ------
    ValueError
        A malformed expression, an unknown parameter or a value that is not a finite number;
        the message names the argument ``threshold``.

    Examples
    --------
    >>> parse_threshold("k<0.7", ["k", "c"])
    Threshold(name='k', direction='below', value=0.7)
    """
    match = _THRESHOLD.match(str(text))
    if match is None:
        raise ValueError(f"threshold: expected NAME<VALUE or NAME>VALUE, e.g. \"k<0.7\", got {text!r}")
    name = match["name"]
    if name not in names:
        raise ValueError(f"threshold: {name!r} is not a parameter of this run; choose from {', '.join(names)}")
    try:
        value = float(match["value"])
    except ValueError:
        raise ValueError(f"threshold: {match['value']!r} in {text!r} is not a number") from None
    if not np.isfinite(value):
        raise ValueError(f"threshold: the value must be finite, got {text!r}")
    return Threshold(name, "below" if match["op"] == "<" else "above", value)


def time_to_threshold(samples: ArrayLike, kernel: Any, parameter: int, threshold: float, horizon: int, *,
                      direction: str = "below", rng: int | np.random.Generator | None = None,
                      paths_per_sample: int = 1, support: ArrayLike | None = None) -> FirstPassage:
    """Distribution of the first future step at which ``theta[:, parameter]`` crosses ``threshold``.

    Parameters
    ----------
    samples : array_like, shape (N, d)
        Equal-weight posterior samples of the current step (``N >= 2``).
    kernel : object with ``propagate(theta (M, d), rng) -> (M, d)``
        The Markov kernel, e.g. a :class:`seqbayes.MarkovKernel`; only ``propagate``
        is used.
    parameter : int
        Column of the parameter watched, ``0 <= parameter < d``.
    threshold : float
        The level.
    horizon : int
        ``H >= 1``: future steps simulated.
    direction : {"below", "above"}
        Crossing means ``theta_j < threshold`` ("below") or ``theta_j > threshold`` ("above").
    rng : numpy.random.Generator or int, optional
        Source of the kernel's noise.
    paths_per_sample : int
        Independent paths simulated from each sample (more paths lower the kernel-noise
        part of the Monte Carlo error, not the posterior-sampling part).
    support : array_like, shape (d, 2), optional
        The parameter space (lower and upper bounds, infinite allowed): report the share of paths
        that leave it before crossing (:attr:`FirstPassage.left_support`).

    Returns
    -------
    FirstPassage
        Probabilities per step ``1..H``, ``P(not crossed by H)`` and their Monte Carlo
        standard errors ``std(per-sample frequency) / sqrt(N)``.

    Examples
    --------
    >>> from seqbayes import Drift, MarkovKernel
    >>> kernel = MarkovKernel([Drift(-1.0, noise_std=0.0)])
    >>> out = time_to_threshold(np.full((4, 1), 3.5), kernel, 0, 1.0, 5, rng=0)
    >>> out.probability.tolist(), out.not_crossed
    ([0.0, 0.0, 1.0, 0.0, 0.0], 0.0)
    """
    theta = as_samples(samples, name="samples")
    n, d = theta.shape
    if n < 2:
        raise ValueError(f"samples: expected at least 2 samples, got shape {theta.shape}")
    if not np.all(np.isfinite(theta)):
        raise ValueError("samples: contains NaN or inf")
    if not callable(getattr(kernel, "propagate", None)):
        raise TypeError(f"kernel: expected an object with propagate(theta, rng), got {type(kernel).__name__}")
    if isinstance(parameter, bool) or not isinstance(parameter, (int, np.integer)) or not 0 <= parameter < d:
        raise ValueError(f"parameter: expected an integer column index in [0, {d}), got {parameter!r}")
    threshold = float(threshold)
    if not np.isfinite(threshold):
        raise ValueError(f"threshold: must be finite, got {threshold}")
    if isinstance(horizon, bool) or not isinstance(horizon, (int, np.integer)) or horizon < 1:
        raise ValueError(f"horizon: expected an integer >= 1, got {horizon!r}")
    if direction not in ("below", "above"):
        raise ValueError(f"direction: expected 'below' or 'above', got {direction!r}")
    if isinstance(paths_per_sample, bool) or not isinstance(paths_per_sample, (int, np.integer)) \
            or paths_per_sample < 1:
        raise ValueError(f"paths_per_sample: expected an integer >= 1, got {paths_per_sample!r}")
    if support is not None:
        support = np.asarray(support, dtype=float)
        if support.shape != (d, 2) or np.any(support[:, 0] > support[:, 1]):
            raise ValueError(f"support: expected (d, 2) = ({d}, 2) lower and upper bounds, got shape {support.shape}")
    rng = as_generator(rng)
    sign = 1.0 if direction == "below" else -1.0

    def beyond(x):
        return sign * (x[:, parameter] - threshold) < 0.0

    paths = np.repeat(theta, paths_per_sample, axis=0)                   # (N R, d), sample-major
    first = np.zeros(paths.shape[0], dtype=np.int64)                     # 0: not crossed yet
    left = np.zeros(paths.shape[0], dtype=bool)                          # left the space before crossing
    for h in range(1, int(horizon) + 1):
        paths = np.asarray(kernel.propagate(paths, rng), dtype=float)    # Eq. (A2)
        if paths.shape != (n * paths_per_sample, d):
            raise ValueError(f"kernel.propagate: returned shape {paths.shape} for input ({n * paths_per_sample}, {d})")
        crossing = (first == 0) & beyond(paths)
        if support is not None:   # leaving and crossing at the same step counts as a crossing
            outside = np.any((paths < support[:, 0]) | (paths > support[:, 1]), axis=1)
            left |= (first == 0) & ~crossing & outside
        first[crossing] = h
    # per-sample frequencies of "first crossing at h" (h = 0 collects "not crossed")
    counts = np.zeros((n, int(horizon) + 1))
    np.add.at(counts, (np.repeat(np.arange(n), paths_per_sample), first), 1.0)
    freq = counts / paths_per_sample                                     # (N, H + 1)
    cum = np.cumsum(freq[:, 1:], axis=1)                                 # (N, H)

    def mean_and_se(x):
        return x.mean(axis=0), x.std(axis=0, ddof=1) / np.sqrt(n)

    p, se = mean_and_se(freq)
    c, c_se = mean_and_se(cum)
    for arr in (p, se, c, c_se):
        arr.setflags(write=False)
    return FirstPassage(probability=p[1:], standard_error=se[1:], not_crossed=float(p[0]),
                        not_crossed_standard_error=float(se[0]), cumulative=c, cumulative_standard_error=c_se,
                        beyond_now=float(np.mean(beyond(theta))), parameter=int(parameter), threshold=threshold,
                        direction=direction, n_paths=int(n * paths_per_sample),
                        left_support=float(np.mean(left)) if support is not None else float("nan"))


def gaussian_first_passage(mean: float, sd: float, drift: float, noise_std: float, threshold: float, horizon: int, *,
                           direction: str = "below", n_grid: int = 1501, width: float = 10.0) -> np.ndarray:
    """Exact first-passage probabilities of a Gaussian random walk from a Gaussian start (a reference).

    ``a_0 ~ N(mean, sd^2)``, ``a_h = a_{h-1} + drift + N(0, noise_std^2)``: returns
    ``P(first h >= 1 with a_h beyond threshold)`` for ``h = 1..horizon``, ``(horizon,)``. This is the
    time to a threshold of a linear-Gaussian drift problem, whose filtering posterior (the Kalman
    filter's) is Gaussian: the reference :func:`time_to_threshold` is tested against.

    Step 1 is closed form; after it the surviving density lives on one side of the threshold, is
    carried by the Gaussian step with the trapezoid rule on a grid whose first node is the threshold
    (so the cut is a grid end) and the mass that steps across is integrated with the exact normal
    CDF. With the defaults the error is below 1e-5 (against a grid twice as fine and 40 % wider).

    Parameters
    ----------
    mean, sd : float
        The start's mean and standard deviation (``sd >= 0``).
    drift, noise_std : float
        The walk's drift per step and its noise standard deviation (``> 0``).
    threshold : float
    horizon : int
    direction : {"below", "above"}
    n_grid, width : int, float
        Grid nodes, and the grid's extent beyond the threshold in standard deviations.
    """
    from scipy import stats

    if direction not in ("below", "above"):
        raise ValueError(f"direction: expected 'below' or 'above', got {direction!r}")
    if not noise_std > 0 or not sd >= 0:
        raise ValueError(f"noise_std and sd: expected noise_std > 0 and sd >= 0, got {noise_std}, {sd}")
    if direction == "above":  # mirror: a -> -a
        return gaussian_first_passage(-mean, sd, -drift, noise_std, -threshold, horizon, n_grid=n_grid, width=width)
    sd1 = float(np.hypot(sd, noise_std))
    out = [stats.norm.cdf(threshold, mean + drift, sd1)]
    upper = max(mean, threshold) + max(drift, 0.0) * horizon + width * (sd1 + noise_std * np.sqrt(horizon))
    x = np.linspace(threshold, upper, n_grid)
    w = np.full(n_grid, x[1] - x[0])
    w[[0, -1]] /= 2                                                      # trapezoid weights
    step = stats.norm.pdf(x[:, None], x[None, :] + drift, noise_std) * w[None, :]
    p_below = stats.norm.cdf(threshold, x + drift, noise_std) * w
    alive = stats.norm.pdf(x, mean + drift, sd1)                         # survivors of step 1, on x >= threshold
    for _ in range(int(horizon) - 1):
        out.append(p_below @ alive)
        alive = step @ alive
    return np.array(out)
