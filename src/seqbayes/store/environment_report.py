"""The report of a year of monitoring under temperature (issue 25, docs/environment.md): the identified
frequencies against temperature with the learned environmental model, P(damage) over the days with the
alarm, the learned coefficients, and the day-by-day table, as one self-contained HTML page.

The damage models of :class:`~seqbayes.structural.environment.EnvironmentMonitor` couple the days (the
damage day is summed out), so they do not run in a run store; this page is what ``seqbayes environment
--report`` writes, built from the monitor's daily records with the run store's HTML pieces.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import plotting
from .pages import figure_html, page, table_html
from .targets import write_output

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..structural.environment import EnvironmentMonitor, MonitorDay

__all__ = ["environment_figure", "render_environment_report", "write_environment_report"]


def _frequencies(table: dict, n: int) -> np.ndarray:
    return np.column_stack([np.asarray(table[f"f{r + 1}"], float) for r in range(n)])


def environment_figure(monitor: EnvironmentMonitor, table: dict, days: list, records: list[MonitorDay],
                       alarm_times: list, damage_day: float | None = None, damage_storey: int | None = None) -> Figure:
    """Four panels: f1 against temperature with the no-damage model's learned law, P(damage) with the
    threshold and the first alarm, the learned temperature coefficients (mean +- 2 sd) over the days, and
    every identified frequency relative to its mean.

    Parameters
    ----------
    monitor : EnvironmentMonitor
        The monitor that ran (its building, prior and alarm threshold).
    table : dict
        The year's columns ``day``, ``temperature``, ``f1..fn`` (rows of identified sets).
    days, records : lists
        The day indices and :class:`~seqbayes.structural.environment.MonitorDay` records of the updates.
    alarm_times : list of float
        Alarm days (the end of the day whose update raised them).
    damage_day, damage_storey : float, int or None
        The true damage, when known (a simulated year).
    """
    n, threshold = monitor.building.n_storeys, monitor.threshold
    frequencies = _frequencies(table, n)
    temperature, day = np.asarray(table["temperature"], float), np.asarray(table["day"], float)
    fig, ax = plotting.new_figure(2, 2, width=11.0, row_height=3.5, sharex=False)
    before = np.ones(day.size, bool) if damage_day is None else day < damage_day
    ax[0, 0].plot(temperature[before], frequencies[before, 0], ".", ms=1.5, alpha=0.4, label="before damage")
    if not before.all():
        ax[0, 0].plot(temperature[~before], frequencies[~before, 0], ".", ms=1.5, color=plotting.COLORS[3],
                      alpha=0.6, label="after damage")
    # the law learned before any damage: the last healthy day's no-damage posterior
    healthy = len(records) - 1 if damage_day is None else max(0, int(np.searchsorted(days, damage_day)) - 1)
    m0 = records[healthy].models[0].mean
    grid = np.linspace(temperature.min(), temperature.max(), 200)
    factor = 1.0 + m0[n] * (grid - monitor.prior.reference_temperature) + m0[n + 1] * np.minimum(grid, 0.0)
    f_ref = monitor.building.modes(m0[:n])[0][0, 0]
    ax[0, 0].plot(grid, f_ref * np.sqrt(np.maximum(factor, 0.0)), "k-",
                  label=f"learned (no damage, day {days[healthy]}): alpha={m0[n]:.2e}, beta={m0[n + 1]:.2e}")
    ax[0, 0].set(xlabel="temperature [degC]", ylabel="f1 [Hz]", title="First frequency against temperature")
    ax[0, 0].legend(fontsize=7, markerscale=5)
    p = np.array([r.p_damage for r in records])
    ax[0, 1].semilogy(np.asarray(days) + 1, np.maximum(p, 1e-12), color=plotting.COLORS[0],
                      label="P(damage by the end of the day)")
    ax[0, 1].axhline(threshold, color="k", ls=":", label=f"threshold {threshold}")
    if damage_day is not None:
        ax[0, 1].axvline(damage_day, color=plotting.COLORS[3], ls="--", label=f"damage (storey {damage_storey})")
    if alarm_times:
        ax[0, 1].axvline(alarm_times[0], color=plotting.COLORS[2], label=f"alarm, day {alarm_times[0]:.0f}")
    ax[0, 1].set(xlabel="day", ylim=(1e-12, 2), title="P(damage) and the alarm")
    ax[0, 1].legend(fontsize=7)
    for k, name in enumerate(("alpha", "beta")):
        mean = np.array([r.models[0].mean[n + k] for r in records])
        sd = np.array([r.models[0].sd[n + k] for r in records])
        plotting.band(ax[1, 0], days, mean, mean - 2 * sd, mean + 2 * sd, color=plotting.COLORS[k],
                      label=f"{name} (no-damage posterior mean +- 2 sd)", marker="")
    ax[1, 0].set(xlabel="day", ylabel="[1/degC]", title="Learned temperature coefficients")
    ax[1, 0].legend(fontsize=7)
    for r in range(n):
        ax[1, 1].plot(day, frequencies[:, r] / frequencies[:, r].mean(), lw=0.3, label=f"f{r + 1}")
    ax[1, 1].set(xlabel="day", ylabel="f / mean(f)", title="Identified frequencies")
    ax[1, 1].legend(fontsize=7)
    return fig


def render_environment_report(monitor: EnvironmentMonitor, table: dict, days: list, records: list[MonitorDay],
                              summary: dict, *, title: str = "A year of monitoring", source: str = "") -> str:
    """The HTML page (one file, the figure embedded): the alarm and learned model, the figure and the
    day-by-day table. ``summary`` is :func:`~seqbayes.structural.environment.monitor_year`'s."""
    n = monitor.building.n_storeys
    env = summary["environment"]
    model = "no damage" if env["model"] == 0 else f"a loss in storey {env['model']}"
    alarm = ("no alarm" if summary["alarm_day"] is None else
             f"first alarm at the end of day {summary['alarm_day'] - 1:.0f}: storey {summary['storey']}, "
             f"loss {summary['damage_size']:.3f}")
    facts = [("data", source or "-"), ("days", len(days)), ("alarm rule", f"P(damage) > {monitor.threshold} on "
                                                          f"{monitor.consecutive} days in a row"),
             ("alarm", alarm), ("most probable model at the end", model),
             ("learned temperature law", f"alpha = {env['alpha']:.3e} /degC, beta = {env['beta']:.3e} /degC "
                                         f"(below 0 degC), sigma = {env['sigma']:.3e}"),
             ("particles per model", summary["n_particles"])]
    rows = []
    for day, record in zip(days, records):
        damaged = record.storey is not None and record.p_damage > 0.5   # storey and loss mean little below
        rows.append([day, f"{record.p_damage:.3g}", record.storey if damaged else "-",
                     f"{record.damage_size:.3f}" if damaged else "-",
                     ", ".join(f"{q:.3g}" for q in record.model_probabilities), "ALARM" if record.alarm else ""])
    figure = environment_figure(monitor, table, days, records, summary["alarm_days"])
    return page(title, [
             table_html(["", ""], [[k, v] for k, v in facts], left=(0, 1)),
             figure_html(figure, "Frequencies against temperature, P(damage) and the alarm, the learned law", "year"),
             "<h2>Day by day</h2>",
             table_html(["day", "P(damage)", "storey", "loss", "P(M0), " + ", ".join(f"P(M{j + 1})" for j in range(n)),
                         "alarm"], rows, left=(4,))])


def write_environment_report(path: str | os.PathLike, *args, **kwargs) -> Path:
    """Write :func:`render_environment_report` to ``path`` (UTF-8, atomically) and return it."""
    return write_output(Path(path), render_environment_report(*args, **kwargs))
