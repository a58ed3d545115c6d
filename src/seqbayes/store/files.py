"""The file machinery under every run store: the redo journal, whole-file writes, reads (and, from
:mod:`seqbayes.store.locks`, the locks).

A run store is one NetCDF-4 (HDF5) file. Writes are atomic, and an update writes only what it
adds. A new step is appended in place, through a redo journal: HDF5 appends the step's rows to
an in-memory overlay of the file (:class:`PendingWrites`), the changed pages are written to the
journal ``.RUN.nc.journal`` with their SHA-256 and ``fsync``-ed (from then on the step is
committed), written into the store under an exclusive lock on it, and the journal is removed. A
crash before the journal is complete leaves the store as it was (an incomplete journal is ignored
and removed); a crash after it leaves a complete journal, which the next seqbayes command that
opens the store writes into it (:func:`complete_journal`, as SQLite's next reader does with a hot
journal; writing pages is idempotent), so that other programs read the file whole again. Readers
hold a shared lock on the file while they read it, so they see the store before or after a step,
never between; one that may not write the store lays the journal over it. The journal is read only
if it is a regular file of bounded size, opened without following a link. A new layout is
written whole by HDF5 to memory (:func:`netcdf_bytes`), then to a temporary file with plain OS
calls (:func:`write_file`) and moved over the old one. The journal, the lock and temporary files
take the store's permission bits. A full disk or a read-only folder is one
:class:`~seqbayes.store.errors.StoreError`. Every read-modify-write holds an exclusive lock on
``RUN.nc.lock`` (:func:`store_lock`).

This module knows nothing of what a store holds: :class:`seqbayes.store.base.BaseStore` and its
backends do.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import mmap
import os
import shutil
import signal
import stat
import struct
import sys
from pathlib import Path

import numpy as np

from .errors import StoreError, StoreLockTimeout, StoreWarning
from .locks import (LOCK_TIMEOUT_ENV, NOFOLLOW, NONBLOCK, file_mode, lock_file, lock_timeout, now, os_message,
                    store_lock, target, unlock_file)

__all__ = ["FAULT_ENV", "LOCK_TIMEOUT_ENV", "fault", "lock_file", "unlock_file", "store_lock", "lock_timeout",
           "os_message", "now", "fsync_dir", "target", "file_mode", "plain", "read_file", "bare_dimension",
           "read_token", "extend", "PendingWrites", "journal_path", "read_journal", "recover_journal",
           "complete_journal", "apply_with_journal", "netcdf_bytes", "write_file", "check_free_space"]

#: Environment variable naming a fault-injection point (tests only): the process
#: SIGKILLs itself there. One of ``before-write``, ``mid-write`` (the temporary file or the
#: journal half written), ``before-replace`` (complete, not yet in place), ``mid-apply`` (half
#: the journal's pages written into the store), ``after-replace``.
FAULT_ENV = "SEQBAYES_STORE_FAULT"


def fault(point: str) -> None:
    if os.environ.get(FAULT_ENV) == point:  # pragma: no cover - the process dies here
        os.kill(os.getpid(), signal.SIGKILL)


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
    is not a readable run store.

    A committed journal an interrupted update left is first written into the store
    (:func:`complete_journal`), so that other programs read the file whole again. No variable is
    read whose declared size exceeds what the file can hold (a crafted header cannot make a
    read allocate gigabytes)."""
    import h5py

    if path.is_dir():
        raise StoreError(f"{path}: is a folder, not a run store")
    target(path)
    if not path.is_file():
        if os.path.lexists(path) and not os.path.islink(path):
            raise StoreError(f"{path}: not a regular file, so not a run store")
        raise StoreError(f"{path}: no such run store (create one with `seqbayes init CONFIG {path}`)")
    complete_journal(path)
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
            size = journal[1] if journal is not None else os.fstat(fh.fileno()).st_size
            with h5py.File(source, "r") as f:
                attrs = {key: plain(value) for key, value in f.attrs.items()}
                datasets = {name: obj for name, obj in f.items()
                            if isinstance(obj, h5py.Dataset) and not bare_dimension(obj)}
                _check_declared(path, datasets, size)
                variables = {name: obj.asstr()[()] if h5py.check_string_dtype(obj.dtype) else obj[()]
                             for name, obj in datasets.items()}
    except StoreError:
        raise
    except OSError as err:
        if err.errno is not None:
            raise StoreError(f"{path}: cannot read the run store: {os_message(err)}") from None
        raise StoreError(f"{path}: cannot read the run store: {err}{_checksum_hint(err)}") from None
    except Exception as err:
        raise StoreError(f"{path}: cannot read the run store: {type(err).__name__}: {err}{_checksum_hint(err)}") from None
    return attrs, variables


