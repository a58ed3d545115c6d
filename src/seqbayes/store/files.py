"""The file machinery under every run store: locks, the redo journal, whole-file writes, reads.

A run store is one NetCDF-4 (HDF5) file. Writes are atomic, and an update writes only what it
adds. A new step is appended in place, through a redo journal: HDF5 appends the step's rows to
an in-memory overlay of the file (:class:`PendingWrites`), the changed pages are written to the
journal ``.RUN.journal`` with their SHA-256 and ``fsync``-ed (from then on the step is
committed), written into the store under an exclusive lock on it, and the journal is removed. A
crash before the journal is complete leaves the store as it was (an incomplete journal is ignored
and removed); a crash after it leaves a complete journal, which readers lay over the file
(:func:`read_file`) and the next writer applies (:func:`recover_journal`; writing pages is
idempotent). Readers hold a shared lock on the file while they read it, so they see the store
before or after a step, never between. A new layout is written whole by HDF5 to memory
(:func:`netcdf_bytes`), then to a temporary file with plain OS calls (:func:`write_file`) and
moved over the old one. A full disk or a read-only folder is one
:class:`~seqbayes.store.errors.StoreError`. Every read-modify-write holds an exclusive lock on
``RUN.lock`` (:func:`store_lock`). The locks are ``flock`` on POSIX and ``msvcrt.locking`` on
Windows (:func:`lock_file`).

This module knows nothing of what a store holds: :class:`seqbayes.store.base.BaseStore` and its
backends do.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import hashlib
import io
import mmap
import os
import shutil
import signal
import struct
import sys
import threading
import time
from pathlib import Path

import numpy as np

from .errors import StoreError

__all__ = ["FAULT_ENV", "fault", "lock_file", "unlock_file", "store_lock", "os_message", "now", "fsync_dir",
           "plain", "read_file", "bare_dimension", "read_token", "extend", "PendingWrites", "journal_path",
           "read_journal", "recover_journal", "apply_with_journal", "netcdf_bytes", "write_file",
           "check_free_space"]

#: Environment variable naming a fault-injection point (tests only): the process
#: SIGKILLs itself there. One of ``before-write``, ``mid-write`` (the temporary file or the
#: journal half written), ``before-replace`` (complete, not yet in place), ``mid-apply`` (half
#: the journal's pages written into the store), ``after-replace``.
FAULT_ENV = "SEQBAYES_STORE_FAULT"


def fault(point: str) -> None:
    if os.environ.get(FAULT_ENV) == point:  # pragma: no cover - the process dies here
        os.kill(os.getpid(), signal.SIGKILL)


# ------------------------------------------------------------------------- locks
def lock_file(fh: BinaryIO, exclusive: bool = True) -> None:
    """Block until this process holds an advisory lock on the open file ``fh``.

    POSIX: ``flock`` (shared or exclusive, released when ``fh`` is closed or by
    :func:`unlock_file`). Windows: ``msvcrt.locking`` of one byte far beyond any
    run store's end (Windows locks are mandatory, so a lock on the content would block
    readers of it), always exclusive, retried every 10 ms.
    """
    if os.name == "nt":  # pragma: no cover - exercised on Windows only
        import msvcrt

        fh.seek(_WINDOWS_LOCK_OFFSET)
        while True:
            try:
                msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)
                return
            except OSError:
                time.sleep(0.01)
    import fcntl

    fcntl.flock(fh.fileno(), fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)


def unlock_file(fh) -> None:
    """Release :func:`lock_file`'s lock on ``fh``."""
    if os.name == "nt":  # pragma: no cover - exercised on Windows only
        import msvcrt

        fh.seek(_WINDOWS_LOCK_OFFSET)
        msvcrt.locking(fh.fileno(), msvcrt.LK_UNLCK, 1)
        return
    import fcntl

    fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


_WINDOWS_LOCK_OFFSET = 2 ** 40
_LOCKS: dict = {}                      # resolved lock path -> [threading.RLock, depth, open lock file]
_LOCKS_GUARD = threading.Lock()


