"""Status tables, modal results and the HTML report of SG-EnMCMC runs (:class:`~seqbayes.store.sg.SGRunStore`).

:func:`sg_status_rows` / :func:`format_sg_status` are the ``seqbayes status`` output of an
SG-EnMCMC run (one row per assimilated block: the posterior of the storey stiffness ratios at
the block's end, its ESS, resample-move events and log-evidence); :func:`modal_rows` the
modal results of a block's posterior (natural frequencies, damping ratios, MAC of the mode
shapes against identified ones); :func:`render_sg_report` / :func:`write_sg_report` the
self-contained HTML page of ``seqbayes report``.
"""

from __future__ import annotations

import html
import textwrap
from pathlib import Path

import numpy as np

from .. import plotting
from .datasets import printable, read_regular
from .pages import figure_html, fmt, page, table_html, text, write_page

__all__ = ["sg_status_rows", "format_sg_status", "modal_rows", "format_modal", "read_mode_shapes",
           "nominal_mode_shapes", "plot_sg_ratios", "plot_modal", "render_sg_report", "write_sg_report"]

ESS_NOTE_SG = ("ESS: effective sample size (sum w)^2 / sum w^2 of the particles' weights after the block's "
               "last sample (N for equal weights). moves: resample-move events in the block (tempered "
               "Metropolis-Hastings moves of the particles), with their mean acceptance rate.")


def sg_status_rows(store: BaseStore, level: float = 0.95) -> list[dict]:
    """One dict per block: ``step, dataset, rows, first_sample, time_start, time_end, ess, moves, acceptance,
    log_evidence_increment, log_evidence, wall_time, parameters`` (``parameters`` maps each ratio to
    ``{mean, sd, lower, upper}``, the central ``level`` interval of the posterior at the block's end), and
    with ``[monitor]`` ``monitor``: ``{class_probabilities, change_probability, detected, storey,
    wall_time}`` of the stiffness-drop monitor at the block's end."""
    rows = []
    dt = store.config.dt
    for i, info in enumerate(store.infos):
        rows.append({"step": int(info["step"]), "dataset": store.sources[i], "rows": int(info["rows"]),
                     "first_sample": int(info["first_sample"]), "time_start": float(info["time_start"]),
                     "time_end": float((info["first_sample"] + info["rows"] - 1) * dt),
                     "ess": float(info["ess_end"]), "moves": int(info["moves"]),
                     "acceptance": None if info["acceptance"] is None else float(info["acceptance"]),
                     "log_evidence_increment": float(info["log_evidence_increment"]),
                     "log_evidence": float(info["log_evidence"]), "wall_time": float(info["wall_time"]),
                     "parameters": store.block_posterior(i, level)})
        if "monitor" in info:  # [monitor]: the stiffness-drop classes at the block's end
            rows[-1]["monitor"] = {k: v for k, v in info["monitor"].items() if k != "rng_state"}
    return rows


