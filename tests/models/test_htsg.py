"""He-Torrance-Sillion-Greenberg (brdf_fit.models.htsg) against an independent NumPy/SciPy
evaluation written from the paper in spherical angles, with the printed (unsimplified) geometric
factor G of eq. 76, Smith's S with the errata exponential, the effective roughness by Brent's
method, complex-arithmetic Fresnel and the series of eq. 78 summed to hundreds of terms by
log-sum-exp; plus exact identities (the T = 0 series in closed form, normal-incidence coherent
reflectance) and finite differences.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import assert_model_gradient_matches_fd, dir_from_cos
from _helpers import eval_cos_jit as _eval_cos
from _helpers import eval_jit as _eval_jit
from _helpers import random_dirs as _random_dirs
from scipy.optimize import brentq
from scipy.special import erfc, expi, gammaln, logsumexp

from brdf_fit import registry
from brdf_fit.core import quadrature
from brdf_fit.core.validate import ParameterError
from brdf_fit.models._base import astype
from brdf_fit.models.htsg import G_SERIES, HTSG, RGB_WAVELENGTHS
from brdf_fit.models.htsg import _series as _series_eager
from brdf_fit.verify import checks

LAM = np.asarray(RGB_WAVELENGTHS)
_series = jax.jit(_series_eager, static_argnums=3)
SMOOTH = dict(sigma0=0.18, tau=3.0, eta=[1.6, 1.5, 1.4], k=[0.2, 0.0, 3.0], albedo=[0.3, 0.2, 0.1])
ROUGH = dict(sigma0=1.1, tau=6.0, eta=[0.2, 1.1, 2.5], k=[3.9, 2.0, 0.5], albedo=[0.0, 0.5, 1.0])


def model(p):
    return HTSG(**{k: jnp.asarray(v) for k, v in p.items()}, wavelength=RGB_WAVELENGTHS)


N_PAIRS = 300  # every evaluation is padded to this batch: one compilation for the whole file


def _eval(m, wi, wo):
    wi, wo = jnp.broadcast_arrays(jnp.atleast_2d(wi), jnp.atleast_2d(wo))
    n = wi.shape[0]
    pad = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 1.0]), (N_PAIRS - n, 3))
    return _eval_jit(m, jnp.concatenate([wi, pad]), jnp.concatenate([wo, pad]))[:n]


def random_dirs(rng, n, lo=1e-2):
    return _random_dirs(rng, n, lo)


# ----------------------------------------------------------------------------- reference


def fresnel_complex(c, eta, k):
    """pbrt-v4 FrComplex (complex Snell + Fresnel amplitudes), unpolarised."""
    n = eta + 1j * k
    sin2_t = (1 - c * c) / (n * n)
    cos_t = np.sqrt(1 - sin2_t)
    r_par = (n * c - cos_t) / (n * c + cos_t)
    r_perp = (c - n * cos_t) / (c + n * cos_t)
    return 0.5 * (abs(r_par) ** 2 + abs(r_perp) ** 2)


def reference(wi, wo, p):
    """rho_dd + rho_ud for one pair, spherical angles and the paper's printed formulas."""
    sigma0, tau = p["sigma0"], p["tau"]
    th_i, th_r = math.acos(wi[2]), math.acos(wo[2])
    n = np.array([0.0, 0.0, 1.0])
    k_i, k_r = -wi, wo

    def K(th):
        t = math.tan(th)
        return t * erfc(tau / (2 * sigma0 * t)) if t > 0 else 0.0

    rhs = (K(th_i) + K(th_r)) / 4.0  # eq. 81: sqrt(pi/2) z0/s0 = rhs exp(-(z0/s0)^2/2)
    x = 0.0 if rhs == 0 else brentq(
        lambda x: math.sqrt(math.pi / 2) * x - rhs * math.exp(-x * x / 2), 0.0, 50.0,
        xtol=1e-15, rtol=1e-15)
    sigma = sigma0 / math.sqrt(1 + x * x)

    def S(th):  # eq. 24, 25 (errata)
        if th == 0:
            return 1.0
        a = tau / (2 * sigma0 * math.tan(th))
        lam_ = 0.5 * (math.exp(-a * a) / (a * math.sqrt(math.pi)) - erfc(a))
        return (1 - 0.5 * erfc(a)) / (lam_ + 1)

    v = k_r - k_i
    s_i = np.cross(k_i, n)
    s_i /= np.linalg.norm(s_i)
    p_i = np.cross(s_i, k_i)
    s_r = np.cross(k_r, n)
    s_r /= np.linalg.norm(s_r)
    p_r = np.cross(s_r, k_r)
    G = ((v @ v / v[2]) ** 2 * ((s_r @ k_i) ** 2 + (p_r @ k_i) ** 2)
         * ((s_i @ k_r) ** 2 + (p_i @ k_r) ** 2) / np.linalg.norm(np.cross(k_r, k_i)) ** 4)
    h = v / np.linalg.norm(v)
    out = []
    for c in range(3):
        lam = LAM[c]
        g = (2 * math.pi * sigma * (math.cos(th_i) + math.cos(th_r)) / lam) ** 2
        vxy2 = (2 * math.pi / lam) ** 2 * (v[0] ** 2 + v[1] ** 2)
        m = np.arange(1, int(g + 60 * math.sqrt(g) + 400))
        logt = m * math.log(g) - g - gammaln(m + 1) - np.log(m) - vxy2 * tau ** 2 / (4 * m)
        D = math.pi ** 2 * tau ** 2 / (4 * lam ** 2) * math.exp(logsumexp(logt))
        F = fresnel_complex(wi @ h, p["eta"][c], p["k"][c])
        dd = F * S(th_i) * S(th_r) * G * D / (math.pi * math.cos(th_i) * math.cos(th_r))
        out.append(dd + p["albedo"][c] / math.pi)
    return np.asarray(out)


