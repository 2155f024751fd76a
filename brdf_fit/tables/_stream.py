"""Stream a table through a compiled function in fixed-size blocks of texels, on every core.

A table of any size is cut into blocks of a fixed number of texels (padded to that size, so one
compilation serves every block); each block is computed by one call of a jitted function and
written into the output arrays, so the live memory is that of ``window`` blocks whatever the
table's size. Blocks run on a pool of ``workers`` threads (JAX releases the GIL while a compiled
call runs, so two blocks compute at once on two cores), at most ``window`` of them in flight.

JAX's ``enable_x64`` setting is thread-local: each block is computed under ``jax.enable_x64(True)``
in its own thread (without it a worker would silently compute in float32).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, as_completed, wait

import jax

__all__ = ["WINDOW_PER_WORKER", "run_blocks", "usable_cores"]

#: blocks in flight per worker thread: one computing, one queued, so a worker never waits for
#: the main thread to hand it the next block; bounds the live memory to ``2 * workers`` blocks
WINDOW_PER_WORKER = 2


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the OS reports it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def run_blocks(compute: Callable[[int, int], None], total: int, block: int, *,
               progress: Callable[[int, int], None] | None = None,
               workers: int | None = None) -> None:
    """Call ``compute(start, stop)`` for ``[0, total)`` cut into blocks of ``block`` items.

    ``compute`` computes and stores its block (blocks are disjoint, so threads never write the
    same element). ``progress(done, total)`` is called from the calling thread after each block,
    with the number of items finished so far (increasing). ``workers`` defaults to
    :func:`usable_cores`; ``workers=1`` runs the blocks in order in the calling thread."""
    starts = list(range(0, total, block))
    workers = usable_cores() if workers is None else max(1, int(workers))

    def job(start: int) -> int:
        stop = min(start + block, total)
        with jax.enable_x64(True):
            compute(start, stop)
        return stop - start

    done = 0
    if not starts:
        return
    # the first block in the calling thread: it compiles the function once, before the pool
    # starts (concurrent first calls would each trace and compile it)
    for s in starts[:1] if workers > 1 else starts:
        done += job(s)
        if progress is not None:
            progress(done, total)
    if workers == 1 or len(starts) == 1:
        return
    window = WINDOW_PER_WORKER * workers
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = set()
        for s in starts[1:]:
            pending.add(pool.submit(job, s))
            if len(pending) < window:
                continue
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in finished:
                done += f.result()
                if progress is not None:
                    progress(done, total)
        for f in as_completed(pending):
            done += f.result()
            if progress is not None:
                progress(done, total)
