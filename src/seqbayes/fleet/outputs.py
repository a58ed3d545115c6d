"""The files a fleet update writes: its record (read by the fleet's status) and its ``--json`` outcome.

Both are JSON texts of the :class:`~seqbayes.fleet.records.FleetOutcome`, written the way the stores are:
to a temporary file in the target's folder, ``fsync``-ed, then moved over the target with ``os.replace``
(a reader sees the old file or the new one, never half of one). Their place and room are taken before any
store is touched (:func:`reserve_output`): the target is checked against the fleet's inputs, the
temporary file is created and the room it needs allocated (``posix_fallocate``), so a read-only folder,
a full disk or a target that is an input gives one line and leaves every store as it was.

A target is refused when it is a folder, one of the fleet's inputs (the manifest, a store, its lock or
journal, a data file) or an existing file that is not a fleet outcome (a JSON object carrying
:data:`~seqbayes.fleet.records.OUTCOME_MARKER`): those are the user's files, never overwritten.

The record lies in the fleet's folder (``FOLDER/.seqbayes-fleet.json``) or beside its manifest
(``.MANIFEST.toml.outcome.json``); :func:`read_record` reads it back for ``seqbayes status``.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import stat
from pathlib import Path

from .plan import FleetError
from .records import OUTCOME_MARKER

__all__ = ["ReservedOutput", "reserve_output", "record_path", "read_record", "outcome_size", "MAX_OUTCOME_BYTES"]

#: An outcome file larger than this is not read back (a fleet of 10^4 stores of 30 steps writes about 20 MB).
MAX_OUTCOME_BYTES = 256 * 2 ** 20
_TMP = ".tmp-"


def record_path(plan) -> Path:
    """Where the fleet's record of its last update lies (module docstring)."""
    if plan.kind == "folder":
        return plan.source / ".seqbayes-fleet.json"
    return plan.source.with_name(f".{plan.source.name}.outcome.json")


def outcome_size(plan) -> int:
    """Bytes to reserve for the outcome of ``plan``: generous bounds of a store's entry and a step's line
    (a step's summary is about 300 characters, an error line at most about 1,000)."""
    return 64 * 1024 + sum(4096 + 1024 * len(task.datasets) for task in plan.tasks)


