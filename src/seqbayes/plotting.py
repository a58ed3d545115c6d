"""Shared matplotlib helpers (Agg, no pyplot state): figures for on-line runs.

Figures are built as :class:`matplotlib.figure.Figure` objects with an Agg
canvas, never through ``pyplot``, so nothing is ever shown, no global figure
registry fills up, and the helpers are safe in worker processes and tests.

Every plotting function takes plain arrays or a :class:`~seqbayes.results.Result`
and returns a :class:`~matplotlib.figure.Figure`; :func:`to_png` and
:func:`to_data_uri` serialise it (the HTML report embeds PNGs as base64).
"""

from __future__ import annotations

import base64
import io
import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .prognostics import FirstPassage
    from .results import Result
    from .selection import ModelComparison

__all__ = ["new_figure", "integer_steps", "to_png", "to_data_uri", "save", "band", "credible_bands", "plot_parameter_evolution",
           "plot_sampler_diagnostics", "plot_evidence", "plot_model_probabilities", "plot_first_passage",
           "plot_data_fit", "COLORS"]

#: Colour cycle (matplotlib's tab10), one per run/model.
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f")


def new_figure(n_rows: int = 1, n_cols: int = 1, *, width: float = 7.0, row_height: float = 2.6,
               sharex: bool = True, squeeze: bool = False) -> tuple[Figure, np.ndarray]:
    """A figure with an Agg canvas and its axes array ``(n_rows, n_cols)``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, max(2.2, row_height * n_rows)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(n_rows, n_cols, sharex=sharex, squeeze=squeeze)
    return fig, axes


def integer_steps(axes: Axes | np.ndarray) -> None:
    """Integer ticks on the x axis (steps) of every axes in ``axes``."""
    from matplotlib.ticker import MaxNLocator

    for ax in np.ravel(axes):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def _finish_step_column(axes: np.ndarray) -> None:
    """A column of step-indexed axes: integer ticks, x label at the bottom, grids, legend on top."""
    integer_steps(axes)
    axes[-1, 0].set_xlabel("step (dataset)")
    for ax in axes[:, 0]:
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="small")


def to_png(fig: Figure, dpi: int = 100) -> bytes:
    """PNG bytes of a figure."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def to_data_uri(fig: Figure, dpi: int = 100) -> str:
    """``data:image/png;base64,...`` for embedding in HTML."""
    return "data:image/png;base64," + base64.b64encode(to_png(fig, dpi)).decode("ascii")


def save(fig: Figure, path: str | os.PathLike, dpi: int = 120) -> None:
    """Write a figure to ``path`` (format from the suffix)."""
    fig.savefig(path, dpi=dpi)


def band(ax: Axes, x: ArrayLike, centre: ArrayLike, lower: ArrayLike, upper: ArrayLike, *, color: str = COLORS[0],
         label: str | None = None, linestyle: str = "-", alpha: float = 0.25, marker: str = "o") -> None:
    """A line with a shaded band between ``lower`` and ``upper`` (all ``(S,)``)."""
    ax.fill_between(x, lower, upper, color=color, alpha=alpha, linewidth=0)
    ax.plot(x, centre, color=color, linestyle=linestyle, marker=marker, markersize=3.5, label=label)


def credible_bands(result: Result, level: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Posterior mean and central credible interval per step: three ``(S, d)`` arrays."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: must lie in (0, 1), got {level}")
    tail = 0.5 * (1.0 - level)
    means = result.means()
    quantiles = np.array([r.quantile([tail, 1.0 - tail]) for r in result.steps])  # (S, 2, d)
    return means, quantiles[:, 0, :], quantiles[:, 1, :]


