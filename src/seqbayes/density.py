"""The predictive prior for step ``s > 1`` (Eq. A3): a weighted mixture of
axis-aligned Gaussians, ``p(theta) = sum_i W_i N(theta; c_i, diag(h^2))``.

Two constructions are offered (see :func:`predictive_density`):

``"kde"`` (the paper's, Eq. A9-A10)
    Centres are the propagated samples ``Gamma(theta_i) + nu_i``; bandwidth by
    Silverman's rule on every dimension. Adds ``h^2`` of spurious variance to
    the drifting parameters on top of the process noise.
``"transition"`` (exact on noisy dimensions; the default with process noise)
    The transition mixture ``sum_i W_i T(theta | theta_i)`` of Eq. (A3) itself:
    centres ``Gamma(theta_i)``, width = process-noise std on noisy dimensions.
    Static dimensions have a delta transition, so they get a Silverman kernel,
    with Liu-West shrinkage of the centres towards the mean so that the
    mixture keeps the posterior's mean and variance instead of inflating it
    by ``(1 + h^2)`` per step.
    With :class:`~seqbayes.kernels.Jump` components the transition of each ancestor is
    a mixture of Gaussian branches with shared shifts and widths, so Eq. (A3) is a
    :class:`MixtureSum`: one such mixture per branch combination, weighted by its
    probability.

``"history"`` (exact; the default when every parameter is static)
    With an identity kernel the prior of step ``s`` is the last posterior,
    ``p_0(theta) prod_{k<s} L_k(theta) / Z_{1:s-1}``, evaluated exactly by
    :class:`HistoryPrior` from the past datasets (as IBIS does, Chopin 2002):
    no kernel density, no ``O(N^2)`` evaluation, but every evaluation costs one
    likelihood call per past dataset.

Why by hand: scipy's ``gaussian_kde`` has no per-dimension diagonal bandwidth
with per-point weights *and* chunked evaluation; evaluating it at N = 10,000
points against 10,000 centres allocates ``N x N x d``. Here evaluation goes
through ``(m, N)`` blocks via one matrix product (never ``N x N x d``).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .gaussian_sum import TruncatedSum
from .priors import as_samples
from .weights import logsumexp, normalise

__all__ = ["GaussianMixture", "MixtureSum", "HistoryPrior", "RunningStatistics", "silverman_bandwidth", "predictive_density", "PREDICTIVE_METHODS"]

#: ``"auto"`` resolves to ``"history"`` for a kernel whose every parameter is static, ``"smc2"`` (nested
#: filters, :mod:`seqbayes.nested`) for one with static and drifting components, else ``"transition"``.
PREDICTIVE_METHODS = ("auto", "transition", "kde", "history", "smc2")

#: Largest block of the (queries x centres) matrix held at once, in floats (~64 MB).
_BLOCK_FLOATS = 8_000_000

#: From this many centres on, a mixture is evaluated with a k-d tree where that saves work
#: (:mod:`seqbayes.gaussian_sum`); below, every pair is summed (as fast, and bit for bit as before).
_TREE_MIN_CENTRES = 4096


def _weighted_moments(samples, log_weights):
    w = np.exp(normalise(log_weights))
    mean = w @ samples
    var = w @ (samples - mean) ** 2
    n_eff = 1.0 / np.sum(w**2)
    return mean, var, n_eff


def silverman_bandwidth(samples: ArrayLike, log_weights: ArrayLike | None = None) -> np.ndarray:
    """Per-dimension Silverman bandwidth of Eq. (A10): ``sigma_j (4 / (N (d + 2)))^(1/(d + 4))``.

    With weights, ``N`` is the effective sample size and ``sigma_j`` the weighted std.
    A dimension with zero spread gets a tiny positive width (``1e-9 (1 + |mean|)``)
    so that the density stays finite.

    Parameters
    ----------
    samples : (N, d) array
    log_weights : (N,) array, optional

    Returns
    -------
    (d,) array
    """
    samples = as_samples(samples, name="samples")
    n, d = samples.shape
    log_weights = np.zeros(n) if log_weights is None else np.asarray(log_weights, dtype=float)
    mean, var, n_eff = _weighted_moments(samples, log_weights)
    h = np.sqrt(var) * (4.0 / (n_eff * (d + 2))) ** (1.0 / (d + 4))  # Eq. (A10)
    return np.maximum(h, 1e-9 * (1.0 + np.abs(mean)))


@dataclass(frozen=True, eq=False)
class GaussianMixture:
    """``sum_i W_i N(theta; centres_i, diag(bandwidth^2))``.

    Parameters
    ----------
    centres : (N, d) array
    bandwidth : (d,) array of positive widths
    log_weights : (N,) array, optional
        Unnormalised log mixture weights (equal if omitted).
    """

    centres: np.ndarray
    bandwidth: np.ndarray
    log_weights: np.ndarray | None = None

    def __post_init__(self):
        centres = as_samples(self.centres, name="centres")
        bandwidth = np.asarray(self.bandwidth, dtype=float)
        if bandwidth.shape != (centres.shape[1],) or not np.all(bandwidth > 0):
            raise ValueError(f"bandwidth: expected {centres.shape[1]} positive widths, got {self.bandwidth!r}")
        n = centres.shape[0]
        log_w = np.full(n, -np.log(n)) if self.log_weights is None else normalise(self.log_weights)
        if log_w.shape != (n,):
            raise ValueError(f"log_weights: expected shape ({n},), got {log_w.shape}")
        object.__setattr__(self, "centres", centres)
        object.__setattr__(self, "bandwidth", bandwidth)
        object.__setattr__(self, "log_weights", log_w)
        # evaluation cache: centres in bandwidth units about their mean, in single precision
        shift = centres.mean(axis=0)
        scaled = (centres - shift) / bandwidth
        object.__setattr__(self, "_shift", shift)
        object.__setattr__(self, "_scaled_centres", np.ascontiguousarray(scaled.T, dtype=np.float32))
        object.__setattr__(self, "_offset", (log_w - 0.5 * np.einsum("ij,ij->i", scaled, scaled)).astype(np.float32))
        object.__setattr__(self, "_const", -np.sum(np.log(bandwidth)) - 0.5 * centres.shape[1] * np.log(2.0 * np.pi))
        # centres within ~2.5 bandwidths of their mean on every axis: the truncation radius (~10 bandwidths,
        # gaussian_sum) holds them all, so no tree can save work (measured: it only costs, bench_scale --mixture)
        object.__setattr__(self, "_compact", bool(np.all(scaled.std(axis=0) < 2.5)))

    @property
    def dim(self) -> int:
        return self.centres.shape[1]

    def logpdf(self, theta: np.ndarray) -> np.ndarray:
        """Log density at ``theta (m, d)``, returns ``(m,)``; memory ``O(block x N)``.

        Below ``_TREE_MIN_CENTRES`` centres every pair is summed (:meth:`_dense_logsum`). With more,
        the sum is truncated with a k-d tree (:class:`~seqbayes.gaussian_sum.TruncatedSum`: the
        dropped terms add up to less than ``e^-40`` of the kept sum, so it is the all-pairs value to
        rounding) wherever that saves work, i.e. where the bandwidth is narrow against the spread
        of the centres; elsewhere every pair is summed.
        """
        theta = as_samples(theta, self.dim)
        x = (theta - self._shift) / self.bandwidth  # centring keeps the expansion below accurate
        if self.centres.shape[0] < _TREE_MIN_CENTRES or self._compact:
            return self._dense_logsum(x) + self._const
        truncated = self.__dict__.get("_truncated")
        if truncated is None:  # built on first use: a mixture that is only sampled never needs it
            truncated = TruncatedSum((self.centres - self._shift) / self.bandwidth, self.log_weights)
            object.__setattr__(self, "_truncated", truncated)
        return truncated(x, self._dense_logsum) + self._const

    def _dense_logsum(self, x) -> np.ndarray:
        """``log sum_i W_i exp(-|x - c_i|^2 / 2)`` over every centre, ``x (m, d)`` centred and in bandwidth units.

        The ``(m, N)`` exponent block is formed and exponentiated in single precision
        (2.3x faster than double): the log-density error is ~1e-6 near the bulk of the
        mixture and grows only where the density is negligible.
        """
        # log sum_i W_i exp(-|x - c_i|^2 / 2) = -|x|^2 / 2 + log sum_i exp(x.c_i - |c_i|^2 / 2 + log W_i)
        out = np.empty(x.shape[0])
        for rows, xb, scaled, peak in self._scaled_terms(x, np.float32):
            out[rows] = (np.log(scaled.sum(axis=1, dtype=np.float64)) + peak[:, 0]
                         - 0.5 * np.einsum("ij,ij->i", xb, xb))
        return out

    def _scaled_terms(self, x, dtype):
        """Blocks of the mixture's terms at ``x (m, d)`` (centred, in bandwidth units), memory ``O(block x N)``:
        yields ``(rows, x[rows], exp(e - peak), peak)`` with ``e_ki = x_k.c_i - |c_i|^2 / 2 + log W_i`` in
        ``dtype`` and ``peak (b, 1)`` its row maximum; never N x N x d."""
        centres = self._scaled_centres if dtype == np.float32 else self._scaled_centres.astype(dtype)
        block = max(1, _BLOCK_FLOATS // max(1, self.centres.shape[0]))
        for start in range(0, x.shape[0], block):
            xb = x[start:start + block]
            exponent = xb.astype(dtype) @ centres
            exponent += self._offset
            peak = exponent.max(axis=1, keepdims=True)
            exponent -= peak
            np.exp(exponent, out=exponent)
            yield slice(start, start + xb.shape[0]), xb, exponent, peak

    def ancestor_ess(self, theta: np.ndarray, log_weights: np.ndarray | None = None) -> float:
        """How many components carry the weighted points ``theta (m, d)``: ``1 / sum_i a_i^2``.

        ``a_i = sum_k v_k r_ki`` is the mass that the points (weights ``v``) give to component ``i``,
        ``r_ki = W_i N(theta_k; c_i, h^2) / p(theta_k)`` its responsibility for point ``k``. For a
        posterior under the predictive prior of Eq. (A3), ``a_i`` is the posterior probability of
        ancestor ``i`` and ``1 / ESS_a - 1 / N`` the relative variance of the evidence that the N
        ancestors carry (:func:`~seqbayes.evidence.increment_variance`). ``O(m N)``, in blocks.

        Parameters
        ----------
        theta : (m, d) array
        log_weights : (m,) array, optional
            The points' log-weights (equal if omitted).

        Returns
        -------
        float
        """
        theta = as_samples(theta, self.dim)
        m = theta.shape[0]
        v = np.full(m, 1.0 / m) if log_weights is None else np.exp(normalise(log_weights))
        mass = np.zeros(self.centres.shape[0])
        for rows, _, scaled, _ in self._scaled_terms((theta - self._shift) / self.bandwidth, np.float64):
            scaled /= scaled.sum(axis=1, keepdims=True)   # responsibilities r_ki
            mass += v[rows] @ scaled
        return float(1.0 / np.dot(mass, mass))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws, shape ``(n, d)``."""
        index = rng.choice(self.centres.shape[0], size=int(n), p=np.exp(self.log_weights))
        return self.centres[index] + rng.standard_normal((int(n), self.dim)) * self.bandwidth

    def draw_one_per_component(self, rng: np.random.Generator) -> np.ndarray:
        """One draw from each component, ``(N, d)``: a stratified draw of the mixture."""
        return self.centres + rng.standard_normal(self.centres.shape) * self.bandwidth


