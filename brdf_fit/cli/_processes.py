"""What a launcher of local processes needs (``fit --processes``, ``fit-batch
--processes``): its arguments for them, starting them, and stopping them all."""

from __future__ import annotations

import os
import sys

#: set in the environment of a launcher's processes: a process stopped by its launcher ends
#: silently (the launcher prints the one line for the run)
LAUNCHED_ENV = "BRDF_FIT_LAUNCHED"


def launch(argv: list[str]):
    """Start ``brdf-fit ARGV`` as a process of this launcher: the same interpreter, its
    output discarded (the launcher reports), its errors on this stderr, in a session of its own
    (a Ctrl-C at the terminal reaches the launcher alone, which stops it: :func:`stop_children`),
    marked :data:`LAUNCHED_ENV`."""
    import subprocess

    return subprocess.Popen([sys.executable, "-m", "brdf_fit.cli", *argv],
                            stdout=subprocess.DEVNULL, start_new_session=True,
                            env={**os.environ, LAUNCHED_ENV: "1"})

#: seconds a stopped launcher's processes get to end on SIGTERM before they are killed (a
#: process answers when its current XLA computation returns; one waiting in a barrier of JAX's
#: coordination service may not: every block a process finished is on disk already)
STOP_GRACE_S = 3.0


def stop_children(procs, folders=()) -> None:
    """End every process of ``procs`` (subprocess.Popen): SIGTERM, then SIGKILL for whichever
    is still running after :data:`STOP_GRACE_S`; waits for all. The launchers start their
    processes in sessions of their own, so a Ctrl-C at the terminal (SIGINT to the foreground
    group) reaches the launcher alone, which stops them here and prints the one line (each
    process printed its own traceback before).

    ``folders``: where the processes write (through :mod:`brdf_fit.core.atomic`). A process
    ended by a signal (the SIGKILL here, or a crash) may have been writing a file, and nothing
    of it ran to remove the temporary: :func:`remove_leftovers_of` removes it (a block's
    temporary was left in a fit-batch folder when its process, in a computation that did not
    return within the grace time, was killed)."""
    import subprocess
    import time

    for p in procs:
        if p.poll() is None:
            p.terminate()
    deadline = time.monotonic() + STOP_GRACE_S
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    remove_leftovers_of(procs, folders)


def remove_leftovers_of(procs, folders) -> None:
    """Remove from ``folders`` the temporary files of those ended processes of ``procs`` that a
    signal ended (a negative exit status: SIGKILL, a crash), which could not remove their own
    (:func:`brdf_fit.core.atomic.remove_leftovers`)."""
    from brdf_fit.core.atomic import remove_leftovers

    ended_by_signal = [p.pid for p in procs if p.returncode is not None and p.returncode < 0]
    for folder in folders:
        remove_leftovers(folder, ended_by_signal)


def child_argv(args, with_value: tuple[str, ...], flags: tuple[str, ...]) -> list[str]:
    """This command's arguments for the processes a launcher starts: without the options
    ``with_value`` (and their values, in either spelling) and the ``flags``."""
    argv, skip = [], False
    for a in sys.argv[1:] if getattr(args, "_argv", None) is None else args._argv:
        if skip:
            skip = False
            continue
        if a in with_value:
            skip = True
            continue
        if a.startswith(tuple(f"{o}=" for o in with_value)) or a in flags:
            continue
        argv.append(a)
    return argv
