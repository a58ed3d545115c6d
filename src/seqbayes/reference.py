"""Exact on-line references by grid filtering: the posterior of every step and the
cumulative log-evidence, on a tensor grid with quadrature instead of samples.

The target is the samplers' (Eqs. A2-A3 of Lye et al. 2023 with the box convention of
:mod:`seqbayes.engine.drivers`): the parameter space is the prior's box and the likelihood
is zero outside it, so at step ``s``

    p_s(theta) = L_s(theta) pi_s(theta) 1_box(theta) / Z_s,
    pi_s(theta') = int T(theta' | theta) p_{s-1}(theta) dtheta,   pi_1 = prior,
    Z_s = int_box L_s pi_s,

and a kernel that predicts mass outside the box loses it from the evidence (the
predictive is never renormalised). Here ``T`` acts on each parameter separately,
``theta'_j = Gamma_j(theta_j) + N(0, q_j^2)`` (the components of a
:class:`~seqbayes.kernels.MarkovKernel`); a parameter with ``q_j = 0`` must be static
(``Gamma_j`` the identity) and keeps the grid axis it got at step 1.

Each step chooses its grid from the data (:func:`adaptive_axes`): a coarse grid over a
window (the whole box, or the previous grid carried through ``Gamma`` and widened by
``20 q``, i.e. 200 nats of the transition density), trimmed to the range that leaves at
most ``tail_mass`` of each marginal of ``L pi`` outside (default 1e-40, about 13 sds of a
Gaussian), zoomed in until it stops shrinking, then a fine grid of ``n_points`` per axis
(or more, see ``points_per_sd``) over that range, uniform or geometric per axis
(``log_axes``, for long tails towards large values). Integrals are composite Simpson on
each axis (in ``log x`` with the Jacobian on a geometric axis); the predictive is the
convolution ``sum_j w_j T(x'_i | x_j) p(x_j)`` along each drifting axis (a matrix product
on scaled exponentials, so the log domain is kept).

The tails are kept that far because a later step whose data conflict with the
prediction puts its posterior where the predictive is made of the previous posterior's
far tail, where a cut at a few sds moves the later posterior by a sizeable fraction of its sd
(docs/exact_references.md measures it; the oscillator uses 1e-100). Discontinuities of the integrand (box bounds, a likelihood
that drops to zero beyond a known value) must be passed as hard bounds so that they are
grid end points.

Accuracy is measured, not assumed: the model functions that use this module are run at
two resolutions and compared (``docs/exact_references.md``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

__all__ = ["simpson_weights", "log_integral", "marginal_moments", "adaptive_axes", "propagate",
           "GridStep", "grid_update", "GridReference", "Resolution", "grid_filter", "reference_from_steps",
           "reference_table", "read_reference_table", "component_transition", "kernel_grid_filter"]


def simpson_weights(grid: ArrayLike) -> np.ndarray:
    """Composite Simpson weights of a uniform or log-uniform grid with an odd number of points.

    A log-uniform (geometric) grid is Simpson's rule in ``u = log x`` with the Jacobian
    ``dx = x du``: fine where ``x`` is small, coarse where it is large.

    Parameters
    ----------
    grid : array_like, shape (n,)
        Uniform or geometric (positive), increasing, ``n`` odd and at least 3.

    Returns
    -------
    ndarray, shape (n,)

    Examples
    --------
    >>> w = simpson_weights(np.linspace(0.0, 1.0, 5))
    >>> float(w @ np.linspace(0.0, 1.0, 5) ** 3)
    0.25
    >>> x = np.geomspace(1.0, 2.0, 201)
    >>> round(float(simpson_weights(x) @ (1.0 / x)), 10)        # log 2
    0.6931471806
    """
    grid = np.asarray(grid, dtype=float)
    n = grid.size
    if grid.ndim != 1 or n < 3 or n % 2 == 0:
        raise ValueError(f"grid: expected a 1-D grid with an odd number >= 3 of points, got shape {grid.shape}")
    w = np.full(n, 2.0)
    w[1::2] = 4.0
    w[0] = w[-1] = 1.0
    h = (grid[-1] - grid[0]) / (n - 1)
    if h > 0 and np.allclose(np.diff(grid), h, rtol=1e-6, atol=0.0):
        return w * (h / 3.0)
    if grid[0] > 0:
        u = np.log(grid)
        hu = (u[-1] - u[0]) / (n - 1)
        if hu > 0 and np.allclose(np.diff(u), hu, rtol=1e-6, atol=0.0):
            return w * (hu / 3.0) * grid
    raise ValueError("grid: expected a uniform or geometric increasing grid")


def _axis(lo: float, hi: float, n: int, log: bool) -> np.ndarray:
    return np.geomspace(lo, hi, n) if log else np.linspace(lo, hi, n)


def _log_weights(axes) -> list[np.ndarray]:
    """Per-axis log Simpson weights, each shaped to broadcast against the tensor grid."""
    d = len(axes)
    out = []
    for j, axis in enumerate(axes):
        shape = [1] * d
        shape[j] = axis.size
        out.append(np.log(simpson_weights(axis)).reshape(shape))
    return out


def _clean(log_values) -> np.ndarray:
    log_values = np.asarray(log_values, dtype=float)
    return np.where(np.isnan(log_values), -np.inf, log_values)


def log_integral(log_values: np.ndarray, axes: Sequence[np.ndarray]) -> float:
    """``log int f`` over a tensor grid, by Simpson on each axis, from ``log f``.

    Parameters
    ----------
    log_values : ndarray, shape (n_0, ..., n_{d-1})
        ``log f`` on the grid; NaN counts as ``-inf`` (zero).
    axes : sequence of d uniform odd-length grids

    Returns
    -------
    float
        ``-inf`` when ``f`` is zero everywhere.
    """
    total = _clean(log_values) + sum(_log_weights(axes))
    return float(logsumexp(total))


def _log_marginals(log_values, axes) -> list[np.ndarray]:
    """Log of the (unnormalised) one-dimensional marginals, ``[(n_j,)]``."""
    total = _clean(log_values) + sum(_log_weights(axes))
    d = len(axes)
    out = []
    for j in range(d):
        others = tuple(i for i in range(d) if i != j)
        m = logsumexp(total, axis=others) if others else total
        out.append(m - _log_weights([axes[j]])[0])          # density, not mass, on axis j
    return out


def marginal_moments(log_density: np.ndarray, axes: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation of each coordinate under a grid density.

    Parameters
    ----------
    log_density : ndarray, shape (n_0, ..., n_{d-1})
        Log density (normalised or not) on the tensor grid.
    axes : sequence of d uniform odd-length grids

    Returns
    -------
    mean, std : ndarray, shape (d,)
    """
    total = _clean(log_density) + sum(_log_weights(axes))
    mass = np.exp(total - logsumexp(total))
    mean, std = np.empty(len(axes)), np.empty(len(axes))
    for j, axis in enumerate(axes):
        others = tuple(i for i in range(len(axes)) if i != j)
        m = mass.sum(axis=others) if others else mass
        mean[j] = m @ axis
        std[j] = np.sqrt(max(m @ (axis - mean[j]) ** 2, 0.0))
    return mean, std