@dataclass(frozen=True, eq=False)
class MixtureSum:
    """``sum_c V_c p_c(theta)``: a weighted sum of :class:`GaussianMixture` s over the same ancestors.

    The predictive prior of Eq. (A3) under a kernel with jump components
    (:class:`~seqbayes.kernels.Jump`): one mixture per branch combination ``c`` of the
    transition, ``p_c(theta) = sum_i W_i N(theta; Gamma(theta_i) + shift_c, diag(h_c^2))``,
    weighted by the branch probabilities ``V_c``.

    Parameters
    ----------
    mixtures : sequence of C GaussianMixture
        Each with the same number ``N`` of centres (centre ``i`` of every mixture belongs to
        ancestor ``i``) and the same weights.
    log_weights : (C,) array
        Unnormalised log branch weights ``log V_c``.
    """

    mixtures: tuple
    log_weights: np.ndarray

    def __post_init__(self):
        mixtures = tuple(self.mixtures)
        if not mixtures or not all(isinstance(m, GaussianMixture) for m in mixtures):
            raise TypeError("mixtures: expected a non-empty sequence of GaussianMixture")
        n, d = mixtures[0].centres.shape
        for c, m in enumerate(mixtures):
            if m.centres.shape != (n, d):
                raise ValueError(f"mixtures[{c}]: {m.centres.shape} centres, mixtures[0] has {(n, d)}")
        log_w = normalise(np.atleast_1d(np.asarray(self.log_weights, dtype=float)))
        if log_w.shape != (len(mixtures),):
            raise ValueError(f"log_weights: expected shape ({len(mixtures)},), got {log_w.shape}")
        object.__setattr__(self, "mixtures", mixtures)
        object.__setattr__(self, "log_weights", log_w)

    @property
    def dim(self) -> int:
        return self.mixtures[0].dim

    def component_logpdfs(self, theta: np.ndarray) -> np.ndarray:
        """``log V_c + log p_c(theta)`` for each branch, ``(m, d) -> (m, C)``."""
        theta = as_samples(theta, self.dim)
        return np.column_stack([lw + m.logpdf(theta) for lw, m in zip(self.log_weights, self.mixtures)])

    def logpdf(self, theta: np.ndarray) -> np.ndarray:
        """Log density at ``theta (m, d)`` (log-sum-exp over the branches), returns ``(m,)``."""
        return logsumexp(self.component_logpdfs(theta), axis=1)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws, shape ``(n, d)``: a branch per draw, then a draw of that branch's mixture."""
        branch = rng.choice(len(self.mixtures), size=int(n), p=np.exp(self.log_weights))
        out = np.empty((int(n), self.dim))
        for c, mixture in enumerate(self.mixtures):   # a loop over the few branches, not over samples
            rows = branch == c
            out[rows] = mixture.sample(int(rows.sum()), rng)
        return out

    def draw_one_per_component(self, rng: np.random.Generator) -> np.ndarray:
        """One draw per ancestor ``i``, ``(N, d)``: its branch ``c_i ~ V``, then ``N(centre_ci, h_ci^2)``
        (a draw of the transition from every ancestor)."""
        branch = rng.choice(len(self.mixtures), size=self.mixtures[0].centres.shape[0], p=np.exp(self.log_weights))
        centres = np.stack([m.centres for m in self.mixtures])            # (C, N, d)
        widths = np.stack([m.bandwidth for m in self.mixtures])           # (C, d)
        rows = np.arange(branch.size)
        return centres[branch, rows] + rng.standard_normal(centres.shape[1:]) * widths[branch]


