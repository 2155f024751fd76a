"""Batch fitting: fit_batch equals fit() problem by problem, stragglers are re-solved without
touching the easy problems, per-problem flags, and the sharded path on 2 host devices."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fitting.batch import fit_batch
from brdf_fit.fitting.single import FitError, fit

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
        assert r.n_samples[b] == s.n_samples
        if noise == 0.0:
            # exact data: both fits reproduce it; what remains of loss, rms and standard error
            # says where each solver stopped inside its tolerance (batch-lm: alpha to 7e-11
            # relative, loss 1.5e-21; fit(): 1e-15, 3e-28 - measured), so only their
            # vanishing is compared, not their values
            np.testing.assert_allclose(r.params["alpha"][b], TRUTHS[b][0], rtol=1e-7)
            for x in (r, s):
                assert np.max(np.asarray(x.loss)) < 1e-18
                assert np.all(np.asarray(x.stderr["alpha"]) < 1e-9 * TRUTHS[b][0])
                assert np.all(np.asarray(x.stderr["f0"]) < 1e-9)
            continue
        np.testing.assert_allclose(r.stderr["alpha"][b], s.stderr["alpha"], rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(r.stderr["f0"][b], s.stderr["f0"], rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(r.loss[b], s.loss, rtol=1e-9, atol=1e-20)
        np.testing.assert_allclose(r.residual_rms[b], s.residual_rms, rtol=1e-7, atol=1e-14)


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
    from brdf_fit.fitting.batch import fit_batch
    d = np.load(sys.argv[1])
    out = {}
    for shard in (True, False):
        r = fit_batch(d["wi"], d["wo"], d["v"], "ggx", chunk_steps=8, shard=shard)
        out[str(shard)] = {"alpha": r.params["alpha"].tolist(), "f0": r.params["f0"].tolist(),
                           "converged": r.converged.tolist(), "n_devices": r.n_devices}
    # one geometry for all problems (the shared guess, its program split over the devices)
    for shard in (True, False):
        r = fit_batch(d["wi"][0], d["wo"][0], d["v"], "ggx", chunk_steps=8, shard=shard)
        out[f"shared {shard}"] = {
            "alpha": r.params["alpha"].tolist(), "f0": r.params["f0"].tolist(),
            "guess": [x.get("shared") for x in r.rounds if x.get("guess")]}
    out["devices"] = len(jax.devices())
    print(json.dumps(out))
""")


def test_sharded_on_two_host_devices(tmp_path):
    """A fresh process (XLA_FLAGS must be set before jax is imported) with 2 host devices: the
    batch (5 problems, padded to 6) is laid over both and matches the unsharded results, with
    per-problem directions and with one geometry for all (the shared guess)."""
    truths = TRUTHS + [(0.3, [0.5, 0.5, 0.5])]
    wi, wo, v = batch(truths, noise=0.01, seed=6)
    np.savez(tmp_path / "d.npz", wi=wi, wo=wo, v=v)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    root = Path(__file__).resolve().parents[2]
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
    sh, un = out["shared True"], out["shared False"]
    assert sh["guess"] == un["guess"] == [True]
    np.testing.assert_allclose(sh["alpha"], un["alpha"], rtol=0, atol=1e-8)
    np.testing.assert_allclose(sh["f0"], un["f0"], rtol=0, atol=1e-8)


def test_grid_guess_starts_no_worse_and_reaches_the_same_optimum():
    """guess="grid" (default) vs guess="none" (registry defaults): the same optimum; the grid's
    start has a loss no higher than the defaults' (the defaults are one of its candidates)."""
    from brdf_fit.fitting import guess as G

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


# --------------------------------------------------------------------------- structured Jacobian


