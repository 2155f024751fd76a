"""One process of a multi-process fit_stream run, for tests/fitting/test_fit_distributed.py:

    python _distributed_worker.py DIR COORDINATOR PROCESS_ID NUM_PROCESSES BLOCK_SIZE [DELAY_S]

DIR holds values.npy (N, M, C) and wi.npy, wo.npy (M, 3); results go to DIR/out. DELAY_S:
seconds the source waits before giving each block (so that a test can kill a process mid-run).
"""

import os
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

from brdf_fit.fitting import distributed  # noqa: E402
from brdf_fit.fitting.stream import fit_stream  # noqa: E402


def main(argv):
    folder, coordinator, pid, n, block_size = argv[:5]
    delay = float(argv[5]) if len(argv) > 5 else 0.0
    folder = Path(folder)
    timeout = float(os.environ.get("BRDF_FIT_TEST_INIT_TIMEOUT", "30"))
    index, count = distributed.initialize(coordinator, int(n), int(pid), timeout_s=timeout,
                                          heartbeat_timeout_s=10)
    import numpy as np

    values = np.load(folder / "values.npy", mmap_mode="r")
    wi, wo = np.load(folder / "wi.npy"), np.load(folder / "wo.npy")

    def source(s, e):
        time.sleep(delay)
        return np.asarray(values[s:e])

    fit_stream(source, "ggx", folder / "out", wi=wi, wo=wo, n_problems=values.shape[0],
               block_size=int(block_size), shard=(index, count), sync=distributed.barrier,
               progress=False, resume=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