def kept_copy(dataset):
    """A copy of a dataset that the sampler keeps (callers reuse their buffers): ``ndarray.copy``, else a deep copy."""
    return dataset.copy() if isinstance(dataset, np.ndarray) else copy.deepcopy(dataset)


@dataclass(frozen=True, eq=False)
class RunningStatistics:
    """A likelihood whose product over datasets depends on them only through additive statistics.

    With it the history prior evaluates ``prod_{k<s} L_k(theta)`` in one call whatever ``s``, so
    an update costs the same at step 1000 as at step 10 (the re-evaluation of the past that IBIS
    pays grows linearly with ``s`` otherwise).

    Parameters
    ----------
    summarise : callable ``dataset -> dict[str, array]``
        The statistics of one dataset; the statistics of several are their sums (e.g. for a
        linear-Gaussian model ``X^T X``, ``X^T y``, ``y^T y`` and the row count).
    loglike : callable ``(theta (N, d), statistics) -> (N,)``
        ``sum_k log L_k(theta)`` from the summed statistics of datasets ``k``.

    Examples
    --------
    >>> import numpy as np
    >>> stats = RunningStatistics(lambda y: {"n": np.array(y.size), "sum": y.sum(), "sq": y @ y},
    ...                           lambda theta, t: -0.5 * (t["sq"] - 2 * theta[:, 0] * t["sum"] + t["n"] * theta[:, 0] ** 2))
    >>> total = stats.add(stats.add(None, np.array([1.0, 2.0])), np.array([3.0]))
    >>> float(total["sum"]), int(total["n"])
    (6.0, 3)
    """

    summarise: object
    loglike: object

    def __post_init__(self):
        if not (callable(self.summarise) and callable(self.loglike)):
            raise TypeError("RunningStatistics: summarise and loglike must be callables")

    def add(self, summary: dict, dataset: Any) -> dict:
        """``summary`` (``None`` for none yet) plus the statistics of ``dataset``."""
        new = self.summarise(dataset)
        if not isinstance(new, dict) or not new:
            raise TypeError("history.summarise: must return a non-empty dict of arrays")
        new = {key: np.asarray(value, dtype=float) for key, value in new.items()}
        if summary is None:
            return new
        if set(summary) != set(new):
            raise ValueError(f"history.summarise: returned keys {sorted(new)}, earlier datasets gave {sorted(summary)}")
        return {key: summary[key] + new[key] for key in summary}


