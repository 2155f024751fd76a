"""fit_stream (brdf_fit.fitting.stream): streamed blocks equal the in-memory fit_batch, a killed
run resumes without refitting what was written, bad output folders are refused before any
work, the progress bar appears. Every stream here uses one block shape (48 problems of 24
samples), so the compiled functions are shared by all tests."""

from __future__ import annotations

import json
import os

import jax
import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.fitting.batch import fit_batch
from brdf_fit.fitting.problem import FitError
from brdf_fit.fitting.stream import MANIFEST, block_size_for, fit_stream

N, M, BS = 100, 24, 48  # 3 blocks, the last one padded (4 real problems)


@pytest.fixture(scope="module")
def problems():
    rng = np.random.default_rng(7)
    mu = rng.uniform(0.1, 1.0, (2, M))
    phi = rng.uniform(0.0, 2 * np.pi, (2, M))
    s = np.sqrt(1 - mu * mu)
    d = np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)
    wi, wo = d[0], d[1]
    alpha = np.exp(rng.uniform(np.log(0.05), np.log(0.8), N))
    f0 = rng.uniform(0.02, 1.0, (N, 3))
    entry = registry.get("ggx")
    ev = jax.jit(jax.vmap(lambda a, f: entry.build(alpha=a, f0=f).eval(wi, wo)))
    v = np.asarray(ev(alpha, f0)) * np.exp(0.01 * rng.standard_normal((N, M, 3)))
    return wi, wo, v


def _same(a, b, idx=slice(None)):
    for k in b.params:
        np.testing.assert_array_equal(a.params[k][idx], b.params[k])
    for k in b.stderr:
        np.testing.assert_array_equal(a.stderr[k][idx], b.stderr[k])
    for k in ("loss", "converged", "steps", "residual_rms", "n_samples"):
        np.testing.assert_array_equal(getattr(a, k)[idx], getattr(b, k))


def test_stream_equals_fit_batch_and_resumes_after_a_kill(problems, tmp_path, capsys):
    wi, wo, v = problems
    # in memory, block by block (the stream's block shape: compiled once for both)
    ref = [fit_batch(wi, wo, v[k * BS:(k + 1) * BS], "ggx") for k in range(2)]
    calls = []

    def source(s, e):
        calls.append((s, e))
        if s >= 2 * BS and len(calls) < 10:
            raise RuntimeError("killed")  # the run dies after writing blocks 0 and 1
        return v[s:e]

    out = tmp_path / "run"
    with pytest.raises(RuntimeError, match="killed"):
        fit_stream(source, "ggx", out, n_problems=N, wi=wi, wo=wo, block_size=BS,
                   progress=False)
    written = sorted(p.name for p in out.iterdir())
    assert written == ["block_000000.npz", "block_000001.npz", MANIFEST]
    stamps = {p: os.stat(out / p).st_mtime_ns for p in written}
    # without resume the folder of a previous run is refused before any work
    calls.clear()
    with pytest.raises(FitError, match="resume"):
        fit_stream(source, "ggx", out, n_problems=N, wi=wi, wo=wo, block_size=BS,
                   progress=False)
    calls.clear()
    calls.extend([None] * 10)  # the source works now
    res = fit_stream(source, "ggx", out, n_problems=N, wi=wi, wo=wo, block_size=BS,
                     resume=True)
    assert res.skipped == [0, 1] and res.fitted == [2]
    assert [c for c in calls[10:] if c[0] > 0] == [(2 * BS, N)]  # only block 2 was read
    assert all(os.stat(out / p).st_mtime_ns == stamps[p] for p in written)
    err = capsys.readouterr().err
    assert "fit_stream:" in err and f"{N:,}/{N:,} problems" in err and "ETA" in err
    full = res.result()
    assert full.batch_size == N
    for k in range(2):  # streamed blocks == the in-memory batches, exactly
        _same(full, ref[k], slice(k * BS, (k + 1) * BS))

    # the same problems in memory, uninterrupted, from a memory-mapped .npy
    np.save(tmp_path / "v.npy", v)
    mm = np.load(tmp_path / "v.npy", mmap_mode="r")
    again = fit_stream(mm, "ggx", None, wi=wi, wo=wo, block_size=BS, progress=False)
    assert again.fitted == [0, 1, 2]
    _same(again.result(), full)
    # a resumed run of a finished folder fits nothing
    done = fit_stream(source, "ggx", out, n_problems=N, wi=wi, wo=wo, block_size=BS,
                      resume=True, progress=False)
    assert done.fitted == [] and done.skipped == [0, 1, 2]
    # a different run in the same folder is refused
    with pytest.raises(FitError, match="differs in .*block_size"):
        fit_stream(source, "ggx", out, n_problems=N, wi=wi, wo=wo, block_size=32,
                   resume=True, progress=False)
    assert json.loads((out / MANIFEST).read_text())["block_size"] == BS


