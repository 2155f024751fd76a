"""Files written whole or not at all: a temporary file in the target's folder, renamed into
place (``os.replace``, atomic on one file system), so a reader never sees half a file and a
failed write (a full disk, a vanished folder) leaves the previous file as it was and no
temporary behind. Every file the package writes goes through here: the command line's
outputs, the fit's exports, glTF files, lookup tables, database parts, fit-batch's blocks and
maps, figures.

The temporary file's name is unique to the write (created with ``O_EXCL``:
``.NAME.PID-XXXXXXXX.tmp`` plus the target's suffix, so writers that choose the format by
extension, as matplotlib and OpenEXR do, see the right one); two runs never touch each other's
temporaries. The writer's process id in the name lets whoever killed a writer (a launcher's
SIGKILL, which no cleanup survives) remove what it left: :func:`remove_leftovers`. A stop
(SIGINT, SIGTERM) that arrives while the temporary is being created is held back until its name
is known to the cleanup, so a stopped command leaves none either. It gets the
permissions ``open()`` would give a new file (0666 less the umask; it is created 0600)."""

from __future__ import annotations

import contextlib
import os
import secrets

__all__ = ["atomic_path", "write_bytes_atomic", "write_text_atomic", "remove_leftovers",
           "TEMP_MARK"]

#: how a temporary file is created (``os.open``; a name the tests replace to stop a write there)
_open = os.open

#: names tried for a temporary file before giving up (each is 8 random hex digits)
TEMP_TRIES = 100

#: what every temporary file's name contains (after the target's name): a folder's leftovers
#: of a killed run are ``.NAME.*.tmp*``
TEMP_MARK = ".tmp"


def _umask() -> int:
    """The process's umask (read by setting it and restoring it at once)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path):
    """Yield the path of a new temporary file beside ``path`` (same folder, same suffix) for the
    caller to write; on a normal exit it is given the usual file permissions and renamed onto
    ``path``; on any exception it is removed and the exception propagates (``path`` untouched;
    an ``OSError`` about the temporary file is raised again naming ``path``)."""
    target = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(target))
    name = os.path.basename(target)
    tmp = None
    try:
        # the temporary's name is known to the cleanup below from the moment the file exists:
        # a stop (KeyboardInterrupt, the CLI's Terminated) can land at any call, and one that
        # landed inside tempfile.mkstemp after it had created the file, before its name came
        # back, left the file behind (a fit-batch run stopped by SIGINT, once in the slow set)
        with _stops_held():
            tmp = _create_temporary(folder, name)
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except OSError as e:
        if e.errno is None or e.filename not in (None, tmp):
            raise
        # the error names the file the caller asked for, not its temporary stand-in
        raise OSError(e.errno, e.strerror, target) from e
    finally:
        if tmp is not None and os.path.lexists(tmp):
            os.unlink(tmp)


@contextlib.contextmanager
def _stops_held():
    """SIGINT and SIGTERM held back (``pthread_sigmask``) while the body runs and delivered when
    it ends: a stop that arrives meanwhile is raised after it, by when the caller has stored
    what it must clean up. A stop already caught before the mask took effect is raised at the
    mask call's return, before the body starts. Where there is no ``pthread_sigmask``
    (Windows), nothing is held."""
    import signal

    held = {signal.SIGINT, signal.SIGTERM}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    except (AttributeError, ValueError, OSError):
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _create_temporary(folder: str, name: str) -> str:
    """A new empty file ``.NAME.PID-XXXXXXXX.tmp<suffix>`` in ``folder`` (``O_EXCL``: never
    another writer's), its path."""
    suffix = TEMP_MARK + os.path.splitext(name)[1]
    for _ in range(TEMP_TRIES):
        candidate = os.path.join(folder,
                                 f".{name}.{os.getpid()}-{secrets.token_hex(4)}{suffix}")
        try:
            fd = _open(candidate, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o600)
        except FileExistsError:
            continue
        os.close(fd)
        return candidate
    raise FileExistsError(f"no unused temporary name for {name} in {folder}")


def write_bytes_atomic(path, data: bytes) -> None:
    """``data`` to ``path`` through :func:`atomic_path`, flushed to disk before the rename; an
    error (``OSError``) leaves no temporary file."""
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def write_text_atomic(path, text: str) -> None:
    """:func:`write_bytes_atomic` of ``text`` in UTF-8."""
    write_bytes_atomic(path, text.encode("utf-8"))


def remove_leftovers(folder, pids) -> list[str]:
    """Remove from ``folder`` the temporary files that the processes ``pids`` were writing
    when they ended (``.*.PID-*.tmp*``), and return their names. For a process that cannot have
    cleaned up, one ended by SIGKILL, and only once it has ended: a live writer's temporary is
    its file being written. A missing folder has none."""
    import glob

    removed = []
    for pid in pids:
        pattern = os.path.join(glob.escape(os.fspath(folder)), f".*.{int(pid)}-*{TEMP_MARK}*")
        for leftover in glob.glob(pattern, include_hidden=True):
            try:
                os.unlink(leftover)
            except FileNotFoundError:
                continue
            removed.append(os.path.basename(leftover))
    return sorted(removed)
