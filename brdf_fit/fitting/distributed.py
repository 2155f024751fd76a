"""Several processes, one run: :func:`brdf_fit.fitting.stream.fit_stream` on JAX's
multi-process runtime (``jax.distributed``), on one machine or many (layer 4).

Every process runs the same program: :func:`initialize` joins the run (the coordinator's
address, the process count and this process's index, given or read by JAX from the cluster's
environment: SLURM, Open MPI), then ``fit_stream(..., shard=(index, count), sync=barrier)``
fits this process's share of the blocks on its local devices and writes each block to the
shared folder atomically. The lead process (index 0) settles the manifest (a new run, a resumed
one, or a refusal) before anyone fits; every process waits at a final barrier, so the lead,
which hosts JAX's coordination service, outlives the others' work. No socket of ours: the
coordination is JAX's (its key-value store and barriers, also its health checks: a process
that dies takes the run down within the heartbeat timeout, and ``--resume`` completes the
folder, fitting only what is not written).
"""

from __future__ import annotations

from brdf_fit.fitting.problem import FitError

__all__ = ["initialize", "barrier", "INIT_TIMEOUT_S", "HEARTBEAT_TIMEOUT_S", "DONE_TIMEOUT_S"]

#: seconds a process waits to reach the coordinator (and at the manifest barrier) before it
#: gives up with an error naming the address: long enough for a cluster's processes to start
#: one after another, short enough that a wrong address is reported within a minute
INIT_TIMEOUT_S = 60
#: seconds without a heartbeat after which JAX declares a process dead and stops the run
#: (JAX's default is 100)
HEARTBEAT_TIMEOUT_S = 100
#: seconds between a barrier's checks for a stop (the longest a stop waits to be seen there)
BARRIER_POLL_S = 0.1
#: seconds a process waits at the final barrier for the others' blocks (a run is as long as
#: its slowest process: a week, within the int32 milliseconds the barrier takes)
DONE_TIMEOUT_S = 7 * 24 * 3600


def initialize(coordinator: str | None = None, num_processes: int | None = None,
               process_id: int | None = None, timeout_s: float = INIT_TIMEOUT_S,
               heartbeat_timeout_s: float = HEARTBEAT_TIMEOUT_S) -> tuple[int, int]:
    """Join a multi-process run (``jax.distributed.initialize``, before any JAX computation)
    and return ``(index, count)``. ``coordinator`` (``HOST:PORT``, process 0's), ``num_processes``
    and ``process_id`` together, or none of them (read from the cluster's environment by
    JAX). A process that cannot reach the coordinator within ``timeout_s`` raises
    :class:`~brdf_fit.fitting.problem.FitError` naming it. The process keeps the SIGTERM
    handling it had: JAX's runtime installs its own handler (its preemption notifier, which
    logs the signal and carries on), under which a stopped launcher's processes ran on until
    they were killed (issue 45)."""
    import signal
    import threading

    import jax

    given = [coordinator is not None, num_processes is not None, process_id is not None]
    if any(given) and not all(given):
        raise FitError("give the coordinator (HOST:PORT), the number of processes and this "
                       "process's id together, or none of them (a cluster's environment)")
    if all(given) and not (0 <= int(process_id) < int(num_processes)):
        raise FitError(f"process id {process_id} is not in 0..{int(num_processes) - 1}")
    if not any(given):
        coordinator, num_processes, process_id = _from_cluster(timeout_s)
    if int(process_id) != 0:
        _wait_for(coordinator, timeout_s, process_id, num_processes)
    main_thread = threading.current_thread() is threading.main_thread()
    sigterm = signal.getsignal(signal.SIGTERM) if main_thread else None
    try:
        jax.distributed.initialize(
            coordinator_address=coordinator, num_processes=num_processes, process_id=process_id,
            initialization_timeout=int(timeout_s),
            heartbeat_timeout_seconds=int(heartbeat_timeout_s))
    except Exception as e:  # JAX raises several kinds (ValueError, XlaRuntimeError, ...)
        where = f"the coordinator at {coordinator}" if coordinator else "the cluster's coordinator"
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise FitError(f"process {process_id} of {num_processes}: could not join the run at "
                       f"{where} within {timeout_s:g} s ({first})") from None
    finally:
        if sigterm is not None:  # (None: a handler not installed from Python, left alone)
            signal.signal(signal.SIGTERM, sigterm)
    return jax.process_index(), jax.process_count()


