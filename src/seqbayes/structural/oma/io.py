"""Records in, modes tables out: the ``seqbayes oma`` command's record, modes table, JSON and diagram as values.

The files are read and written by the command (:mod:`seqbayes.store.modal_files` reads the record through
the store's strict reader, :mod:`seqbayes.store.targets` checks and writes the outputs atomically); this
module turns their content into values and back, without touching a file:

- :func:`record_from_npy` and :func:`record_from_table`: a ``.npy`` array ``(T, p)``, or the columns of a
  CSV with a header row of channel names and an optional time column ``time``/``t``/``time_s`` (its
  step must be uniform), as ``(y (T, p), channels, dt_from_time)``;
- :func:`modes_table`: the modes table of docs/oma.md (the schema of the shared mast poles,
  ``time_start, day, slot, frequency_hz, damping_pct, std_frequency_hz, std_damping_pct, mpc, mpd,
  model_order``, then ``phi_<channel>`` and ``std_phi_<channel>``), :func:`modes_csv` and
  :func:`modes_json` its text;
- :func:`diagram_png`: the stabilisation diagram (matplotlib's Agg canvas, no global backend);
- :func:`summary_lines`: what the command prints (the settings, the modes with their standard errors).
"""

from __future__ import annotations

import io as _io
import json
import math

import numpy as np

__all__ = ["record_from_npy", "record_from_table", "time_column", "modes_table", "modes_csv", "modes_json",
           "diagram_png", "parse_band", "summary_lines", "MAX_RECORD_BYTES", "COLUMNS", "TIME_NAMES"]

#: Largest record file read [bytes]: an hour of 20 channels at 200 Hz as CSV is about 0.2 GB.
MAX_RECORD_BYTES = 1 << 30
#: The modes table's fixed columns (the shared mast poles' schema).
COLUMNS = ("time_start", "day", "slot", "frequency_hz", "damping_pct", "std_frequency_hz", "std_damping_pct", "mpc",
           "mpd", "model_order")
#: Header names (any case) of a record's time column [s].
TIME_NAMES = ("time", "t", "time_s", "time [s]")


def _short(text: str, limit: int = 40) -> str:
    text = text if len(text) <= limit else text[:limit] + "..."
    return text.encode("unicode_escape").decode("ascii")