@pytest.mark.parametrize("params", [SMOOTH, ROUGH], ids=["smooth", "rough"])
def test_matches_independent_reference(params):
    rng = np.random.default_rng(11)
    wi, wo = random_dirs(rng, N_PAIRS), random_dirs(rng, N_PAIRS)
    got = np.asarray(_eval(model(params), jnp.asarray(wi), jnp.asarray(wo)))
    want = np.stack([reference(a, b, params) for a, b in zip(wi, wo, strict=True)])
    dd_got = got - np.asarray(params["albedo"]) / math.pi
    dd_want = want - np.asarray(params["albedo"]) / math.pi
    scale = np.max(np.abs(dd_want), axis=0)
    # relative to the lobe's peak over the sample (values 1e-100 of the peak are round-off)
    err = np.max(np.abs(dd_got - dd_want) / scale)
    assert err < 1e-10, err
    big = np.abs(dd_want) > 1e-6 * scale
    rel = np.max(np.abs(dd_got - dd_want)[big] / np.abs(dd_want)[big])
    assert rel < 1e-9, rel
    if params is ROUGH:  # the rough case exercises the strided (trapezoid) series regime
        g_max = (4 * math.pi * params["sigma0"] / LAM.min()) ** 2
        assert g_max > 3 * G_SERIES


def test_series_closed_form_at_T0():
    """T = 0 (wi the mirror of wo): sum_m g^m/(m! m) = Ein(g) = Ei(g) - gamma - ln g, so
    Sigma' = e^-g (Ei(g) - gamma - ln g)/g, on both sides of the regime switch."""
    g = np.array([1e-2, 0.3, 2.0, 17.0, 54.0, 56.0, 120.0, 400.0, 700.0])
    want = np.exp(-g) * (expi(g) - np.euler_gamma - np.log(g)) / g
    gj = jnp.asarray(g)
    got = np.asarray(_series(jnp.log(gj), gj, jnp.zeros_like(gj), jnp.float64))
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_rough_limit_is_beckmann():
    """For large g the series tends to Beckmann's rough-surface form e^(-T/g)/g (the asymptote
    BBM and Westin blend in): relative difference O(1/g)."""
    g = jnp.asarray([2000.0, 2000.0, 8000.0])
    T = jnp.asarray([0.0, 3000.0, 12000.0])
    got = np.asarray(g * _series(jnp.log(g), g, T, jnp.float64))  # g Sigma' = the D series
    want = np.asarray(jnp.exp(-T / g) / g)
    assert np.all(np.abs(got / want - 1) < 3.0 / np.asarray(g))


