"""Hostile tables for the commands that read one (issue 42): a valid table of a command, then the classes of
trouble the issue found, combined at random, written as the file (or FIFO, or device) a command is handed.

A table is abstract until it is written: a header of names and rows of cells (text), the position of its time
column, its covariate column (or None) and its measurement columns. Each class of trouble is a function
``(table, rng) -> table``; :func:`hostile_table` applies one to three of them. :func:`write_table` writes it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import stat
from pathlib import Path

import numpy as np


@dataclasses.dataclass(frozen=True)
class Table:
    """A table as text cells. ``kind``: "csv" (a file), "fifo", "device" (a link to /dev/zero) or "sparse"
    (a regular file larger than the reader's bound, holding nothing)."""

    header: tuple
    rows: tuple
    time: int
    covariate: int | None
    measurements: tuple
    sep: str = ","
    bom: bool = False
    newline: str = "\n"
    kind: str = "csv"
    tail: bytes = b""               # raw bytes appended (NUL bytes, invalid UTF-8)
    classes: tuple = ()             # what was done, in words (with the variant: "extra column 'f3'")
    families: tuple = ()            # the functions of CLASSES that changed the table

    def with_(self, name, **changes):
        return dataclasses.replace(self, classes=self.classes + (name,), **changes)


def base_table(columns, rng, n_rows=12, *, covariate=True, frequencies=(4.0, 10.0)) -> Table:
    """A valid table: increasing times (6 sets a day), a temperature between -5 and 25 degC when ``covariate``,
    and measurements near ``frequencies`` (the 2-storey building of the tests: 3.98 and 10.06 Hz)."""
    day = np.arange(n_rows) / 6.0
    cells = [[f"{d:.10g}" for d in day]]
    if covariate:
        cells.append([f"{t:.10g}" for t in rng.uniform(-5, 25, n_rows)])
    for f in frequencies[:len(columns) - len(cells)]:
        cells.append([f"{v:.10g}" for v in f * np.exp(rng.normal(0, 0.004, n_rows))])
    rows = tuple(tuple(row) for row in zip(*cells))
    return Table(tuple(columns), rows, time=0, covariate=1 if covariate else None,
                 measurements=tuple(range(2 if covariate else 1, len(columns))))


def record_table(columns, rng, n_rows=512, dt=0.01, frequencies=(1.5, 4.0)) -> Table:
    """A valid response record (for an OMA command): times ``k dt`` in the first column, then one channel per
    other column, each a sum of lightly damped modes at ``frequencies`` [Hz] driven by white noise."""
    t = np.arange(n_rows) * dt
    channels = []
    for c in range(len(columns) - 1):
        signal = sum(np.convolve(rng.standard_normal(n_rows), np.exp(-0.02 * 2 * np.pi * f * t)
                                 * np.sin(2 * np.pi * f * t), mode="full")[:n_rows] * (c + 1) ** k
                     for k, f in enumerate(frequencies))
        channels.append(signal + 0.01 * rng.standard_normal(n_rows))
    cells = [[f"{v:.10g}" for v in t]] + [[f"{v:.10g}" for v in ch] for ch in channels]
    return Table(tuple(columns), tuple(tuple(r) for r in zip(*cells)), time=0, covariate=None,
                 measurements=tuple(range(1, len(columns))))


def _set(table, row, col, value):
    rows = [list(r) for r in table.rows]
    rows[row][col] = value
    return tuple(tuple(r) for r in rows)


def _any_row(table, rng):
    return int(rng.integers(len(table.rows))) if table.rows else None


def unsorted_days(table, rng):
    order = rng.permutation(len(table.rows))
    return table.with_("unsorted days", rows=tuple(table.rows[i] for i in order))


def negative_days(table, rng):
    row = _any_row(table, rng)
    return table if row is None else table.with_("negative day", rows=_set(table, row, table.time, "-3.5"))


def duplicated_days(table, rng):
    row = _any_row(table, rng)
    if row is None:
        return table
    rows = list(table.rows)
    rows.insert(row + 1, rows[row])
    return table.with_("duplicated day", rows=tuple(rows))


def huge_days(table, rng):
    row = _any_row(table, rng)
    return table if row is None else table.with_("day 1e20", rows=_set(table, row, table.time, "1e20"))


def gapped_days(table, rng):
    if len(table.rows) < 2:
        return table
    cut = int(rng.integers(1, len(table.rows)))
    rows = [list(r) for r in table.rows]
    for r in rows[cut:]:
        try:
            r[table.time] = f"{float(r[table.time]) + 1e9:.10g}"
        except (ValueError, IndexError):      # a cell another class made non-numeric, or a short row
            pass
    return table.with_("gap of 1e9 days", rows=tuple(tuple(r) for r in rows))


def extra_columns(table, rng):
    name = str(rng.choice(["f3", "note", "", "f1"]))  # another mode, a text column, a trailing ',', a repeated name
    value = {"note": "sensor 3"}.get(str(name), "12.5")
    return table.with_(f"extra column {name!r}", header=table.header + (str(name),),
                       rows=tuple(r + (value,) for r in table.rows))


def hash_inside_rows(table, rng):
    row = _any_row(table, rng)
    if row is None or rng.random() < 0.3:             # a comment line
        rows = list(table.rows)
        rows.insert(0 if row is None else row, ("# calibrated on 2024-01-01",) + ("",) * (len(table.header) - 1))
        return table.with_("comment line", rows=tuple(rows))
    col = int(rng.integers(len(table.header)))
    return table.with_("'#' inside a row", rows=_set(table, row, col, table.rows[row][col] + " # check"))


def extreme_frequencies(table, rng):
    row = _any_row(table, rng)
    if row is None:
        return table
    col = int(rng.choice(table.measurements))
    return table.with_("extreme frequency", rows=_set(table, row, col, str(rng.choice(["1e-6", "1e6", "0", "-4"]))))


def extreme_temperatures(table, rng):
    row = _any_row(table, rng)
    if row is None or table.covariate is None:
        return table
    return table.with_("extreme temperature", rows=_set(table, row, table.covariate,
                                                        str(rng.choice(["1e6", "1e300", "-300"]))))


def bom(table, rng):
    return table.with_("BOM", bom=True)


def wrong_case_header(table, rng):
    return table.with_("upper-case header", header=tuple(h.upper() for h in table.header))


def semicolons(table, rng):
    return table.with_("';' separators", sep=";")


def header_only(table, rng):
    return table.with_("header only", rows=())


def fifo(table, rng):
    return table.with_("FIFO", kind="fifo")


def device(table, rng):
    return table.with_(str(rng.choice(["/dev/zero", "sparse 1 GiB"])),
                       kind="device" if rng.random() < 0.5 else "sparse")


def nan_inf(table, rng):
    row = _any_row(table, rng)
    if row is None:
        return table
    col = int(rng.integers(len(table.header)))
    return table.with_("NaN/inf", rows=_set(table, row, col, str(rng.choice(["nan", "inf", "-inf", "NaN", ""]))))


def non_numeric(table, rng):
    row = _any_row(table, rng)
    if row is None:
        return table
    col = int(rng.integers(len(table.header)))
    return table.with_("non-numeric", rows=_set(table, row, col, str(rng.choice(["abc", "1_0", "\uff11", "1,5",
                                                                                  "0x10", "\x1b[2J"]))))


def huge_numbers(table, rng):
    row = _any_row(table, rng)
    if row is None:
        return table
    col = int(rng.integers(len(table.header)))
    return table.with_("huge number", rows=_set(table, row, col, str(rng.choice(["1e308", "1e400", "9" * 400]))))


def binary_tail(table, rng):
    tails = (b"\0\0\0", b"\xff\xfe\x00", b"\x89HDF")       # NUL bytes, UTF-16's mark, an HDF5 signature
    return table.with_("binary bytes", tail=tails[int(rng.integers(len(tails)))])


def ragged_rows(table, rng):
    row = _any_row(table, rng)
    if row is None:
        return table
    rows = list(table.rows)
    rows[row] = rows[row][:-1] if rng.random() < 0.5 else rows[row] + ("1",)
    return table.with_("ragged row", rows=tuple(rows))


def crlf(table, rng):
    return table.with_("CRLF", newline="\r\n")


#: Every class of trouble (the issue's, and a few more a careless user meets).
CLASSES = (unsorted_days, negative_days, duplicated_days, huge_days, gapped_days, extra_columns, hash_inside_rows,
           extreme_frequencies, extreme_temperatures, bom, wrong_case_header, semicolons, header_only, fifo, device,
           nan_inf, non_numeric, huge_numbers, binary_tail, ragged_rows, crlf)


def hostile_table(base: Table, rng) -> Table:
    """``base`` with one to three classes of :data:`CLASSES` applied, drawn with ``rng``."""
    table = base
    for index in rng.choice(len(CLASSES), size=int(rng.integers(1, 4)), replace=False):
        changed = CLASSES[index](table, rng)
        if changed.classes != table.classes:
            changed = dataclasses.replace(changed, families=changed.families + (CLASSES[index].__name__,))
        table = changed
    return table


def write_table(table: Table, path: Path, max_bytes: int) -> Path:
    """Write ``table`` at ``path`` as its kind says (``max_bytes``: the reader's bound, which "sparse" exceeds)."""
    if table.kind == "fifo":
        os.mkfifo(path)
    elif table.kind == "device":
        os.symlink("/dev/zero", path)
    elif table.kind == "sparse":
        with open(path, "wb") as fh:
            fh.truncate(max_bytes + 1)
    else:
        lines = [table.sep.join(table.header)] + [table.sep.join(row) for row in table.rows]
        text = ("\ufeff" if table.bom else "") + table.newline.join(lines) + table.newline
        path.write_bytes(text.encode("utf-8") + table.tail)
    return path


def snapshot(folder: Path) -> dict:
    """Every entry of ``folder``: the SHA-256 of a regular file, the kind of anything else (not opened)."""
    out = {}
    for entry in sorted(folder.iterdir()):
        info = os.lstat(entry)
        if stat.S_ISREG(info.st_mode) and info.st_size > 1 << 24:    # the sparse file: not read (1 GiB of zeros)
            out[entry.name] = (info.st_size, info.st_mtime_ns, info.st_ino)
        elif stat.S_ISREG(info.st_mode):
            out[entry.name] = hashlib.sha256(entry.read_bytes()).hexdigest()
        else:
            out[entry.name] = stat.S_IFMT(info.st_mode)
    return out


def mount_tmpfs(folder: Path, size: str = "4m") -> Path:
    """Mount a tmpfs of ``size`` on ``folder`` (created); pytest.skip where that is not permitted (not root).
    Unmount with :func:`unmount`."""
    import subprocess

    import pytest

    folder.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)], capture_output=True,
                          text=True)
    if done.returncode:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    return folder


def unmount(folder: Path) -> None:
    import subprocess

    subprocess.run(["umount", "-l", str(folder)], capture_output=True)


def remount_read_only(folder: Path) -> None:
    import subprocess

    subprocess.run(["mount", "-o", "remount,ro", str(folder)], check=True)


def fill(folder: Path, leave_bytes: int) -> Path:
    """Fill the filesystem of ``folder`` to ``leave_bytes`` free, with the file ``folder/filler``."""
    info = os.statvfs(folder)
    with open(folder / "filler", "wb") as fh:
        fh.write(b"\0" * max(0, info.f_bavail * info.f_frsize - leave_bytes))
    return folder / "filler"
