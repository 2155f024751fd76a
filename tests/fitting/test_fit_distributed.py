"""fit_stream on JAX's multi-process runtime (issue 29): two local processes share a run's
blocks and give the single-process result exactly; a process killed mid-run leaves a folder
that a resumed run completes to the same result."""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from brdf_fit.fitting.stream import fit_stream

WORKER = Path(__file__).with_name("_distributed_worker.py")
ROOT = Path(__file__).resolve().parents[2]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _problems(folder: Path, n: int, m: int = 24, seed: int = 0):
    """n GGX problems on one shared geometry (random alpha and RGB f0, 1% noise)."""
    import jax
    import jax.numpy as jnp

    from brdf_fit import registry

    rng = np.random.default_rng(seed)
    mu_i, mu_o = rng.uniform(0.2, 1.0, m), rng.uniform(0.2, 1.0, m)
    phi = rng.uniform(0, 2 * np.pi, m)
    wi = np.stack([np.sqrt(1 - mu_i**2), np.zeros(m), mu_i], -1)
    wo = np.stack([np.sqrt(1 - mu_o**2) * np.cos(phi), np.sqrt(1 - mu_o**2) * np.sin(phi),
                   mu_o], -1)
    alpha = rng.uniform(0.1, 0.6, n)
    f0 = rng.uniform(0.1, 0.9, (n, 3))
    e = registry.get("ggx")

    def one(a, f):
        return e.build(alpha=a, f0=f).eval(jnp.asarray(wi), jnp.asarray(wo))

    vals = np.asarray(jax.vmap(one)(jnp.asarray(alpha), jnp.asarray(f0)))
    vals = vals * np.exp(rng.normal(0, 0.01, vals.shape))
    np.save(folder / "values.npy", vals)
    np.save(folder / "wi.npy", wi)
    np.save(folder / "wo.npy", wo)
    return vals, wi, wo