def record_from_npy(data: bytes, source) -> tuple[np.ndarray, tuple, None]:
    """A ``.npy`` file's bytes as ``(y, channels ch1..chp, None)``; pickled objects are never loaded."""
    try:
        y = np.load(_io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        raise ValueError(f"RECORD: {source}: not a readable .npy array ({_short(str(err), 80)})") from None
    if y.dtype.kind not in "biuf":
        raise ValueError(f"RECORD: {source}: the array holds {y.dtype}, not numbers")
    y = np.asarray(y, dtype=float)
    p = 1 if y.ndim == 1 else (y.shape[1] if y.ndim == 2 else 0)
    return y, tuple(f"ch{j + 1}" for j in range(p)), None


def time_column(header) -> int | None:
    """The index of the header's time column (:data:`TIME_NAMES`, any case), or None."""
    found = [j for j, h in enumerate(header) if h.strip().lower() in TIME_NAMES]
    return found[0] if found else None


def record_from_table(header, table: np.ndarray, source) -> tuple[np.ndarray, tuple, float | None]:
    """A record CSV's columns ``table (T, len(header))`` as ``(y (T, p), channels, dt_from_time)``: the time
    column (:func:`time_column`) must step uniformly (to 0.1 %), and is taken out."""
    header = [str(h) for h in header]
    j = time_column(header)
    if j is None:
        return table, tuple(header), None
    steps = np.diff(table[:, j])
    if steps.size == 0 or np.any(steps <= 0) or np.ptp(steps) > 1e-3 * np.mean(steps):
        raise ValueError(f"RECORD: {source}: the time column {_short(header[j])!r} must increase by a uniform step")
    keep = [k for k in range(len(header)) if k != j]
    return table[:, keep], tuple(header[k] for k in keep), float(np.mean(steps))


def _number(value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return f"{float(value):.6g}"


def modes_table(modes, channels, day: float = float("nan"), time_start: str = "") -> tuple[list, list]:
    """Header and rows (one per mode) of the modes table; numbers as text, NaN as empty."""
    channels = [str(c) for c in channels]
    header = list(COLUMNS) + [f"phi_{c}" for c in channels] + [f"std_phi_{c}" for c in channels]
    rows = []
    for j in range(modes.frequencies.size):
        row = [time_start, _number(day), str(j), _number(modes.frequencies[j]), _number(100 * modes.damping_ratios[j]),
               _number(modes.std_frequencies[j]), _number(100 * modes.std_damping_ratios[j]), _number(modes.mpc[j]),
               _number(modes.mpd[j]), _number(int(modes.orders[j]))]
        row += [_number(v) for v in modes.shapes[:, j]] + [_number(v) for v in modes.std_shapes[:, j]]
        rows.append(row)
    return header, rows


def _json_value(value):
    if isinstance(value, dict):
        return {k: _json_value(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_json_value(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, (np.integer,)):
        return int(value)
    return value


def diagram_png(modes) -> bytes:
    """The stabilisation diagram of ``modes`` (stable poles, other poles, the modes) as PNG bytes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, 5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for poles in modes.diagram:
        ax.plot(poles.frequencies[~poles.stable], np.full((~poles.stable).sum(), poles.order), ".", color="0.75", ms=3)
        ax.plot(poles.frequencies[poles.stable], np.full(poles.stable.sum(), poles.order), "o", color="C0", ms=3,
                mfc="none")
    for j, f in enumerate(modes.frequencies):
        ax.axvline(f, color="C3", lw=1)
        ax.annotate(f"{f:.4g}", (f, 1.0), xycoords=("data", "axes fraction"), rotation=90, va="top", ha="right",
                    fontsize=7, color="C3")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("model order")
    lo, hi = modes.settings.band
    ax.set_xlim(lo, hi)
    ax.set_title(f"stabilisation diagram: {modes.frequencies.size} modes ({modes.status}); o stable, . other poles",
                 fontsize=9)
    buffer = _io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    return buffer.getvalue()


def modes_csv(modes, channels, day: float = float("nan")) -> str:
    """The modes table (:func:`modes_table`) as CSV text."""
    header, rows = modes_table(modes, channels, day)
    return ",".join(header) + "\n" + "".join(",".join(r) + "\n" for r in rows)


def modes_json(modes, channels, day: float = float("nan"), source: str = "") -> str:
    """The modes table's rows, the settings chosen, the status, the messages and the candidates as JSON text."""
    header, rows = modes_table(modes, channels, day)
    settings = modes.settings.as_dict() if modes.settings is not None else {}
    document = {"record": str(source), "status": modes.status, "messages": list(modes.messages),
                "settings": settings, "channels": list(channels), "columns": header,
                "modes": [{k: (v if k == "time_start" else (float(v) if v else None)) for k, v in zip(header, r)}
                          for r in rows],
                "candidates_hz": list(modes.candidates)}
    return json.dumps(_json_value(document), indent=1, allow_nan=False) + "\n"


def parse_band(text):
    """``--band LO,HI`` as two floats (``None`` for none given)."""
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--band: expected LO,HI in Hz (two numbers), got {text!r}") from None
    return lo, hi


def summary_lines(name: str, y_shape, dt: float, modes) -> list[str]:
    """What ``seqbayes oma`` prints: the settings chosen, one line per mode (frequency and its standard error,
    damping [%] and its standard error, MPC, orders stable at), the status."""
    lo, hi = modes.settings.band
    lines = [f"{name}: {y_shape[0]} samples x {y_shape[1]} channels at {1 / dt:.6g} Hz; band {lo:.4g}-{hi:.4g} Hz"
             f" (decimated by {modes.settings.decimation}), block rows {modes.settings.block_rows}, orders 2-"
             f"{modes.settings.max_order}"]
    if modes.frequencies.size:
        lines.append(f"{'mode':>4} {'f [Hz]':>10} {'sd f':>9} {'damping %':>9} {'sd %':>7} {'MPC':>6} {'orders':>6}")
        for j in range(modes.frequencies.size):
            lines.append(f"{j + 1:>4} {modes.frequencies[j]:>10.5g} {modes.std_frequencies[j]:>9.2g} "
                         f"{100 * modes.damping_ratios[j]:>9.3g} {100 * modes.std_damping_ratios[j]:>7.2g} "
                         f"{modes.mpc[j]:>6.3f} {modes.n_stable[j]:>6}")
    lines.append(f"status: {modes.status}")
    return lines