def test_coherent_reflectance_at_normal_incidence():
    """Normal incidence: K = 0, so sigma = sigma0 and S = 1:
    rho_sp = F(1) exp(-(4 pi sigma0/lam)^2)."""
    m = model(SMOOTH)
    got = np.asarray(jax.jit(lambda m, w: m.coherent_reflectance(w))(
        m, jnp.asarray([0.0, 0.0, 1.0])))
    eta, k = np.asarray(SMOOTH["eta"]), np.asarray(SMOOTH["k"])
    f0 = ((eta - 1) ** 2 + k ** 2) / ((eta + 1) ** 2 + k ** 2)
    np.testing.assert_allclose(got, f0 * np.exp(-(4 * math.pi * 0.18 / LAM) ** 2), rtol=1e-13)


def test_reciprocity_and_retro_reflection():
    m = model(ROUGH)
    rng = np.random.default_rng(2)
    wi, wo = jnp.asarray(random_dirs(rng, 200, 1e-4)), jnp.asarray(random_dirs(rng, 200, 1e-4))
    np.testing.assert_allclose(_eval(m, wi, wo), _eval(m, wo, wi), rtol=1e-12)
    # l = v: G has the finite limit 4/cv^2 (the printed form is 0/0 there; BBM sets G = 1)
    w = jnp.asarray([0.3, 0.4, math.sqrt(0.75)])
    eps = jnp.asarray([1e-6, -1e-6, 0.0])
    vals = _eval(m, jnp.stack([w + eps, w]), jnp.stack([w, w]))
    np.testing.assert_allclose(vals[1], vals[0], rtol=1e-5)


@pytest.mark.slow  # ~60 s on 2 cores (a 131k-node rule); the energy check runs in test_checks
def test_energy_quadrature_against_brute_force():
    """The checks' albedo (half-vector rule at the sampler width) against a plain 256 x 512
    Gauss-Legendre x trapezoid rule."""
    m = model(SMOOTH)
    rule = quadrature.gauss_legendre_hemisphere(256, 512)
    for c in (0.9, 0.2):
        wo = dir_from_cos(c)
        e = checks.directional_albedo(m, wo)
        brute = np.asarray(jnp.sum(rule.weights[:, None] * _eval_cos(
            m, rule.directions, jnp.asarray(wo)), axis=0))
        np.testing.assert_allclose(e, brute, rtol=1e-7)


def test_gradients_match_finite_differences_rough():
    rng = np.random.default_rng(6)
    wi, wo = jnp.asarray(random_dirs(rng, 8, 0.1)), jnp.asarray(random_dirs(rng, 8, 0.1))
    p0 = {k: np.asarray(v, float) for k, v in ROUGH.items()}
    p0["albedo"] = np.asarray([0.2, 0.5, 0.7])
    assert_model_gradient_matches_fd(lambda **p: model(p), wi, wo, p0, rel=1e-6, abs=1e-9,
                                     relative_step=True)


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32], ids=["f64", "f32"])
def test_extreme_parameters_finite(dtype):
    """Values and gradients at grazing (1e-7), the horizon, wi = wo, wi = -wo and extreme
    sigma0 (1e-4 .. 5 um: g from 1e-5 to 2e4) and tau."""
    cos = [1e-7, 1e-4, 0.5, 1.0]
    dirs = [dir_from_cos(c, p) for c in cos for p in (0.0, 2.0)]
    wi = [a for a in dirs for _ in dirs] + [np.array([1.0, 0, 0])]
    wo = [b for _ in dirs for b in dirs] + [np.array([-1.0, 0, 0])]
    wi, wo = jnp.asarray(np.asarray(wi), dtype), jnp.asarray(np.asarray(wo), dtype)

    def total(p):
        m = astype(model(p), dtype)
        return jnp.sum(m.eval(wi, wo)) + jnp.sum(m.pdf(wi, wo))

    cases = [(1e-4, 3.0), (5.0, 3.0), (0.18, 1e-3), (0.18, 1e3), (5.0, 1e-2)]
    grid = {k: np.repeat(np.asarray(v, float)[None], len(cases), 0) for k, v in SMOOTH.items()}
    grid["sigma0"] = np.array([c[0] for c in cases])
    grid["tau"] = np.array([c[1] for c in cases])
    val, grads = jax.jit(jax.vmap(jax.value_and_grad(total)))(
        {k: jnp.asarray(v, dtype) for k, v in grid.items()})
    assert np.all(np.isfinite(np.asarray(val)))
    for k, gk in grads.items():
        assert np.all(np.isfinite(np.asarray(gk))), k