@dataclass(frozen=True, eq=False)
class HistoryPrior:
    """The exact prior of step ``s`` for static parameters: ``p_0(theta) prod_{k<s} L_k(theta) / Z_{1:s-1}``.

    Parameters
    ----------
    initial : object with ``logpdf``
        The initial prior ``p_0``.
    datasets : tuple
        The datasets ``D^1 .. D^{s-1}`` already assimilated.
    log_normaliser : float
        ``log Z_{1:s-1}``, the running log-evidence estimate, so that the density is
        normalised up to that estimate's error (an importance estimate of the next
        increment then estimates the whole ``log Z_{1:s}`` afresh).
    running : RunningStatistics, optional
        Evaluates the past in one call from ``summary`` instead of one call per dataset.
    summary : dict, optional
        The summed statistics of ``datasets`` (with ``running``).
    """

    initial: object
    datasets: tuple
    log_normaliser: float
    running: RunningStatistics | None = None
    summary: dict | None = None

    @classmethod
    def start(cls, initial, running, dataset, log_normaliser) -> "HistoryPrior":
        """The prior after the first dataset."""
        return cls(initial, (), 0.0, running, None).extended(dataset, log_normaliser)

    def extended(self, dataset, log_normaliser) -> "HistoryPrior":
        """The prior after one more dataset (a copy is kept: callers reuse buffers)."""
        kept = kept_copy(dataset)
        summary = self.running.add(self.summary, kept) if self.running is not None else None
        return HistoryPrior(self.initial, self.datasets + (kept,), float(log_normaliser), self.running, summary)

    def logpdf(self, theta, loglike, summary_loglike=None) -> np.ndarray:
        """Log density at ``theta (m, d)``; returns ``(m,)``.

        Parameters
        ----------
        theta : (m, d) array
        loglike : callable ``(theta (k, d), dataset) -> (k,)``
            Used per past dataset; rows that reach ``-inf`` are not evaluated on later datasets.
        summary_loglike : callable ``(theta (k, d), summary) -> (k,)``, optional
            Used instead, in one call, when the prior has running statistics.
        """
        out = np.asarray(self.initial.logpdf(theta), dtype=float) - self.log_normaliser
        if self.running is not None and self.summary is not None:
            alive = np.isfinite(out)
            if alive.any():
                out[alive] += (summary_loglike or self.running.loglike)(theta[alive], self.summary)
            return out
        for dataset in self.datasets:
            alive = np.isfinite(out)
            if alive.all():
                out = out + loglike(theta, dataset)
            elif alive.any():
                out[alive] += loglike(theta[alive], dataset)
            else:
                break
        return out