def _problem_at(entry, rng, metric="log", cos_weight=False):
    from brdf_fit.fitting.problem import FitProblem
    d = {n: (np.broadcast_to(v, (3,)) if entry.param(n).channels and v.size in (1, 3) else v)
         for n, v in entry.defaults().items()}  # channel parameters (C,), as fit_batch has them
    free = entry.param_names
    shapes = tuple(np.shape(d[n]) for n in free)
    prob = FitProblem.of(entry, free, shapes, metric=metric, cos_weight=cos_weight)
    u = prob.layout.inverse(d)
    return prob, u + 0.3 * rng.standard_normal(u.shape)


def _check_structured(entry, prob, u, n=24, seed=0):
    """Residuals and Jacobian of fit_batch's structured path against jacfwd of fit()'s
    residual; returns the largest relative Jacobian error."""
    import jax

    from brdf_fit.fitting._lm import directions as tangent_directions
    from brdf_fit.fitting._lm import tangents
    from brdf_fit.fitting.problem import RELATIVE_FLOOR
    rng = np.random.default_rng(seed)
    wi, wo = directions(rng, n), directions(rng, n)
    # every evaluation jitted: one compilation is far cheaper than running a complex model
    # (ggx-conductor's complex Fresnel) primitive by primitive (measured: 19 s -> 3 s)
    f = np.abs(np.asarray(jax.jit(lambda x: entry.build(**prob.unflatten(x)).eval(
        jnp.asarray(wi), jnp.asarray(wo)))(jnp.asarray(u))))
    f = np.broadcast_to(f.reshape(n, -1), (n, 3)) * np.exp(0.1 * rng.standard_normal((n, 3)))
    raw = (wi, wo, f, np.ones_like(f), None, RELATIVE_FLOOR * f.max())
    dirs, Q = tangent_directions(prob, 3)
    r, T = jax.jit(lambda x: tangents(prob, dirs, x, prob.prepare(raw), {}))(jnp.asarray(u))
    J_ref, r_ref = jax.jit(lambda x: (jax.jacfwd(lambda y: prob.residuals(y, raw))(x),
                                      prob.residuals(x, raw)))(jnp.asarray(u))
    J_ref = np.asarray(J_ref)
    np.testing.assert_allclose(np.asarray(r).reshape(-1), np.asarray(r_ref),
                               rtol=1e-12, atol=1e-13)
    # the full Jacobian (M C, p) of the flattened residual: tangent a of residual (m, c)
    # is column Q[c, a]
    J = np.einsum("amc,cap->mcp", np.asarray(T), Q).reshape(-1, Q.shape[-1])
    return float(np.max(np.abs(J - J_ref)) / max(np.max(np.abs(J_ref)), 1e-300)), len(dirs)


#: a cheap cross-section of the families (channel parameters, complex-index Fresnel, several
#: lobes, anisotropy, shared vector parameters); every entry runs with -m slow (stop 36: six of
#: the twelve moved there, 29 s for the twelve by default, stop 35's profile)
STRUCTURED_FAST = ("lambert", "ggx", "ggx-conductor", "ggx-aniso", "ward", "lafortune")


@pytest.mark.parametrize("name", [
    n if n in STRUCTURED_FAST else pytest.param(n, marks=pytest.mark.slow)
    for n in registry.names() if "delta" not in registry.get(n).tags])  # delta: never fitted
def test_structured_jacobian_matches_jacfwd(name):
    """fit_batch's 'one tangent per channel parameter' Jacobian rests on every channel's
    residual depending only on its own entry of a channel parameter: checked per model against
    jacfwd of the flattened fit() residual (and the prepared residual against fit()'s)."""
    entry = registry.get(name)
    prob, u = _problem_at(entry, np.random.default_rng(3))
    err, _ = _check_structured(entry, prob, u)
    assert err < 1e-12, err