@contextlib.contextmanager
def store_lock(path: str | os.PathLike) -> Iterator[None]:
    """Exclusive advisory lock on ``<path>.lock`` (:func:`lock_file`), held for a read-modify-write.

    Re-entrant within a process (the CLI holds it around :meth:`RunStore.assimilate`, which
    takes it too) and exclusive between threads and between processes. The lock file
    stays (removing it would let two processes lock two different files).

    Raises
    ------
    StoreError
        The lock file cannot be created (a read-only folder, ...).
    """
    lock_path = str(path) + ".lock"
    key = os.path.abspath(lock_path)
    with _LOCKS_GUARD:
        entry = _LOCKS.setdefault(key, [threading.RLock(), 0, None])
    with entry[0]:
        if entry[1] == 0:
            try:
                fh = open(lock_path, "a+b")
            except OSError as err:
                raise StoreError(f"{path}: cannot take the lock {lock_path}: {os_message(err)}") from None
            lock_file(fh)
            entry[2] = fh
        entry[1] += 1
        try:
            yield
        finally:
            entry[1] -= 1
            if entry[1] == 0:
                fh, entry[2] = entry[2], None
                unlock_file(fh)
                fh.close()


def os_message(err: OSError) -> str:
    """``strerror`` (and the file, when the error names one) of an OS error, for one-line messages."""
    text = err.strerror or str(err)
    return f"{text} ({err.filename})" if err.filename else text


def now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


# -------------------------------------------------------------------------- reading
_NETCDF3 = (b"CDF\x01", b"CDF\x02", b"CDF\x05")
_HDF5 = b"\x89HDF\r\n\x1a\n"


def plain(value):
    """An HDF5 attribute as a Python value (text attributes may come back as bytes)."""
    if isinstance(value, (bytes, np.bytes_)):
        return value.decode("utf-8", "replace")
    if isinstance(value, np.ndarray) and value.shape == (1,):   # h5netcdf writes numbers as 1-element arrays
        return value[0]
    return value


def read_file(path: Path) -> tuple[dict, dict]:
    """``(attributes, variables)`` of the store: every variable read whole (text as ``str``), under a
    shared lock on the file and through a committed journal; a :class:`StoreError` for anything that
    is not a readable run store."""
    import h5py

    if path.is_dir():
        raise StoreError(f"{path}: is a folder, not a run store")
    if not path.is_file():
        raise StoreError(f"{path}: no such run store (create one with `seqbayes init CONFIG {path}`)")
    try:
        with open(path, "rb") as fh:
            head = fh.read(8)
            if head[:4] in _NETCDF3:
                raise StoreError(f"{path}: a NetCDF-3 (classic) file; run stores are NetCDF-4 (HDF5) files written "
                                 f"by `seqbayes init`, so this is not a run store")
            if head != _HDF5:
                raise StoreError(f"{path}: not a run store (not a NetCDF-4/HDF5 file)")
            with contextlib.suppress(OSError):   # a filesystem without locks: read unlocked
                lock_file(fh, exclusive=False)
            journal = read_journal(path)
            # HDF5 reads the file itself (faster than through Python) unless a journal is laid over it;
            # the shared lock taken on fh holds either way
            source = PendingWrites(fh, journal) if journal is not None else path
            with h5py.File(source, "r") as f:
                attrs = {key: plain(value) for key, value in f.attrs.items()}
                variables = {}
                for name, obj in f.items():
                    if not isinstance(obj, h5py.Dataset) or bare_dimension(obj):
                        continue
                    variables[name] = obj.asstr()[()] if h5py.check_string_dtype(obj.dtype) else obj[()]
    except StoreError:
        raise
    except OSError as err:
        if err.errno is not None:
            raise StoreError(f"{path}: cannot read the run store: {os_message(err)}") from None
        raise StoreError(f"{path}: cannot read the run store: {err}{_checksum_hint(err)}") from None
    except Exception as err:
        raise StoreError(f"{path}: cannot read the run store: {type(err).__name__}: {err}{_checksum_hint(err)}") from None
    return attrs, variables


def bare_dimension(dataset) -> bool:
    """Whether an HDF5 dataset is a NetCDF-4 dimension without coordinates (it holds no data). Those
    are float32, which no store variable is, so only they have their attributes read (slow in h5py)."""
    return (dataset.dtype.kind == "f" and dataset.dtype.itemsize == 4
            and str(plain(dataset.attrs.get("NAME", b""))).startswith("This is a netCDF dimension but not"))


