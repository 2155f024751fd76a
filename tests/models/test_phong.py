"""Phong-family models (brdf_fit.models.phong) and the Phong/microfacet conversions.

Independent quadrature: the pdfs are integrated over the upper hemisphere in polar coordinates
about the mirror direction ``r_o`` (graded Gauss-Legendre panels in the polar angle, each azimuth
cut exactly at the horizon, periodic trapezoid in azimuth), not with brdf_fit.core.quadrature.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import dir_from_cos, fd_central, random_dirs
from _helpers import draw_jit as _draw
from _helpers import eval_cos_jit as _eval_cos
from _helpers import eval_jit as _eval
from _helpers import pdf_jit as _pdf

from brdf_fit.convert import phong as convert_phong
from brdf_fit.core.validate import ParameterError
from brdf_fit.models._base import astype
from brdf_fit.models.phong import (
    BlinnPhong,
    ModifiedPhong,
    ModifiedPhongFresnel,
    PhongOriginal,
    registry_entries,
)
from brdf_fit.verify import checks
from brdf_fit.verify.chi2 import chi2_test_brdf

EXPONENTS = (1.0, 10.0, 100.0, 1000.0, 10000.0)
VIEW_COS = (0.8, 0.3)
HEAVY = 1000.0  # exponents >= this are marked slow


def _models(n):
    return {
        "phong-original": PhongOriginal(rho_s=0.7, exponent=n),
        "modified-phong": ModifiedPhong(rho_d=0.2, rho_s=jnp.asarray([0.7, 0.5, 0.3]), exponent=n),
        "modified-phong-fresnel": ModifiedPhongFresnel(rho_d=0.3, f0=0.5, exponent=n),
        "modified-phong-dielectric": ModifiedPhongFresnel(
            rho_d=0.3, f0=0.04, exponent=n, fresnel="dielectric"),
        "blinn-phong": BlinnPhong(rho_s=0.5, exponent=n),
        "blinn-phong-approx": BlinnPhong(rho_s=0.5, exponent=n, normalisation="approx"),
        "blinn-phong-none": BlinnPhong(rho_s=0.5, exponent=n, normalisation="none"),
    }


# the sampler of the approx/none Blinn-Phong and of the dielectric variant is shared with another
# model: the chi-square tests cover one of each sampler code path
CHI2_MODELS = ("phong-original", "modified-phong", "modified-phong-fresnel", "blinn-phong")
#: by default the view 0.3 (the lobe near the horizon) for exponents below HEAVY; the view 0.8
#: and the heavy exponents in the slow set (25 s for both views by default, stop 35's profile)
CHI2_CASES = [
    pytest.param(name, n, c, marks=[pytest.mark.slow] if n >= HEAVY or c == 0.8 else [])
    for name in CHI2_MODELS for n in EXPONENTS for c in VIEW_COS
]
CHI2_COUNT = len(CHI2_CASES)  # Sidak correction over every chi-square test in this file


def _dir(cos, phi=0.3):
    return dir_from_cos(cos, phi)


def _random_dirs(rng, n, lo=-1.0):
    return random_dirs(rng, n, lo)


# ----------------------------------------------------------------------------- quadrature


def _lobe_frame(a):
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(helper, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(a, e1)


def hemisphere_integral(fn, wo, width, n_phi=512, n_gl=24):
    """``Int_{wi.z > 0} fn(wi) dwi`` in polar coordinates about ``r_o = mirror(wo)``: the polar
    angle runs from 0 to the horizon ``pi/2 + atan2(B, A)`` of each azimuth in graded panels
    (``width`` times powers of two), so the integrand is smooth in every panel."""
    a = np.array([-wo[0], -wo[1], wo[2]])
    e1, e2 = _lobe_frame(a)
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    B = np.cos(phi) * e1[2] + np.sin(phi) * e2[2]
    tmax = np.pi / 2 + np.arctan2(B, a[2])
    grades = [0.0] + [width * 2.0**k for k in range(-3, 40) if width * 2.0**k < np.pi] + [np.pi]
    b = np.minimum(np.asarray(grades)[None, :], tmax[:, None])  # (n_phi, K+1)
    x, w = np.polynomial.legendre.leggauss(n_gl)
    lo, hi = b[:, :-1, None], b[:, 1:, None]
    theta = 0.5 * (lo + hi) + 0.5 * (hi - lo) * x  # (n_phi, K, n_gl)
    wt = 0.5 * (hi - lo) * w * np.sin(theta) * (2 * np.pi / n_phi)
    cp, sp = np.cos(phi)[:, None, None], np.sin(phi)[:, None, None]
    d = (np.cos(theta)[..., None] * a
         + np.sin(theta)[..., None] * (cp[..., None] * e1 + sp[..., None] * e2))
    vals = np.asarray(fn(jnp.asarray(d.reshape(-1, 3)))).reshape(theta.shape + (-1,))
    return np.sum(wt[..., None] * vals, axis=(0, 1, 2))


def _width(n):
    return 1.0 / math.sqrt(n + 1.0)




def _samples(model, wo, n=200_000, seed=0):
    rng = np.random.default_rng(seed)
    uc, u = jnp.asarray(rng.random(n)), jnp.asarray(rng.random((n, 2)))
    return _draw(model, jnp.asarray(wo), uc, u)


# ----------------------------------------------------------------------------- basic properties


@pytest.mark.parametrize("name", list(_models(10.0)))
@pytest.mark.parametrize("n", (0.0, 1.0, 30.0, 1e4))
def test_non_negative_and_zero_below_horizon(name, n):
    model = _models(n)[name]
    rng = np.random.default_rng(1)
    wi = jnp.asarray(_random_dirs(rng, 4000))
    wo = jnp.asarray(_random_dirs(rng, 4000))
    f = np.asarray(_eval(model, wi, wo))
    p = np.asarray(_pdf(model, wi, wo))
    assert np.all(np.isfinite(f)) and np.all(f >= 0)
    assert np.all(np.isfinite(p)) and np.all(p >= 0)
    below = (np.asarray(wi)[:, 2] <= 0) | (np.asarray(wo)[:, 2] <= 0)
    fb = f.reshape(4000, -1)
    assert np.all(fb[below] == 0) and np.all(p[below] == 0)
    # wo below the horizon: every sample fails cleanly
    _, sp, sw = _draw(model, jnp.asarray([0.3, 0.1, -0.5]) / math.sqrt(0.35),
                      jnp.full((64,), 0.4), jnp.asarray(rng.random((64, 2))))
    assert np.all(np.asarray(sp) == 0) and np.all(np.asarray(sw) == 0)


@pytest.mark.parametrize("name", [k for k in _models(1.0) if k != "phong-original"])
def test_reciprocity(name):
    model = _models(37.0)[name]
    rng = np.random.default_rng(2)
    wi = jnp.asarray(_random_dirs(rng, 4000, lo=1e-3))
    wo = jnp.asarray(_random_dirs(rng, 4000, lo=1e-3))
    a, b = np.asarray(_eval(model, wi, wo)), np.asarray(_eval(model, wo, wi))
    assert np.max(np.abs(a - b)) <= 1e-12 * np.max(a)


def test_phong_original_not_reciprocal_but_f_cos_symmetric():
    model = PhongOriginal(rho_s=0.6, exponent=5.0)
    rng = np.random.default_rng(3)
    wi = jnp.asarray(_random_dirs(rng, 2000, lo=1e-2))
    wo = jnp.asarray(_random_dirs(rng, 2000, lo=1e-2))
    a, b = np.asarray(_eval(model, wi, wo)), np.asarray(_eval(model, wo, wi))
    assert np.max(np.abs(a - b)) > 1e-2 * np.max(a)
    # f cos(theta_i) = rho_s (n+1)/(2 pi) cos^n(alpha_r) is symmetric
    ac, bc = np.asarray(_eval_cos(model, wi, wo)), np.asarray(_eval_cos(model, wo, wi))
    assert np.max(np.abs(ac - bc)) <= 1e-12 * np.max(ac)


def test_formulas_against_direct_evaluation():
    rng = np.random.default_rng(4)
    wi = _random_dirs(rng, 500, lo=0.01)
    wo = _random_dirs(rng, 500, lo=0.01)
    n = 13.5
    r = wo * np.array([-1, -1, 1])
    ca = np.maximum(np.sum(r * wi, -1), 0)
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
    ch, d = h[:, 2], np.sum(wo * h, -1)
    W, O = jnp.asarray(wi), jnp.asarray(wo)
    np.testing.assert_allclose(_eval(PhongOriginal(0.7, n), W, O),
                               0.7 * (n + 1) / (2 * np.pi) * ca**n / wi[:, 2], rtol=1e-12)
    np.testing.assert_allclose(_eval(ModifiedPhong(0.2, 0.7, n), W, O),
                               0.2 / np.pi + 0.7 * (n + 2) / (2 * np.pi) * ca**n, rtol=1e-12)
    F = 0.3 + 0.7 * (1 - d) ** 5
    np.testing.assert_allclose(_eval(ModifiedPhongFresnel(0.2, 0.3, n), W, O),
                               0.2 / np.pi + F * (n + 2) / (2 * np.pi) * ca**n, rtol=1e-12)
    for norm, K in (("ndf", (n + 2) / (2 * np.pi)), ("approx", (n + 8) / (8 * np.pi)),
                    ("none", 1.0)):
        np.testing.assert_allclose(_eval(BlinnPhong(0.5, n, norm), W, O), 0.5 * K * ch**n,
                                   rtol=1e-12)
    np.testing.assert_allclose(_pdf(BlinnPhong(0.5, n), W, O),
                               (n + 1) / (2 * np.pi) * ch**n / (4 * d), rtol=1e-12)


def test_parameter_errors():
    with pytest.raises(ParameterError, match="rho_d \\+ rho_s must be <= 1"):
        ModifiedPhong(rho_d=0.6, rho_s=0.5, exponent=10.0)
    with pytest.raises(ParameterError, match="rho_d \\+ rho_s"):
        ModifiedPhong(rho_d=jnp.asarray([0.1, 0.6, 0.1]), rho_s=0.5, exponent=10.0)
    ModifiedPhong(rho_d=0.5, rho_s=0.5, exponent=10.0)  # = 1 is allowed
    with pytest.raises(ParameterError, match="exponent"):
        ModifiedPhong(rho_d=0.1, rho_s=0.5, exponent=-1.0)
    with pytest.raises(ParameterError, match="normalisation"):
        BlinnPhong(normalisation="giesen")
    with pytest.raises(ParameterError, match="fresnel"):
        ModifiedPhongFresnel(fresnel="conductor")
    with pytest.raises(ParameterError, match="f0"):
        ModifiedPhongFresnel(f0=1.0, fresnel="dielectric")


# ----------------------------------------------------------------------------- albedo closed forms


@pytest.mark.parametrize("n", (0.0, 1.0, 10.0, 100.0, 1e4))
def test_modified_phong_albedo_normal_view(n):
    """rho_d = 0, wo = normal: the lobe about r = n lies above the horizon, so
    E = rho_s (n+2)/(2 pi) Int_H cos^n cos dw = rho_s (n+2)/(2 pi) 2 pi/(n+2) = rho_s."""
    model = ModifiedPhong(rho_d=0.0, rho_s=0.8, exponent=n)
    wo = np.array([0.0, 0.0, 1.0])
    E = hemisphere_integral(lambda wi: _eval_cos(model, wi, jnp.asarray(wo))[..., None], wo,
                            _width(n))
    assert abs(E[0] - 0.8) < 1e-10
    # Phong 1975 as a BRDF: f cos = rho_s x (sphere-normalised lobe), also rho_s at normal view
    po = PhongOriginal(rho_s=0.8, exponent=n)
    E = hemisphere_integral(lambda wi: _eval_cos(po, wi, jnp.asarray(wo))[..., None], wo, _width(n))
    assert abs(E[0] - 0.8) < 1e-10


@pytest.mark.parametrize("n", (0.0, 1.0, 8.0, 10.0, 100.0, 1e4))
def test_blinn_phong_albedo_normal_view(n):
    """At wo = n, theta_h = theta_i/2 and Int_H cos^n(theta_h) cos(theta_i) dw =
    8 pi (2^(-n/2) + n)/((n+2)(n+4)) (models.md 4.9, Giesen 2009)."""
    exact = 8 * np.pi * (2.0 ** (-n / 2) + n) / ((n + 2) * (n + 4))
    x, w = np.polynomial.legendre.leggauss(400)
    th = np.pi / 4 * (x + 1)
    direct = np.sum(np.pi / 4 * w * np.cos(th / 2) ** n * np.cos(th) * np.sin(th)) * 2 * np.pi
    if n < 1e3:
        assert abs(direct / exact - 1) < 1e-10
    wo = np.array([0.0, 0.0, 1.0])
    for norm, K in (("ndf", (n + 2) / (2 * np.pi)), ("approx", (n + 8) / (8 * np.pi))):
        model = BlinnPhong(rho_s=1.0, exponent=n, normalisation=norm)
        E = hemisphere_integral(lambda wi, m=model: _eval_cos(m, wi, jnp.asarray(wo))[..., None],
                                wo, 2 * _width(n))
        assert abs(E[0] / (K * exact) - 1) < 1e-9
    # (n+8)/(8 pi) overshoots by at most ~7.5% (n ~ 8..10)
    assert (n + 8) / (8 * np.pi) * exact < 1.076


# ----------------------------------------------------------------------------- pdf normalisation


PDF_CASES = [
    pytest.param(name, n, c, marks=[pytest.mark.slow] if n >= HEAVY else [])
    for name in ("phong-original", "modified-phong", "blinn-phong")
    for n in EXPONENTS for c in (1.0, *VIEW_COS, 0.05)
]


@pytest.mark.parametrize("name, n, cos_o", PDF_CASES)
def test_pdf_integrates_to_one_minus_p_fail(name, n, cos_o):
    model = _models(n)[name]
    wo = _dir(cos_o)
    width = _width(n) * (2.0 if name.startswith("blinn") else 1.0)
    integral = float(hemisphere_integral(
        lambda wi: _pdf(model, wi, jnp.asarray(wo))[..., None], wo, width)[0])
    N = 200_000
    _, pdf, weight = _samples(model, wo, N, seed=5)
    pdf, weight = np.asarray(pdf), np.asarray(weight)
    assert np.all(np.isfinite(pdf)) and np.all(np.isfinite(weight))
    p_fail = float(np.mean(pdf == 0))
    assert np.all(weight[pdf == 0] == 0)
    sigma = math.sqrt(max(p_fail * (1 - p_fail), 1.0 / N) / N)
    assert abs(integral - (1 - p_fail)) <= 5 * sigma, (integral, p_fail)
    if cos_o == 1.0:
        # exact failure probabilities at normal view: the Phong lobe about n never fails; the
        # Blinn-Phong reflection fails iff cos(theta_h)^2 < 1/2, probability 2^(-(n+1)/2)
        exact = 2.0 ** (-(n + 1) / 2) if name.startswith("blinn") else 0.0
        assert abs(integral - (1 - exact)) < 1e-9


def test_phong_original_weight_is_rho_s():
    model = PhongOriginal(rho_s=jnp.asarray([0.7, 0.5, 0.2]), exponent=7.0)
    _, pdf, weight = _samples(model, _dir(0.3), 10_000)
    ok = np.asarray(pdf) > 0
    np.testing.assert_allclose(np.asarray(weight)[ok], np.broadcast_to([0.7, 0.5, 0.2],
                                                                        (ok.sum(), 3)), rtol=1e-12)


# ----------------------------------------------------------------------------- chi-square


@pytest.mark.parametrize("name, n, cos_o", CHI2_CASES)
def test_chi2(name, n, cos_o):
    model = _models(n)[name]
    res = chi2_test_brdf(model, jnp.asarray(_dir(cos_o)), n_samples=100_000,
                         test_count=CHI2_COUNT)
    assert res.passed, str(res)


# ----------------------------------------------------------------------------- gradients


def _grad_models(n):
    m = _models(n)
    # blinn-phong-approx differs from blinn-phong only by its constant K(n)
    return [m["phong-original"], m["modified-phong"], m["modified-phong-fresnel"],
            m["modified-phong-dielectric"], m["blinn-phong"]]


def _exponent_loss(model, n, wi, wo, uc, u):
    m = eqx.tree_at(lambda t: t.exponent, model, n)
    s = m.sample(wo, uc, u)
    return (jnp.sum(m.eval_cos(wi, wo)) + jnp.sum(m.pdf(wi, wo)) * 1e-3
            + jnp.sum(s.weight) + jnp.sum(s.pdf) * 1e-3)


_loss = jax.jit(_exponent_loss)
_grad_n = jax.jit(jax.grad(_exponent_loss, argnums=1))
# one compilation per model and dtype: gradients w.r.t. the parameters, n and both directions
_value_and_grad = jax.jit(jax.value_and_grad(_exponent_loss, argnums=(0, 1, 2, 3)))


@pytest.mark.parametrize("idx", range(5))
def test_gradient_exponent_matches_finite_difference(idx):
    rng = np.random.default_rng(6)
    wo = jnp.asarray(_random_dirs(rng, 300, lo=0.05))
    r = np.asarray(wo) * np.array([-1, -1, 1])
    wi = jnp.asarray(r + 0.1 * _random_dirs(rng, 300))
    wi = wi / jnp.linalg.norm(wi, axis=-1, keepdims=True)
    uc, u = jnp.asarray(rng.random(300)), jnp.asarray(rng.random((300, 2)))
    n0 = 12.0
    model = _grad_models(n0)[idx]
    g = _grad_n(model, jnp.asarray(n0), wi, wo, uc, u)
    h = 1e-5
    fd = fd_central(lambda n: _loss(model, n, wi, wo, uc, u), n0, h)
    assert np.isfinite(float(g))
    assert abs(float(g) - float(fd)) <= 1e-6 * max(1.0, abs(float(fd)))


@pytest.mark.parametrize("n", (0.0, 1.0, 100.0, 1e4, 1e6))
def test_gradients_finite_float32(n):
    rng = np.random.default_rng(7)
    cos = np.array([1e-7, 1e-4, 1e-2, 0.5, 1.0])
    dirs = [_dir(c, p) for c in cos for p in (0.3, 0.3 + np.pi)]
    wi = np.array([a for a in dirs for _ in dirs])
    wo = np.array([b for _ in dirs for b in dirs])
    wi, wo = jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32)
    uc = jnp.asarray(rng.random(wi.shape[0]), jnp.float32)
    u = jnp.asarray(rng.random((wi.shape[0], 2)), jnp.float32)
    for model in _grad_models(1.0):
        m32 = astype(model, jnp.float32)
        val, g = _value_and_grad(m32, jnp.asarray(n, jnp.float32), wi, wo, uc, u)
        assert np.isfinite(float(val)), type(model).__name__
        for leaf in jax.tree_util.tree_leaves(g):
            assert np.all(np.isfinite(np.asarray(leaf))), type(model).__name__


# ----------------------------------------------------------------------------- conversions


def test_conversions_round_trip_and_what_they_match():
    n = np.array([0.5, 1.0, 10.0, 100.0, 1e4])
    for fwd, inv in (
        (convert_phong.blinn_phong_to_beckmann_alpha, convert_phong.beckmann_alpha_to_blinn_phong),
        (convert_phong.blinn_phong_to_beckmann_alpha_slope_moment,
         convert_phong.beckmann_alpha_to_blinn_phong_slope_moment),
        (convert_phong.blinn_phong_to_ggx_alpha, convert_phong.ggx_alpha_to_blinn_phong),
        (convert_phong.blinn_phong_to_ggx_roughness, convert_phong.ggx_roughness_to_blinn_phong),
        (convert_phong.blinn_phong_to_phong_exponent, convert_phong.phong_to_blinn_phong_exponent),
    ):
        np.testing.assert_allclose(inv(fwd(n)), n, rtol=1e-10)
    # peak match: (n+2)/(2 pi) = 1/(pi alpha^2) for Beckmann and GGX
    a = np.asarray(convert_phong.blinn_phong_to_beckmann_alpha(n))
    np.testing.assert_allclose((n + 2) / (2 * np.pi), 1 / (np.pi * a * a), rtol=1e-12)
    r = np.asarray(convert_phong.blinn_phong_to_ggx_roughness(n))
    np.testing.assert_allclose(r**2, convert_phong.blinn_phong_to_ggx_alpha(n), rtol=1e-12)
    # mean-square slope of the Blinn-Phong NDF: (n+2) Int_0^1 (1 - c^2) c^(n-1) dc = 2/n
    x, w = np.polynomial.legendre.leggauss(200)
    for nn in (1.0, 10.0, 100.0):
        c = 0.5 * (x + 1)
        m2 = (nn + 2) * np.sum(0.5 * w * (1 - c * c) * c ** (nn - 1))
        a2 = float(convert_phong.blinn_phong_to_beckmann_alpha_slope_moment(nn)) ** 2
        assert abs(m2 - a2) < 1e-10


# ----------------------------------------------------------------------------- registry entries


def test_registry_entries_build_and_declare():
    entries = {e.name: e for e in registry_entries()}
    assert set(entries) >= {"phong-original", "modified-phong", "modified-phong-fresnel",
                            "blinn-phong", "blinn-phong-approx"}
    for e in entries.values():
        model = e.build()
        assert model.channels() == 3
        for c in e.expected_failures:
            assert c in checks.CHECKS
    assert "reciprocity" in entries["phong-original"].expected_failures
    r = checks.check_reciprocity(entries["phong-original"].build())
    assert not r.passed


@pytest.mark.slow
def test_registry_entries_run_checks():
    """Every check either passes or is declared, and every declared failure really fails."""
    for e in registry_entries():
        res = checks.run_checks(e.build(), name=e.name, expected_failures=e.expected_failures,
                                checks=[c for c in checks.CHECKS if c != "finite"])
        for r in res:
            assert r.ok, (e.name, r.check, r.statistic)
            if r.check in e.expected_failures:
                assert not r.passed, (e.name, r.check, "declared failure passes")