def _range_with_mass(log_marginal, axis, tail_mass):
    """Indices of the first and last grid point such that at most ``tail_mass`` of the
    marginal's mass lies beyond each of them."""
    log_mass = log_marginal + np.log(simpson_weights(axis))
    mass = np.exp(log_mass - logsumexp(log_mass))
    below = np.cumsum(mass) - mass                       # mass strictly left of each point
    above = np.cumsum(mass[::-1])[::-1] - mass           # mass strictly right of each point
    return int(np.flatnonzero(below <= tail_mass)[-1]), int(np.flatnonzero(above <= tail_mass)[0])


def adaptive_axes(log_target: Callable, window: ArrayLike, n_points: int | Sequence[int], *,
                  hard: ArrayLike | None = None, fixed: Sequence[np.ndarray | None] | None = None,
                  n_coarse: int = 201, tail_mass: float = 1e-40, max_rounds: int = 12,
                  points_per_sd: float | None = None, scales: ArrayLike | None = None, max_points: int = 2001,
                  log_axes: Sequence[bool] | None = None) -> tuple[np.ndarray, ...]:
    """A data-centred fine grid: the range of every marginal of ``exp(log_target)`` but for
    ``tail_mass`` of its mass in each tail.

    Starting from a coarse grid over ``window``, each round trims every axis to the
    range that leaves at most ``tail_mass`` of its marginal's mass on each side (plus
    one coarse cell each side), widens an axis whose mass reaches a window edge that is not a hard
    bound (by the window's width), and zooms in; it stops when no axis shrinks below
    half its width or moves.

    Parameters
    ----------
    log_target : callable ``(axes) -> ndarray (n_0, ..., n_{d-1})``
        Log of the unnormalised density on a tensor grid; NaN counts as zero.
    window : array_like, shape (d, 2)
        Initial ``[lower, upper]`` per axis.
    n_points : int or sequence of d ints
        Fine points per axis (made odd).
    hard : array_like, shape (d, 2), optional
        Bounds never crossed (the box, or where the density drops to zero); a window
        edge equal to a hard bound is never widened. Default: ``window``.
    fixed : sequence of d (ndarray or None), optional
        Axes that are given (static parameters after step 1): used as they are.
    n_coarse : int or sequence of d ints
        Coarse points per axis.
    tail_mass : float
        Mass of each marginal allowed outside the grid, per side (a density-based
        cut-off would fail on likelihoods with a far, flat plateau: the damped
        oscillator's likelihood is only ~40 nats below its peak wherever the model
        response has died out).
    max_rounds : int
    points_per_sd : float, optional
        If given, an axis gets more than ``n_points`` when needed to put this many
        points in the smaller of its marginal sd (estimated on the coarse grid) and its
        ``scales`` entry (up to ``max_points``): wide ranges kept for far tails stay resolved.
    scales : array_like, shape (d,), optional
        A further length per axis to resolve (e.g. the transition's width in the
        previous step's coordinates); ``inf`` for none.
    max_points : int
    log_axes : sequence of d bool, optional
        Axes gridded geometrically (positive windows only): for posteriors with long
        tails towards large values. ``points_per_sd`` then counts in ``log x`` and the
        ``scales`` are taken relative to the marginal's geometric mean.

    Returns
    -------
    tuple of d ndarrays
        The fine axes.
    """
    window = np.array(window, dtype=float)
    d = window.shape[0]
    if window.shape != (d, 2) or not np.all(window[:, 1] > window[:, 0]):
        raise ValueError(f"window: expected (d, 2) with lower < upper, got {window.tolist()}")
    hard = window.copy() if hard is None else np.array(hard, dtype=float)
    if hard.shape != (d, 2):
        raise ValueError(f"hard: expected shape ({d}, 2), got {hard.shape}")
    fixed = [None] * d if fixed is None else list(fixed)
    n_points = np.broadcast_to(np.asarray(n_points, dtype=int), (d,)) | 1
    n_coarse = np.broadcast_to(np.asarray(n_coarse, dtype=int), (d,)) | 1
    window[:, 0] = np.maximum(window[:, 0], hard[:, 0])
    window[:, 1] = np.minimum(window[:, 1], hard[:, 1])
    if np.any(window[:, 1] <= window[:, 0]):     # e.g. a predictive that left the box entirely
        raise ValueError(f"log_target: zero everywhere on the window {window.tolist()} (outside the hard bounds)")
    log_axes = np.zeros(d, dtype=bool) if log_axes is None else np.asarray(log_axes, dtype=bool)
    if log_axes.shape != (d,) or np.any(window[log_axes, 0] <= 0):
        raise ValueError(f"log_axes: expected {d} flags, and positive windows on the flagged axes")
    n_fine = n_points.copy()
    for _ in range(max_rounds):
        axes = [fixed[j] if fixed[j] is not None else _axis(*window[j], n_coarse[j], log_axes[j]) for j in range(d)]
        values = _clean(log_target(axes))
        if not np.isfinite(values).any():
            raise ValueError(f"log_target: zero everywhere on the window {window.tolist()}")
        marginals = _log_marginals(values, axes)
        new = window.copy()
        changed = False
        for j in range(d):
            if fixed[j] is not None:
                continue
            axis = axes[j]
            i0, i1 = _range_with_mass(marginals[j], axis, tail_mass)
            width = window[j, 1] - window[j, 0]
            lo, hi = axis[max(i0 - 1, 0)], axis[min(i1 + 1, axis.size - 1)]
            if i0 == 0 and window[j, 0] > hard[j, 0]:        # mass at an open edge: widen
                lo = max(window[j, 0] - width, hard[j, 0])
            if i1 == axis.size - 1 and window[j, 1] < hard[j, 1]:
                hi = min(window[j, 1] + width, hard[j, 1])
            new[j] = lo, hi
            if (hi - lo) < 0.5 * width or lo < window[j, 0] or hi > window[j, 1]:
                changed = True
        window = new
        if not changed:
            break
    else:
        raise RuntimeError(f"adaptive_axes: the grid range did not settle in {max_rounds} rounds ({window.tolist()})")
    if points_per_sd is not None:
        scale = np.full(d, np.inf) if scales is None else np.asarray(scales, dtype=float)
        width = window[:, 1] - window[:, 0]
        length = np.empty(d)
        for j, m in enumerate(_log_marginals(values, axes)):
            mass = np.exp(m + np.log(simpson_weights(axes[j])) - logsumexp(m + np.log(simpson_weights(axes[j]))))
            coord = np.log(axes[j]) if log_axes[j] else axes[j]
            centre = mass @ coord
            sd = np.sqrt(max(mass @ (coord - centre) ** 2, 0.0))
            length[j] = min(sd, scale[j] / np.exp(centre) if log_axes[j] else scale[j]) / float(points_per_sd)
            if log_axes[j]:
                width[j] = np.log(window[j, 1] / window[j, 0])
        with np.errstate(divide="ignore", invalid="ignore"):
            needed = np.where(length > 0, np.ceil(width / length), n_points)
        n_fine = np.clip(np.nan_to_num(needed, nan=0.0, posinf=max_points), n_points, max_points).astype(int) | 1
    return tuple(fixed[j] if fixed[j] is not None else _axis(*window[j], n_fine[j], log_axes[j]) for j in range(d))


