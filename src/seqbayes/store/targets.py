"""The files a command writes besides a run store: never one of its inputs, never a file it did not write
before, always whole.

Every ``--json``, ``--report``, ``--output``/``-o`` and ``--out`` target (and the figures of ``report
--no-embed``) goes through this module, in two calls:

1. :func:`check_outputs`, before the work starts. A target is refused in one line (:class:`OutputError`)

   - always, even with ``force``: if it is one of the command's inputs or its run store, or one of the
     store's side files (its lock, its journal), compared as files (device and inode, so through
     symbolic and hard links too); if two options name one file; if it is a folder, a FIFO, a device
     or a socket;
   - unless ``force``: if it exists and is not a file this command wrote before (each
     :class:`Output` says how to recognise its own files from their first bytes), or is a symbolic
     link (which the new file would replace).

2. :func:`write_output`, once the content is known. The content goes to a new temporary file beside the
   target, is ``fsync``-ed and moved over the target with :func:`os.replace`: a reader sees the old
   file or the new one, never half of one, and a file hard-linked to the target's name is never written
   through. The free space is checked first; a full disk or a read-only folder is one
   :class:`OutputError`, and the old file stays as it was. A replaced file keeps its permission bits.

The OMA and fleet commands call them the same way (with ``--force`` as ``seqbayes.cli.common.FORCE_OPTION``)::

    from seqbayes.store.targets import Output, check_outputs, json_with_keys, starts_with, write_output

    targets = check_outputs([Output("--out", args.out, starts_with(b"time_start,day,slot,")),
                             Output("--json", args.json, json_with_keys("settings", "modes"))],
                            inputs=[args.record], stores=[], force=args.force)
    ...                                                    # the work
    write_output(targets["--out"], modes_csv_text, "--out")   # str (UTF-8) or bytes

``inputs`` are every file the command reads and ``stores`` every run store it reads or writes (a fleet:
all of its members' stores); a command writing several files names each in its own :class:`Output`. A
target left out (``path=None``) is skipped, and :func:`check_outputs` maps only the given ones. The
recognisers here (:func:`html_page`, :func:`png_figure`, :func:`forecast_file`, :func:`json_with_keys`,
:func:`starts_with`) say which existing files are earlier outputs; a new output kind adds its own.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import shutil
import stat
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from .datasets import printable
from .files import fsync_dir, journal_path
from .locks import NOFOLLOW, NONBLOCK, os_message, target

__all__ = ["OutputError", "Output", "check_outputs", "refuse_inputs", "write_output", "starts_with", "json_with_keys",
           "read_head", "html_page", "png_figure", "forecast_file"]

#: Bytes of an existing target read to recognise it as an earlier output of the command.
HEAD_BYTES = 1 << 16
#: Slack over the content's size in the free-space check (the folder entry, filesystem blocks).
_SLACK = 64 << 10


class OutputError(ValueError):
    """An output target refused, or an output that could not be written (one line, naming the option)."""


@dataclass(frozen=True)
class Output:
    """One output target of a command.

    Attributes
    ----------
    option : str
        The option that names it (``"--json"``), for messages.
    path : path-like or None
        The target; ``None`` when the option was not given.
    recognise : callable or None
        ``recognise(head: bytes) -> bool``: whether an existing file whose first :data:`HEAD_BYTES`
        bytes are ``head`` is an earlier output of this command (then it is replaced without
        ``force``). ``None``: every existing file needs ``force``.
    creates_folder : bool
        The command creates a missing folder of the target (else a missing folder is refused).
    """

    option: str
    path: str | os.PathLike | None
    recognise: Callable[[bytes], bool] | None = None
    creates_folder: bool = False


def starts_with(*prefixes: bytes) -> Callable[[bytes], bool]:
    """A recogniser of files that start with all of ``prefixes`` in turn (e.g. an HTML head, then a CSS)."""
    def recognise(head: bytes) -> bool:
        position = 0
        for prefix in prefixes:
            found = head.find(prefix, position) if position else (0 if head.startswith(prefix) else -1)
            if found < 0:
                return False
            position = found + len(prefix)
        return True
    return recognise


def json_with_keys(*keys: str) -> Callable[[bytes], bool]:
    """A recogniser of a JSON object holding ``keys`` (its head must parse: for outputs of at most
    :data:`HEAD_BYTES`; larger ones are recognised by their first key, ``keys[0]``)."""
    first = f'{{\n "{keys[0]}":'.encode()

    def recognise(head: bytes) -> bool:
        if len(head) >= HEAD_BYTES:
            return head.startswith(first)
        try:
            value = json.loads(head.decode("utf-8"))
        except ValueError:
            return False
        return isinstance(value, dict) and all(key in value for key in keys)
    return recognise


#: The start of every HTML page seqbayes writes (the run reports, the year report: :data:`seqbayes.store.report.CSS`
#: follows the title), by which an earlier page is recognised.
_PAGE = (b"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>",
         b"</title>\n<style>\nbody { font-family: system-ui, sans-serif;")
_PNG = b"\x89PNG\r\n\x1a\n"
_HDF5 = b"\x89HDF\r\n\x1a\n"


def html_page(head: bytes) -> bool:
    """A page of ``seqbayes report`` or ``seqbayes environment --report``."""
    return starts_with(*_PAGE)(head)


def png_figure(head: bytes) -> bool:
    """A figure matplotlib wrote (the figures of ``report --no-embed``)."""
    return head.startswith(_PNG) and b"Matplotlib" in head[:512]


def forecast_file(names) -> Callable[[bytes], bool]:
    """A recogniser of ``seqbayes predict --output`` files of the parameters ``names``: the CSV's header
    ``step,<names>``, or a NetCDF-4 file naming a ``forecast`` variable in its first bytes."""
    header = ",".join(["step", *names]).encode() + b"\n"
    return lambda head: head.startswith(header) or (head.startswith(_HDF5) and b"forecast" in head)


def read_head(path: str | os.PathLike, n: int = HEAD_BYTES) -> bytes | None:
    """The first ``n`` bytes of ``path`` if it is a regular file (not followed if it is a link; a FIFO is
    not waited on), else None."""
    try:
        fd = os.open(path, os.O_RDONLY | NOFOLLOW | NONBLOCK)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        parts, left = [], n
        while left > 0:
            chunk = os.read(fd, left)
            if not chunk:
                break
            parts.append(chunk)
            left -= len(chunk)
        return b"".join(parts)
    except OSError:
        return None
    finally:
        os.close(fd)


def _identity(path) -> tuple | None:
    """``(device, inode)`` of the file ``path`` names (links followed), or None if there is none."""
    try:
        info = os.stat(path)
    except (OSError, ValueError):
        return None
    return info.st_dev, info.st_ino


def _protected(inputs: Iterable, stores: Iterable) -> tuple[dict, dict]:
    """``({(dev, ino): what}, {real path: what})``: the inputs and the stores with their side files."""
    files, names = {}, {}
    for path in inputs:
        if path is not None and _identity(path) is not None:
            files.setdefault(_identity(path), f"the input {printable(path)}")
    for path in stores:
        if path is None:
            continue
        real = target(path)
        for side, what in ((real, "the run store"), (real.with_name(real.name + ".lock"), "the run store's lock"),
                           (journal_path(real), "the run store's journal")):
            label = f"{what} {printable(path)}" if side == real else f"{what} ({printable(side.name)})"
            names.setdefault(str(side), label)
            if _identity(side) is not None:
                files.setdefault(_identity(side), label)
    return files, names


def _refuse_protected(where: str, path: Path, protected: tuple) -> None:
    files, names = protected
    same = files.get(_identity(path)) or names.get(os.path.realpath(path))
    if same is not None:
        raise OutputError(f"{where}: is {same}; an output never replaces what the command reads "
                          f"(give another file name)")


def refuse_inputs(option: str, path, *, inputs: Iterable = (), stores: Iterable = ()) -> None:
    """Only the first rule of :func:`check_outputs`: refuse ``path`` if it is one of ``inputs`` or ``stores``
    (with their side files), as files. For a target that another check owns (``init``'s run store)."""
    _refuse_protected(f"{option} {printable(path)}", Path(path), _protected(inputs, stores))


def check_outputs(outputs: Iterable[Output], *, inputs: Iterable = (), stores: Iterable = (),
                  force: bool = False) -> dict[str, Path]:
    """Check a command's output targets before it starts (see the module); ``{option: Path}`` of the given ones.

    Parameters
    ----------
    outputs : iterable of Output
    inputs : iterable of path-like
        Every file the command reads (data files, configurations, the likelihood module, mode shapes).
    stores : iterable of path-like
        The run stores the command reads or writes (their locks and journals are protected too).
    force : bool
        Replace an existing file that is not an earlier output of the command (``--force``).

    Raises
    ------
    OutputError
        ``{option} {path}: ...`` saying why and what to do.
    """
    protected = _protected(inputs, stores)
    chosen: dict[str, Path] = {}
    seen: dict = {}
    for output in outputs:
        if output.path is None:
            continue
        path = Path(output.path)
        where = f"{output.option} {printable(path)}"
        if str(path) in ("", "."):
            raise OutputError(f"{output.option}: expected a file name, got {str(output.path)!r}")
        _refuse_protected(where, path, protected)
        key = _identity(path) or os.path.realpath(path)
        if key in seen:
            raise OutputError(f"{where}: is also the target of {seen[key]}; give each output its own file")
        seen[key] = output.option
        try:
            info = os.lstat(path)
        except FileNotFoundError:
            if not output.creates_folder and not os.path.isdir(path.parent or "."):
                raise OutputError(f"{where}: the folder {printable(path.parent)} does not exist") from None
            chosen[output.option] = path
            continue
        except OSError as err:
            raise OutputError(f"{where}: cannot be checked: {os_message(err)}") from None
        mode = os.stat(path).st_mode if stat.S_ISLNK(info.st_mode) and _identity(path) else info.st_mode
        if stat.S_ISDIR(mode):
            raise OutputError(f"{where}: is a folder; give a file name, e.g. {printable(path / 'out')}")
        if not stat.S_ISREG(mode) and not stat.S_ISLNK(mode):
            raise OutputError(f"{where}: is not a regular file (a FIFO, a device or a socket); give a file name")
        if not force:
            if stat.S_ISLNK(info.st_mode):
                raise OutputError(f"{where}: is a symbolic link (to {printable(os.readlink(path))}), which the "
                                  f"output would replace; give another name, or --force to replace the link")
            head = read_head(path)
            if output.recognise is None or head is None or not output.recognise(head):
                raise OutputError(f"{where}: exists and is not a file this command wrote; give another name, "
                                  f"or --force to replace it")
        chosen[output.option] = path
    return chosen


def write_output(path: str | os.PathLike, content: str | bytes, option: str | None = None) -> Path:
    """Write ``content`` (``str``: UTF-8) to ``path`` atomically: a temporary file in its folder, ``fsync``,
    :func:`os.replace`; returns ``path``. A link at ``path`` is replaced, never written through.

    Raises
    ------
    OutputError
        Not enough free space, a read-only or missing folder, an I/O error: nothing was written and
        an old file at ``path`` is unchanged.
    """
    path = Path(path)
    data = content.encode("utf-8") if isinstance(content, str) else bytes(content)
    where = f"{option} {printable(path)}" if option else printable(path)
    folder = path.parent if str(path.parent) else Path(".")
    try:
        free = shutil.disk_usage(folder).free
    except OSError as err:
        raise OutputError(f"{where}: cannot write: {os_message(err)}; nothing was written") from None
    if free < len(data) + _SLACK:
        raise OutputError(f"{where}: not enough free space in {printable(folder)}: about "
                          f"{(len(data) + _SLACK) // 1024} KiB needed, {free // 1024} KiB free "
                          f"({os.strerror(errno.ENOSPC)}); nothing was written")
    try:
        old = os.stat(path)
        keep_mode = stat.S_IMODE(old.st_mode) if stat.S_ISREG(old.st_mode) else None
    except OSError:
        keep_mode = None
    temporary = folder / f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_EXCL | NOFOLLOW, 0o666)
        try:
            if keep_mode is not None and hasattr(os, "fchmod"):
                os.fchmod(fd, keep_mode)
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(temporary, path)
    except OSError as err:
        with contextlib.suppress(OSError):
            os.remove(temporary)
        kept = "; the old file is kept" if os.path.lexists(path) else ""
        raise OutputError(f"{where}: cannot write: {err.strerror or err}; nothing was written{kept}") from None
    fsync_dir(folder)
    return path