def test_bad_output_is_refused_before_any_work(problems, tmp_path):
    wi, wo, v = problems
    calls = []

    def source(s, e):
        calls.append(s)
        return v[s:e]

    afile = tmp_path / "file.npz"
    afile.write_text("x")
    for out, msg in ((afile, "existing file"), (tmp_path / "missing" / "out", "does not exist")):
        with pytest.raises(FitError, match=msg):
            fit_stream(source, "ggx", out, n_problems=N, wi=wi, wo=wo, block_size=BS,
                       progress=False)
    assert calls == []
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            with pytest.raises(FitError, match="permission denied"):
                fit_stream(source, "ggx", ro / "out", n_problems=N, wi=wi, wo=wo,
                           block_size=BS, progress=False)
        finally:
            ro.chmod(0o700)
    assert calls == []
    with pytest.raises(FitError, match="n_problems"):
        fit_stream(source, "ggx", None, wi=wi, wo=wo)
    with pytest.raises(FitError, match="shared"):
        fit_stream(v, "ggx", None, wi=wi[:5], wo=wo, block_size=BS)


def test_shared_geometry_equals_per_problem_geometry(problems):
    """(M, 3) directions shared by every problem (vmapped with in_axes=None) give the fits of
    the same directions repeated per problem, up to rounding, from the same start; with the
    grid guess (finer when the geometry is shared: guess.SHARED_CANDIDATES) the same optimum
    to the solver's tolerance."""
    from brdf_fit.fitting import guess as G

    wi, wo, v = problems
    wib, wob = np.broadcast_to(wi, (BS, M, 3)), np.broadcast_to(wo, (BS, M, 3))
    a = fit_batch(wi, wo, v[:BS], "ggx", guess="none")
    b = fit_batch(wib, wob, v[:BS], "ggx", guess="none")
    np.testing.assert_allclose(a.loss, b.loss, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(a.params["alpha"], b.params["alpha"], rtol=1e-6)
    np.testing.assert_allclose(a.params["f0"], b.params["f0"], atol=1e-6)
    assert (a.converged == b.converged).all()
    a = fit_batch(wi, wo, v[:BS], "ggx")
    b = fit_batch(wib, wob, v[:BS], "ggx")
    guesses = [[r for r in x.rounds if r.get("guess")][0] for x in (a, b)]
    assert [g["shared"] for g in guesses] == [True, False]
    assert guesses[0]["candidates"] > guesses[1]["candidates"] == G.GUESS_CANDIDATES
    assert (a.converged == b.converged).all()  # one problem slides onto f0's bound in both
    # both stopped by the default tolerances (rtol = atol = 1e-10 on the loss change)
    np.testing.assert_allclose(a.loss, b.loss, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(a.params["alpha"], b.params["alpha"], rtol=1e-5)
    np.testing.assert_allclose(a.params["f0"], b.params["f0"], atol=1e-5)


def test_prefetch_reads_ahead_in_order_and_changes_nothing(problems):
    """The next block is read on one worker thread while the current one is fitted, in block
    order; the results equal reading every block on the calling thread (prefetch=False)."""
    import threading

    wi, wo, v = problems
    seen = {True: [], False: []}

    def source(flag):
        def read(s, e):
            seen[flag].append((s, threading.current_thread() is threading.main_thread()))
            return v[s:e]
        return read

    a = fit_stream(source(True), "ggx", None, n_problems=N, wi=wi, wo=wo, block_size=BS,
                   progress=False)
    b = fit_stream(source(False), "ggx", None, n_problems=N, wi=wi, wo=wo, block_size=BS,
                   progress=False, prefetch=False)
    # the first call (shape probe) is on the calling thread; then blocks 0, 1, 2 in order
    assert [s for s, _ in seen[True]] == [s for s, _ in seen[False]] == [0, 0, BS, 2 * BS]
    assert [m for _, m in seen[True]] == [True, False, False, False]
    assert all(m for _, m in seen[False])
    _same(a.result(), b.result())


def test_block_size_from_memory_budget():
    assert block_size_for(300, 3, True, 512) % 16 == 0
    assert block_size_for(300, 3, False, 512) < block_size_for(300, 3, True, 512)
    assert block_size_for(300, 3, True, 0.001) == 16