def _transition_matrix(new_axis, old_axis, nominal, noise_std) -> np.ndarray:
    """``M[i, j] = w_j N(new_i; Gamma(old_j), q^2)``, shape ``(n_new, n_old)`` (Eq. A2)."""
    mean = np.asarray(nominal(old_axis), dtype=float)
    z = (new_axis[:, None] - mean[None, :]) / noise_std
    return np.exp(-0.5 * z * z) / (noise_std * np.sqrt(2.0 * np.pi)) * simpson_weights(old_axis)[None, :]


def propagate(log_density: np.ndarray, old_axes: Sequence[np.ndarray], new_axes: Sequence[np.ndarray],
              nominals: Sequence[Callable], noise_stds: ArrayLike) -> np.ndarray:
    """Log predictive density ``log int T(theta' | theta) p(theta) dtheta`` on a new grid (Eq. A3).

    Parameters
    ----------
    log_density : ndarray, shape (n_0, ..., n_{d-1})
        Log posterior density on ``old_axes``.
    old_axes, new_axes : sequences of d uniform odd-length grids
        A static axis (``noise_stds[j] == 0``) must be the same array in both.
    nominals : sequence of d callables ``(n,) -> (n,)``
        ``Gamma_j``; ignored for static axes.
    noise_stds : sequence of d floats

    Returns
    -------
    ndarray, shape (len(new_axes[0]), ..., len(new_axes[d-1]))
        ``-inf`` where the predictive underflows.
    """
    matrices = []
    for j, q in enumerate(noise_stds):
        if q == 0:
            if new_axes[j] is not old_axes[j] and not np.array_equal(new_axes[j], old_axes[j]):
                raise ValueError(f"new_axes[{j}]: a static axis keeps its grid")
            matrices.append(None)
        else:
            matrices.append(_transition_matrix(np.asarray(new_axes[j]), np.asarray(old_axes[j]), nominals[j],
                                               float(q)))
    return apply_axis_transitions(log_density, matrices)