def test_bad_parameters_are_named():
    entry = registry.get("htsg")
    for bad, name in [({"sigma0": -0.1}, "sigma0"), ({"tau": 0.0}, "tau"),
                      ({"eta": [1.5, -1.0, 1.5]}, "eta"), ({"k": [0.0, -1.0, 0.0]}, "'k'"),
                      ({"albedo": [0.1, 1.2, 0.1]}, "albedo"), ({"sigma0": [0.1, 0.2]}, "sigma0")]:
        with pytest.raises(ParameterError, match=name):
            entry.build(**bad)
    with pytest.raises(ParameterError, match="wavelength"):
        HTSG(eta=jnp.asarray([1.5, 1.5, 1.5]), wavelength=(0.5, 0.6))


def test_registry_metadata():
    e = registry.get("htsg")
    assert e.year == 1991 and e.catalogue == "He-Torrance-Sillion-Greenberg" and e.sampler
    assert registry.get("he") is e


# ----------------------------------------------------------------------------- float32 (issue 16)

#: float32 against float64: the directional-diffuse term is a product of ~10 factors each good to
#: a few float32 ulp, times the series whose log-weights carry an absolute round-off of ~30 eps
#: (the largest exponent magnitude, see _series): measured <= 2e-5 relative over sigma0, tau, eta,
#: k = 1e-6..1e6 (directions down to cos = 1e-3); 1e-4 leaves a factor 5
F32_RTOL = 1e-4
ISSUE_WI, ISSUE_WO = np.array([0.6, 0.0, 0.8]), np.array([-0.6, 0.0, 0.8])


def _dd_and_eval(p, wi, wo):
    m = model(p)
    return m.directional_diffuse(wi, wo), m.eval(wi, wo)


_dd_and_eval_batch = jax.jit(jax.vmap(_dd_and_eval, in_axes=(0, None, None)))


def _grid(name, values, base=SMOOTH):
    grid = {k: np.repeat(np.asarray(v, float)[None], len(values), 0) for k, v in base.items()}
    grid[name] = np.asarray(values, float)
    return grid


def _both_precisions(grid, wi, wo):
    out = {}
    for dt in (jnp.float64, jnp.float32):
        out[dt] = [np.asarray(x, float) for x in _dd_and_eval_batch(
            {k: jnp.asarray(v, dt) for k, v in grid.items()}, jnp.asarray(wi, dt),
            jnp.asarray(wo, dt))]
    return out[jnp.float64], out[jnp.float32]


def test_float32_large_sigma0_issue_case():
    """Issue 16: sigma0 = 300 gave (1.9e14, 6.3, 1.1e29) and 1000 gave inf in float32 (eval is
    ~(0.095, 0.064, 0.032) = albedo/pi); the series' log-weights were ~g log g (g ~ 2e7 .. 2e9)
    with an absolute float32 round-off of tens."""
    grid = _grid("sigma0", [100.0, 300.0, 1000.0, 1e4])
    (dd64, f64), (dd32, f32) = _both_precisions(grid, ISSUE_WI[None], ISSUE_WO[None])
    assert np.all(np.isfinite(f32)) and np.all(np.isfinite(dd32))
    np.testing.assert_allclose(f32, f64, rtol=F32_RTOL)
    np.testing.assert_allclose(f32[:, 0], [[0.3 / math.pi, 0.2 / math.pi, 0.1 / math.pi]] * 4,
                               rtol=1e-5)
    assert np.all(dd64 > 0)
    np.testing.assert_allclose(dd32, dd64, rtol=F32_RTOL)  # the small dd term itself, relative