def predictive_density(posterior: np.ndarray, log_weights: np.ndarray, kernel: MarkovKernel,
                       rng: np.random.Generator, method: str = "transition",
                       shrink_static: bool = True) -> tuple[GaussianMixture, np.ndarray]:
    """The predictive prior of Eq. (A3) and the samples that represent it.

    Parameters
    ----------
    posterior : (N, d) array
        Posterior samples at step ``s``.
    log_weights : (N,) array
        Their log-weights.
    kernel : MarkovKernel
    rng : numpy.random.Generator
    method : {"transition", "kde"}
        See the module docstring.
    shrink_static : bool
        Liu-West shrinkage on the static dimensions (``"transition"`` only).

    Returns
    -------
    density : GaussianMixture or MixtureSum
        The prior density for step ``s + 1`` (a :class:`MixtureSum` for a kernel with jumps, ``"transition"``).
    samples : (N, d) array
        Predictive samples; their log-weights are ``log_weights`` (carried over).
    """
    posterior = as_samples(posterior, kernel.dim, "posterior")
    if method == "kde":  # Eq. (A9): KDE over the propagated samples, weights carried
        samples = kernel.propagate(posterior, rng)
        return GaussianMixture(samples, silverman_bandwidth(samples, log_weights), log_weights), samples
    if method != "transition":
        raise ValueError(f"predictive: unknown method {method!r}; choose from {PREDICTIVE_METHODS}")
    centres = kernel.nominal(posterior)
    static = kernel.static_mask
    bandwidth = kernel.noise_std.copy()
    if static.any():
        h = silverman_bandwidth(centres[:, static], log_weights)
        if shrink_static:  # Liu & West (2001): a = sqrt(1 - h^2 / sigma^2) keeps mean and variance
            mean, var, _ = _weighted_moments(centres[:, static], log_weights)
            a = np.sqrt(np.clip(1.0 - h**2 / np.maximum(var, 1e-300), 0.0, 1.0))
            centres[:, static] = mean + a * (centres[:, static] - mean)
        bandwidth[static] = h
    if getattr(kernel, "has_jumps", False):  # Eq. (A3) with a mixture transition: one mixture per branch
        branches, noisy = kernel.branches, ~static
        mixtures = []
        for shift, sd in zip(branches.shifts, branches.sds):
            width = bandwidth.copy()
            width[noisy] = sd[noisy]
            mixtures.append(GaussianMixture(centres + shift, width, log_weights))
        density = MixtureSum(mixtures, branches.log_weights)
    else:
        density = GaussianMixture(centres, bandwidth, log_weights)
    return density, density.draw_one_per_component(rng)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any
    from numpy.typing import ArrayLike

    from .kernels import MarkovKernel