def _from_cluster(timeout_s: float) -> tuple[str, int, int]:
    """``(coordinator, count, index)`` read from a cluster scheduler's environment (SLURM, Open
    MPI, ...) by JAX's own cluster detection (the function ``jax.distributed.initialize`` calls
    when they are not given), so that this process can check the coordinator is reachable
    before JAX tries (see :func:`_wait_for`). Raises FitError when no cluster is detected."""
    try:
        from jax._src.clusters import ClusterEnv

        coordinator, count, index, _ = ClusterEnv.auto_detect_unset_distributed_params(
            None, None, None, None, None, int(timeout_s))
    except Exception as e:  # a private API: any failure is reported, not hidden
        raise FitError(f"could not read the cluster's environment ({type(e).__name__}: {e}); "
                       "give --coordinator, --num-processes and --process-id") from None
    if coordinator is None or count is None or index is None:
        raise FitError("no cluster environment found (SLURM, Open MPI, ...: JAX's detection "
                       "found none); give --coordinator, --num-processes and --process-id")
    return str(coordinator), int(count), int(index)


def _wait_for(coordinator: str, timeout_s: float, process_id, num_processes) -> None:
    """Wait until something listens at ``coordinator`` (``HOST:PORT``), or raise FitError after
    ``timeout_s``. JAX's client, when the coordinator never answers, ends the process from C++
    (a fatal log and an abort, nothing Python can catch); this check, a TCP connection opened
    and closed again (the service's own protocol is JAX's), turns that into an error message."""
    import socket
    import time

    host, _, port = coordinator.rpartition(":")
    if not host or not port.isdigit():
        raise FitError(f"coordinator {coordinator!r}: expected HOST:PORT")
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host.strip("[]"), int(port)), timeout=2.0):
                return
        except OSError as e:
            if time.monotonic() >= deadline:
                raise FitError(f"process {process_id} of {num_processes}: could not join the "
                               f"run at the coordinator at {coordinator} within {timeout_s:g} s "
                               f"({e.strerror or e}); is process 0 running there?") from None
            time.sleep(0.5)


def barrier(name: str, timeout_s: float | None = None) -> None:
    """Wait until every process of the run reaches the barrier ``name`` (JAX's coordination
    service; nothing to wait for in a single process). ``timeout_s``: :data:`INIT_TIMEOUT_S`
    for the manifest, :data:`DONE_TIMEOUT_S` for the final barrier (by the name's suffix).

    The wait is a thread's, joined by this one in short steps, so that a stop (SIGINT, SIGTERM)
    reaches the waiting process at once: Python runs signal handlers in the main thread between
    bytecodes, and a main thread inside the client's C++ wait ran none until it returned (a
    process done with its blocks sat in the final barrier until its launcher's SIGKILL). A
    stopped process's waiting thread is abandoned (a daemon; the command line ends the process
    with ``os._exit``)."""
    import threading

    from jax._src import distributed  # the client of the service initialize() started

    client = distributed.global_state.client
    if client is None:
        return
    if timeout_s is None:
        timeout_s = DONE_TIMEOUT_S if name.endswith(".done") else INIT_TIMEOUT_S
    failure: list[Exception] = []

    def wait():
        try:
            client.wait_at_barrier(name, int(timeout_s * 1000))
        except Exception as e:  # raised below, in the caller's thread
            failure.append(e)

    waiter = threading.Thread(target=wait, name=f"barrier {name}", daemon=True)
    waiter.start()
    while waiter.is_alive():
        waiter.join(BARRIER_POLL_S)
    if failure:
        e = failure[0]
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise FitError(f"barrier {name!r}: not every process arrived within {timeout_s:g} s "
                       f"({first}); a process failed or was killed: --resume completes the "
                       "folder") from None
