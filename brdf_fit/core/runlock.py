"""One run per output folder: an advisory lock (``fcntl.flock``) on a file in the folder.

Two runs on one folder used to work against each other (issue 45): both fitted every block,
and a second ``--resume`` deleted the first run's temporary file mid-write. A run that writes
into a folder holds :func:`hold` for as long as it writes; a second run on the same folder
fails at once with a :class:`FolderBusy` naming the holder's process id. The lock belongs to the
holding process: the kernel releases it when that process ends in any way, so a stale lock
(its holder killed) is simply free and the next run takes it. Advisory: only runs that ask
are kept apart (every command of this package that writes a run folder asks).
"""

from __future__ import annotations

import contextlib
import os

__all__ = ["LOCK_NAME", "FolderBusy", "hold"]

#: the lock file in the folder (it holds the holder's process id, for the message)
LOCK_NAME = ".brdf_fit.lock"


class FolderBusy(RuntimeError):
    """Another process holds the folder's lock: a user error (one line, exit status 2)."""


@contextlib.contextmanager
def hold(folder):
    """Hold ``folder``'s run lock for the ``with`` block (the folder is created if missing);
    raises :class:`FolderBusy` at once when another process holds it."""
    import fcntl

    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, LOCK_NAME)
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
            raise FolderBusy(f"{folder}: another run is writing here (process {holder}); wait "
                             "for it, stop it, or choose another folder") from None
        try:  # the holder's process id, for the message of a second run (not the lock itself)
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
        except OSError:
            pass  # a full disk: the lock holds all the same; a second run says "unknown"
        yield
    finally:
        os.close(fd)  # closing the descriptor releases the lock
