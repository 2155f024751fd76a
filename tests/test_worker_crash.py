"""tests/conftest.py's handling of a test that crashes its pytest-xdist worker: the first crash
is a rerun in a fresh worker (which must then pass), a second crash is the test's failure, and
an assertion's failure is never rerun. Runs pytest on a folder of its own (this conftest, three
small test files) with two workers and ``--dist loadfile``, as the Makefile does."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

CRASH_ONCE = """
import os, signal, pathlib
MARK = pathlib.Path(__file__).with_name("crashed_once")

def test_crashes_once():
    if not MARK.exists():
        MARK.write_text("crashed")
        os.kill(os.getpid(), signal.SIGSEGV)

def test_after_it():
    pass
"""

CRASH_ALWAYS = """
import os, signal, pathlib

def test_crashes_always():
    (pathlib.Path(__file__).parent / "crashing_runs").open("a").write("x")
    os.kill(os.getpid(), signal.SIGSEGV)
"""

QUICK = """
import time, pytest

@pytest.mark.parametrize("k", range(4))
def test_quick(k):
    time.sleep(0.02)
"""

FAILS = """
import pathlib

def test_fails():
    (pathlib.Path(__file__).parent / "failed_runs").open("a").write("x")
    assert False, "an assertion"
"""


def _pytest(folder: Path, *files: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "2",
         "--dist", "loadfile", "--max-worker-restart", "2", "-o", "addopts=", *files],
        cwd=folder, capture_output=True, text=True, timeout=timeout)


@pytest.mark.slow
def test_a_crash_runs_again_once_and_a_failure_never(tmp_path):
    shutil.copy(Path(__file__).with_name("conftest.py"), tmp_path / "conftest.py")
    (tmp_path / "test_crash_once.py").write_text(CRASH_ONCE)
    (tmp_path / "test_crash_always.py").write_text(CRASH_ALWAYS)
    (tmp_path / "test_fails.py").write_text(FAILS)

    once = _pytest(tmp_path, "test_crash_once.py")
    assert once.returncode == 0, once.stdout[-3000:]
    assert "2 passed, 1 rerun" in once.stdout, once.stdout[-3000:]
    assert "RERUN test_crash_once.py::test_crashes_once" in once.stdout

    # negative controls: the same hook does not hide a test that crashes every time, nor
    # run an assertion's failure again
    always = _pytest(tmp_path, "test_crash_always.py")
    assert always.returncode == 1, always.stdout[-3000:]
    assert "FAILED test_crash_always.py::test_crashes_always" in always.stdout
    # run once and once again, not until --max-worker-restart is spent
    assert (tmp_path / "crashing_runs").read_text() == "xx"
    fails = _pytest(tmp_path, "test_fails.py")
    assert fails.returncode == 1 and "rerun" not in fails.stdout, fails.stdout[-3000:]
    assert (tmp_path / "failed_runs").read_text() == "x"


@pytest.mark.slow
def test_a_crash_in_a_long_run_does_not_hang_it(tmp_path):
    """pytest-xdist 3.8.0 puts every file a dead worker had finished back on the queue; each then
    reaches a worker as an empty command that is never answered, and the run hangs with idle
    workers (two slow runs of this suite did, issue 41). Without the conftest's scheduler this
    folder (a crash in the 15th of 30 files) hangs until the time-out; with it the run ends."""
    shutil.copy(Path(__file__).with_name("conftest.py"), tmp_path / "conftest.py")
    for k in range(30):
        (tmp_path / f"test_{k:02d}.py").write_text(CRASH_ONCE if k == 15 else QUICK)
    run = _pytest(tmp_path, timeout=120)
    assert run.returncode == 0, run.stdout[-3000:]
    assert "118 passed, 1 rerun" in run.stdout, run.stdout[-3000:]
