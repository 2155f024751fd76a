"""Large-data fits (brdf_fit.fitting.chunked): the normal equations summed over chunks give the
dense solver's optimum, standard errors and diagnostics; the chunk layout; the time and step
limits; a whole MERL file in bounded memory (slow set: a subprocess measures its peak)."""

import json
import os
import subprocess
import sys

import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import PEAK_RSS_CODE, peak_kib, random_dirs

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fitting import chunked, solvers
from brdf_fit.fitting.problem import FitProblem
from brdf_fit.fitting.single import _arrays, fit

#: samples of the synthetic data and the chunk size that splits them into many chunks (and a
#: coarse subset of COARSE_CHUNKS of them) while the dense solver still fits them in moments
N_SAMPLES = 3000
SMALL_CHUNK = 256
TRUTH = {"alpha": 0.23, "f0": [0.9, 0.6, 0.3]}
START = {"alpha": 0.5, "f0": [0.5, 0.5, 0.5]}


def _data(noise: float, sigma: bool, seed: int = 3):
    rng = np.random.default_rng(seed)

    wi, wo = random_dirs(rng, N_SAMPLES, 0.05), random_dirs(rng, N_SAMPLES, 0.05)
    m = registry.get("ggx").build(**TRUTH)
    v = np.asarray(m.eval(jnp.asarray(wi), jnp.asarray(wo)))
    v = v * np.exp(noise * rng.standard_normal(v.shape))
    return GonioData(wi=wi, wo=wo, value=v, channels=("R", "G", "B"),
                     sigma=noise * v if sigma else None)


@pytest.fixture
def small_chunks(monkeypatch):
    """fit() takes the chunked path for this file's data, in chunks of SMALL_CHUNK samples."""
    monkeypatch.setattr(chunked, "CHUNKED_FROM", 1)
    monkeypatch.setattr(chunked, "CHUNK", SMALL_CHUNK)


@pytest.mark.parametrize("sigma", [False, True], ids=["sandwich", "pooled"])
def test_chunked_equals_dense(sigma, monkeypatch):
    """Same optimum, standard errors (the HC1 sandwich without sigma, the pooled estimator with
    it), loss and rms as the dense optimistix path, on 2% noise from a start away from the
    truth: the sums are the dense quantities reordered, so they agree to rounding of the
    optimum (tolerances 1e-10). The chunked path's sandwich is HC1 (no leverages without a
    second pass; fitting.solvers.SANDWICH), so the dense reference is told to use HC1 too."""
    d = _data(0.02, sigma)
    monkeypatch.setattr(solvers, "SANDWICH", "HC1")  # the dense path reads it on the host
    dense = fit(d, "ggx", init=START)
    monkeypatch.setattr(chunked, "CHUNKED_FROM", 1)
    monkeypatch.setattr(chunked, "CHUNK", SMALL_CHUNK)
    big = fit(d, "ggx", init=START)
    assert dense.converged and big.converged, (dense.message, big.message)
    for k in TRUTH:
        np.testing.assert_allclose(big.params[k], dense.params[k], rtol=1e-7, err_msg=k)
        np.testing.assert_allclose(big.stderr[k], dense.stderr[k], rtol=1e-5, err_msg=k)
    np.testing.assert_allclose(big.loss, dense.loss, rtol=1e-9)
    np.testing.assert_allclose(big.residual_rms, dense.residual_rms, rtol=1e-9)
    assert big.n_samples == dense.n_samples == N_SAMPLES
    assert big.undetermined == dense.undetermined == ()
    np.testing.assert_allclose(big.correlation, dense.correlation, rtol=0, atol=1e-6)


def test_chunk_layout():
    """A sorted random subset in front, then every sample in order, padding of scale 0."""
    d = _data(0.0, False)
    prob = FitProblem.of("ggx", n_channels=3)
    arrays, n = _arrays(d, None, np.float64)
    c = chunked.chunk_data(prob, arrays, n, seed=5, chunk=SMALL_CHUNK)
    wi = np.asarray(c.prep[0]).reshape(-1, 3)
    scale = np.asarray(c.prep[4]).reshape(-1, 3)
    k = chunked.COARSE_CHUNKS * SMALL_CHUNK
    assert c.coarse_chunks == chunked.COARSE_CHUNKS
    assert c.n_chunks * SMALL_CHUNK >= n and wi.shape[0] == k + c.n_chunks * SMALL_CHUNK
    # the subset: distinct samples of the data, in the data's order
    idx = [int(np.flatnonzero((d.wi == row).all(1))[0]) for row in wi[:k]]
    assert len(set(idx)) == k and idx == sorted(idx)
    np.testing.assert_array_equal(wi[k:k + n], d.wi)
    assert np.all(scale[:k + n] == 1.0) and np.all(scale[k + n:] == 0.0)
    np.testing.assert_array_equal(wi[k + n:], np.tile([0.0, 0.0, 1.0], (wi.shape[0] - k - n, 1)))
    # fewer samples than the subset would take: no subset
    few = chunked.chunk_data(prob, tuple(a[:100] if isinstance(a, np.ndarray) else a
                                         for a in arrays), 100, chunk=SMALL_CHUNK)
    assert few.coarse_chunks == 0 and few.n_chunks == 1