def test_structured_jacobian_detects_channel_mixing():
    """The check above has teeth: a model whose red channel leaks into the others breaks the
    block-diagonal assumption and fails it."""
    from brdf_fit.registry import Entry
    ggx = registry.get("ggx")

    class Mixing:
        def __init__(self, inner):
            self.inner = inner

        def eval(self, wi, wo):
            m = self.inner.eval(wi, wo)
            return m + 0.2 * m[..., :1]

    entry = Entry(name="mixing", builder=lambda **p: Mixing(ggx.builder(**p)),
                  params=ggx.params, reference="test", description="test")
    prob, u = _problem_at(entry, np.random.default_rng(3))
    err, _ = _check_structured(entry, prob, u)
    assert err > 1e-3


def _metric_reference(name, m, f, c, sigma, w, floor, cos_weight):
    """The residual metrics written out from their definitions (fit.py's module docstring),
    independently of brdf_fit.fitting.problem.metric_parts."""
    if name == "log":
        g, dg = np.log1p(m * c) - np.log1p(f * c), c / (1.0 + f * c)
    elif name == "cuberoot":
        g, dg = np.cbrt(m) - np.cbrt(f), 1.0 / (3.0 * np.cbrt(np.maximum(f, floor)) ** 2)
    elif name == "relative":
        den = np.maximum(f, floor)
        g, dg = (m - f) / den, 1.0 / den
    else:
        g, dg = m - f, np.ones_like(f)
    r = np.where(w > 0, g / (dg * sigma), 0.0) if sigma is not None else g * np.sqrt(w)
    return r * c if cos_weight else r


@pytest.mark.parametrize("metric", ["log", "cuberoot", "relative", "absolute"])
@pytest.mark.parametrize("sigma", ["none", "weights", "sigma"])
@pytest.mark.parametrize("cos_weight", [False, True], ids=["", "cos"])
def test_prepared_residuals_equal_fit_residuals(metric, sigma, cos_weight):
    """The residual with the data side of the metric computed once (FitProblem.prepare, NumPy
    for the test, jax.numpy in fit() and fit_batch) equals the metric written out from its
    definition, for every metric, without weights, with weights (some zero) or sigma, and
    with cosine weighting; fit()'s flat residual is the same."""
    from brdf_fit.fitting.problem import RELATIVE_FLOOR
    rng = np.random.default_rng(5)
    entry = registry.get("ggx")
    prob, u = _problem_at(entry, rng, metric=metric, cos_weight=cos_weight)
    n = 30
    wi, wo = directions(rng, n), directions(rng, n)
    f = np.asarray(entry.build(alpha=0.2, f0=[0.9, 0.5, 0.1]).eval(jnp.asarray(wi),
                                                                   jnp.asarray(wo)))
    f = f * np.exp(0.05 * rng.standard_normal(f.shape))
    w = rng.uniform(0.5, 2.0, f.shape) * (rng.uniform(size=f.shape) > 0.2)
    sg = 0.01 * f + 1e-3 if sigma == "sigma" else None
    raw = (wi, wo, f, w, sg, RELATIVE_FLOOR * f.max())
    if sigma == "none":  # fit()'s residual with unit weights; the prepared one without any
        raw = (wi, wo, f, np.ones_like(f), None, RELATIVE_FLOOR * f.max())
        prep = prob.prepare((*raw[:3], None, *raw[4:]))
        assert (prep[4] is None) == (not cos_weight)
    else:
        prep = prob.prepare(raw)
    params = prob.unflatten(jnp.asarray(u))
    got = np.asarray(prob.residuals_prepared(params, prep))
    m = np.asarray(entry.build(**params).eval(jnp.asarray(wi), jnp.asarray(wo)))
    want = _metric_reference(metric, m, f, wi[:, 2:3], raw[4], raw[3], raw[5], cos_weight)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.asarray(prob.residuals(jnp.asarray(u), raw)), got.reshape(-1),
                               rtol=1e-12, atol=1e-14)


def _has_product_design(entry):
    kinds = {p.channels for p in entry.params}
    return kinds == {True, False} and not entry.channels_coupled


