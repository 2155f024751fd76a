"""Files written whole or not at all: a temporary file in the target's folder, renamed into
place (``os.replace``, atomic on one file system), so a reader never sees half a file and a
failed write (a full disk, a vanished folder) leaves the previous file as it was and no
temporary behind. Every file the package writes goes through here: the command line's
outputs, the fit's exports, glTF files, lookup tables, database parts, fit-batch's blocks and
maps, figures.

The temporary file's name is unique to the write (``tempfile.mkstemp``: ``.NAME.XXXXXXXX.tmp``
plus the target's suffix, so writers that choose the format by extension, as matplotlib and
OpenEXR do, see the right one); two runs never touch each other's temporaries. It gets the
permissions ``open()`` would give a new file (0666 less the umask; ``mkstemp`` makes 0600)."""

from __future__ import annotations

import contextlib
import os
import tempfile

__all__ = ["atomic_path", "write_bytes_atomic", "write_text_atomic", "TEMP_MARK"]

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
    fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=TEMP_MARK + os.path.splitext(name)[1],
                               dir=folder)
    os.close(fd)
    try:
        yield tmp
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except OSError as e:
        if e.errno is None or e.filename not in (None, tmp):
            raise
        # the error names the file the caller asked for, not its temporary stand-in
        raise OSError(e.errno, e.strerror, target) from e
    finally:
        if os.path.lexists(tmp):
            os.unlink(tmp)


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