def _checksum_hint(err) -> str:
    text = str(err).lower()
    return "; a checksum failed: the file is corrupted" if "filter" in text or "checksum" in text else ""


def read_token(path: Path):
    """``(content hash, n_steps)`` of the file as it is on disk (``None`` if it cannot be read)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return plain(f.attrs.get("content_sha256")), int(plain(f.attrs["n_steps"]))
    except Exception:
        return None


def extend(dataset, n: int, values=None) -> None:
    """Grow an HDF5 dataset by ``n`` rows along its first axis and write ``values`` there."""
    old = dataset.shape[0]
    dataset.resize(old + n, axis=0)
    if values is not None:
        dataset[old:] = values


def _pread(fd: int, n: int, offset: int) -> bytes:
    """``os.pread``, or seek and read where it does not exist (Windows; the descriptor is this module's own)."""
    if hasattr(os, "pread"):
        return os.pread(fd, n, offset)
    os.lseek(fd, offset, os.SEEK_SET)  # pragma: no cover - Windows
    return os.read(fd, n)  # pragma: no cover - Windows


def _pwrite(fd: int, data, offset: int) -> int:
    """``os.pwrite``, or seek and write where it does not exist (Windows)."""
    if hasattr(os, "pwrite"):
        return os.pwrite(fd, data, offset)
    os.lseek(fd, offset, os.SEEK_SET)  # pragma: no cover - Windows
    return os.write(fd, data)  # pragma: no cover - Windows


class PendingWrites(io.RawIOBase):
    """The file HDF5 appends to, or reads: reads come from the file with pending pages laid over
    them, writes stay in memory (the pages then go to the journal, :func:`apply_with_journal`).
    So a full disk or an I/O error is an OSError raised by plain OS calls, never inside HDF5
    (where ENOSPC crashed the process). With ``journal`` (:func:`read_journal`) it is the file as a
    committed journal makes it."""

    PAGE = 1 << 12                              # the journal holds whole pages: small ones keep it small

    def __init__(self, fh, journal=None):
        self.fd = fh.fileno()
        self.size = os.fstat(self.fd).st_size       # the logical size
        self.on_disk = self.size                    # bytes of the file below which the disk content is valid
        self.pages = {}
        self.pos = 0
        if journal is not None:
            self.on_disk, self.size, pages = journal
            self.pages = {offset // self.PAGE: bytearray(data.ljust(self.PAGE, b"\0")) for offset, data in pages}

    def readable(self):
        return True

    def writable(self):
        return True

    def seekable(self):
        return True

    def seek(self, offset, whence=io.SEEK_SET):
        self.pos = {io.SEEK_SET: 0, io.SEEK_CUR: self.pos, io.SEEK_END: self.size}[whence] + offset
        return self.pos

    def tell(self):
        return self.pos

    def _disk(self, start, length) -> bytes:
        valid = max(0, min(length, self.on_disk - start))
        data = _pread(self.fd, valid, start) if valid else b""
        return data.ljust(length, b"\0")

    def readinto(self, buffer):
        view = memoryview(buffer).cast("B")
        n = max(0, min(len(view), self.size - self.pos))
        done = 0
        while done < n:
            index, offset = divmod(self.pos + done, self.PAGE)
            take = min(self.PAGE - offset, n - done)
            page = self.pages.get(index)
            view[done:done + take] = (page[offset:offset + take] if page is not None
                                      else self._disk(self.pos + done, take))
            done += take
        self.pos += n
        return n

    def write(self, data):
        view = memoryview(data).cast("B")
        done = 0
        while done < len(view):
            index, offset = divmod(self.pos + done, self.PAGE)
            take = min(self.PAGE - offset, len(view) - done)
            page = self.pages.get(index)
            if page is None:
                page = self.pages[index] = bytearray(self._disk(index * self.PAGE, self.PAGE))
            page[offset:offset + take] = view[done:done + take]
            done += take
        self.pos += len(view)
        self.size = max(self.size, self.pos)
        return len(view)

    def truncate(self, size=None):
        size = self.pos if size is None else size
        if size < self.size:                        # what lies beyond must read as zeros if the file grows again
            self.on_disk = min(self.on_disk, size)
            for index in [i for i in self.pages if i * self.PAGE >= size]:
                del self.pages[index]
            if size // self.PAGE in self.pages:
                page = self.pages[size // self.PAGE]
                page[size % self.PAGE:] = bytes(self.PAGE - size % self.PAGE)
        self.size = size
        return size

    def flush(self):
        pass

    def changes(self) -> list:
        """``[(offset, bytes)]``: every page whose content differs from the file's, within the new size
        (a page below the old size that a truncation zeroed counts too)."""
        old_size = os.fstat(self.fd).st_size
        for index in range(self.on_disk // self.PAGE, (min(old_size, self.size) + self.PAGE - 1) // self.PAGE):
            if index not in self.pages:             # zeros where the file still holds old bytes
                self.pages[index] = bytearray(self._disk(index * self.PAGE, self.PAGE))
        return [(index * self.PAGE, bytes(self.pages[index][:min(self.PAGE, self.size - index * self.PAGE)]))
                for index in sorted(self.pages) if index * self.PAGE < self.size]


# ------------------------------------------------------------------------ the journal
_JOURNAL_MAGIC = b"seqbayes run-store journal 1\n"


def journal_path(path: Path) -> Path:
    return path.parent / f".{path.name}.journal"


def _encode_journal(old_size: int, new_size: int, pages) -> bytes:
    """The journal: magic, ``(old size, new size, page count)``, ``(offset, length, bytes)`` per page, SHA-256."""
    parts = [_JOURNAL_MAGIC, struct.pack("<QQQ", old_size, new_size, len(pages))]
    for offset, data in pages:
        parts += [struct.pack("<QQ", offset, len(data)), data]
    body = b"".join(parts)
    return body + hashlib.sha256(body).digest()


def read_journal(path: Path):
    """``(old size, new size, [(offset, bytes)])`` of a complete journal of the store ``path``, or
    ``None`` when there is none or it is incomplete (torn by a crash while it was written: then the
    store was not touched)."""
    try:
        content = journal_path(path).read_bytes()
    except OSError:
        return None
    body, digest = content[:-32], content[-32:]
    if not body.startswith(_JOURNAL_MAGIC) or hashlib.sha256(body).digest() != digest:
        return None
    pos = len(_JOURNAL_MAGIC)
    old_size, new_size, count = struct.unpack_from("<QQQ", body, pos)
    pos += 24
    pages = []
    for _ in range(count):
        offset, length = struct.unpack_from("<QQ", body, pos)
        pos += 16
        pages.append((offset, body[pos:pos + length]))
        pos += length
    return old_size, new_size, pages


def _apply_pages(path: Path, journal, inject_fault: bool = False) -> None:
    """Write a journal's pages into the store and set its size, under an exclusive lock on it, then
    ``fsync`` (idempotent: a second application after a crash in the first gives the same file).

    Where the filesystem takes it, the pages go with ``O_DIRECT`` (one aligned buffer, a partial last
    page padded with zeros before the size is set): a buffered write of 4 KiB into a page-cache folio
    that readahead made large sends the whole folio to the disk, so the bytes reaching the disk
    would grow with the store."""
    _, new_size, pages = journal
    with open(path, "r+b") as fh:
        lock_file(fh, exclusive=True)
        direct = _direct_fd(path)
        fd = fh.fileno() if direct is None else direct
        try:
            buffer = mmap.mmap(-1, PendingWrites.PAGE) if direct is not None else None
            for i, (offset, data) in enumerate(pages):
                if inject_fault and i == len(pages) // 2:
                    fault("mid-apply")
                view = memoryview(data)
                if buffer is not None:             # a page (the last may be shorter), aligned for O_DIRECT
                    buffer[:len(data)] = data
                    buffer[len(data):] = bytes(len(buffer) - len(data))
                    view = memoryview(buffer)
                while view:
                    written = _pwrite(fd, view, offset)
                    view, offset = view[written:], offset + written
            os.ftruncate(fd, new_size)
            os.fsync(fd)
        finally:
            if direct is not None:
                os.close(direct)
        # the journal goes while readers are still locked out: they never see the store half written
        os.remove(journal_path(path))
        fsync_dir(path.resolve().parent)


def _direct_fd(path: Path):
    """A descriptor of ``path`` opened with ``O_DIRECT``, or None where there is none (tmpfs, Windows, macOS)."""
    if not hasattr(os, "O_DIRECT"):
        return None
    try:
        return os.open(path, os.O_RDWR | os.O_DIRECT)
    except OSError:
        return None


def recover_journal(path: Path) -> None:
    """Under the store's lock: finish a step a crash left in a complete journal, or drop an incomplete one."""
    journal_file = journal_path(path)
    if not journal_file.exists():
        return
    journal = read_journal(path)
    try:
        if journal is None or not path.exists():
            os.remove(journal_file)
        else:
            _apply_pages(path, journal)
    except OSError as err:
        raise StoreError(f"{path}: cannot complete the step left in {journal_file.name} by an interrupted update: "
                         f"{os_message(err)}; readers still see it") from None


def apply_with_journal(path: Path, journal) -> None:
    """Commit the appended pages ``journal = (old size, new size, [(offset, bytes)])``
    (:meth:`PendingWrites.changes`): the store's new size is allocated (``posix_fallocate``,
    so that writing the pages cannot meet a full disk), the journal is written and
    ``fsync``-ed (the step is committed), then its pages are written into the store
    (:func:`_apply_pages`). A failure before the commit restores the store's size: the
    store stays byte-identical."""
    content = _encode_journal(*journal)
    folder = path.resolve().parent
    old_size = os.path.getsize(path)
    check_free_space(path, folder, len(content) + max(0, journal[1] - old_size))
    fault("before-write")
    journal_file = journal_path(path)
    try:
        if journal[1] > old_size and hasattr(os, "posix_fallocate"):
            with open(path, "r+b") as fh:
                os.posix_fallocate(fh.fileno(), 0, journal[1])   # beyond HDF5's end of file: readers ignore it
        if os.environ.get(FAULT_ENV) == "mid-write":  # pragma: no cover - simulate a torn journal
            write_file(journal_file, content[:len(content) // 2])
            fault("mid-write")
        write_file(journal_file, content)
        fsync_dir(folder)
    except OSError as err:
        with contextlib.suppress(OSError):
            os.remove(journal_file)
        with contextlib.suppress(OSError):
            if os.path.getsize(path) != old_size:
                os.truncate(path, old_size)
        raise StoreError(f"{path}: cannot write the run store: {os_message(err)}; the previous store is "
                         f"kept") from None
    fault("before-replace")
    try:
        _apply_pages(path, journal, inject_fault=True)
    except OSError as err:  # an I/O error, not a full disk (the space was allocated)
        raise StoreError(f"{path}: the new step is committed in {journal_file.name} but could not be written into "
                         f"the store: {os_message(err)}; readers see the step, and the next update completes the "
                         f"store once the cause is fixed") from None


def netcdf_bytes(ds, encoding, unlimited_dims=()):
    """The NetCDF-4 file of ``ds`` as bytes. With a Dask client active xarray would take a
    distributed lock named after the target (here a buffer); the write is local, so Dask's
    synchronous scheduler is used for it."""
    kwargs = dict(engine="h5netcdf", encoding=encoding, unlimited_dims=list(unlimited_dims))
    if "dask" in sys.modules:
        import dask

        with dask.config.set(scheduler="synchronous"):
            return ds.to_netcdf(**kwargs)
    return ds.to_netcdf(**kwargs)


def write_file(path: Path, content) -> None:
    """Write ``content`` to a new file ``path`` and ``fsync`` it."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666)
    try:
        view = memoryview(content)
        while view:
            view = view[os.write(fd, view):]
        os.fsync(fd)
    finally:
        os.close(fd)


def check_free_space(path: Path, folder: Path, needed: int) -> None:
    """Refuse a write the folder has no room for (the old file stays until the new one is complete)."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:  # pragma: no cover - no statvfs
        return
    if free < needed:
        raise StoreError(f"{path}: not enough free space in {folder}: about {needed // 1024} KiB needed, "
                         f"{free // 1024} KiB free ({os.strerror(errno.ENOSPC)}); the previous store is kept")


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Iterator
    from typing import BinaryIO
