"""The modes table: poles or identified modes of one or many records, as CSV (docs/modal.md).

One row per pole (the output of an automated OMA, :func:`seqbayes.structural.oma.ssi_cov`, or the
mast's ``poles_60min.csv``) or per tracked mode (:mod:`seqbayes.structural.tracking`). Columns, in
this order where present::

    time_start, day, slot, mode, frequency_hz, damping_pct, std_frequency_hz, std_damping_pct, mpc, mpd,
    model_order, phi_<channel>..., std_phi_<channel>..., <covariates>...

``day`` is the record's start in float days, ``time_start`` an ISO time or empty, ``slot`` the row's
index within its record (not a mode index), ``mode`` the tracked mode (1-based; tracked datasets only),
``std_*`` standard errors in the column's units, ``phi_<channel>`` a real mode shape (largest
component +1). Empty cells are NaN. Any other numeric column is a covariate (a temperature). Rows are
grouped into records by ``day``.

Written by hand rather than with pandas (not a dependency): the table is a few numeric columns and one
text column, read with :mod:`csv` in 5 ms for the mast's 2877 rows.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

__all__ = ["PoleTable", "read_modes_table", "write_modes_table", "read_covariates", "MODES_COLUMNS"]

#: The numeric columns of the modes table besides the shapes, in their order (``time_start`` comes first).
MODES_COLUMNS = ("day", "slot", "mode", "frequency_hz", "damping_pct", "std_frequency_hz", "std_damping_pct",
                 "mpc", "mpd", "model_order")
_FIELDS = {"frequency_hz": "frequency", "std_frequency_hz": "std_frequency", "damping_pct": "damping_pct",
           "std_damping_pct": "std_damping_pct", "mpc": "mpc", "mpd": "mpd", "model_order": "model_order"}


@dataclass(frozen=True)
class PoleTable:
    """Poles (or modes) of one or many records; every array has one entry per row (``n`` rows).

    Attributes
    ----------
    day : (n,) array
        Start of the row's record [days].
    frequency : (n,) array
        [Hz], positive.
    std_frequency, damping_pct, std_damping_pct, mpc, mpd, model_order, slot : (n,) arrays
        NaN where unknown.
    time_start : tuple of str
        ISO time of the record ("" where unknown).
    shapes, std_shapes : (n, p) arrays or None
        Real mode shapes at ``channels`` and their standard errors (NaN where unknown).
    channels : tuple of str
        The shape columns' channel names (``phi_<channel>``).
    mode : (n,) int array or None
        Tracked mode id (1-based), in tracked datasets.
    covariates : dict of str -> (n,) array
        Further numeric columns (e.g. temperatures), in their order.
    """

    day: np.ndarray
    frequency: np.ndarray
    std_frequency: np.ndarray
    damping_pct: np.ndarray
    std_damping_pct: np.ndarray
    mpc: np.ndarray
    mpd: np.ndarray
    model_order: np.ndarray
    slot: np.ndarray
    time_start: tuple = ()
    shapes: np.ndarray | None = None
    std_shapes: np.ndarray | None = None
    channels: tuple = ()
    mode: np.ndarray | None = None
    covariates: dict = field(default_factory=dict)

    def __post_init__(self):
        n = np.asarray(self.frequency).size
        for name in ("day", "frequency", "std_frequency", "damping_pct", "std_damping_pct", "mpc", "mpd",
                     "model_order", "slot"):
            value = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if value.size != n:
                raise ValueError(f"{name}: expected {n} values (one per row), got {value.size}")
            object.__setattr__(self, name, value)
        if not np.all(np.isfinite(self.frequency) & (self.frequency > 0)):
            bad = int(np.flatnonzero(~(np.isfinite(self.frequency) & (self.frequency > 0)))[0])
            raise ValueError(f"frequency_hz: row {bad + 1} is {self.frequency[bad]!r}; expected a positive number")
        if not np.all(np.isfinite(self.day)):
            raise ValueError(f"day: row {int(np.flatnonzero(~np.isfinite(self.day))[0]) + 1} is empty or NaN")
        object.__setattr__(self, "time_start", tuple(self.time_start) if self.time_start else ("",) * n)
        if len(self.time_start) != n:
            raise ValueError(f"time_start: expected {n} values, got {len(self.time_start)}")
        for name in ("shapes", "std_shapes"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=float).reshape(n, -1)
                if value.shape[1] != len(self.channels):
                    raise ValueError(f"{name}: expected shape ({n}, {len(self.channels)}) for channels "
                                     f"{list(self.channels)}, got {value.shape}")
                object.__setattr__(self, name, value)
        if self.mode is not None:
            mode = np.asarray(self.mode, dtype=float).reshape(-1)
            if mode.size != n or not np.all(np.isfinite(mode) & (mode >= 1) & (mode == np.round(mode))):
                raise ValueError("mode: expected a positive integer (the tracked mode, 1-based) in every row")
            object.__setattr__(self, "mode", mode.astype(int))
        covariates = {}
        for name, value in dict(self.covariates).items():
            value = np.asarray(value, dtype=float).reshape(-1)
            if value.size != n:
                raise ValueError(f"covariates[{name!r}]: expected {n} values, got {value.size}")
            covariates[str(name)] = value
        object.__setattr__(self, "covariates", covariates)

    @property
    def n_rows(self) -> int:
        return int(self.frequency.size)

    def take(self, index) -> PoleTable:
        """The rows ``index`` (an integer or boolean array), as a new table."""
        index = np.asarray(index)
        index = np.flatnonzero(index) if index.dtype == bool else index.astype(int)

        def pick(a):
            return None if a is None else np.asarray(a)[index]
        return replace(self, day=self.day[index], frequency=self.frequency[index],
                       std_frequency=self.std_frequency[index], damping_pct=self.damping_pct[index],
                       std_damping_pct=self.std_damping_pct[index], mpc=self.mpc[index], mpd=self.mpd[index],
                       model_order=self.model_order[index], slot=self.slot[index],
                       time_start=tuple(self.time_start[i] for i in index), shapes=pick(self.shapes),
                       std_shapes=pick(self.std_shapes), mode=pick(self.mode),
                       covariates={k: v[index] for k, v in self.covariates.items()})

    def records(self) -> list[np.ndarray]:
        """Row indices of each record (rows sharing a ``day``), records in time order, rows in file order."""
        order = np.argsort(self.day, kind="stable")
        days = self.day[order]
        starts = np.flatnonzero(np.r_[True, np.diff(days) > 1e-9])
        return np.split(order, starts[1:])

    @classmethod
    def from_modes(cls, modes, day: float = 0.0, time_start: str = "", channels=None) -> PoleTable:
        """One record's table from an OMA result (:class:`seqbayes.structural.oma.Modes`: ``frequencies``,
        ``damping_ratios``, ``shapes (p, k)`` and, where the OMA gives them, ``std_frequencies``,
        ``std_damping_ratios``, ``std_shapes``).

        Raises
        ------
        ValueError
            ``modes`` holds no mode (the OMA found nothing stable: its message says what to change).
        """
        f = np.asarray(modes.frequencies, dtype=float).reshape(-1)
        if f.size == 0:
            raise ValueError("modes: the OMA identified no mode in this record (no stable pole); see its "
                             "settings (max_order, the band) or the record's length and sampling rate")
        k = f.size
        nan = np.full(k, np.nan)
        shapes = np.asarray(modes.shapes, dtype=float) if getattr(modes, "shapes", None) is not None else None
        if shapes is not None and shapes.size == 0:
            shapes = None
        channels = tuple(channels) if channels is not None else (
            tuple(f"{j + 1}" for j in range(shapes.shape[0])) if shapes is not None else ())
        std_shapes = getattr(modes, "std_shapes", None)
        zeta = np.asarray(getattr(modes, "damping_ratios", nan), dtype=float)
        std_zeta = np.asarray(getattr(modes, "std_damping_ratios", nan), dtype=float)
        return cls(day=np.full(k, float(day)), frequency=f,
                   std_frequency=np.asarray(getattr(modes, "std_frequencies", nan), dtype=float),
                   damping_pct=100 * zeta, std_damping_pct=100 * std_zeta, mpc=nan, mpd=nan,
                   model_order=nan, slot=np.arange(k), time_start=(time_start,) * k,
                   shapes=None if shapes is None else shapes.T, channels=channels if shapes is not None else (),
                   std_shapes=None if shapes is None or std_shapes is None else np.asarray(std_shapes, float).T)


def _number(cell: str, path, line: int, column: str) -> float:
    cell = cell.strip()
    if not cell or cell.lower() == "nan":
        return math.nan
    try:
        value = float(cell)
    except ValueError:
        raise ValueError(f"{path}: line {line}, column {column!r}: not a number: {cell[:20]!r}") from None
    if math.isinf(value):
        raise ValueError(f"{path}: line {line}, column {column!r}: infinite value")
    return value


def _read_rows(path) -> tuple[list, list]:
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    with open(path, newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        header = [h.strip() for h in next(reader, [])]
        rows = [(reader.line_num, r) for r in reader if r and any(c.strip() for c in r)]
    if not header:
        raise ValueError(f"{path}: empty file (expected a header row)")
    for line, row in rows:
        if len(row) != len(header):
            raise ValueError(f"{path}: line {line} has {len(row)} fields, the header has {len(header)}")
    return header, rows


def read_modes_table(path) -> PoleTable:
    """Read a modes table (the module docstring's columns; ``frequency_hz`` and ``day`` are required).

    Raises
    ------
    ValueError
        One line naming the file, line and column: a missing ``frequency_hz`` or ``day`` column, a cell
        that is not a number, a non-positive frequency, a ragged line, no rows.
    """
    header, rows = _read_rows(path)
    missing = [c for c in ("day", "frequency_hz") if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {', '.join(missing)}; a modes table has day, frequency_hz, "
                         f"std_frequency_hz, ... (docs/modal.md)")
    if not rows:
        raise ValueError(f"{path}: no rows (no pole or mode)")
    twice = sorted({c for c in header if header.count(c) > 1})
    if twice:
        raise ValueError(f"{path}: column(s) {', '.join(twice)} appear more than once in the header")
    numeric = [c for c in header if c != "time_start"]
    values = {c: np.array([_number(r[header.index(c)], path, line, c) for line, r in rows]) for c in numeric}
    n = len(rows)
    nan = np.full(n, np.nan)
    channels = tuple(c[4:] for c in header if c.startswith("phi_"))
    std_channels = [c for c in channels if f"std_phi_{c}" in header]
    try:
        table = PoleTable(
            day=values["day"], frequency=values["frequency_hz"], time_start=tuple(
                r[header.index("time_start")].strip() for _, r in rows) if "time_start" in header else (),
            slot=values.get("slot", np.arange(n, dtype=float)),
            **{attr: values.get(col, nan) for col, attr in _FIELDS.items() if col != "frequency_hz"},
            shapes=np.column_stack([values[f"phi_{c}"] for c in channels]) if channels else None,
            std_shapes=(np.column_stack([values[f"std_phi_{c}"] if c in std_channels else nan for c in channels])
                        if channels and std_channels else None),
            channels=channels, mode=values.get("mode"),
            covariates={c: values[c] for c in numeric if c not in MODES_COLUMNS and not c.startswith(("phi_", "std_phi_"))})
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    return table


def _cell(value: float, digits: int = 9) -> str:
    return "" if not np.isfinite(value) else f"{value:.{digits}g}"


def write_modes_table(path, table: PoleTable) -> Path:
    """Write ``table`` as a modes table CSV (the module docstring's column order; NaN as empty cells).

    Returns
    -------
    pathlib.Path
    """
    path = Path(path)
    header = ["time_start", "day", "slot"] + (["mode"] if table.mode is not None else []) + [
        "frequency_hz", "damping_pct", "std_frequency_hz", "std_damping_pct", "mpc", "mpd", "model_order"]
    header += [f"phi_{c}" for c in table.channels] if table.shapes is not None else []
    header += [f"std_phi_{c}" for c in table.channels] if table.std_shapes is not None else []
    header += list(table.covariates)
    lines = [",".join(header)]
    for i in range(table.n_rows):
        cells = [table.time_start[i], _cell(table.day[i]), _cell(table.slot[i])]
        cells += [str(int(table.mode[i]))] if table.mode is not None else []
        cells += [_cell(getattr(table, a)[i]) for a in ("frequency", "damping_pct", "std_frequency",
                                                        "std_damping_pct", "mpc", "mpd", "model_order")]
        cells += [_cell(v) for v in table.shapes[i]] if table.shapes is not None else []
        cells += [_cell(v) for v in table.std_shapes[i]] if table.std_shapes is not None else []
        cells += [_cell(v[i]) for v in table.covariates.values()]
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def read_covariates(path) -> tuple[np.ndarray, dict]:
    """``(day (R,), {name: (R,) array})``: a table of covariates per record (a CSV with a ``day`` column and
    numeric columns, e.g. the mast's ``temperature_60min.csv``; ``time_start`` is ignored, empty cells NaN)."""
    header, rows = _read_rows(path)
    if "day" not in header:
        raise ValueError(f"{path}: missing column day (the record's start in days, as in the modes table)")
    names = [c for c in header if c not in ("time_start", "day")]
    if not names:
        raise ValueError(f"{path}: no covariate column besides day and time_start")
    day = np.array([_number(r[header.index("day")], path, line, "day") for line, r in rows])
    return day, {c: np.array([_number(r[header.index(c)], path, line, c) for line, r in rows]) for c in names}
