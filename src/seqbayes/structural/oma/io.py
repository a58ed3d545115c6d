"""Records in, modes tables out: the ``seqbayes oma`` command's reading, writing and drawing.

- :func:`read_record`: a CSV (a header row of channel names, comma separated, an optional time
  column ``time``/``t``/``time_s``) or a ``.npy`` array ``(T, p)``; only regular files of at most
  ``MAX_RECORD_BYTES`` are read (a FIFO, a device or ``/dev/zero`` is refused without waiting).
- :func:`modes_table`: the modes table of docs/oma.md (the schema of the shared mast poles,
  ``time_start, day, slot, frequency_hz, damping_pct, std_frequency_hz, std_damping_pct, mpc, mpd,
  model_order``, then ``phi_<channel>`` and ``std_phi_<channel>``).
- :func:`write_outputs`: the CSV, the JSON (the same fields and the settings) and the stabilisation
  diagram (matplotlib's Agg canvas, no global backend), each written to a temporary file and
  renamed; a target that is the record, or twice the same file, is refused before anything is written.
- :func:`run`: the command (prints the modes with their standard errors; exit status 1 when no
  mode was identified, after saying why).
"""

from __future__ import annotations

import io as _io
import json
import math
import os
import stat
import sys
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["read_record", "modes_table", "write_outputs", "run", "MAX_RECORD_BYTES", "COLUMNS"]

#: Largest record file read [bytes]: an hour of 20 channels at 200 Hz as CSV is about 0.2 GB.
MAX_RECORD_BYTES = 1 << 30
#: The modes table's fixed columns (the shared mast poles' schema).
COLUMNS = ("time_start", "day", "slot", "frequency_hz", "damping_pct", "std_frequency_hz", "std_damping_pct", "mpc",
           "mpd", "model_order")
_TIME_NAMES = ("time", "t", "time_s", "time [s]")


def _read_bytes(path: Path, limit: int) -> bytes:
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise ValueError(f"RECORD: {path}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"RECORD: {path}: is a folder, not a record file") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"RECORD: {path}: not a regular file (a FIFO, a device or a socket is not read)")
        if st.st_size > limit:
            raise ValueError(f"RECORD: {path}: {st.st_size:,} bytes, more than the {limit:,} read")
        parts, left = [], st.st_size
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 24))
            if not chunk:
                break
            parts.append(chunk)
            left -= len(chunk)
        return b"".join(parts)
    finally:
        os.close(fd)


def _short(text: str, limit: int = 40) -> str:
    text = text if len(text) <= limit else text[:limit] + "..."
    return text.encode("unicode_escape").decode("ascii")


def _parse_csv(path: Path, data: bytes):
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"RECORD: {path}: not UTF-8 text; expected a CSV or a .npy file") from None
    lines = [line for line in text.splitlines() if line.strip()]
    if not lines:
        raise ValueError(f"RECORD: {path}: empty file")
    first = [cell.strip() for cell in lines[0].split(",")]
    try:
        [float(c) for c in first]
        header, body = [f"ch{j + 1}" for j in range(len(first))], lines
    except ValueError:
        header, body = first, lines[1:]
        if len(set(header)) != len(header) or any(not h for h in header):
            raise ValueError(f"RECORD: {path}: the header row names each column once (got {_short(lines[0])!r})")
    width = len(header)
    for number, line in enumerate(body, start=2 if header is first else 1):
        if line.count(",") != width - 1:
            raise ValueError(f"RECORD: {path}: line {number} has {line.count(',') + 1} fields, expected {width} "
                             f"(comma separated; got {_short(line)!r})")
    try:
        table = np.loadtxt(_io.StringIO("\n".join(body)), delimiter=",", comments=None, ndmin=2, dtype=float)
    except ValueError:
        for number, line in enumerate(body, start=2 if header is first else 1):
            try:
                [float(c) for c in line.split(",")]
            except ValueError:
                raise ValueError(f"RECORD: {path}: line {number} is not all numbers ({_short(line)!r})") from None
        raise ValueError(f"RECORD: {path}: not a table of numbers") from None
    time_col = [j for j, h in enumerate(header) if h.lower() in _TIME_NAMES]
    dt_time = None
    if time_col:
        t = table[:, time_col[0]]
        steps = np.diff(t)
        if steps.size == 0 or not np.all(np.isfinite(steps)) or np.any(steps <= 0) \
                or np.ptp(steps) > 1e-3 * np.mean(steps):
            raise ValueError(f"RECORD: {path}: the time column {header[time_col[0]]!r} must increase by a uniform step")
        dt_time = float(np.mean(steps))
        keep = [j for j in range(width) if j != time_col[0]]
        table, header = table[:, keep], [header[j] for j in keep]
    return table, tuple(header), dt_time


def read_record(path, max_bytes: int = MAX_RECORD_BYTES):
    """Read a record file (module docstring).

    Returns
    -------
    y : (T, p) array
    channels : tuple of str
    dt_from_time : float or None
        The step of the file's time column [s], if it has one.
    """
    path = Path(path)
    data = _read_bytes(path, max_bytes)
    if path.suffix.lower() == ".npy" or data[:6] == b"\x93NUMPY":
        try:
            y = np.load(_io.BytesIO(data), allow_pickle=False)
        except (ValueError, OSError, EOFError) as err:
            raise ValueError(f"RECORD: {path}: not a readable .npy array ({_short(str(err), 80)})") from None
        if y.dtype.kind not in "biuf":
            raise ValueError(f"RECORD: {path}: the array holds {y.dtype}, not numbers")
        y = np.asarray(y, dtype=float)
        p = 1 if y.ndim == 1 else (y.shape[1] if y.ndim == 2 else 0)
        return y, tuple(f"ch{j + 1}" for j in range(p)), None
    return _parse_csv(path, data)


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