def _start(folder, port, pid, n, block_size, delay=0.0, timeout_s=30):
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_PLATFORMS="cpu",
               BRDF_FIT_TEST_INIT_TIMEOUT=str(timeout_s))
    return subprocess.Popen(
        [sys.executable, str(WORKER), str(folder), f"127.0.0.1:{port}", str(pid), str(n),
         str(block_size), str(delay)],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _same(a, b):
    for k in a.params:
        np.testing.assert_allclose(a.params[k], b.params[k], rtol=1e-12, atol=0, err_msg=k)
    for k in a.stderr:
        np.testing.assert_allclose(a.stderr[k], b.stderr[k], rtol=1e-12, atol=0, err_msg=k)
    np.testing.assert_array_equal(a.converged, b.converged)
    np.testing.assert_allclose(a.loss, b.loss, rtol=1e-12, atol=0)


def test_two_processes_equal_one(tmp_path, capsys):
    """The command line's --processes 2 on a memory-mapped value array (4,096 problems, one
    geometry): the parameter maps equal a single process's fit_stream."""
    from brdf_fit.cli import main

    vals, wi, wo = _problems(tmp_path, 4096)
    np.savez(tmp_path / "geometry.npz", wi=wi, wo=wo)
    rc = main(["fit-batch", "--values", str(tmp_path / "values.npy"), "--geometry",
               str(tmp_path / "geometry.npz"), "--model", "ggx", "--out-dir",
               str(tmp_path / "out"), "--block-size", "512", "--processes", "2", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "(0 fitted now, 8 already written)" in out  # all eight by the two processes
    ref = fit_stream(vals, "ggx", None, wi=wi, wo=wo, block_size=512, progress=False).result()
    maps = tmp_path / "out" / "maps"
    for k in ref.params:
        np.testing.assert_allclose(np.load(maps / f"params_{k}.npy"), ref.params[k], rtol=1e-12,
                                   atol=0, err_msg=k)
        np.testing.assert_allclose(np.load(maps / f"stderr_{k}.npy"), ref.stderr[k], rtol=1e-12,
                                   atol=0, err_msg=k)
    np.testing.assert_array_equal(np.load(maps / "converged.npy"), ref.converged)


def test_a_killed_process_is_completed_by_resume(tmp_path):
    vals, wi, wo = _problems(tmp_path, 2048, seed=1)
    port = _free_port()
    # 16 blocks, 8 per process, each given after 0.5 s: a kill after the first lands mid-run
    procs = [_start(tmp_path, port, pid, 2, 128, delay=0.5) for pid in (0, 1)]
    out = tmp_path / "out"
    t0 = time.time()
    while not any(out.glob("block_*.npz")) and time.time() - t0 < 240:
        time.sleep(0.1)
    assert any(out.glob("block_*.npz")), "no block was written"
    procs[1].send_signal(signal.SIGKILL)
    procs[1].communicate(timeout=30)
    try:  # the other stops within the heartbeat timeout (10 s here), or ends its share
        procs[0].communicate(timeout=120)
    except subprocess.TimeoutExpired:
        procs[0].kill()
        procs[0].communicate()
    written = sorted(int(p.stem.split("_")[1]) for p in out.glob("block_*.npz"))
    assert 0 < len(written) < 16, written
    res = fit_stream(vals, "ggx", out, wi=wi, wo=wo, block_size=128, progress=False,
                     resume=True)
    assert res.skipped == written and sorted(res.fitted) == sorted(set(range(16)) - set(written))
    ref = fit_stream(vals, "ggx", tmp_path / "ref", wi=wi, wo=wo, block_size=128,
                     progress=False)
    _same(res.result(), ref.result())


def test_a_process_that_cannot_reach_the_coordinator_says_so(tmp_path):
    """No coordinator listening: the process gives up within its stated timeout (5 s here)
    with an error that names the address."""
    _problems(tmp_path, 16)
    port = _free_port()
    t0 = time.time()
    p = _start(tmp_path, port, 1, 2, 16, timeout_s=5)
    out = p.communicate(timeout=120)[0]
    assert p.returncode != 0
    assert f"could not join the run at the coordinator at 127.0.0.1:{port} within 5 s" in out
    assert time.time() - t0 < 60


@pytest.mark.parametrize("extra, fragment", [
    (["--coordinator", "127.0.0.1:1"], "go together"),
    (["--cluster", "--coordinator", "127.0.0.1:1", "--num-processes", "2", "--process-id", "0"],
     "not with --coordinator"),
    (["--process-id", "0"], "go together"),
])
def test_bad_multi_process_requests(tmp_path, capsys, extra, fragment):
    from brdf_fit.cli import main

    np.save(tmp_path / "v.npy", np.ones((4, 3, 1)))
    np.savez(tmp_path / "g.npz", wi=np.tile([0.0, 0.0, 1.0], (3, 1)),
             wo=np.tile([0.0, 0.0, 1.0], (3, 1)))
    rc = main(["fit-batch", "--values", str(tmp_path / "v.npy"), "--geometry",
               str(tmp_path / "g.npz"), "--model", "lambert", "--out-dir", str(tmp_path / "o"),
               *extra])
    assert rc == 2 and fragment in capsys.readouterr().err


@pytest.mark.parametrize("argv, fragment", [
    (["--values", "V"], "--values needs --out-dir"),
    (["--values", "V", "--out-dir", "O"], "--values needs --geometry"),
    (["--values", "V", "--out-dir", "O", "--geometry", "B"], "a direction below the horizon"),
    (["--values", "V", "--out-dir", "O", "--geometry", "G", "x.csv"], "not both"),
    ([], "fit-batch needs data files"),
])
def test_bad_value_array_requests(tmp_path, capsys, monkeypatch, argv, fragment):
    from brdf_fit.cli import main

    monkeypatch.chdir(tmp_path)
    np.save("V.npy", np.ones((4, 3, 1)))
    np.savez("G.npz", wi=np.tile([0.0, 0.0, 1.0], (3, 1)), wo=np.tile([0.0, 0.0, 1.0], (3, 1)))
    np.savez("B.npz", wi=np.tile([0.0, 0.0, -1.0], (3, 1)), wo=np.tile([0.0, 0.0, 1.0], (3, 1)))
    names = {"V": "V.npy", "G": "G.npz", "B": "B.npz"}
    rc = main(["fit-batch", "--model", "lambert", *[names.get(a, a) for a in argv]])
    assert rc == 2 and fragment in capsys.readouterr().err
