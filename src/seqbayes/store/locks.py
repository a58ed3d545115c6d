"""The locks of a run store, and where its files lie.

Every read-modify-write of a store holds an exclusive lock on ``RUN.nc.lock`` (:func:`store_lock`),
readers a shared lock on the store itself (:func:`lock_file`). The locks are ``flock`` on POSIX and
``msvcrt.locking`` on Windows. The lock file lies beside the store's real file (:func:`target`: a
symbolic link to a store is written through), is never a link followed, has the store's permission
bits (:func:`file_mode`) and, while held, names its holder; a second update waits for it at most
:func:`lock_timeout` seconds, saying who holds it.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import os
import socket
import stat
import sys
import threading
import time
from pathlib import Path

from .errors import StoreError, StoreLockTimeout

__all__ = ["LOCK_TIMEOUT_ENV", "DEFAULT_LOCK_TIMEOUT", "NOFOLLOW", "NONBLOCK", "lock_file", "unlock_file",
           "store_lock", "lock_timeout", "target", "file_mode", "os_message", "now"]

#: Flags of every open of a store's side files: a link is not followed, a FIFO not waited on.
NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
NONBLOCK = getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)


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

#: Environment variable: seconds an update waits for another update's lock before it gives up
#: (default :data:`DEFAULT_LOCK_TIMEOUT`; ``inf`` waits without limit). ``--lock-timeout`` overrides it.
LOCK_TIMEOUT_ENV = "SEQBAYES_LOCK_TIMEOUT"
#: An update queued behind another waits this long: longer than most sampler steps, short enough that a
#: stuck holder does not block a scheduled update for ever.
DEFAULT_LOCK_TIMEOUT = 3600.0


def lock_timeout(value: float | str | None = None) -> float:
    """Seconds to wait for a store's lock: ``value``, else ``$SEQBAYES_LOCK_TIMEOUT``, else
    :data:`DEFAULT_LOCK_TIMEOUT`; ``inf`` waits without limit.

    Raises
    ------
    StoreError
        Not a number >= 0.
    """
    source = "lock timeout"
    if value is None:
        value, source = os.environ.get(LOCK_TIMEOUT_ENV) or DEFAULT_LOCK_TIMEOUT, LOCK_TIMEOUT_ENV
    try:
        seconds = float(value)
    except (TypeError, ValueError):
        seconds = float("nan")
    if not seconds >= 0:
        raise StoreError(f"{source}: expected a number of seconds >= 0 (or inf), got {str(value)[:40]!r}")
    return seconds


def target(path: str | os.PathLike) -> Path:
    """The file a store's path names: a symbolic link is written through to its target (so that the link
    and the file never diverge), and the lock, the journal and temporary files lie beside the target.

    Raises
    ------
    StoreError
        The path is a loop of symbolic links.
    """
    try:
        os.stat(path)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise StoreError(f"{path}: a loop of symbolic links ({os_message(err)}); give the run store's "
                             f"real file name") from None
    return Path(os.path.realpath(path))


def file_mode(path: str | os.PathLike) -> int | None:
    """The permission bits of an existing file (the store's), or None: the lock, journal and temporary
    files take them, so that a private store's new step is private too."""
    try:
        return os.stat(path).st_mode & 0o666
    except OSError:
        return None


def _open_lock(lock_path: Path, store: Path, name) -> BinaryIO:
    """Open (create) the lock file without following a link, with the store's permission bits."""
    flags = os.O_RDWR | NOFOLLOW | NONBLOCK
    try:
        mode = file_mode(store)
        try:   # created private and then given the store's bits (a new store's: the umask's)
            fd = os.open(lock_path, flags | os.O_CREAT | os.O_EXCL, 0o666 if mode is None else 0o600)
            if mode is not None and hasattr(os, "fchmod"):   # not on Windows before Python 3.13
                os.fchmod(fd, mode)
        except FileExistsError:
            fd = os.open(lock_path, flags)
    except OSError as err:
        if err.errno == errno.ELOOP or os.path.islink(lock_path):
            raise StoreError(f"{name}: the lock file {lock_path} is a symbolic link, which seqbayes does not "
                             f"follow (remove it)") from None
        raise StoreError(f"{name}: cannot take the lock {lock_path}: {os_message(err)}") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise StoreError(f"{name}: the lock file {lock_path} is not a regular file (remove it)")
    return os.fdopen(fd, "r+b", buffering=0)   # unbuffered: a full disk fails the holder line, not the close


def _try_lock(fh) -> bool:
    """Take the exclusive lock without waiting; False when another process holds it."""
    if os.name == "nt":  # pragma: no cover - exercised on Windows only
        import msvcrt

        fh.seek(_WINDOWS_LOCK_OFFSET)
        try:
            msvcrt.locking(fh.fileno(), msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False
    import fcntl

    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    return True


def _holder(fh) -> str:
    """Who holds the lock, as its holder wrote it in the lock file (printable text, at most 120 characters)."""
    try:
        fh.seek(0)
        text = fh.read(200).decode("utf-8", "replace")
    except OSError:
        text = ""
    text = "".join(c if c.isprintable() else "?" for c in text.strip())[:120]
    return text or "another process (which did not say who it is)"


def _say_waiting(message: str) -> None:
    print(f"seqbayes: {message}", file=sys.stderr, flush=True)


def _acquire(fh, lock_path: Path, store, timeout: float, notify) -> None:
    """Take the lock on ``fh``, waiting at most ``timeout`` seconds; say once who holds it while waiting."""
    if _try_lock(fh):
        return
    holder = _holder(fh)
    limit = "without limit" if timeout == float("inf") else f"for up to {timeout:g} s"
    if timeout > 0 and notify is not None:
        notify(f"{store}: waiting {limit} for the lock {lock_path.name}, held by {holder}")
    deadline = time.monotonic() + timeout
    while True:
        if time.monotonic() >= deadline:
            raise StoreLockTimeout(f"{store}: gave up after {timeout:g} s waiting for the lock {lock_path}, held by "
                                   f"{_holder(fh)}; the run store is unchanged (--lock-timeout or ${LOCK_TIMEOUT_ENV} "
                                   f"sets how long to wait)")
        time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))
        if _try_lock(fh):
            return