def _check_declared(path: Path, datasets: dict, size: int) -> None:
    """Refuse variables whose declared sizes add up to more than the file holds: a store's arrays are
    written whole and uncompressed, so an honest store's add up to less (text variables declare 8 bytes
    per string, less than HDF5 stores for each)."""
    declared = {name: obj.size * obj.dtype.itemsize for name, obj in datasets.items()}
    if sum(declared.values()) > size:
        name = max(declared, key=declared.get)
        raise StoreError(f"{path}: damaged run store: its variables declare {sum(declared.values()):,} bytes "
                         f"({name!r} alone {tuple(datasets[name].shape)}, {declared[name]:,} bytes), more than the "
                         f"whole file of {size:,} bytes holds; nothing was read")


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
    """``.RUN.nc.journal`` beside the store's real file (:func:`target`)."""
    store = Path(os.path.realpath(path))
    return store.parent / f".{store.name}.journal"


def _encode_journal(old_size: int, new_size: int, pages) -> bytes:
    """The journal: magic, ``(old size, new size, page count)``, ``(offset, length, bytes)`` per page, SHA-256."""
    parts = [_JOURNAL_MAGIC, struct.pack("<QQQ", old_size, new_size, len(pages))]
    for offset, data in pages:
        parts += [struct.pack("<QQ", offset, len(data)), data]
    body = b"".join(parts)
    return body + hashlib.sha256(body).digest()


_JOURNAL_HEAD = len(_JOURNAL_MAGIC) + 24
#: slack of a journal's size over twice the store's (on filesystems without posix_fallocate the store is
#: not yet grown when the journal is written)
_JOURNAL_SLACK = 64 << 20


def _read_regular(file: Path, limit: int) -> bytes | None:
    """The bytes of ``file`` if it is a regular file of at most ``limit`` bytes, opened without following
    a link (a FIFO, a device or a link to /dev/zero is never read), else None."""
    try:
        fd = os.open(file, os.O_RDONLY | NOFOLLOW | NONBLOCK)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size > limit:
            return None
        parts, left = [], st.st_size
        while left > 0:
            chunk = os.read(fd, min(left, 1 << 24))
            if not chunk:
                break
            parts.append(chunk)
            left -= len(chunk)
        return b"".join(parts)
    except OSError:
        return None
    finally:
        os.close(fd)


def read_journal(path: Path):
    """``(old size, new size, [(offset, bytes)])`` of a complete journal of the store ``path``, or
    ``None`` when there is none, it is incomplete (torn by a crash while it was written: then the
    store was not touched), or it is not a journal: not a regular file (a link is not followed,
    a FIFO not opened for long), larger than twice the store plus 64 MiB, or with pages outside
    its declared size."""
    try:
        store_size = os.stat(path).st_size
    except OSError:
        return None
    content = _read_regular(journal_path(path), 2 * store_size + _JOURNAL_SLACK)
    if content is None or len(content) < _JOURNAL_HEAD + 32:
        return None
    body, digest = content[:-32], content[-32:]
    if not body.startswith(_JOURNAL_MAGIC) or hashlib.sha256(body).digest() != digest:
        return None
    pos = len(_JOURNAL_MAGIC)
    old_size, new_size, count = struct.unpack_from("<QQQ", body, pos)
    pos += 24
    if count > (len(body) - pos) // 16:
        return None
    pages = []
    for _ in range(count):
        if pos + 16 > len(body):
            return None
        offset, length = struct.unpack_from("<QQ", body, pos)
        pos += 16
        if offset % PendingWrites.PAGE or length > PendingWrites.PAGE or offset + length > new_size \
                or pos + length > len(body):
            return None
        pages.append((offset, body[pos:pos + length]))
        pos += length
    return (old_size, new_size, pages) if pos == len(body) else None


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
        fsync_dir(journal_path(path).parent)