def format_sg_status(store: BaseStore, level: float = 0.95) -> str:
    """The ``status`` command's plain-text tables for an SG-EnMCMC run."""
    cfg = store.config
    lines = [f"run {printable(store.path)}  model '{printable(cfg.name)}'  SG-EnMCMC  {cfg.n_storeys}-storey shear building  "
             f"N={cfg.n_members} seed={cfg.seed}  blocks: {store.n_steps}  samples: {store.n_samples} "
             f"(dt = {cfg.dt:g} s)"]
    if store.n_steps == 0:
        lines.append("no block assimilated yet (use `seqbayes update RUN BLOCK.csv`)")
        return "\n".join(lines)
    rows = sg_status_rows(store, level)
    lines += ["", f"{'step':>4}  {'dataset':<20} {'samples':>13} {'t end [s]':>9} {'ESS':>8} {'ESS/N':>6} "
                  f"{'moves':>5} {'accept':>6} {'log Z_block':>12} {'log Z':>12}"]
    for r in rows:
        accept = "-" if r["acceptance"] is None else f"{r['acceptance']:.3f}"
        span = f"{r['first_sample']}-{r['first_sample'] + r['rows'] - 1}"
        lines.append(f"{r['step']:>4}  {printable(r['dataset'])[:20]:<20} {span:>13} {r['time_end']:9.2f} {r['ess']:8.1f} "
                     f"{r['ess'] / cfg.n_members:6.3f} {r['moves']:5d} {accept:>6} "
                     f"{r['log_evidence_increment']:12.4f} {r['log_evidence']:12.4f}")
    lines += textwrap.wrap(f"({ESS_NOTE_SG})", 100)
    pct = f"{level:.0%}"
    lines += ["", f"posterior of the storey stiffness ratios at the end of each block (k_i = theta_i k_i^u):",
              f"{'step':>4}  {'parameter':<10} {'mean':>11} {'sd':>11} {pct + ' lower':>11} {pct + ' upper':>11}"]
    for r in rows:
        for name, p in r["parameters"].items():
            lines.append(f"{r['step']:>4}  {name:<10} {fmt(p['mean']):>11} {fmt(p['sd']):>11} "
                         f"{fmt(p['lower']):>11} {fmt(p['upper']):>11}")
    if cfg.monitor is not None:
        lines += [""] + textwrap.wrap("stiffness-drop monitor: probability of each model class at the end of "
                                      "each block (none: no change; storey j: a drop in storey j), P(changed by "
                                      f"now) and detection (P > {cfg.build_monitor().threshold:g}):", 100)
        lines += [f"{'step':>4}  {'none':>9} " + " ".join(f"{'storey ' + str(j + 1):>9}" for j in range(cfg.n_storeys))
                  + f" {'P(changed)':>10}  detected"]
        for r in rows:
            m = r["monitor"]
            flag = f"yes, storey {m['storey']}" if m["detected"] else "no"
            lines.append(f"{r['step']:>4}  " + " ".join(f"{p:9.3g}" for p in m["class_probabilities"])
                         + f" {m['change_probability']:10.4g}  {flag}")
        first = next((r for r in rows if r["monitor"]["detected"]), None)
        lines.append("no change detected" if first is None else
                     f"change first detected at the end of step {first['step']} (t = {first['time_end']:.2f} s), "
                     f"attributed to storey {first['monitor']['storey']}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- modal results
def nominal_mode_shapes(store: BaseStore, theta: ArrayLike | None = None) -> np.ndarray:
    """Mode shapes ``(n, n)`` (columns, ascending frequency) of the configured building at ``theta``
    (default: all ratios 1, the undamaged design): a reference for the MAC when no identified shapes are given."""
    building = store.config.build_building()
    theta = np.ones(building.n_storeys) if theta is None else np.asarray(theta, float)
    return building.modes(theta)[1][0]


def read_mode_shapes(path: str | os.PathLike, n_storeys: int) -> np.ndarray:
    """Identified mode shapes from a CSV file: one row per floor (bottom to top), one column per mode;
    an optional header row of mode names. Returns ``(n_storeys, k)``.

    Raises
    ------
    ValueError
        Naming the file: unreadable, not numeric, NaN, or not ``n_storeys`` rows.
    """
    path = Path(path)
    raw = read_regular(path, "mode-shape CSV", error=lambda message: ValueError(f"--modes: {message}"))
    try:
        text = raw.decode("utf-8-sig").strip().splitlines()
        if text and any(c.isalpha() and c not in "eE" for c in text[0]):
            text = text[1:]
        shapes = np.array([[float(v) for v in line.split(",")] for line in text if line.strip()], float)
    except ValueError as err:
        raise ValueError(f"--modes: {path}: not a table of numbers ({err})") from None
    if shapes.ndim != 2 or shapes.shape[0] != n_storeys or shapes.shape[1] < 1:
        raise ValueError(f"--modes: {path}: expected {n_storeys} rows (one per floor, bottom to top) and one column "
                         f"per mode, got shape {shapes.shape}")
    if not np.isfinite(shapes).all() or np.any(np.linalg.norm(shapes, axis=0) == 0):
        raise ValueError(f"--modes: {path}: holds NaN/inf or a zero mode shape")
    return shapes


def modal_rows(summary: ModalSummary) -> list[dict]:
    """One dict per mode: ``mode, frequency_mean, frequency_sd, frequency_lower, frequency_upper,
    damping_mean, damping_sd, damping_lower, damping_upper, shape_mac`` and, with identified shapes,
    ``mac_identified`` (the MAC of the posterior mean shape with the identified shape of the same
    number, or ``None``) and ``best_identified`` (the identified shape it matches best, 1-based, and that MAC)."""
    rows = []
    for r in range(summary.frequency_mean.size):
        row = {"mode": r + 1, "frequency_mean": float(summary.frequency_mean[r]),
               "frequency_sd": float(summary.frequency_sd[r]),
               "frequency_lower": float(summary.frequency_interval[0, r]),
               "frequency_upper": float(summary.frequency_interval[1, r]),
               "damping_mean": float(summary.damping_mean[r]), "damping_sd": float(summary.damping_sd[r]),
               "damping_lower": float(summary.damping_interval[0, r]),
               "damping_upper": float(summary.damping_interval[1, r]), "shape_mac": float(summary.shape_mac[r])}
        if summary.mac_identified is not None:
            macs = summary.mac_identified[r]
            row["mac_identified"] = float(macs[r]) if r < macs.size else None
            row["best_identified"] = [int(np.argmax(macs)) + 1, float(np.max(macs))]
        rows.append(row)
    return rows


def format_modal(summary: ModalSummary, level_note: str = "95 %") -> str:
    """Plain-text table of :func:`modal_rows`."""
    rows = modal_rows(summary)
    ident = summary.mac_identified is not None
    lines = [f"{'mode':>4} {'f mean [Hz]':>11} {'sd':>9} {level_note + ' interval [Hz]':>24} {'zeta mean':>9} "
             f"{level_note + ' interval':>19}" + (f" {'MAC ident.':>10}" if ident else "")]
    for r in rows:
        line = (f"{r['mode']:>4} {r['frequency_mean']:11.4f} {r['frequency_sd']:9.2e} "
                f"{'[' + format(r['frequency_lower'], '.4f') + ', ' + format(r['frequency_upper'], '.4f') + ']':>24} "
                f"{r['damping_mean']:9.4f} "
                f"{'[' + format(r['damping_lower'], '.4f') + ', ' + format(r['damping_upper'], '.4f') + ']':>19}")
        if ident:
            line += f" {'-' if r['mac_identified'] is None else format(r['mac_identified'], '.4f'):>10}"
        lines.append(line)
    return "\n".join(lines)



# ----------------------------------------------------------------------------- figures
def plot_sg_ratios(store: BaseStore, truth: ArrayLike | None = None) -> Figure:
    """Posterior mean and 95 % band of every stiffness ratio against the record's time (the
    identifier's per-sample histories), with the block boundaries dotted."""
    result = store.result()
    t = np.arange(result.theta_mean.shape[0]) * store.config.dt
    fig, axes = plotting.new_figure(len(store.names), 1, row_height=1.9)
    bounds = np.cumsum([table.shape[0] for table in store.tables])[:-1] * store.config.dt
    for j, name in enumerate(store.names):
        ax = axes[j, 0]
        plotting.band(ax, t, result.theta_mean[:, j], result.theta_quantiles[:, 0, j], result.theta_quantiles[:, 2, j],
                      marker="", label="posterior mean, 95 % band")
        for b in bounds:
            ax.axvline(b, color="0.6", linestyle=":", linewidth=0.8)
        if truth is not None:
            ax.axhline(np.asarray(truth, float)[j], color="k", linestyle="--", linewidth=0.8, label="reference")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="small")
    axes[-1, 0].set_xlabel("time in the record [s] (dotted: block boundaries)")
    return fig