def apply_axis_transitions(log_density: np.ndarray, matrices: Sequence[np.ndarray | None]) -> np.ndarray:
    """``log sum_old M_0[new_0, old_0] ... M_{d-1}[new_{d-1}, old_{d-1}] p(old)``: a transition that acts
    on each axis separately, applied to a log density on a grid (quadrature weights inside ``M``).

    Parameters
    ----------
    log_density : ndarray, shape (n_0, ..., n_{d-1})
    matrices : sequence of d ``(m_j, n_j)`` arrays, or None for an axis left as it is

    Returns
    -------
    ndarray, shape (m_0, ..., m_{d-1}); ``-inf`` where the result underflows.
    """
    log_density = _clean(log_density)
    shift = np.max(log_density)
    if not np.isfinite(shift):
        raise ValueError("log_density: zero everywhere")
    values = np.exp(log_density - shift)             # scaled exponentials: log-sum-exp as a matrix product
    for j, matrix in enumerate(matrices):
        if matrix is not None:
            values = np.moveaxis(np.tensordot(matrix, values, axes=([1], [j])), 0, j)
    with np.errstate(divide="ignore"):
        return np.log(values) + shift


@dataclass(frozen=True)
class GridStep:
    """One step of a grid filter.

    Attributes
    ----------
    axes : tuple of d ndarrays
        The fine grid.
    log_density : ndarray, shape (n_0, ..., n_{d-1})
        Normalised log posterior density on the grid.
    log_evidence_increment : float
        ``log Z_s = log int_box L_s pi_s``.
    mean, std : ndarray, shape (d,)
        Posterior moments of each coordinate.
    """

    axes: tuple
    log_density: np.ndarray
    log_evidence_increment: float
    mean: np.ndarray
    std: np.ndarray