def plot_parameter_evolution(result: Result, *, level: float = 0.95, forecast: np.ndarray | None = None,
                             truth: ArrayLike | None = None, title: str | None = None) -> Figure:
    """Posterior mean and credible band of every parameter against the step, with an optional forecast.

    Parameters
    ----------
    result : Result
    level : float
        Credible level of the band.
    forecast : (K, N, d) array, optional
        Equal-weight forecast draws for steps ``S + 1 .. S + K`` (dashed, lighter band).
    truth : (S, d) array, optional
        Reference values drawn as black crosses.
    """
    steps = np.array([r.info.step for r in result.steps])
    means, lower, upper = credible_bands(result, level)
    d = means.shape[1]
    fig, axes = new_figure(d, 1)
    tail = 0.5 * (1.0 - level)
    for j, name in enumerate(result.names):
        ax = axes[j, 0]
        band(ax, steps, means[:, j], lower[:, j], upper[:, j], label=f"posterior mean, {level:.0%} band")
        if forecast is not None:
            k = np.arange(1, forecast.shape[0] + 1) + steps[-1]
            q = np.quantile(forecast[:, :, j], [tail, 1.0 - tail], axis=1)
            x = np.concatenate([[steps[-1]], k])
            band(ax, x, np.concatenate([[means[-1, j]], forecast[:, :, j].mean(axis=1)]),
                 np.concatenate([[lower[-1, j]], q[0]]), np.concatenate([[upper[-1, j]], q[1]]),
                 color=COLORS[1], linestyle="--", alpha=0.18, label=f"forecast, {level:.0%} band")
        if truth is not None:
            ax.plot(steps, np.asarray(truth)[:, j], "kx", label="reference")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="small")
    integer_steps(axes)
    axes[-1, 0].set_xlabel("step (dataset)")
    if title:
        fig.suptitle(title)
    return fig


def plot_sampler_diagnostics(results: Mapping[str, Result], *, target_acceptance: float | None = None) -> Figure:
    """Acceptance rate and ESS / N per step for one or more runs (``name -> Result``)."""
    fig, axes = new_figure(2, 1)
    for i, (name, result) in enumerate(results.items()):
        steps = [r.info.step for r in result.steps]
        n = result.steps[0].posterior.shape[0]
        color = COLORS[i % len(COLORS)]
        axes[0, 0].plot(steps, [r.info.acceptance_rate for r in result.steps], "o-", color=color, label=name)
        axes[1, 0].plot(steps, [r.info.ess / n for r in result.steps], "o-", color=color, label=name)
    if target_acceptance is not None:
        axes[0, 0].axhline(target_acceptance, color="k", linestyle=":", label="target")
    axes[0, 0].set_ylabel("acceptance rate")
    axes[1, 0].set_ylabel("ESS / N (last stage)")
    # fixed limits: an auto-scaled axis would zoom into the step-to-step noise of a steady rate
    axes[0, 0].set_ylim(0, 1)
    axes[1, 0].set_ylim(0, 1.05)
    _finish_step_column(axes)
    return fig


def plot_evidence(results: Mapping[str, Result]) -> Figure:
    """Cumulative log-evidence and per-step increments for one or more runs (``name -> Result``)."""
    fig, axes = new_figure(2, 1)
    for i, (name, result) in enumerate(results.items()):
        steps = [r.info.step for r in result.steps]
        color = COLORS[i % len(COLORS)]
        axes[0, 0].plot(steps, result.log_evidence, "o-", color=color, label=name)
        axes[1, 0].plot(steps, result.log_evidence_increments, "o-", color=color, label=name)
    axes[0, 0].set_ylabel(r"$\log p(D^{1:s})$")
    axes[1, 0].set_ylabel(r"$\log p(D^s \mid D^{1:s-1})$")
    _finish_step_column(axes)
    return fig


