"""A command stopped while XLA compiles ends with its own status (130), not a crash.

jaxlib (0.10.2) compiles on a thread of its own, and the caller's wait for the compile ends when
a signal arrives: Ctrl-C raises KeyboardInterrupt in the command while the compile goes on. A
process that then shuts down normally destroys the JAX client under the compiling thread, which
jumps to a null or freed function pointer: SIGSEGV, exit status -11 (139 from a shell) and a core
file, where a stopped command should exit 130 with its one line. Seen in the workers of an
interrupted ``fit-batch --processes 2`` (a core file of one, from the slow set, had its main thread
in ``Py_FinalizeEx`` destroying ``PjRtClient`` and the crashed thread in
``PjRtCompiler::CompileAndLoad``). :func:`brdf_fit.cli.main.run` ends a stopped command with
``os._exit`` after flushing its output.

The program here swaps ``brdf-fit models``' run for one that compiles a program XLA takes over a
second to compile (1.7 s on 2 AMD EPYC cores) and sends itself SIGINT 0.25 s into the compile.
The negative control runs the same command through ``sys.exit(main(...))``, the shutdown the
program had before, on a longer compile (:data:`CONTROL_STEPS`), and crashes (in one of
:data:`CONTROL_TRIES` tries: a race).
"""

import os
import subprocess
import sys

import pytest

#: seconds into the compile at which the program sends itself SIGINT
DELAY_S = 0.25

#: a chain of this many where/sin/cos/sqrt steps: 1.7 s to compile on 2 AMD EPYC cores, 0.3 s
#: to trace and lower (which happens before the signal's timer starts)
STEPS = 400
#: the negative control's chain: a compile of about 6 s, so that the interpreter's shutdown
#: certainly comes while it runs (with the 1.7 s one, on a machine loaded by the rest of the
#: suite, the compile sometimes ended before the shutdown reached the client: no crash in 2 of
#: 3 runs under AVX2 beside the slow set, where idle runs crashed 5 of 5)
CONTROL_STEPS = 1500

PROGRAM = """
import os, resource, signal, sys, threading
resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # the control's crash leaves no core file
# SIGINT as a terminal gives it: a suite started in the background (`make test-slow &` from a
# script) has SIGINT ignored, which this child inherits and Python keeps, so the compile ran
# to its end ("compiled before the signal", both tests failing in such a run)
signal.signal(signal.SIGINT, signal.default_int_handler)
import jax, jax.numpy as jnp
import brdf_fit.cli.models as models
from brdf_fit.cli.main import main, run

def chain(x):
    for i in range({steps}):
        x = jnp.where(x > 0.5, jnp.sin(x) * jnp.cos(x + i), jnp.sqrt(jnp.abs(x) + i))
    return x

lowered = jax.jit(chain).lower(jnp.ones(64))

def compile_until_stopped(args):
    threading.Timer({delay}, os.kill, (os.getpid(), signal.SIGINT)).start()
    lowered.compile()
    print("compiled before the signal", flush=True)
    return 0

models.run = compile_until_stopped
{end}
"""


def _stopped_mid_compile(end: str, steps: int = STEPS) -> subprocess.CompletedProcess:
    env = {**os.environ, "BRDF_FIT_NO_CACHE": "1"}  # every run compiles; no user cache touched
    code = PROGRAM.format(steps=steps, delay=DELAY_S, end=end)
    # (no preexec_fn: a fork of this process, where JAX runs threads, warns, and the suite
    # turns warnings into errors)
    return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=300)


@pytest.mark.slow
def test_a_command_stopped_while_compiling_exits_130():
    p = _stopped_mid_compile("run(['models'])")
    assert "compiled before the signal" not in p.stdout, (
        "the compile finished within the delay: raise STEPS so the signal comes mid-compile")
    assert p.returncode == 130, p.stderr[-2000:]
    assert p.stderr.strip().splitlines()[-1] == "brdf-fit: interrupted", p.stderr[-2000:]


#: the negative control's tries: the crash is a race between the interpreter's shutdown and the
#: compiling thread. Idle, and beside two busy-looping processes, 12 of 12 tries crashed here
#: (Sapphire Rapids, 2 cores); in CI's slow set one try in one run ended 130 without a crash
#: (2026-12-07), and an earlier, shorter compile missed it in 2 of 3 runs beside the slow set, so
#: the control asks for a crash in any of this many tries (a try that crashes ends the loop:
#: one try, 4 s, in the usual case; eight misses in a row at even odds: 0.4%)
CONTROL_TRIES = 8


@pytest.mark.slow
def test_negative_control_the_normal_shutdown_crashes():
    """If this starts passing, jaxlib no longer crashes here: run()'s os._exit can go (and
    this control with it)."""
    statuses = []
    for _ in range(CONTROL_TRIES):
        p = _stopped_mid_compile("sys.exit(main(['models']))", CONTROL_STEPS)
        assert "compiled before the signal" not in p.stdout
        assert "brdf-fit: interrupted" in p.stderr  # the command itself stopped as it should
        statuses.append(p.returncode)
        if p.returncode == -11:
            break
    assert statuses[-1] == -11, (statuses, p.stderr[-2000:])