def _atomic_write(path: Path, write) -> None:
    folder = path.parent if str(path.parent) else Path(".")
    fd, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as fh:
            write(fh)
        mask = os.umask(0)  # mkstemp makes the file private; give it the mode a plain open would have
        os.umask(mask)
        os.chmod(temporary, 0o666 & ~mask)
        os.replace(temporary, path)
    except BaseException:
        if os.path.exists(temporary):
            os.unlink(temporary)
        raise


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    return a.resolve() == b.resolve()


def check_targets(record: Path, targets: dict) -> None:
    """Refuse an output that is the record or another output (``targets``: option -> path or None)."""
    given = [(option, Path(path)) for option, path in targets.items() if path]
    for option, path in given:
        if _same(path, record):
            raise ValueError(f"{option} {path}: that is the record being read; choose another file")
        if path.is_dir():
            raise ValueError(f"{option} {path}: is a folder; give a file name")
    for i, (option, path) in enumerate(given):
        for other, second in given[i + 1:]:
            if _same(path, second):
                raise ValueError(f"{option} and {other}: both name {path}; give each output its own file")


def _draw(path: Path, modes) -> None:
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
    _atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=110))


def write_outputs(modes, channels, out=None, json_path=None, diagram=None, day=float("nan"), source=""):
    """Write the modes table, its JSON and the diagram where asked (each atomically)."""
    header, rows = modes_table(modes, channels, day)
    if out:
        text = ",".join(header) + "\n" + "".join(",".join(r) + "\n" for r in rows)
        _atomic_write(Path(out), lambda fh: fh.write(text.encode()))
    if json_path:
        settings = modes.settings.as_dict() if modes.settings is not None else {}
        document = {"record": str(source), "status": modes.status, "messages": list(modes.messages),
                    "settings": settings, "channels": list(channels), "columns": header,
                    "modes": [dict(zip(header, r)) for r in rows],
                    "candidates_hz": list(modes.candidates)}
        document["modes"] = [{k: (v if k == "time_start" else (float(v) if v else None)) for k, v in m.items()}
                             for m in document["modes"]]
        text = json.dumps(_json_value(document), indent=1, allow_nan=False) + "\n"
        _atomic_write(Path(json_path), lambda fh: fh.write(text.encode()))
    if diagram:
        _draw(Path(diagram), modes)


def _band(text):
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--band: expected LO,HI in Hz (two numbers), got {text!r}") from None
    return lo, hi


def run(record, dt=None, fs=None, band=None, out=None, json_path=None, diagram=None, day=None, stream=None) -> int:
    """``seqbayes oma``: identify one record, print its modes, write the outputs asked for (module docstring)."""
    from .core import check_sampling_step
    from .identify import ssi_cov

    stream = stream or sys.stdout
    record = Path(record)
    check_targets(record, {"--out": out, "--json": json_path, "--diagram": diagram})
    if (dt is None) == (fs is None):
        raise ValueError("--dt/--fs: give exactly one (the sampling step in s, or the rate in Hz)")
    if fs is not None:
        if not (isinstance(fs, (int, float)) and math.isfinite(fs) and fs > 0):
            raise ValueError(f"--fs: expected a positive sampling rate in Hz, got {fs}")
        dt = 1.0 / fs
    dt = check_sampling_step(dt)
    if day is not None and not (math.isfinite(day) and abs(day) < 1e9):
        raise ValueError(f"--day: expected a finite number of days, got {day}")
    y, channels, dt_time = read_record(record)
    if dt_time is not None and abs(dt_time - dt) > 1e-3 * dt:
        raise ValueError(f"--dt/--fs: the record's time column steps by {dt_time:g} s ({1 / dt_time:.6g} Hz), not the "
                         f"{dt:g} s ({1 / dt:.6g} Hz) given: a wrong sampling rate")
    modes = ssi_cov(y, dt, band=_band(band))
    lo, hi = modes.settings.band
    print(f"{record.name}: {y.shape[0]} samples x {y.shape[1]} channels at {1 / dt:.6g} Hz; band {lo:.4g}-{hi:.4g} Hz"
          f" (decimated by {modes.settings.decimation}), block rows {modes.settings.block_rows}, orders 2-"
          f"{modes.settings.max_order}", file=stream)
    if modes.frequencies.size:
        print(f"{'mode':>4} {'f [Hz]':>10} {'sd f':>9} {'damping %':>9} {'sd %':>7} {'MPC':>6} {'orders':>6}",
              file=stream)
        for j in range(modes.frequencies.size):
            print(f"{j + 1:>4} {modes.frequencies[j]:>10.5g} {modes.std_frequencies[j]:>9.2g} "
                  f"{100 * modes.damping_ratios[j]:>9.3g} {100 * modes.std_damping_ratios[j]:>7.2g} "
                  f"{modes.mpc[j]:>6.3f} {modes.n_stable[j]:>6}", file=stream)
    print(f"status: {modes.status}", file=stream)
    write_outputs(modes, channels, out, json_path, diagram, float("nan") if day is None else float(day), record)
    for option, path in (("modes", out), ("json", json_path), ("diagram", diagram)):
        if path:
            print(f"{option}: {path}", file=stream)
    return 1 if modes.status == "empty" else 0