@pytest.mark.parametrize("name", [
    e.name if e.name == "gltf-pbr-specular" else pytest.param(e.name, marks=pytest.mark.slow)
    for e in registry.entries() if e.channels_coupled])  # one class: one entry by default
def test_models_that_couple_channels_take_no_channel_shortcut(name):
    """An entry that declares its channels coupled (glTF's max over the Fresnel colour) gets
    neither the one-tangent-per-channel-parameter Jacobian nor the per-channel guess: its
    structured Jacobian is jacfwd's (the test above, which it must pass all the same)."""
    from brdf_fit.fitting import guess as G

    entry = registry.get(name)
    prob, u = _problem_at(entry, np.random.default_rng(3))
    assert not any(prob.layout.structured(3))
    assert np.all(prob.layout.channel_index(3) == -1)
    assert G.layout(prob, prob.free) is None
    err, _ = _check_structured(entry, prob, u)
    assert err < 1e-12, err


@pytest.mark.parametrize("name", [
    n if n in STRUCTURED_FAST else pytest.param(n, marks=pytest.mark.slow)
    for n in registry.names() if _has_product_design(registry.get(n))])
def test_guess_pseudo_channels_equal_candidate_by_candidate(name):
    """The grid guess evaluates all channel levels of a shared point at once, as extra
    (pseudo-)channels; the per-channel losses equal evaluating every candidate on its own."""
    from brdf_fit.fitting import guess as G
    from brdf_fit.fitting.problem import RELATIVE_FLOOR
    entry = registry.get(name)
    rng = np.random.default_rng(7)
    prob, u = _problem_at(entry, rng)
    lay = G.layout(prob, prob.free)
    assert lay is not None
    cands = G.design(prob, u, prob.free, entry.defaults())
    n = 16
    wi, wo = directions(rng, n), directions(rng, n)
    f = np.abs(np.asarray(jax.jit(lambda x: entry.build(**prob.unflatten(x)).eval(
        jnp.asarray(wi), jnp.asarray(wo)))(jnp.asarray(u))))
    f = np.broadcast_to(f.reshape(n, -1), (n, 3)) * np.exp(0.1 * rng.standard_normal((n, 3)))
    prep = tuple(jnp.asarray(a) for a in prob.prepare(
        (wi, wo, f, np.ones_like(f), None, RELATIVE_FLOOR * f.max())))
    # jitted, both in one program (see _check_structured)
    got, want = (np.asarray(x) for x in jax.jit(lambda c: (
        G.candidate_losses(prob, c, prep, {}, lay),
        G.candidate_losses(prob, c, prep, {}, None)))(jnp.asarray(cands)))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)


@pytest.mark.parametrize("metric,weights,cos_weight", [
    ("log", False, False), ("log", True, False), ("cuberoot", True, True),
    ("absolute", False, True)])