def _read_limited(path: Path, limit: int) -> bytes | None:
    """The bytes of ``path`` if it is a regular file of at most ``limit`` bytes (opened without following a link
    or waiting on a FIFO), else None."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0))
    except OSError:
        return None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_size > limit:
            return None
        chunks, size = [], 0
        while size <= limit:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        return b"".join(chunks) if size <= limit else None
    except OSError:
        return None
    finally:
        os.close(fd)


def _outcome_json(path: Path) -> dict | None:
    """The outcome a fleet update wrote at ``path``, or None when it is not one."""
    raw = _read_limited(path, MAX_OUTCOME_BYTES)
    if raw is None:
        return None
    try:
        content = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    return content if isinstance(content, dict) and content.get(OUTCOME_MARKER) == 1 else None


def read_record(plan) -> tuple[dict, str | None]:
    """``(outcomes by store name, problem)``: the last fleet update's store outcomes as JSON objects (from its
    record, :func:`record_path`), and one line when a record exists but cannot be used (else None)."""
    path = record_path(plan)
    if not os.path.lexists(path):
        return {}, None
    content = _outcome_json(path)
    stores = content.get("stores") if content is not None else None
    if not isinstance(stores, list):
        return {}, f"{path}: not a fleet update's record (damaged or replaced); the last update's errors are unknown"
    found = {}
    for entry in stores:
        if isinstance(entry, dict) and isinstance(entry.get("name"), str):
            found[entry["name"]] = dict(entry, started=content.get("started"))
    return found, None


class ReservedOutput:
    """An output file whose place and room are taken (:func:`reserve_output`); :meth:`commit` writes it."""

    def __init__(self, path: Path, tmp: Path, fd: int, reserved: int):
        self.path, self.tmp, self.fd, self.reserved = path, tmp, fd, reserved

    def commit(self, text: str) -> None:
        """Write ``text`` into the reserved file, ``fsync`` it and move it over the target.

        Raises
        ------
        OSError
            The write failed (the text outgrew the room reserved on a full disk, an I/O error); the target
            is as it was and the temporary file is removed.
        """
        data = memoryview(text.encode())
        try:
            offset = 0
            while offset < len(data):
                offset += os.pwrite(self.fd, data[offset:], offset)
            os.ftruncate(self.fd, len(data))
            os.fsync(self.fd)
            os.close(self.fd)
            self.fd = -1
            os.replace(self.tmp, self.path)
        except BaseException:
            self.abandon()
            raise
        with contextlib.suppress(OSError):
            folder = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(folder)
            finally:
                os.close(folder)

    def abandon(self) -> None:
        """Give the reservation up: the temporary file is removed, the target left as it was."""
        if self.fd >= 0:
            with contextlib.suppress(OSError):
                os.close(self.fd)
            self.fd = -1
        with contextlib.suppress(OSError):
            os.remove(self.tmp)


def _remove_stale(folder: Path, prefix: str) -> None:
    """Remove temporary files ``prefix<pid>`` of processes that are gone (a killed fleet update's)."""
    with contextlib.suppress(OSError):
        for entry in os.listdir(folder):
            rest = entry[len(prefix):] if entry.startswith(prefix) else ""
            if rest.isdigit() and int(rest) != os.getpid():
                try:
                    os.kill(int(rest), 0)
                except ProcessLookupError:
                    with contextlib.suppress(OSError):
                        os.remove(folder / entry)
                except OSError:
                    pass


def reserve_output(path, size: int, inputs, what: str, *, replace_any: bool = False) -> ReservedOutput:
    """Check the output target ``path`` and take its place and ``size`` bytes of room (module docstring).

    Parameters
    ----------
    path : path-like
    size : int
        Bytes to allocate now (:func:`outcome_size`).
    inputs : set of str
        Real paths of the fleet's inputs (:attr:`seqbayes.fleet.plan.FleetPlan.inputs`).
    what : str
        What the target is, for messages (``"--json"``, ``"the fleet's record"``).
    replace_any : bool
        The target may replace a regular file that is not a fleet outcome (the record, whose name is the
        fleet's: a damaged record must not stop the next update).

    Raises
    ------
    FleetError
        One line naming the target: a folder, an input, an existing file that is not a fleet outcome, a
        missing or read-only folder, no room.
    """
    from ..store.datasets import printable

    path = Path(path)
    shown = printable(str(path))
    untouched = "no store was touched"
    if path.is_dir():
        raise FleetError(f"{what} {shown}: is a folder; give a file name, e.g. {printable(str(path / 'fleet.json'))}")
    if os.path.realpath(path) in inputs:
        raise FleetError(f"{what} {shown}: is one of the fleet's inputs (its manifest, a store or a data file), "
                         f"which is never overwritten; give another file; {untouched}")
    if os.path.lexists(path) and not (replace_any and path.is_file()) and _outcome_json(path) is None:
        raise FleetError(f"{what} {shown}: exists and is not a fleet update's outcome, so it is not overwritten; "
                         f"remove it or give another file; {untouched}")
    folder = path.parent
    if not folder.is_dir():
        raise FleetError(f"{what} {shown}: the folder {printable(str(folder))} does not exist; {untouched}")
    prefix = f".{path.name}{_TMP}"
    _remove_stale(folder, prefix)
    tmp = folder / f"{prefix}{os.getpid()}"
    try:
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_TRUNC | getattr(os, "O_NOFOLLOW", 0), 0o644)
    except OSError as err:
        raise FleetError(f"{what} {shown}: cannot write in {printable(str(folder))}: {err.strerror or err}; "
                         f"{untouched}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, "not a regular file")
        if hasattr(os, "posix_fallocate"):
            os.posix_fallocate(fd, 0, size)
        else:  # pragma: no cover - not on Linux
            os.pwrite(fd, b"\0" * size, 0)
        os.fsync(fd)
    except OSError as err:
        with contextlib.suppress(OSError):
            os.close(fd)
        with contextlib.suppress(OSError):
            os.remove(tmp)
        raise FleetError(f"{what} {shown}: cannot take {size // 1024} KiB for it in {printable(str(folder))}: "
                         f"{err.strerror or err}; {untouched}") from None
    return ReservedOutput(path, tmp, fd, size)
