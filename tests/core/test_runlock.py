"""One run per output folder (brdf_fit.core.runlock): a second run stops at once naming the
holder; a dead holder's lock is free (issue 45: two --resume runs both fitted every block, and
one deleted the other's temporary file mid-write)."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from brdf_fit.cli import main
from brdf_fit.core.runlock import LOCK_NAME, FolderBusy, hold


def test_second_holder_refused_and_a_dead_holders_lock_is_free(tmp_path):
    with hold(tmp_path / "run"):
        with pytest.raises(FolderBusy, match=rf"another run is writing here \(process "
                                             rf"{os.getpid()}\)"):
            with hold(tmp_path / "run"):
                pass
    with hold(tmp_path / "run"):  # released on leaving the block
        pass
    code = ("import sys, time\nfrom brdf_fit.core.runlock import hold\n"
            "with hold(sys.argv[1]):\n    print('held', flush=True)\n    time.sleep(600)\n")
    p = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "run")],
                         stdout=subprocess.PIPE, text=True)
    assert p.stdout.readline().strip() == "held"
    with pytest.raises(FolderBusy, match=rf"process {p.pid}"):
        with hold(tmp_path / "run"):
            pass
    p.send_signal(signal.SIGKILL)
    p.wait()
    p.stdout.close()
    t0 = time.monotonic()
    with hold(tmp_path / "run"):  # the killed holder's lock went with it
        assert (tmp_path / "run" / LOCK_NAME).read_text() == str(os.getpid())
    assert time.monotonic() - t0 < 5


def test_cli_runs_on_a_held_folder_stop_at_once(tmp_path, capsys):
    np.save(tmp_path / "v.npy", np.ones((4, 3, 1)))
    np.savez(tmp_path / "g.npz", wi=np.tile([0.0, 0.0, 1.0], (3, 1)),
             wo=np.tile([0.0, 0.0, 1.0], (3, 1)))
    argv = ["fit-batch", "--values", str(tmp_path / "v.npy"), "--geometry",
            str(tmp_path / "g.npz"), "--model", "lambert", "--out-dir", str(tmp_path / "o"),
            "--quiet"]
    with hold(tmp_path / "o"):
        assert main(argv) == 2
        assert f"another run is writing here (process {os.getpid()})" in capsys.readouterr().err
        assert not list((tmp_path / "o").glob("block_*"))
    table = tmp_path / "t.csv"
    with hold(str(table) + ".parts"):
        assert main(["fit", str(tmp_path / "x.npz"), "--model", "lambert", "--table",
                     str(table)]) == 2
        assert "another run is writing here" in capsys.readouterr().err
