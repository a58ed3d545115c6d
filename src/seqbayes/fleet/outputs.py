"""The files a fleet update writes: its record (read by the fleet's status) and its ``--json`` outcome.

Both are JSON texts of the :class:`~seqbayes.fleet.records.FleetOutcome` and go through the output guard
of every command (:mod:`seqbayes.store.targets`), in three moves:

1. :func:`check_targets`, before any store is touched: :func:`~seqbayes.store.targets.check_outputs`
   refuses a target that is one of the fleet's inputs (the manifest, a data file), a store or its lock or
   journal (as files, through links too), a folder or a special file, and, unless ``--force``, an existing
   file that is not a fleet outcome (a JSON object carrying :data:`~seqbayes.fleet.records.OUTCOME_MARKER`).
   The record's own name (hidden, the fleet's) may hold anything: a damaged record must not stop the
   next update.
2. :func:`reserve_room`, still before any store is touched: a temporary file in the target's folder takes
   the room the outcome needs (``posix_fallocate``), so a read-only folder or a full disk gives one line
   and leaves every store as it was, rather than failing after the stores were updated.
3. :meth:`ReservedOutput.commit`, at the end: the room is given back and the text written by
   :func:`~seqbayes.store.targets.write_output` (a temporary file, ``fsync``, ``os.replace``: a reader sees
   the old file or the new one, never half of one).

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

__all__ = ["ReservedOutput", "check_targets", "reserve_room", "record_path", "read_record", "outcome_size",
           "MAX_OUTCOME_BYTES", "RECORD"]

#: An outcome file larger than this is not read back (a fleet of 10^4 stores of 30 steps writes about 20 MB).
MAX_OUTCOME_BYTES = 256 * 2 ** 20
_TMP = ".tmp-"
#: How the record is named in messages.
RECORD = "the fleet's record"


def record_path(plan) -> Path:
    """Where the fleet's record of its last update lies (module docstring)."""
    if plan.kind == "folder":
        return plan.source / ".seqbayes-fleet.json"
    return plan.source.with_name(f".{plan.source.name}.outcome.json")


def outcome_size(plan) -> int:
    """Bytes to reserve for the outcome of ``plan``: generous bounds of a store's entry and a step's line
    (a step's summary is about 300 characters, an error line at most about 1,000)."""
    return 64 * 1024 + sum(4096 + 1024 * len(task.datasets) for task in plan.tasks)


def _outcome_json(path: Path) -> dict | None:
    """The outcome a fleet update wrote at ``path`` (read by the store's strict reader), or None when it is
    not one."""
    from ..store.datasets import read_regular

    try:
        raw = read_regular(path, "fleet record", MAX_OUTCOME_BYTES, error=FleetError)
        content = json.loads(raw.decode("utf-8"))
    except (FleetError, UnicodeDecodeError, json.JSONDecodeError):
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


def _is_outcome(head: bytes) -> bool:
    """Recogniser of an earlier fleet outcome (:func:`~seqbayes.store.targets.check_outputs`): its JSON
    carries the marker, or, past the bytes read, starts with it (:meth:`FleetOutcome.to_json` puts it first)."""
    from ..store.targets import HEAD_BYTES

    if len(head) >= HEAD_BYTES:
        return head.startswith(f'{{\n "{OUTCOME_MARKER}": 1'.encode())
    try:
        content = json.loads(head.decode("utf-8"))
    except ValueError:
        return False
    return isinstance(content, dict) and content.get(OUTCOME_MARKER) == 1


def check_targets(plan, json_path=None, force: bool = False) -> list:
    """``[(path, what)]`` of the fleet's outputs (its record, and ``json_path`` when it is another file),
    checked by :func:`~seqbayes.store.targets.check_outputs` against the fleet's inputs and stores.

    Raises
    ------
    seqbayes.store.targets.OutputError
        One line naming the option and the target.
    """
    from ..store.targets import Output, check_outputs

    record = record_path(plan)
    outputs = [Output(RECORD, record, lambda head: True)]
    if json_path is not None and os.path.realpath(json_path) != os.path.realpath(record):
        outputs.append(Output("--json", json_path, _is_outcome))
    inputs = ([plan.source] if plan.kind == "manifest" else []) + [d for t in plan.tasks for d in t.datasets]
    chosen = check_outputs(outputs, inputs=inputs, stores=[t.store for t in plan.tasks], force=force)
    return [(chosen[o.option], o.option) for o in outputs]


class ReservedOutput:
    """An output file whose room is taken (:func:`reserve_room`); :meth:`commit` writes it."""

    def __init__(self, path: Path, what: str, tmp: Path, fd: int, reserved: int):
        self.path, self.what, self.tmp, self.fd, self.reserved = path, what, tmp, fd, reserved

    def commit(self, text: str) -> None:
        """Give the room back and write ``text`` to the target atomically
        (:func:`~seqbayes.store.targets.write_output`).

        Raises
        ------
        seqbayes.store.targets.OutputError
            The write failed (a disk filled since the room was taken, an I/O error); the target is as it was.
        """
        from ..store.targets import write_output

        self.abandon()
        write_output(self.path, text, self.what)

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


def reserve_room(path, size: int, what: str) -> ReservedOutput:
    """Take ``size`` bytes of room in the folder of the (checked) target ``path``, before any store is touched.

    Raises
    ------
    FleetError
        One line naming the target: a read-only folder, no room.
    """
    from ..store.datasets import printable

    path = Path(path)
    shown = printable(str(path))
    untouched = "no store was touched"
    folder = path.parent if str(path.parent) else Path(".")
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
    return ReservedOutput(path, what, tmp, fd, size)