def test_shared_guess_losses_equal_problem_by_problem(metric, weights, cos_weight):
    """guess.shared_losses (candidate values computed once for one geometry, every problem's
    losses by matrix products of the expanded square) equals the per-problem losses; the
    expansion's cancellation stays at rounding of the terms it subtracts."""
    from brdf_fit.fitting import guess as G
    from brdf_fit.fitting.problem import METRIC_H, RELATIVE_FLOOR, FitProblem

    entry = registry.get("ggx")
    rng = np.random.default_rng(5)
    B, m = 6, 40
    wi, wo = directions(rng, m), directions(rng, m)
    prob = FitProblem.of("ggx", ("alpha", "f0"), ((), (3,)), metric=metric,
                         cos_weight=cos_weight)
    f = np.asarray(entry.build(alpha=0.2, f0=[0.9, 0.5, 0.1]).eval(jnp.asarray(wi),
                                                                   jnp.asarray(wo)))
    f = f[None] * np.exp(0.2 * rng.standard_normal((B, m, 3)))
    w = rng.uniform(0.5, 2.0, f.shape) * (rng.uniform(size=f.shape) > 0.2) if weights else None
    prep = prob.prepare((wi[None], wo[None], f, w, None,
                         RELATIVE_FLOOR * f.max(axis=(1, 2))), jnp)
    u0 = prob.layout.inverse(entry.defaults(), lead=())
    lay = G.layout(prob, prob.free, G.SHARED_CANDIDATES)
    cands = jnp.asarray(G.design(prob, u0, prob.free, entry.defaults(), G.SHARED_CANDIDATES))
    vals = G.candidate_values(prob, cands, (prep[0][0], prep[1][0]), {}, lay, 3)
    got = np.asarray(G.shared_losses(prob, vals, prep[2][0], G.shared_terms(prep[3], prep[4])))
    for b in range(B):
        pb = tuple(None if x is None else (x[0] if x.shape[0] == 1 else x[b]) for x in prep)
        want = np.asarray(G.candidate_losses(prob, cands, pb, {}, lay))
        # the expanded terms are T = 0.5 sum s^2 (H^2 + g(f)^2): m eps T of rounding, at most
        H = np.asarray(METRIC_H[metric](vals * pb[2]))
        s2 = 1.0 if pb[4] is None else np.asarray(pb[4]) ** 2
        T = 0.5 * np.sum(s2 * (H ** 2 + np.asarray(pb[3]) ** 2), axis=1)
        np.testing.assert_allclose(got[b], want, rtol=0, atol=m * 2.3e-16 * T.max())
    with pytest.raises(ValueError, match="shared"):  # mul per problem (relative): refused
        G.shared_losses(prob, vals, prep[3], G.shared_terms(prep[3], None))


def test_float32_normal_equations_equal_the_einsum_form():
    """_lm.normal's float32 path (sample axis last, issue 15) forms the same J^T J and J^T r as
    the einsum of the float64 path, to float32 rounding (the channel parameter's Q included)."""
    from brdf_fit.fitting import _lm
    from brdf_fit.fitting.problem import FitProblem

    rng = np.random.default_rng(11)
    dirs, Q = _lm.directions(FitProblem.of("ggx", ("alpha", "f0"), ((), (3,)), metric="log"), 3)
    T = rng.standard_normal((len(dirs), 300, 3))
    r = rng.standard_normal((300, 3))
    A64, g64 = _lm.normal(jnp.asarray(T), jnp.asarray(r), Q)
    A32, g32 = _lm.normal(jnp.asarray(T, jnp.float32), jnp.asarray(r, jnp.float32), Q)
    assert A32.dtype == jnp.float32 and A32.shape == (4, 4) and g32.shape == (4,)
    np.testing.assert_allclose(np.asarray(A32), np.asarray(A64), rtol=2e-5, atol=2e-4)
    np.testing.assert_allclose(np.asarray(g32), np.asarray(g64), rtol=2e-5, atol=2e-4)
    # the float64 path is the einsum itself
    G = np.einsum("amc,bmc->cab", T, T)
    np.testing.assert_allclose(np.asarray(A64), np.einsum("cap,cab,cbq->pq", Q, G, Q),
                               rtol=1e-13)


def test_float32_batch_recovers_what_float64_does():
    """fit_batch(dtype=float32) on 1% noise: the same parameters as float64 to well inside
    the noise's effect (float32 tolerances 1e-5)."""
    wi, wo, v = batch(TRUTHS, noise=0.01, seed=4)
    r64 = fit_batch(wi, wo, v, "ggx")
    r32 = fit_batch(wi, wo, v, "ggx", dtype=jnp.float32, rtol=1e-5, atol=1e-5)
    assert r32.converged.all() and r32.params["alpha"].dtype == np.float32
    np.testing.assert_allclose(r32.params["alpha"], r64.params["alpha"], rtol=2e-4)
    np.testing.assert_allclose(r32.params["f0"], r64.params["f0"], rtol=0, atol=2e-4)
