"""Batch fitting: fit_batch equals fit() problem by problem, stragglers are re-solved without
touching the easy problems, per-problem flags, and the sharded path on 2 host devices."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fit import FitError, fit
from brdf_fit.fit_batch import fit_batch

TRUTHS = [(0.23, [0.9, 0.6, 0.3]), (0.08, [0.6, 0.5, 0.4]), (0.5, [0.95, 0.9, 0.2]),
          (0.14, [0.3, 0.3, 0.3])]


def directions(rng, n):
    mu = rng.uniform(0.05, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - mu * mu)
    return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)


def batch(truths, n=120, seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    wi, wo, v = [], [], []
    for a, f0 in truths:
        x, y = directions(rng, n), directions(rng, n)
        m = registry.get("ggx").build(alpha=a, f0=f0)
        val = np.asarray(m.eval(jnp.asarray(x), jnp.asarray(y)))
        if noise:
            val = val * np.exp(noise * rng.standard_normal(val.shape))
        wi.append(x)
        wo.append(y)
        v.append(val)
    return np.stack(wi), np.stack(wo), np.stack(v)


def single(wi, wo, v, b, **kw):
    return fit(GonioData(wi=wi[b], wo=wo[b], value=v[b], channels=("R", "G", "B")), "ggx", **kw)


@pytest.mark.parametrize(
    "noise", [0.0, pytest.param(0.02, marks=pytest.mark.slow)], ids=["noise-free", "noisy"])
def test_batch_equals_single_fits(noise):
    wi, wo, v = batch(TRUTHS, noise=noise, seed=1)
    r = fit_batch(wi, wo, v, "ggx", chunk_steps=8)  # small chunks: compaction is exercised
    assert r.converged.all() and r.params["f0"].shape == (4, 3)
    assert len([x for x in r.rounds if not (x.get("finalise") or x.get("init"))]) > 1
    for b in range(len(TRUTHS)):
        s = single(wi, wo, v, b)
        assert s.converged
        np.testing.assert_allclose(r.params["alpha"][b], s.params["alpha"], rtol=0, atol=1e-8)
        np.testing.assert_allclose(r.params["f0"][b], s.params["f0"], rtol=0, atol=1e-8)
        np.testing.assert_allclose(r.stderr["alpha"][b], s.stderr["alpha"], rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(r.stderr["f0"][b], s.stderr["f0"], rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(r.loss[b], s.loss, rtol=1e-9, atol=1e-20)
        np.testing.assert_allclose(r.residual_rms[b], s.residual_rms, rtol=1e-7, atol=1e-14)
        assert r.n_samples[b] == s.n_samples
        if noise == 0.0:
            np.testing.assert_allclose(r.params["alpha"][b], TRUTHS[b][0], rtol=1e-7)


@pytest.mark.slow  # the optimistix path is fit()'s solve, tested in test_fit.py
def test_optimistix_solver_in_chunks_matches_fit():
    """solver="lm": fit()'s optimistix solver, restarted at chunk boundaries."""
    wi, wo, v = batch(TRUTHS[:2], noise=0.01, seed=2)
    r = fit_batch(wi, wo, v, "ggx", solver="lm", chunk_steps=16)
    assert r.converged.all()
    for b in range(2):
        s = single(wi, wo, v, b)
        np.testing.assert_allclose(r.params["f0"][b], s.params["f0"], rtol=0, atol=1e-8)