def plot_model_probabilities(comparison: ModelComparison) -> Figure:
    """Posterior model probabilities per step (stacked areas) from a :class:`~seqbayes.selection.ModelComparison`."""
    fig, axes = new_figure(1, 1, row_height=3.0)
    ax = axes[0, 0]
    steps = np.arange(1, comparison.probabilities.shape[0] + 1)
    ax.stackplot(steps, comparison.probabilities.T, labels=comparison.names,
                 colors=[COLORS[i % len(COLORS)] for i in range(len(comparison.names))], alpha=0.85)
    ax.set_ylim(0, 1)
    ax.set_xlim(steps[0] - 0.5 if steps.size == 1 else steps[0], steps[-1] + 0.5 if steps.size == 1 else steps[-1])
    ax.set_ylabel("P(model | data)")
    integer_steps(axes)
    ax.set_xlabel("step (dataset)")
    ax.legend(loc="best", fontsize="small")
    return fig


def plot_first_passage(passages: Sequence[tuple[str, FirstPassage]], *, start_step: int = 0,
                       n_se: float = 2.0) -> Figure:
    """Cumulative distribution of the time to a threshold, with its Monte Carlo error.

    Parameters
    ----------
    passages : sequence of (str, FirstPassage)
        A label and a :class:`~seqbayes.prognostics.FirstPassage` per threshold.
    start_step : int
        The step the forecast starts from (the x axis shows ``start_step + h``).
    n_se : float
        Half-width of the shaded band in Monte Carlo standard errors (2: about 95 %).
    """
    fig, axes = new_figure(1, 1, row_height=3.0)
    ax = axes[0, 0]
    for i, (label, passage) in enumerate(passages):
        h = start_step + np.arange(1, passage.horizon + 1)
        c, se = passage.cumulative, passage.cumulative_standard_error
        color = COLORS[i % len(COLORS)]
        ax.fill_between(h, np.clip(c - n_se * se, 0, 1), np.clip(c + n_se * se, 0, 1), step="post", color=color,
                        alpha=0.25, linewidth=0)
        ax.step(h, c, where="post", color=color, label=f"P({label} by step)")
    ax.set_ylim(-0.02, 1.02)
    ax.set_ylabel("P(crossed by step)")
    ax.set_xlabel(f"step (band: +-{n_se:g} Monte Carlo standard errors)")
    ax.grid(alpha=0.3)
    integer_steps(axes)
    ax.legend(loc="best", fontsize="small")
    return fig


def plot_data_fit(x: ArrayLike, observed: ArrayLike, predicted: ArrayLike, *, level: float = 0.95,
                  title: str | None = None, xlabel: str | None = None, ylabel: str | None = None) -> Figure:
    """Data against the posterior-predictive fit: observations as dots, the predictive mean and band.

    Parameters
    ----------
    x : (n,) array
        Abscissa of the observations (e.g. time).
    observed : (n,) or (n, m) array
        The dataset's observations (``m`` channels).
    predicted : (N, n) or (N, n, m) array
        The model's prediction at ``N`` posterior draws.
    level : float
        Credible level of the band.
    title, xlabel, ylabel : str, optional
    """
    x = np.asarray(x, dtype=float)
    observed = np.asarray(observed, dtype=float).reshape(x.size, -1)
    predicted = np.asarray(predicted, dtype=float).reshape(-1, x.size, observed.shape[1])
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: must lie in (0, 1), got {level}")
    tail = 0.5 * (1.0 - level)
    lower, upper = np.quantile(predicted, [tail, 1.0 - tail], axis=0)
    fig, axes = new_figure(observed.shape[1], 1)
    order = np.argsort(x)
    for j in range(observed.shape[1]):
        ax = axes[j, 0]
        band(ax, x[order], predicted[:, order, j].mean(axis=0), lower[order, j], upper[order, j], color=COLORS[0],
             marker="", label=f"model at the posterior draws: mean, {level:.0%} band")
        ax.plot(x, observed[:, j], "k.", markersize=4, label="data")
        ax.grid(alpha=0.3)
        if ylabel:
            ax.set_ylabel(ylabel)
    if xlabel:
        axes[-1, 0].set_xlabel(xlabel)
    axes[0, 0].legend(loc="best", fontsize="small")
    if title:
        fig.suptitle(title)
    return fig