def _write_holder(fh) -> None:
    """Say in the lock file who holds it (a waiting update prints it)."""
    with contextlib.suppress(OSError):
        os.ftruncate(fh.fileno(), 0)
        fh.seek(0)
        fh.write(f"pid {os.getpid()} on host {socket.gethostname()} since {now()}\n".encode())
        fh.flush()


@contextlib.contextmanager
def store_lock(path: str | os.PathLike, *, create: bool = False, timeout: float | None = None,
               notify: Callable[[str], None] | None = _say_waiting) -> Iterator[None]:
    """Exclusive advisory lock on ``<path>.lock`` (:func:`lock_file`), held for a read-modify-write.

    Re-entrant within a process (the CLI holds it around :meth:`RunStore.assimilate`, which
    takes it too) and exclusive between threads and between processes. The lock file
    stays (removing it would let two processes lock two different files); while held it says
    which process holds it. It lies beside the store's real file (:func:`target`), is never
    a link followed, and has the store's permission bits.

    Parameters
    ----------
    path : path-like
        The run store.
    create : bool
        The store is being created; otherwise it must exist (no lock file is left beside a
        store that does not).
    timeout : float, optional
        Seconds to wait for another holder (:func:`lock_timeout`: by default
        ``$SEQBAYES_LOCK_TIMEOUT`` or :data:`DEFAULT_LOCK_TIMEOUT`); 0 does not wait.
    notify : callable, optional
        Called once with a line saying who holds the lock, when it must be waited for
        (default: printed to stderr).

    Raises
    ------
    StoreError
        The store or its folder does not exist, the lock file cannot be created (a read-only
        folder, ...) or is a link; :class:`~seqbayes.store.errors.StoreLockTimeout` when
        ``timeout`` passed.
    """
    timeout = lock_timeout(timeout)
    store = target(path)
    lock_path = store.with_name(store.name + ".lock")
    key = str(lock_path)
    with _LOCKS_GUARD:
        entry = _LOCKS.setdefault(key, [threading.RLock(), 0, None])
    if not entry[0].acquire(timeout=-1 if timeout == float("inf") else timeout):
        raise StoreLockTimeout(f"{path}: gave up after {timeout:g} s waiting for the lock {lock_path}, held by "
                               f"another thread of this process")
    try:
        if entry[1] == 0:
            if not store.parent.is_dir():
                raise StoreError(f"{path}: the folder {store.parent} does not exist")
            if not create and not os.path.lexists(store):
                raise StoreError(f"{path}: no such run store (create one with `seqbayes init CONFIG {path}`)")
            fh = _open_lock(lock_path, store, path)
            try:
                _acquire(fh, lock_path, path, timeout, notify)
            except BaseException:
                fh.close()
                raise
            _write_holder(fh)
            entry[2] = fh
        entry[1] += 1
        try:
            yield
        finally:
            entry[1] -= 1
            if entry[1] == 0:
                fh, entry[2] = entry[2], None
                with contextlib.suppress(OSError):
                    os.ftruncate(fh.fileno(), 0)   # before the unlock: never erase the next holder's line
                unlock_file(fh)
                fh.close()
    finally:
        entry[0].release()


def os_message(err: OSError) -> str:
    """``strerror`` (and the file, when the error names one) of an OS error, for one-line messages."""
    text = err.strerror or str(err)
    return f"{text} ({err.filename})" if err.filename else text


def now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")




import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable, Iterator
    from typing import BinaryIO