def grid_update(log_target: Callable, window: ArrayLike, n_points: int | Sequence[int], **kwargs: Any) -> GridStep:
    """One Bayes update on an adaptive grid: ``log_target = log(L pi)`` integrated and normalised.

    Parameters are those of :func:`adaptive_axes` (``kwargs``: ``hard``, ``fixed``,
    ``n_coarse``, ``tail_mass``). After the fine evaluation the marginal density at every
    edge that is not a hard bound must lie 20 nats below its peak (else ``RuntimeError``).
    """
    axes = adaptive_axes(log_target, window, n_points, **kwargs)
    values = _clean(log_target(axes))
    hard = kwargs.get("hard", window)
    for j, m in enumerate(_log_marginals(values, axes)):
        peak = np.max(m)
        open_lo, open_hi = axes[j][0] > np.asarray(hard)[j, 0], axes[j][-1] < np.asarray(hard)[j, 1]
        if (open_lo and m[0] > peak - 20.0) or (open_hi and m[-1] > peak - 20.0):
            raise RuntimeError(f"grid_update: axis {j} carries mass at an open edge "
                               f"({m[0] - peak:.1f}, {m[-1] - peak:.1f} nats below the peak); widen the grid")
    log_z = log_integral(values, axes)
    log_density = values - log_z
    mean, std = marginal_moments(log_density, axes)
    for arr in (log_density, mean, std):
        arr.setflags(write=False)
    return GridStep(tuple(axes), log_density, log_z, mean, std)


@dataclass(frozen=True)
class GridReference:
    """Exact per-step posterior summaries and evidence of one model and kernel.

    Attributes
    ----------
    parameter_names : tuple of str
    mean, std : ndarray, shape (S, d)
        Posterior mean and standard deviation of each parameter after each step.
    log_evidence : ndarray, shape (S,)
        Cumulative ``log p(D^{1:s} | M)``.
    log_evidence_increment : ndarray, shape (S,)
    settings : dict
        Resolution and thresholds used.
    """

    parameter_names: tuple
    mean: np.ndarray
    std: np.ndarray
    log_evidence: np.ndarray
    log_evidence_increment: np.ndarray
    settings: dict

    def __post_init__(self):
        for name in ("mean", "std", "log_evidence", "log_evidence_increment"):
            arr = np.array(getattr(self, name), dtype=float)
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def errors(self, mean: ArrayLike, std: ArrayLike, log_evidence: ArrayLike) -> dict:
        """A sampler's errors against this reference, step by step.

        Parameters
        ----------
        mean, std : array_like, shape (S', d)
            The sampler's posterior means and sds for the first ``S' <= S`` steps
            (e.g. ``Result.means()``, ``Result.stds()``).
        log_evidence : array_like, shape (S',)
            Its cumulative log-evidence.

        Returns
        -------
        dict
            ``"mean_sd" (S', d)``: (sampler - exact) / exact sd; ``"std_ratio" (S', d)``:
            sampler sd / exact sd - 1; ``"log_evidence" (S',)``: sampler - exact [nats].
        """
        mean, std = np.atleast_2d(np.asarray(mean, dtype=float)), np.atleast_2d(np.asarray(std, dtype=float))
        log_evidence = np.atleast_1d(np.asarray(log_evidence, dtype=float))
        n = log_evidence.size
        d = self.mean.shape[1]
        if mean.shape != (n, d) or std.shape != (n, d) or n > self.log_evidence.size:
            raise ValueError(f"mean, std, log_evidence: expected shapes (S, {d}), (S, {d}), (S,) with "
                             f"S <= {self.log_evidence.size}; got {mean.shape}, {std.shape}, {log_evidence.shape}")
        return {"mean_sd": (mean - self.mean[:n]) / self.std[:n], "std_ratio": std / self.std[:n] - 1.0,
                "log_evidence": log_evidence - self.log_evidence[:n]}

    def rows(self) -> list[dict]:
        """One dict per (step, quantity): ``step, quantity, mean, std`` (``std`` empty for the evidence)."""
        out = []
        for s in range(self.log_evidence.size):
            out.append({"step": s + 1, "quantity": "log_evidence", "mean": float(self.log_evidence[s]), "std": None})
            for j, name in enumerate(self.parameter_names):
                out.append({"step": s + 1, "quantity": name, "mean": float(self.mean[s, j]),
                            "std": float(self.std[s, j])})
        return out


@dataclass(frozen=True)
class Resolution:
    """How finely the grid filters resolve each step's density: :func:`adaptive_axes`'s ``n_coarse``,
    ``tail_mass``, ``points_per_sd``, ``max_points`` and ``log_axes``."""

    n_coarse: int = 201
    tail_mass: float = 1e-40
    points_per_sd: float | None = None
    max_points: int = 2001
    log_axes: Sequence[bool] | None = None

    def keywords(self) -> dict:
        return {"n_coarse": self.n_coarse, "tail_mass": self.tail_mass, "points_per_sd": self.points_per_sd,
                "max_points": self.max_points, "log_axes": self.log_axes}