def _direct_fd(path: Path):
    """A descriptor of ``path`` opened with ``O_DIRECT``, or None where there is none (tmpfs, Windows, macOS)."""
    if not hasattr(os, "O_DIRECT"):
        return None
    try:
        return os.open(path, os.O_RDWR | os.O_DIRECT)
    except OSError:
        return None


def recover_journal(path: Path) -> None:
    """Under the store's lock: finish a step a crash left in a complete journal, or drop an incomplete one
    (or anything else in the journal's place: a link or a FIFO is removed itself, never followed)."""
    journal_file = journal_path(path)
    if not os.path.lexists(journal_file):
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


def complete_journal(path: Path) -> None:
    """Write a committed journal into the store when opening it, as SQLite's next reader does with a hot
    journal: afterwards xarray, ncdump and MATLAB read the file whole again, not only seqbayes (which
    lays the journal over it).

    Skipped while an update holds the store's lock (it completes the journal itself). A store this
    process may not write keeps its journal, and a :class:`~seqbayes.store.errors.StoreWarning` says so
    in one line; readers still see the step."""
    journal_file = journal_path(path)
    if not os.path.lexists(journal_file):
        return
    folder = journal_file.parent
    if not (os.access(path, os.R_OK | os.W_OK) and os.access(folder, os.W_OK | os.X_OK)):
        if read_journal(path) is not None:
            _warn_unwritten(path, journal_file, "no permission to write the store or its folder")
        return
    try:
        with store_lock(path, timeout=0, notify=None):
            recover_journal(path)
    except StoreLockTimeout:
        return
    except StoreError as err:
        if read_journal(path) is not None:
            _warn_unwritten(path, journal_file, str(err).split(": ")[-1])


def _warn_unwritten(path: Path, journal_file: Path, why: str) -> None:
    import warnings

    warnings.warn(f"{path}: read with the step an interrupted update left in {journal_file.name}, which could not "
                  f"be written into the store ({why}); until a seqbayes command that may write the store opens it, "
                  f"other programs (xarray, ncdump) read it without that step, or not at all", StoreWarning,
                  stacklevel=3)


def apply_with_journal(path: Path, journal) -> None:
    """Commit the appended pages ``journal = (old size, new size, [(offset, bytes)])``
    (:meth:`PendingWrites.changes`): the store's new size is allocated (``posix_fallocate``,
    so that writing the pages cannot meet a full disk), the journal is written and
    ``fsync``-ed (the step is committed), then its pages are written into the store
    (:func:`_apply_pages`). A failure before the commit restores the store's size: the
    store stays byte-identical."""
    content = _encode_journal(*journal)
    folder = target(path).parent
    old_size = os.path.getsize(path)
    check_free_space(path, folder, len(content) + max(0, journal[1] - old_size))
    fault("before-write")
    journal_file = journal_path(path)
    try:
        if journal[1] > old_size and hasattr(os, "posix_fallocate"):
            with open(path, "r+b") as fh:
                os.posix_fallocate(fh.fileno(), 0, journal[1])   # beyond HDF5's end of file: readers ignore it
        if os.environ.get(FAULT_ENV) == "mid-write":  # pragma: no cover - simulate a torn journal
            write_file(journal_file, content[:len(content) // 2], mode=file_mode(path))
            fault("mid-write")
        write_file(journal_file, content, mode=file_mode(path))
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


def write_file(path: Path, content, mode: int | None = None) -> None:
    """Write ``content`` to a new file ``path`` and ``fsync`` it; a link in its place is not followed (an
    error). With ``mode`` (the store's :func:`file_mode`) the file has those permission bits before
    anything is written to it, else the umask's."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | NOFOLLOW | NONBLOCK,
                 0o666 if mode is None else 0o600)
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise OSError(errno.EINVAL, "not a regular file", str(path))
        if mode is not None and hasattr(os, "fchmod"):   # not on Windows before Python 3.13
            os.fchmod(fd, mode)
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