def test_float32_large_sigma0_gradient_and_sample_weights():
    """The gradient at sigma0 = 1000 (NaN before) and the sample weights at 1e4 (inf before) are
    finite in float32; the float32 gradient matches float64."""
    wi, wo = jnp.asarray(ISSUE_WI), jnp.asarray(ISSUE_WO)

    def total(p, dt):
        m = astype(model(p), dt)
        return jnp.sum(m.eval(wi.astype(dt), wo.astype(dt)))

    p = {k: np.asarray(v, float) for k, v in SMOOTH.items()}
    p["sigma0"] = np.asarray(1000.0)
    grads = {}
    for dt in (jnp.float64, jnp.float32):
        grads[dt] = jax.jit(jax.grad(total), static_argnums=1)(
            {k: jnp.asarray(v, dt) for k, v in p.items()}, dt)
    for k in p:
        g32 = np.asarray(grads[jnp.float32][k], float)
        assert np.all(np.isfinite(g32)), k
        scale = np.max(np.abs(np.asarray(grads[jnp.float64][k])))
        np.testing.assert_allclose(g32, grads[jnp.float64][k], rtol=1e-3, atol=1e-3 * scale,
                                   err_msg=k)
    from _helpers import assert_sampling_finite

    for s0 in (1e4, 1e6):
        q = dict(SMOOTH, sigma0=s0)
        assert_sampling_finite(astype(model(q), jnp.float32), jnp.float32)


@pytest.mark.parametrize("name", ["sigma0", "tau"])
def test_float32_matches_float64_over_the_interval(name):
    """sigma0 and tau from 1e-6 to 1e6 (g from 1e-12 to 1e15): the directional-diffuse term in
    float32 equals float64 to F32_RTOL relative wherever float64 is above 1e-30 (float32's
    normal range ends at 1.2e-38), at normal, 45 degree and grazing (cos = 1e-3) directions."""
    cos = [1.0, math.sqrt(0.5), 0.3, 1e-3]
    dirs = [dir_from_cos(c, ph) for c in cos for ph in (0.0, math.pi)]
    wi = np.array([a for a in dirs for _ in dirs])
    wo = np.array([b for _ in dirs for b in dirs])
    values = 10.0 ** np.arange(-6, 7)
    (dd64, f64), (dd32, f32) = _both_precisions(_grid(name, values), wi, wo)
    assert np.all(np.isfinite(dd32)) and np.all(np.isfinite(f32))
    ok = dd64 > 1e-30
    assert ok.sum() > 0.5 * ok.size
    np.testing.assert_allclose(dd32[ok], dd64[ok], rtol=F32_RTOL)
    assert np.all(np.abs(dd32[~ok]) <= 1e-29)
    np.testing.assert_allclose(f32, f64, rtol=F32_RTOL, atol=1e-30)


def test_series_float32_large_g():
    """The rough-regime series in float32 against float64 for g = 56 .. 1e14 (before the fix:
    7090 times too large at g = 1e7, inf at 1e8); the float64 value against the asymptote
    g^2 Sigma'(T = 0) = g E[1/N] = 1 + 1/g + 2/g^2 + O(g^-3) (N ~ Poisson(g), conditioned
    on N >= 1)."""
    g = np.array([56.0, 300.0, 1e3, 1e5, 1e7, 1e8, 1e10, 1e12, 1e14])
    T = np.array([0.0, 10.0, 1e3, 1e4, 1e8, 0.0, 1e10, 0.0, 1e14])
    out = {}
    for dt in (jnp.float64, jnp.float32):
        gj, Tj = jnp.asarray(g, dt), jnp.asarray(T, dt)
        out[dt] = np.asarray(_series(jnp.log(gj), gj, Tj, dt), float)
    assert np.all(out[jnp.float32] > 0)
    np.testing.assert_allclose(out[jnp.float32], out[jnp.float64], rtol=F32_RTOL)
    big = (T == 0) & (g >= 1e8)
    np.testing.assert_allclose(g[big] ** 2 * out[jnp.float64][big], 1 + 1 / g[big], rtol=1e-13)
