"""Files written whole or not at all: a temporary file in the target's folder, renamed into
place (``os.replace``, atomic on one file system), so a reader never sees half a file and a
failed write (a full disk, a vanished folder) leaves the previous file as it was and no
temporary behind. Every output of the command line goes through here or through a writer
that does the same (fit-batch's blocks, the tables' exporters)."""

from __future__ import annotations

import os
import tempfile

__all__ = ["write_text_atomic", "write_bytes_atomic"]


def write_bytes_atomic(path, data: bytes) -> None:
    """``data`` to ``path`` through a temporary file beside it, flushed to disk and renamed
    into place; an error (``OSError``) leaves no temporary file."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path)))
    fd, tmp = tempfile.mkstemp(prefix=".tmp-", dir=folder)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def write_text_atomic(path, text: str) -> None:
    """:func:`write_bytes_atomic` of ``text`` in UTF-8."""
    write_bytes_atomic(path, text.encode("utf-8"))