def grid_filter(datasets: Sequence, log_likelihood: Callable, box: ArrayLike, nominals: Sequence[Callable],
                noise_stds: ArrayLike, n_points: int | Sequence[int], *, first_window: ArrayLike | None = None,
                hard: ArrayLike | None = None, widen: float = 20.0,
                resolution: Resolution = Resolution()) -> list[GridStep]:
    """Grid filter under a uniform box prior and a per-parameter Gaussian kernel.

    Parameters
    ----------
    datasets : sequence
        One item per step, passed to ``log_likelihood``.
    log_likelihood : callable ``(axes, dataset) -> ndarray (n_0, ..., n_{d-1})``
        On a tensor grid; NaN counts as zero.
    box : array_like, shape (d, 2)
        The uniform prior's box (the parameter space).
    nominals : sequence of d callables ``(n,) -> (n,)``
        ``Gamma_j`` of the kernel, per parameter.
    noise_stds : array_like, shape (d,)
        ``q_j``; 0 marks a static parameter (its grid is fixed at step 1).
    n_points : int or sequence of d ints
        Fine points per axis.
    first_window : array_like (d, 2), optional
        Step 1's grid stays inside this window (default: the box). For a likelihood
        with a far plateau (the damped oscillator's) this is where its peak is; the
        plateau's mass outside is neglected.
    hard : callable ``(step_index, dataset) -> (d, 2)``, optional
        Hard bounds per step (default: the box); for likelihoods that drop to zero
        beyond a known value, so that the discontinuity is a grid end point.
    widen : float
        The step-``s > 1`` window is the previous grid carried through ``Gamma`` and
        widened by ``widen`` noise stds each side.
    resolution : Resolution
        As :func:`adaptive_axes`; the transition's width in the previous step's
        coordinates, ``q_j / |dGamma_j/dtheta_j|``, is a length to resolve too.

    Returns
    -------
    list of GridStep
        One per dataset; the list stops early if a step has zero evidence (the
        predictive puts no mass where the likelihood is positive).
    """
    box = np.array(box, dtype=float)
    d = box.shape[0]
    noise = np.asarray(noise_stds, dtype=float)
    if noise.shape != (d,) or np.any(noise < 0):
        raise ValueError(f"noise_stds: expected {d} values >= 0, got {noise_stds!r}")
    if len(nominals) != d:
        raise ValueError(f"nominals: expected {d} callables, got {len(nominals)}")
    log_volume = float(np.sum(np.log(box[:, 1] - box[:, 0])))
    scales = np.full(d, np.inf)          # the transition's width seen from the previous grid
    for j in range(d):
        if noise[j] > 0:
            ends = np.asarray(nominals[j](box[j]), dtype=float)
            slope = abs(ends[1] - ends[0]) / (box[j, 1] - box[j, 0])
            scales[j] = noise[j] / slope if slope > 0 else np.inf
    steps: list[GridStep] = []
    for s, dataset in enumerate(datasets):
        bounds = box if hard is None else np.array(hard(s, dataset), dtype=float)
        if s == 0:
            def log_target(axes, dataset=dataset):
                return log_likelihood(axes, dataset) - log_volume
            if first_window is not None:
                window = np.array(first_window, dtype=float)
                bounds = np.column_stack([np.maximum(window[:, 0], bounds[:, 0]),
                                          np.minimum(window[:, 1], bounds[:, 1])])
            window = bounds
            fixed = None
        else:
            prev = steps[-1]

            def log_target(axes, dataset=dataset, prev=prev):
                return propagate(prev.log_density, prev.axes, axes, nominals, noise) + log_likelihood(axes, dataset)
            window = np.empty((d, 2))
            for j in range(d):
                ends = np.asarray(nominals[j](prev.axes[j][[0, -1]]), dtype=float)
                window[j] = ends.min() - widen * noise[j], ends.max() + widen * noise[j]
            fixed = [prev.axes[j] if noise[j] == 0 else None for j in range(d)]
        try:
            step = grid_update(log_target, window, n_points, hard=bounds, fixed=fixed, scales=scales,
                               **resolution.keywords())
        except ValueError as err:
            if "zero everywhere" in str(err):
                break
            raise
        steps.append(step)
    return steps


