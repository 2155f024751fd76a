"""brdf_fit.core.atomic: a file is written whole or not at all, and no temporary is left behind,
whatever ends the write: an error in the caller's body, or a stop (SIGINT) arriving the moment
the temporary file has been created (held back until its name is known to the cleanup)."""

import contextlib
import os
import signal

import pytest

from brdf_fit.core import atomic


def _files(folder):
    return sorted(p.name for p in folder.iterdir())


def test_written_whole(tmp_path):
    atomic.write_text_atomic(tmp_path / "a.txt", "one")
    atomic.write_text_atomic(tmp_path / "a.txt", "two")
    assert (tmp_path / "a.txt").read_text() == "two" and _files(tmp_path) == ["a.txt"]


def test_an_error_leaves_the_old_file_and_no_temporary(tmp_path):
    atomic.write_text_atomic(tmp_path / "a.txt", "one")
    with pytest.raises(RuntimeError), atomic.atomic_path(tmp_path / "a.txt") as tmp:
        with open(tmp, "w") as fh:
            fh.write("half")
        raise RuntimeError("the caller failed")
    assert (tmp_path / "a.txt").read_text() == "one" and _files(tmp_path) == ["a.txt"]


@contextlib.contextmanager
def _sigint_raises():
    """SIGINT as a terminal gives it (a suite started in the background has it ignored)."""
    old = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _stop_once_created(monkeypatch):
    real = atomic._open

    def open_then_stop(*args, **kwargs):
        fd = real(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)  # the file exists; its name is not stored yet
        return fd

    monkeypatch.setattr(atomic, "_open", open_then_stop)


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="no pthread_sigmask here")
def test_a_stop_at_creation_leaves_no_temporary(tmp_path, monkeypatch):
    _stop_once_created(monkeypatch)
    body = []
    with _sigint_raises(), pytest.raises(KeyboardInterrupt):
        with atomic.atomic_path(tmp_path / "b.npz"):
            body.append(1)
    assert _files(tmp_path) == [] and body == []


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="no pthread_sigmask here")
def test_without_the_hold_that_stop_leaves_it(tmp_path, monkeypatch):
    """The negative control: the same stop with SIGINT not held leaves the temporary file (what
    the slow set saw once from a fit-batch run stopped by SIGINT)."""
    _stop_once_created(monkeypatch)
    monkeypatch.setattr(atomic, "_stops_held", contextlib.nullcontext)
    with _sigint_raises(), pytest.raises(KeyboardInterrupt):
        with atomic.atomic_path(tmp_path / "b.npz"):
            pass
    left = _files(tmp_path)
    assert len(left) == 1 and left[0].startswith(".b.npz.") and atomic.TEMP_MARK in left[0]
    os.unlink(tmp_path / left[0])


_WRITER = """
import signal, sys, time
from brdf_fit.core.atomic import atomic_path
signal.signal(signal.SIGTERM, signal.SIG_IGN)  # a process that does not answer its launcher
with atomic_path(sys.argv[1]) as tmp:
    print(tmp, flush=True)
    time.sleep(600)
"""


@pytest.mark.parametrize("sweep", [True, False])
def test_a_killed_writers_temporary_is_removed_by_its_launcher(tmp_path, monkeypatch, sweep):
    """A writer that outlives its launcher's grace time is killed (SIGKILL) inside
    ``atomic_path``: nothing of it runs to remove its temporary, so the launcher's
    ``stop_children`` does, in the folders it is given, and only the killed process's (another
    writer's temporary and the folder's files are kept). Negative control (``sweep=False``): the
    temporary stays (a fit-batch --processes run stopped by SIGTERM left one in the CI run of
    2026-12-07)."""
    import subprocess
    import sys

    from brdf_fit.cli import _processes

    monkeypatch.setattr(_processes, "STOP_GRACE_S", 0.5)
    (tmp_path / "kept.txt").write_text("kept")
    with atomic.atomic_path(tmp_path / "mine.npz") as mine:  # a live writer's, this process's
        p = subprocess.Popen([sys.executable, "-c", _WRITER, str(tmp_path / "block_000001.npz")],
                             stdout=subprocess.PIPE, text=True)
        theirs = p.stdout.readline().strip()
        assert os.path.exists(theirs) and f".{p.pid}-" in os.path.basename(theirs)
        _processes.stop_children([p], folders=[tmp_path] if sweep else [])
        p.stdout.close()
        assert p.returncode == -signal.SIGKILL
        left = _files(tmp_path)
        expected = ["kept.txt", os.path.basename(mine)]
        assert left == sorted(expected if sweep else [*expected, os.path.basename(theirs)])
    assert atomic.remove_leftovers(tmp_path / "missing", [p.pid]) == []