@pytest.mark.parametrize("model", ["mitsuba-roughconductor", "ggx-aniso"])
@pytest.mark.parametrize("sandwich", [False, True])
def test_pairwise_sums_equal_stacked(model, sandwich):
    """The chunk's sums formed tangent pair by tangent pair (``_lm.quad_pairs``, what the
    chunked fit runs) equal the stacked form (``_lm.quad``, the batch solver's) to rounding:
    channel parameters (RGB eta, k) and a shared vector alike, with and without the meat."""
    import jax

    from brdf_fit.fitting import _lm

    rng = np.random.default_rng(7)
    wi, wo = random_dirs(rng, 500, 0.05), random_dirs(rng, 500, 0.05)
    prob = FitProblem.of(model, n_channels=3)
    f = np.exp(rng.normal(0.0, 1.0, (500, 3)))
    arrays = (wi, wo, f, None, None, np.zeros(()))
    prep = tuple(None if a is None else jnp.asarray(a) for a in prob.prepare(arrays, np))
    dq = _lm.directions(prob, 3)
    u = jnp.asarray(rng.normal(0.0, 0.5, prob.layout.size))
    want = jax.jit(lambda u: _lm.quad(prob, dq, u, prep, prob.fixed, sandwich))(u)
    got = jax.jit(lambda u: _lm.quad_pairs(prob, dq, u, prep, prob.fixed, sandwich))(u)
    for w, g in zip(want, got, strict=True):
        np.testing.assert_allclose(np.asarray(g), np.asarray(w), rtol=1e-12,
                                   atol=1e-12 * float(np.max(np.abs(np.asarray(w))) + 1e-300))


def test_full_stage_starts_no_more_damped_than_a_fresh_start(small_chunks, monkeypatch):
    """However damped the subset's stage ends (a subset solved to rounding ends with rejected
    steps that each multiply lam: 1e21 on a MERL plastic fitted with GGX), the whole data's
    stage starts from at most the initial damping: it converges, as from the subset's
    optimum it should, instead of rejecting every step."""
    import dataclasses

    run = chunked._run_stage

    def spent(progs, state, prep, rows, fx, budget, deadline, progress, stage):
        state, steps, why = run(progs, state, prep, rows, fx, budget, deadline, progress, stage)
        if stage == "coarse":
            state = dataclasses.replace(state, lam=jnp.asarray(1e21, state.lam.dtype))
        return state, steps, why

    monkeypatch.setattr(chunked, "_run_stage", spent)
    steps = []
    r = fit(_data(0.02, False), "ggx", init=START, progress=lambda *a: steps.append(a[0]))
    assert r.converged, r.message
    assert 0 < steps.count("full") <= 5
    np.testing.assert_allclose(r.params["alpha"], TRUTH["alpha"], rtol=0.05)


def test_limits_are_reported(small_chunks):
    """A time limit passed and a step budget spent end not converged, each saying why."""
    d = _data(0.02, False)
    r = fit(d, "ggx", init=START, time_limit=1e-9)
    assert not r.converged and "time limit" in r.message
    r = fit(d, "ggx", init=START, max_steps=2)
    assert not r.converged and r.steps == 2 and "did not converge in 2 steps" in r.message


def test_progress_reports_each_step(small_chunks):
    seen = []
    r = fit(_data(0.02, False), "ggx", init=START,
            progress=lambda stage, step, loss: seen.append((stage, step, loss)))
    assert r.converged
    stages = [s for s, _, _ in seen]
    assert stages[0] == "coarse" and set(stages) <= {"coarse", "full"}
    assert len(seen) == r.steps
    assert all(np.isfinite(loss) for _, _, loss in seen)


@pytest.mark.slow
def test_whole_merl_file_in_bounded_memory(tmp_path):
    """`brdf-fit fit` on a whole MERL file (1,096,216 valid bins per channel of Mitsuba's
    roughconductor as transcribed here) from a generic start: converged to the rendered alpha,
    with the peak resident memory of the process below 1 GiB (it was 4.7-5.1 GiB with the
    dense Jacobian)."""
    from brdf_fit.io.merl import write_merl

    path = tmp_path / "conductor.binary"
    write_merl(path, registry.get("mitsuba-roughconductor").build(alpha=np.array(0.12)))
    code = PEAK_RSS_CODE + ("from brdf_fit.cli import main\n"
                            "status = main(_s.argv[1:])\n"
                            "_peak()\n"
                            "_s.exit(status)\n")
    env = {**os.environ, "BRDF_FIT_CACHE_DIR": str(tmp_path / "cache")}
    out = subprocess.run(
        [sys.executable, "-c", code, "fit", str(path), "--model", "mitsuba-roughconductor",
         "--init", "alpha=0.3", "--init", "eta=1,1,1", "--init", "k=1,1,1", "--json",
         "--quiet"], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads(out.stdout)
    assert doc["converged"] and doc["n_samples"] == 1096216
    assert abs(doc["params"]["alpha"] - 0.12) < 1e-6
    assert peak_kib(out.stderr) < 1024 * 1024, out.stderr[-500:]  # KiB


def test_parameters_on_their_bounds(small_chunks):
    """Data 20 times too bright for the models: a lambert fit runs every rho onto its upper
    bound, a constrained optimum reported converged and at bound (converged_at_bounds); a GGX
    fit runs f0 onto its bound: converged at bound where alpha settles, else not converged
    with a message that says which parameter sits at its bound (measured: from the default
    start alpha still creeps at the stall; the dense solver ends both at max_steps)."""
    import dataclasses

    d = _data(0.02, False)
    d = dataclasses.replace(d, value=d.value * 20)
    r = fit(d, "lambert")
    assert r.converged and r.at_bound == ("rho",)
    np.testing.assert_allclose(r.params["rho"], 1.0, rtol=1e-6)
    assert np.all(np.isnan(r.stderr["rho"]))
    for init in ({}, START):  # one start stalls while alpha creeps, the other settles
        r = fit(d, "ggx", init=init)
        assert "f0" in r.at_bound
        np.testing.assert_allclose(r.params["f0"], 1.0, rtol=1e-4)
        assert r.converged or ("without converging" in r.message
                               and "f0 at an end of its interval" in r.message), r.message