def component_transition(new_axis: np.ndarray, old_axis: np.ndarray, component: Any,
                         slab_only: bool = False) -> np.ndarray:
    """``M[i, l] = sum_b P_b N(new_i; Gamma(old_l) + shift_b, sd_b^2) w_l`` for one parameter's kernel
    component, ``w`` the Simpson weights of ``old_axis`` (the per-axis convolution of Eq. A3).

    A :class:`~seqbayes.kernels.Jump` contributes its spike and slab branches (``Jump.branches``), any
    other component its single Gaussian; ``slab_only`` keeps a jump's slab branches alone (times
    their probabilities), whose integral against ``L_s`` is the jump's posterior mass.

    Parameters
    ----------
    new_axis : ndarray, shape (m,)
    old_axis : ndarray, shape (n,)
        A uniform or geometric odd-length grid.
    component : Drift, Decay, Custom or Jump
    slab_only : bool

    Returns
    -------
    ndarray, shape (m, n)
    """
    from .kernels import Jump

    if isinstance(component, Jump):
        log_p, shift, sd = component.branches()
    else:
        log_p, shift, sd = np.zeros(1), np.zeros(1), np.array([component.noise_std])
    if slab_only:
        log_p, shift, sd = log_p[1:], shift[1:], sd[1:]
    new_axis, old_axis = np.asarray(new_axis, dtype=float), np.asarray(old_axis, dtype=float)
    mean = np.asarray(component.nominal(old_axis), dtype=float)
    out = np.zeros((new_axis.size, old_axis.size))
    for lp, b, s in zip(log_p, shift, sd):      # a few branches
        z = (new_axis[:, None] - mean[None, :] - b) / s
        out += np.exp(lp - 0.5 * z * z) / (s * np.sqrt(2.0 * np.pi))
    return out * simpson_weights(old_axis)[None, :]


def kernel_grid_filter(datasets: Sequence, log_likelihood: Callable, kernel: Any, first_window: ArrayLike, *,
                       log_prior: Callable | None = None, box: ArrayLike | None = None, n_points: int = 201,
                       widen: float = 20.0, resolution: Resolution = Resolution(tail_mass=1e-100, points_per_sd=5.0)
                       ) -> tuple[list[GridStep], np.ndarray]:
    """Grid filter under any prior density and a :class:`~seqbayes.kernels.MarkovKernel` whose components act
    on one parameter each, :class:`~seqbayes.kernels.Jump` included: the posterior of every step and the
    probability that each jump parameter jumped into it.

    Step 1's target is ``log_prior + L_1``; step ``s`` convolves the last posterior with each axis's
    transition mixture (:func:`component_transition`, Eq. A3) and multiplies by ``L_s``. The probability
    that parameter ``j`` jumped into step ``s`` is ``int L_s pi_s^{slab j} / Z_s``, ``pi_s^{slab j}`` the
    predictive with only ``j``'s slab branches (times their probability).

    Parameters
    ----------
    datasets : sequence
        One item per step, passed to ``log_likelihood``.
    log_likelihood : callable ``(axes, dataset) -> ndarray (n_0, ..., n_{d-1})``
        On a tensor grid; NaN counts as zero.
    kernel : MarkovKernel
        Built from components (every one with process noise).
    first_window : array_like, shape (d, 2)
        Step 1's initial window (widened where mass reaches an edge inside ``box``).
    log_prior : callable ``(axes) -> ndarray``, optional
        Log prior density on the grid (default: uniform on ``box``, which must then be finite).
    box : array_like, shape (d, 2), optional
        The parameter space (hard bounds; default unbounded).
    n_points
        As :func:`adaptive_axes`.
    widen : float
        A later step's window is the previous grid carried through each branch, widened by ``widen``
        of that branch's sds.
    resolution : Resolution
        As :func:`adaptive_axes` (``tail_mass`` 1e-100 and ``points_per_sd`` 5 by default).

    Returns
    -------
    steps : list of GridStep
    jump_probability : ndarray, shape (S, d)
        NaN at step 1 and for components that are not jumps.
    """
    from .kernels import Jump

    components = tuple(getattr(kernel, "components", ()))
    if not components or np.any(np.asarray(kernel.noise_std) == 0):
        raise ValueError("kernel: expected a MarkovKernel of per-parameter components, each with process noise")
    d = len(components)
    box = np.tile([-np.inf, np.inf], (d, 1)) if box is None else np.array(box, dtype=float)
    first_window = np.array(first_window, dtype=float)
    if box.shape != (d, 2) or first_window.shape != (d, 2):
        raise ValueError(f"box, first_window: expected shape ({d}, 2), got {box.shape}, {first_window.shape}")
    if log_prior is None:
        if not np.all(np.isfinite(box)):
            raise ValueError("log_prior: required when the box is unbounded")
        log_volume = float(np.sum(np.log(box[:, 1] - box[:, 0])))

        def log_prior(axes):
            return np.full(tuple(a.size for a in axes), -log_volume)
    scales = np.empty(d)          # the transition's width seen from the previous grid
    for j, c in enumerate(components):
        ends = np.asarray(c.nominal(first_window[j]), dtype=float)
        scales[j] = c.noise_std * (first_window[j, 1] - first_window[j, 0]) / abs(ends[1] - ends[0])
    settings = dict(scales=scales, **resolution.keywords())
    branches = [c.branches() if isinstance(c, Jump) else (np.zeros(1), np.zeros(1), np.array([c.noise_std]))
                for c in components]

    def predictive(prev, axes, slab_axis=None):
        return apply_axis_transitions(prev.log_density, [
            component_transition(axes[j], prev.axes[j], c, j == slab_axis) for j, c in enumerate(components)])

    steps: list[GridStep] = []
    jumps = np.full((len(datasets), d), np.nan)
    for s, dataset in enumerate(datasets):
        if s == 0:
            window = first_window

            def log_target(axes, dataset=dataset):
                return log_prior(axes) + log_likelihood(axes, dataset)
        else:
            prev = steps[-1]
            window = np.empty((d, 2))
            for j, c in enumerate(components):
                ends = np.asarray(c.nominal(prev.axes[j][[0, -1]]), dtype=float)
                _, shift, sd = branches[j]
                window[j] = ends.min() + np.min(shift - widen * sd), ends.max() + np.max(shift + widen * sd)

            def log_target(axes, dataset=dataset, prev=prev):
                return predictive(prev, axes) + log_likelihood(axes, dataset)
        step = grid_update(log_target, window, n_points, hard=box, **settings)
        if s > 0:
            for j, c in enumerate(components):
                if isinstance(c, Jump):
                    slab = predictive(prev, step.axes, slab_axis=j) + _clean(log_likelihood(step.axes, dataset))
                    jumps[s, j] = np.exp(log_integral(slab, step.axes) - step.log_evidence_increment)
        steps.append(step)
    jumps.setflags(write=False)
    return steps, jumps


