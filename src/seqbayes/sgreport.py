"""Status tables, modal results and the HTML report of SG-EnMCMC runs (:class:`~seqbayes.sgstore.SGRunStore`).

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

from . import plotting

__all__ = ["sg_status_rows", "format_sg_status", "modal_rows", "format_modal", "read_mode_shapes",
           "nominal_mode_shapes", "render_sg_report", "write_sg_report"]

ESS_NOTE_SG = ("ESS: effective sample size (sum w)^2 / sum w^2 of the particles' weights after the block's "
               "last sample (N for equal weights). moves: resample-move events in the block (tempered "
               "Metropolis-Hastings moves of the particles), with their mean acceptance rate.")


def sg_status_rows(store: SGRunStore, level: float = 0.95) -> list[dict]:
    """One dict per block: ``step, dataset, rows, first_sample, time_start, time_end, ess, moves, acceptance,
    log_evidence_increment, log_evidence, wall_time, parameters`` (``parameters`` maps each ratio to
    ``{mean, sd, lower, upper}``, the central ``level`` interval of the posterior at the block's end)."""
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
    return rows


def _fmt(x) -> str:
    return f"{x:.4g}" if np.isfinite(x) else "nan"


def format_sg_status(store: SGRunStore, level: float = 0.95) -> str:
    """The ``status`` command's plain-text tables for an SG-EnMCMC run."""
    cfg = store.config
    lines = [f"run {store.path}  model {cfg.name!r}  SG-EnMCMC  {cfg.n_storeys}-storey shear building  "
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
        lines.append(f"{r['step']:>4}  {r['dataset'][:20]:<20} {span:>13} {r['time_end']:9.2f} {r['ess']:8.1f} "
                     f"{r['ess'] / cfg.n_members:6.3f} {r['moves']:5d} {accept:>6} "
                     f"{r['log_evidence_increment']:12.4f} {r['log_evidence']:12.4f}")
    lines += textwrap.wrap(f"({ESS_NOTE_SG})", 100)
    pct = f"{level:.0%}"
    lines += ["", f"posterior of the storey stiffness ratios at the end of each block (k_i = theta_i k_i^u):",
              f"{'step':>4}  {'parameter':<10} {'mean':>11} {'sd':>11} {pct + ' lower':>11} {pct + ' upper':>11}"]
    for r in rows:
        for name, p in r["parameters"].items():
            lines.append(f"{r['step']:>4}  {name:<10} {_fmt(p['mean']):>11} {_fmt(p['sd']):>11} "
                         f"{_fmt(p['lower']):>11} {_fmt(p['upper']):>11}")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- modal results
def nominal_mode_shapes(store: SGRunStore, theta: ArrayLike | None = None) -> np.ndarray:
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
    if not path.is_file():
        raise ValueError(f"--modes: {path}: no such file")
    try:
        text = path.read_text().strip().splitlines()
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


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    import os

    from numpy.typing import ArrayLike

    from .sgstore import SGRunStore
    from .structures.modal import ModalSummary