def test_straggler_is_resolved_and_easy_problems_unchanged():
    """One problem started far off (alpha at 0.999, f0 at 0.001) among easy ones started at
    their truth: it needs more chunks; the easy ones stop in the first chunk with the same
    result and step count as when solved without the straggler."""
    truths = TRUTHS * 2
    wi, wo, v = batch(truths, noise=0.01, seed=3)
    init_a = np.array([t[0] for t in truths])
    init_f = np.array([t[1] for t in truths])
    kw = dict(rtol=1e-6, atol=1e-6, chunk_steps=4)
    easy = fit_batch(wi[1:], wo[1:], v[1:], "ggx", init={"alpha": init_a[1:], "f0": init_f[1:]},
                     **kw)
    init_a[0], init_f[0] = 0.999, [0.001, 0.001, 0.001]
    r = fit_batch(wi, wo, v, "ggx", init={"alpha": init_a, "f0": init_f}, **kw)
    assert r.converged.all()
    assert r.steps[0] > 8 and r.steps[1:].max() <= 4
    chunks = [x for x in r.rounds if not (x.get("finalise") or x.get("init"))]
    assert chunks[0]["active"] == 8 and chunks[1]["active"] == 1  # only the straggler goes on
    np.testing.assert_array_equal(r.steps[1:], easy.steps)
    np.testing.assert_allclose(r.params["f0"][1:], easy.params["f0"], rtol=0, atol=1e-12)
    s = single(wi, wo, v, 0)  # the straggler reaches the same optimum as fit() from defaults
    np.testing.assert_allclose(r.params["alpha"][0], s.params["alpha"], rtol=0, atol=1e-6)
    # the same answer as a single unchunked vmapped solve, at the same per-problem step counts
    plain = fit_batch(wi, wo, v, "ggx", init={"alpha": init_a, "f0": init_f}, rtol=1e-6,
                      atol=1e-6, chunk_steps=None, group=None)
    np.testing.assert_array_equal(plain.steps, r.steps)
    np.testing.assert_allclose(plain.params["f0"], r.params["f0"], rtol=0, atol=1e-12)


def test_per_problem_converged_flags():
    wi, wo, v = batch(TRUTHS[:3], noise=0.01, seed=4)
    f0 = np.array([[0.9, 0.6, 0.3], [1e-3] * 3, [0.95, 0.9, 0.2]])
    init = {"alpha": np.array([0.23, 0.999, 0.5]), "f0": f0}
    # without a budget these need 3, 13 and 3 steps: a budget of 8 stops only the second
    r = fit_batch(wi, wo, v, "ggx", init=init, max_steps=8, chunk_steps=4, rtol=1e-6, atol=1e-6)
    assert r.converged.tolist() == [True, False, True]
    assert r.steps[1] == 8 and r.steps[0] < 8
    assert r.to_dict()["converged"] == [True, False, True]


def test_fixed_parameters_and_errors():
    wi, wo, v = batch(TRUTHS[:2], seed=5)
    f0 = np.array([t[1] for t in TRUTHS[:2]])
    r = fit_batch(wi, wo, v, "ggx", fix={"f0": f0})
    np.testing.assert_array_equal(r.params["f0"], f0)
    assert set(r.stderr) == {"alpha"} and r.n_params == 1
    np.testing.assert_allclose(r.params["alpha"], [0.23, 0.08], rtol=1e-8)
    with pytest.raises(FitError, match="unknown metric"):
        fit_batch(wi, wo, v, "ggx", metric="l2")
    with pytest.raises(FitError, match="unknown solver"):
        fit_batch(wi, wo, v, "ggx", solver="bfgs")
    with pytest.raises(FitError, match="expected wi, wo"):
        fit_batch(wi[0], wo[0], v[0], "ggx")
    with pytest.raises(FitError, match="3 rows for 2 problems"):
        fit_batch(wi, wo, v, "ggx", init={"alpha": [0.1, 0.2, 0.3]})


SHARDED = textwrap.dedent("""
    import json, sys
    import jax
    jax.config.update("jax_enable_x64", True)
    import numpy as np
    from brdf_fit.fit_batch import fit_batch
    d = np.load(sys.argv[1])
    out = {}
    for shard in (True, False):
        r = fit_batch(d["wi"], d["wo"], d["v"], "ggx", chunk_steps=8, shard=shard)
        out[str(shard)] = {"alpha": r.params["alpha"].tolist(), "f0": r.params["f0"].tolist(),
                           "converged": r.converged.tolist(), "n_devices": r.n_devices}
    out["devices"] = len(jax.devices())
    print(json.dumps(out))
""")


