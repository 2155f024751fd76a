"""Parameter recovery over the whole registry (issue 5, "Done"), and a coverage study of the fit's
standard errors.

1. Noise-free recovery: every registry entry that is not a delta lobe recovers its own parameters
   to 1e-6 relative (float64) from a start away from the truth. Parametrised over
   ``registry.names()``, so a new model is covered automatically (it needs no entry here unless
   a parameter of it is not identifiable; then it goes in :data:`HELD` or :data:`XFAIL` with the
   reason).

   Truth: the registry default moved inside its interval (:func:`perturb`): a parameter on a
   bounded interval of width <= 10 (albedos, f0, alpha) by ``+0.07, -0.05, +0.03 (x width)`` per
   channel, kept 5% of the width away from the ends; any other (eta, k, exponents) scaled by
   ``1.15, 0.9, 1.05`` per channel. Start (:func:`start_from`): a bounded parameter 0.1 x width
   toward the interval's middle, any other x 1.25 (a 20-40% relative offset for most).

   Plan (:func:`plan`): 400 random pairs uniform in solid angle up to 85 deg (seeded) plus the
   in-plane sweeps ``theta_i`` = 0, 30, 60, 80, 85 deg x ``theta_o`` = -85..85 deg step 5 (so the
   specular peaks and in-plane grazing are sampled): 575 samples.

2. Coverage (slow): 200 seeded trials of 1% lognormal noise (``v exp(0.01 z)``, sigma = 0.01 v
   as :class:`data_synth.noise.Lognormal` estimates it) for ggx, beckmann and modified-phong; each
   recovered parameter must lie within 3 standard errors of the truth in >= 95% of the trials.
   The 200 fits run batched (``jax.vmap`` of the same :func:`brdf_fit.fitting.single.solve`
   that :func:`brdf_fit.fitting.single.fit` runs, with fit()'s standard-error formula); the batch
   reproduces fit()'s parameters and standard errors on the first trials (asserted), so the
   study measures fit() without 600 separate compilations (about 6 s each on this CPU).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.data import GonioData
from brdf_fit.fitting.problem import FitProblem
from brdf_fit.fitting.single import covariance, fit, solve
from data_synth.plans import in_plane, random_sparse

RTOL = 1e-6

#: Parameters held fixed at the truth (not identifiable from eval), with the reason.
HELD = {
    "granier-heidrich": {
        "d": "the layer thickness enters eval only through the per-channel constant kd D(eta, d) "
             "(eta is fixed by the specular part): changing d and rescaling kd leaves eval "
             "identical to 1e-13 (tests/test_granier_heidrich.py)",
    },
    "phong-energy-normalized-arvo": {
        "exponent": "the Arvo path rounds the exponent to an integer (lobe and normaliser), so "
                    "eval is piecewise constant in it: zero gradient, no unique optimum",
    },
}
#: Truth overrides, with the reason (defaults that sit where a parameter is not identifiable).
TRUTH = {
    # the registry's gold default has its red channel at the bounds (eta = 0.001, k = 100) where
    # F ~ 1 and dF/d(eta, k) ~ 0 (see tests/test_fit.py): a perturbed default there is not
    # identifiable; use a mid-range metal
    "ggx-conductor": {"eta": [0.27, 0.68, 1.32], "k": [3.6, 2.6, 2.3]},
    "ggx-conductor-aniso": {"eta": [0.27, 0.68, 1.32], "k": [3.6, 2.6, 2.3]},
}
#: Solver steps beyond the default 256, with the reason (identifiable, but slow to converge).
MAX_STEPS = {
    # metallic (the metal F0 = base colour) and specularColor (the dielectric F0) both move the
    # specular level: a long narrow valley; measured 609 LM steps to the truth (residual
    # 2.6e-17) from the standard start, 2e-8 after 256
    "gltf-pbr-specular": 1000,
}
#: Expected failures (strict): a test here that starts passing is reported.
XFAIL: dict[str, str] = {}
#: Cases excluded from the default run (each 5-40 s, measured: four compilations per fit() call):
#: the ones tests/test_fit.py already recovers by default (first line), close variants of a
#: default case, and the slowest (phong-energy-normalized ~40 s, cook-torrance ~24 s).
SLOW = {
    "ggx", "beckmann", "ggx-aniso", "ggx-conductor", "lambert", "ggx-plastic",
    "ggx-separable", "beckmann-walter", "beckmann-aniso", "ggx-conductor-aniso",
    "modified-phong-fresnel", "blinn-phong-approx", "phong-energy-normalized", "cook-torrance",
    # keep the default suite near its time budget: these share their code path with a default
    # case (torrance-sparrow: cook-torrance's lobe; blinn-phong: blinn-phong-approx's sampler)
    "torrance-sparrow", "blinn-phong",
}

CH_OFFSETS = (0.07, -0.05, 0.03)
CH_FACTORS = (1.15, 0.9, 1.05)


def _bounded(p):
    return p.lo is not None and p.hi is not None and (p.hi - p.lo) <= 10.0


def perturb(p, default):
    d = np.asarray(default, float)
    k = np.arange(d.size) % 3
    if _bounded(p):
        w = p.hi - p.lo
        t = d.ravel() + w * np.asarray(CH_OFFSETS)[k]
        t = np.clip(t, p.lo + 0.05 * w, p.hi - 0.05 * w)
    else:
        t = d.ravel() * np.asarray(CH_FACTORS)[k]
    return t.reshape(d.shape)


def start_from(p, truth):
    t = np.asarray(truth, float)
    if _bounded(p):
        w = p.hi - p.lo
        mid = 0.5 * (p.lo + p.hi)
        return np.where(t < mid, t + 0.1 * w, t - 0.1 * w)
    return 1.25 * t


def plan():
    r = random_sparse(n=400, seed=7, max_zenith_deg=85.0)
    ip = in_plane(theta_i_deg=(0.0, 30.0, 60.0, 80.0, 85.0),
                  theta_o_deg=tuple(range(-85, 86, 5)))
    return np.concatenate([r.wi, ip.wi]), np.concatenate([r.wo, ip.wo])


def synth(entry, truth, wi, wo):
    v = np.asarray(entry.build(**truth).eval(jnp.asarray(wi), jnp.asarray(wo)), float)
    v = v if v.ndim == 2 else v[:, None]
    ch = ("R", "G", "B") if v.shape[1] == 3 else ("Y",)
    return GonioData(wi=wi, wo=wo, value=v, channels=ch)


def truth_and_start(entry):
    over = TRUTH.get(entry.name, {})
    truth, start = {}, {}
    for p in entry.params:
        t = np.asarray(over[p.name], float) if p.name in over else perturb(p, p.default_value())
        truth[p.name] = t
        start[p.name] = start_from(p, t)
    return truth, start


def _case(name):
    entry = registry.get(name)
    marks = []
    if name in SLOW:
        marks.append(pytest.mark.slow)
    if name in XFAIL:
        marks.append(pytest.mark.xfail(strict=True, reason=XFAIL[name]))
    return pytest.param(name, marks=marks, id=name) if "delta" not in entry.tags else None


CASES = [c for c in (_case(n) for n in registry.names()) if c is not None]


def test_every_non_delta_entry_is_a_case():
    """The parametrisation follows the registry (only delta lobes are left out)."""
    ids = {c.id for c in CASES}
    want = {e.name for e in registry.entries() if "delta" not in e.tags}
    assert ids == want and "mirror" not in ids


@pytest.mark.parametrize("name", CASES)
def test_noise_free_recovery(name):
    entry = registry.get(name)
    truth, start = truth_and_start(entry)
    held = HELD.get(name, {})
    fix = {k: truth[k] for k in held}
    init = {k: v for k, v in start.items() if k not in held}
    wi, wo = plan()
    data = synth(entry, truth, wi, wo)
    r = fit(data, name, fix=fix, init=init, max_steps=MAX_STEPS.get(name, 256))
    assert r.converged, r.message
    for k, v in truth.items():
        np.testing.assert_allclose(r.params[k], v, rtol=RTOL, atol=0, err_msg=f"{name}: {k}")
    assert r.residual_rms < 1e-8


# ----------------------------------------------------------------------------- coverage study

N_TRIALS = 200
NOISE = 0.01
COVERAGE = {
    "ggx": {"alpha": 0.23, "f0": 0.6},
    "beckmann": {"alpha": 0.31, "f0": 0.45},
    "modified-phong": {"rho_d": 0.2, "rho_s": 0.5, "exponent": 30.0},
    "ward": {"rho_d": 0.2, "rho_s": 0.3, "alpha_x": 0.12, "alpha_y": 0.3},
}


def batched_fits(name, truth, use_sigma=True, n_trials=N_TRIALS, seed0=0):
    """Fit ``n_trials`` noisy copies at once: (params (T, p), stderr (T, p), converged (T,),
    the datasets of the first two trials). Mono channel; the same problem, start (the truth),
    solver and standard-error formula as :func:`brdf_fit.fitting.single.fit` with its defaults."""
    entry = registry.get(name)
    wi, wo = plan()
    clean = np.asarray(entry.build(**truth).eval(jnp.asarray(wi), jnp.asarray(wo)), float)
    clean = clean.reshape(-1, 1)
    F, S = [], []
    for t in range(n_trials):
        rng = np.random.default_rng(seed0 + t)
        v = clean * np.exp(NOISE * rng.standard_normal(clean.shape))
        F.append(v)
        S.append(NOISE * np.abs(v))
    F, S = np.stack(F), np.stack(S)
    free = entry.param_names
    shapes = tuple((1,) if entry.param(n).channels else () for n in free)
    prob = FitProblem.of(entry, free, shapes)
    trs = prob.transforms
    u0 = jnp.asarray(np.concatenate([np.atleast_1d(tr.inverse(truth[n])).ravel()
                                     for n, tr in zip(free, trs, strict=True)]))
    Wi, Wo = jnp.asarray(wi), jnp.asarray(wo)
    w = jnp.ones((wi.shape[0], 1))

    def one(f, s):
        sig = s if use_sigma else None
        arrays = (Wi, Wo, f, w, sig, 0.0)
        u, ok, _ = solve(prob, u0, arrays)
        x = jnp.stack([jnp.ravel(tr.forward(u[k]))[0] for k, tr in enumerate(trs)])

        def resid(x):  # the residual of fit(), in the physical parameters
            return prob.residuals_phys(x, arrays)

        r = resid(x)
        J = jax.jacfwd(resid)(x)
        cov = covariance(J, r, r.shape[0], sandwich=not use_sigma)
        se = jnp.sqrt(jnp.maximum(jnp.diag(cov), 0.0))
        return x, se, ok

    x, se, ok = jax.jit(jax.vmap(one))(jnp.asarray(F), jnp.asarray(S))
    datasets = [GonioData(wi=wi, wo=wo, value=F[t], sigma=S[t] if use_sigma else None)
                for t in range(2)]
    return np.asarray(x), np.asarray(se), np.asarray(ok), datasets


def coverage(name, use_sigma=True):
    truth = COVERAGE[name]
    x, se, ok, datasets = batched_fits(name, truth, use_sigma)
    t = np.asarray([truth[n] for n in registry.get(name).param_names])
    inside = np.abs(x - t) <= 3.0 * se
    return x, se, ok, inside, datasets


@pytest.mark.slow
@pytest.mark.parametrize("use_sigma", [True, False], ids=["sigma", "no-sigma"])
@pytest.mark.parametrize("name", list(COVERAGE))
def test_three_sigma_coverage(name, use_sigma):
    """>= 95% of 200 seeded 1%-noise trials within 3 standard errors, per parameter, with the
    data carrying sigma (standardised residuals) and without (fit() then uses the HC1 sandwich;
    with a pooled s^2 coverage was 57-82%). The batch is first checked against fit() itself on
    two trials."""
    entry = registry.get(name)
    truth = COVERAGE[name]
    x, se, ok, inside, datasets = coverage(name, use_sigma)
    for t, d in enumerate(datasets):
        r = fit(d, name, init=truth)
        for k, n in enumerate(entry.param_names):
            np.testing.assert_allclose(np.ravel(r.params[n])[0], x[t, k], rtol=1e-6)
            np.testing.assert_allclose(np.ravel(r.stderr[n])[0], se[t, k], rtol=1e-4)
    assert ok.all()
    frac = inside.mean(axis=0)
    assert math.isfinite(float(se.sum()))
    for k, n in enumerate(entry.param_names):
        assert frac[k] >= 0.95, f"{name}.{n}: {frac[k]:.3f} of {N_TRIALS} within 3 SE"