def plot_modal(summaries: Sequence[ModalSummary], reference_shapes: np.ndarray, reference_label: str) -> Figure:
    """Left: each mode's natural frequency at the end of every block (posterior mean and 95 % interval).
    Right: the last block's posterior mean mode shapes (solid) and the reference shapes (dashed)."""
    fig, axes = plotting.new_figure(1, 2, width=8.0, row_height=3.4, sharex=False)
    ax = axes[0, 0]
    blocks = np.arange(1, len(summaries) + 1)
    n = summaries[-1].frequency_mean.size
    for r in range(n):
        mean = np.array([s.frequency_mean[r] for s in summaries])
        lower = np.array([s.frequency_interval[0, r] for s in summaries])
        upper = np.array([s.frequency_interval[1, r] for s in summaries])
        ax.errorbar(blocks, mean, yerr=[mean - lower, upper - mean], marker="o", markersize=3.5, capsize=3,
                    color=plotting.COLORS[r % len(plotting.COLORS)], label=f"mode {r + 1}")
    ax.set_xlabel("block (step)")
    ax.set_ylabel("natural frequency [Hz]")
    plotting.integer_steps(axes[:, :1])
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    ax = axes[0, 1]
    floors = np.arange(0, n + 1)
    last = summaries[-1]
    ref = reference_shapes / np.abs(reference_shapes).max(axis=0, keepdims=True)
    for r in range(n):
        color = plotting.COLORS[r % len(plotting.COLORS)]
        shape = last.shapes[:, r] / np.abs(last.shapes[:, r]).max()
        ax.plot(np.concatenate([[0], shape]), floors, "-o", color=color, markersize=3.5, label=f"mode {r + 1}")
        if r < ref.shape[1]:
            sign = np.sign(shape @ ref[:, r]) or 1.0
            ax.plot(np.concatenate([[0], sign * ref[:, r]]), floors, "--", color=color, linewidth=1)
    ax.plot([], [], "k-", label="posterior mean")
    ax.plot([], [], "k--", linewidth=1, label=reference_label)
    ax.legend(fontsize="small", loc="best")
    ax.axvline(0, color="0.5", linewidth=0.6)
    ax.set_xlabel("mode shape (largest component 1)")
    ax.set_ylabel("floor")
    ax.set_yticks(floors)
    ax.grid(alpha=0.3)
    return fig