def reference_from_steps(steps: Sequence[GridStep], parameter_names: Sequence[str], n_steps: int,
                         settings: dict) -> GridReference:
    """Stack :class:`GridStep` records into a :class:`GridReference` (``-inf`` evidence, NaN moments
    for the steps after a zero-evidence step)."""
    d = len(parameter_names)
    mean = np.full((n_steps, d), np.nan)
    std = np.full((n_steps, d), np.nan)
    inc = np.full(n_steps, -np.inf)
    for s, step in enumerate(steps):
        mean[s], std[s], inc[s] = step.mean, step.std, step.log_evidence_increment
    return GridReference(tuple(parameter_names), mean, std, np.cumsum(inc), inc, dict(settings))


_TABLE_COLUMNS = ("step", "quantity", "mean", "std")


def reference_table(references: dict, key_names: Sequence[str]) -> str:
    """CSV text of several references: one row per (key, step, quantity).

    Parameters
    ----------
    references : dict tuple -> GridReference
        Keyed by tuples named ``key_names`` (e.g. ``("T1",)`` or ``(9, "T2")``).
    key_names : sequence of str
        Column names of the key's fields.

    Returns
    -------
    str
        Header ``*key_names, step, quantity, mean, std``; ``std`` is empty for the
        cumulative log-evidence; values to 10 significant digits.
    """
    lines = [",".join((*key_names, *_TABLE_COLUMNS))]
    for key, ref in references.items():
        key = key if isinstance(key, tuple) else (key,)
        if len(key) != len(key_names):
            raise ValueError(f"references: key {key!r} does not match key_names {tuple(key_names)}")
        for row in ref.rows():
            std = "" if row["std"] is None else f"{row['std']:.10g}"
            lines.append(",".join((*map(str, key), str(row["step"]), row["quantity"], f"{row['mean']:.10g}", std)))
    return "\n".join(lines) + "\n"


def read_reference_table(text: str, key_names: Sequence[str], parameter_names: Sequence[str],
                         key_types: Sequence[type] | None = None) -> dict:
    """Parse :func:`reference_table` output (lines starting with ``#`` are comments).

    Returns
    -------
    dict tuple -> GridReference
        ``settings`` is empty; ``log_evidence_increment`` is recomputed from the cumulative values.
    """
    import csv

    key_types = tuple(key_types) if key_types is not None else (str,) * len(key_names)
    rows = list(csv.DictReader(line for line in text.splitlines() if line and not line.startswith("#")))
    grouped: dict = {}
    for row in rows:
        key = tuple(t(row[name]) for t, name in zip(key_types, key_names))
        grouped.setdefault(key, []).append(row)
    out = {}
    for key, group in grouped.items():
        n_steps = max(int(r["step"]) for r in group)
        mean = np.full((n_steps, len(parameter_names)), np.nan)
        std = np.full((n_steps, len(parameter_names)), np.nan)
        log_evidence = np.full(n_steps, np.nan)
        for r in group:
            s = int(r["step"]) - 1
            if r["quantity"] == "log_evidence":
                log_evidence[s] = float(r["mean"])
            else:
                j = list(parameter_names).index(r["quantity"])
                mean[s, j], std[s, j] = float(r["mean"]), float(r["std"])
        out[key] = GridReference(tuple(parameter_names), mean, std, log_evidence,
                                 np.diff(log_evidence, prepend=0.0), {})
    return out

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any
    from numpy.typing import ArrayLike