def test_sharded_on_two_host_devices(tmp_path):
    """A fresh process (XLA_FLAGS must be set before jax is imported) with 2 host devices: the
    batch (5 problems, padded to 6) is laid over both and matches the unsharded results."""
    truths = TRUTHS + [(0.3, [0.5, 0.5, 0.5])]
    wi, wo, v = batch(truths, noise=0.01, seed=6)
    np.savez(tmp_path / "d.npz", wi=wi, wo=wo, v=v)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    root = Path(__file__).resolve().parents[1]
    p = subprocess.run([sys.executable, "-c", SHARDED, str(tmp_path / "d.npz")], env=env,
                       capture_output=True, text=True, cwd=root, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2
    sh, un = out["True"], out["False"]
    assert sh["n_devices"] == 2 and un["n_devices"] == 1
    assert all(sh["converged"]) and all(un["converged"])
    np.testing.assert_allclose(sh["alpha"], un["alpha"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(sh["f0"], un["f0"], rtol=0, atol=1e-8)
    r = fit_batch(wi, wo, v, "ggx", chunk_steps=8)  # and this process (1 device) agrees
    np.testing.assert_allclose(sh["f0"], r.params["f0"], rtol=0, atol=1e-8)


def test_grid_guess_starts_no_worse_and_reaches_the_same_optimum():
    """guess="grid" (default) vs guess="none" (registry defaults): the same optimum; the grid's
    start has a loss no higher than the defaults' (the defaults are one of its candidates)."""
    from brdf_fit import guess as G

    truths = [(0.05, [0.9, 0.9, 0.9]), (0.7, [0.1, 0.1, 0.1]), (0.3, [0.5, 0.4, 0.3])]
    wi, wo, v = batch(truths, noise=0.01, seed=7)
    grid = fit_batch(wi, wo, v, "ggx")
    none = fit_batch(wi, wo, v, "ggx", guess="none")
    assert grid.converged.all() and none.converged.all()
    np.testing.assert_allclose(grid.params["alpha"], none.params["alpha"], rtol=1e-6)
    np.testing.assert_allclose(grid.params["f0"], none.params["f0"], rtol=0, atol=1e-6)
    assert [r for r in grid.rounds if r.get("guess")][0]["candidates"] == G.GUESS_CANDIDATES
    assert not [r for r in none.rounds if r.get("guess")]
    start_grid = fit_batch(wi, wo, v, "ggx", max_steps=0)  # no iterations: the start itself
    start_none = fit_batch(wi, wo, v, "ggx", max_steps=0, guess="none")
    np.testing.assert_allclose(start_none.params["alpha"], 0.3)
    sub = G.subsample(wi.shape[1])
    for b in range(3):  # compare on the subsample the guess was chosen on
        ls = [fit_batch(wi[b:b + 1, sub], wo[b:b + 1, sub], v[b:b + 1, sub], "ggx",
                        init={k: s.params[k][b:b + 1] for k in ("alpha", "f0")},
                        max_steps=0).loss[0] for s in (start_grid, start_none)]
        assert ls[0] <= ls[1] * (1 + 1e-12)
    with pytest.raises(FitError, match="unknown guess"):
        fit_batch(wi, wo, v, "ggx", guess="moments")


def test_at_bound_flags_and_progress():
    """An f0 channel whose data need reflectance > 1 ends at the bound and is flagged; the
    progress callback sees the start, every chunk, and all problems finished at the end."""
    wi, wo, v = batch([(0.2, [0.5, 0.5, 0.5]), (0.2, [0.5, 0.5, 0.5])], seed=8)
    v[1, :, 0] *= 4.0  # red needs F > 1 at every angle: f0_r runs to 1
    calls = []
    r = fit_batch(wi, wo, v, "ggx", progress=lambda d, t, s: calls.append((d, t, s)))
    assert r.at_bound["alpha"].tolist() == [False, False]
    assert r.at_bound["f0"].tolist() == [[False] * 3, [True, False, False]]
    assert r.to_dict()["at_bound"]["f0"][1] == [True, False, False]
    assert calls[0] == (0, 2, "start") and calls[-1][:2] == (2, 2)
    assert [c[2] for c in calls[1:]] == [f"chunk {k}" for k in range(1, len(calls))]
    data = GonioData(wi=wi[1], wo=wo[1], value=v[1], channels=("R", "G", "B"))
    assert fit(data, "ggx").at_bound == ("f0",)