# ----------------------------------------------------------------------------- the report
def render_sg_report(store: BaseStore, *, level: float = 0.95, image_dir: Path | None = None,
                     identified_shapes: ArrayLike | None = None, identified_source: str | None = None,
                     truth: ArrayLike | None = None) -> str:
    """The HTML text of the report of an SG-EnMCMC run.

    Parameters
    ----------
    store : SGRunStore
    level : float
        Credible level of the per-block intervals of the ratios (the figure's band and the modal
        intervals are 95 %).
    image_dir : pathlib.Path, optional
        Write the figures as PNG files there instead of embedding them.
    identified_shapes : (n, k) array, optional
        Identified mode shapes (columns, floors bottom to top) for the MAC; default: the shapes of the
        configured building at ratios 1 (the nominal design).
    identified_source : str, optional
        Where they came from (shown).
    truth : (n,) array, optional
        Reference ratios drawn in the figure (a synthetic record's truth).
    """
    if store.n_steps == 0:
        raise ValueError(f"{store.path}: no block to report yet (run `seqbayes update` first)")
    cfg = store.config
    building = cfg.build_building()
    nominal_f = building.modes(np.ones(cfg.n_storeys))[0][0]
    if identified_shapes is None:
        reference = nominal_mode_shapes(store)
        reference_label = "nominal design (ratios 1)"
    else:
        reference = np.asarray(identified_shapes, float)
        reference = reference[:, None] if reference.ndim == 1 else reference
        reference_label = f"identified ({identified_source or 'given'})"
    summaries = [store.modal(i, reference) for i in range(store.n_steps)]
    parts = []
    sensors = ", ".join([f"acceleration at floor {f}" for f in cfg.accelerations]
                        + [f"drift of storey {f}" for f in cfg.drifts])
    parts.append(f"<p>Run <code>{text(store.path)}</code>: SG-EnMCMC (resample-move, "
                 f"N = {text(cfg.n_members)}, seed {text(cfg.seed)}) of a {cfg.n_storeys}-storey shear building; "
                 f"{store.n_steps} block(s), {store.n_samples} samples at dt = {cfg.dt:g} s "
                 f"({store.n_samples * cfg.dt:.2f} s of record). Sensors: {html.escape(sensors)}. Model fingerprint "
                 f"<code>{text(cfg.fingerprint()[:12])}</code>; cumulative log-evidence {store.log_evidence:.4f}.</p>")
    parts.append("<h2>Model</h2>" + table_html(
        ["storey", "mass [kg]", "undamaged stiffness k^u [N/m]", "prior of the ratio theta"],
        [[j + 1, f"{cfg.masses[j]:.6g}", f"{cfg.stiffnesses[j]:.6g}", f"U({cfg.lower[j]:g}, {cfg.upper[j]:g})"]
         for j in range(cfg.n_storeys)], left=()))
    parts.append(f"<p>Storey stiffness k_i = theta_i k_i^u; Rayleigh damping {cfg.damping_ratios[0]:g} / "
                 f"{cfg.damping_ratios[1]:g} in modes {cfg.damping_modes[0]} / {cfg.damping_modes[1]} of the "
                 f"undamaged building (coefficients fixed, so the damping ratios change with the stiffness); "
                 f"measurement noise sd {', '.join(f'{v:g}' for v in cfg.measurement_std)}"
                 + (f", times a scale factor estimated with the ratios ({text(cfg.settings['noise_parameters'])}; "
                    f"log_noise_scale is its logarithm, log-uniform prior over "
                    f"{text(tuple(cfg.settings.get('noise_scale_bounds', (0.25, 4.0))))})"
                    if cfg.settings.get("noise_parameters") else "")
                 + (f"; transition chosen at init by surrogate = \"auto\": {html.escape(cfg.surrogate_choice)}"
                    if cfg.surrogate_choice else "") + ".</p>")

    parts.append("<h2>Stiffness ratios</h2>")
    parts.append(figure_html(plot_sg_ratios(store, truth), "Posterior mean and 95 % band of the storey stiffness "
                              "ratios after every sample of the record", "fig-ratios", image_dir))
    rows = sg_status_rows(store, level)
    pct = f"{level:.0%}"
    parts.append(table_html(["step", "dataset", "t end [s]", "parameter", "mean", "sd", f"{pct} lower", f"{pct} upper"],
                             [[r["step"], r["dataset"], f"{r['time_end']:.2f}", name, fmt(p["mean"]), fmt(p["sd"]),
                               fmt(p["lower"]), fmt(p["upper"])]
                              for r in rows for name, p in r["parameters"].items()], left=(1, 3)))

    parts.append("<h2>Modal results</h2>")
    last = summaries[-1]
    ident = last.mac_identified is not None
    modal = modal_rows(last)
    parts.append(f"<p>From the posterior at the end of block {store.n_steps}: for each particle the undamped modes "
                 f"of K(theta) phi = w^2 M phi and the Rayleigh damping ratio a0 / (2 w) + a1 w / 2; weighted "
                 f"posterior mean, sd and 95 % interval; nominal f: the frequency of the design (all ratios 1). MAC: modal assurance criterion of the posterior mean shape "
                 f"with the {html.escape(reference_label)} shape of the same mode (1: the same shape); spread: the "
                 f"posterior mean MAC of each particle's shape with the mean shape.</p>")
    header = ["mode", "f mean [Hz]", "f sd", "f 95 % interval", "nominal f [Hz]", "damping ratio mean", "sd",
              "95 % interval", f"MAC with {reference_label}", "spread"]
    parts.append(table_html(header, [[
        r["mode"], f"{r['frequency_mean']:.4f}", f"{r['frequency_sd']:.2e}",
        f"[{r['frequency_lower']:.4f}, {r['frequency_upper']:.4f}]", f"{nominal_f[r['mode'] - 1]:.4f}",
        f"{r['damping_mean']:.4f}", f"{r['damping_sd']:.1e}", f"[{r['damping_lower']:.4f}, {r['damping_upper']:.4f}]",
        "-" if not ident or r["mac_identified"] is None else f"{r['mac_identified']:.4f}", f"{r['shape_mac']:.6f}"]
        for r in modal], left=()))
    parts.append(figure_html(plot_modal(summaries, reference, reference_label),
                              "Natural frequencies at the end of every block (posterior mean and 95 % interval) and "
                              "the last block's mode shapes against the reference", "fig-modal", image_dir))

    parts.append("<h2>Sampler diagnostics and evidence</h2>")
    parts.append(table_html(["step", "dataset", "samples", "ESS", "moves", "acceptance", "log Z (block)", "log Z"],
                             [[r["step"], r["dataset"], f"{r['first_sample']}-{r['first_sample'] + r['rows'] - 1}",
                               f"{r['ess']:.1f}", r["moves"], "-" if r["acceptance"] is None else f"{r['acceptance']:.3f}",
                               f"{r['log_evidence_increment']:.4f}", f"{r['log_evidence']:.4f}"] for r in rows],
                             left=(1,)))
    parts.append(f"<p>{html.escape(ESS_NOTE_SG)} N = {text(cfg.n_members)}.</p>")
    return page(f"seqbayes report: {cfg.name}", parts)


def write_sg_report(store: BaseStore, output: str | os.PathLike, *, embed: bool = True, **kwargs: Any) -> Path:
    """Write :func:`render_sg_report` to ``output`` (an ``.html`` file; ``embed=False``: figures as PNG files
    in ``<output stem>_figures/``); returns its path."""
    return write_page(output, lambda **k: render_sg_report(store, **k), embed, **kwargs)


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    import os
    from collections.abc import Sequence
    from typing import Any

    from matplotlib.figure import Figure
    from numpy.typing import ArrayLike

    from .base import BaseStore
    from ..structural.structures.modal import ModalSummary
