"""Hanrahan-Krueger single scattering (brdf_fit.models.hanrahan_krueger).

Independent reference: a NumPy computation in spherical angles (Snell's law with arcsin, Fresnel
amplitudes from the refracted angle, the scattering angle from the refracted propagation vectors)
that integrates the single-scattering path over depth numerically (Gauss-Legendre in optical
depth) instead of using the closed-form depth integral. Limits: Chandrasekhar / Lommel-Seeliger
for a semi-infinite layer, the thin-layer expansion, and an energy balance computed in the
layer's internal angles (which is what fixes the 1/eta^2 factor).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import (
    assert_finite,
    assert_model_gradient_matches_fd,
    dir_from_cos,
    eval_jit,
    random_dirs,
    values_pdfs_grads,
)

from brdf_fit import registry
from brdf_fit.core.validate import ParameterError
from brdf_fit.models._base import astype
from brdf_fit.models.hanrahan_krueger import HanrahanKrueger
from brdf_fit.verify import albedo, checks

GL_DEPTH = np.polynomial.legendre.leggauss(400)


def _angles(w):
    return np.arccos(np.clip(w[..., 2], -1, 1)), np.arctan2(w[..., 1], w[..., 0])


def _fresnel_t(theta, theta_t, eta):
    ci, ct = np.cos(theta), np.cos(theta_t)
    rs = (ci - eta * ct) / (ci + eta * ct)
    rp = (eta * ci - ct) / (eta * ci + ct)
    return 1.0 - 0.5 * (rs * rs + rp * rp)


def reference(wi, wo, albedo, tau, g, eta, solid_angle_factor=True):
    """f by depth quadrature of the single-scattering path; shape (N, C)."""
    ti, pi_ = _angles(np.asarray(wi))
    to, po = _angles(np.asarray(wo))
    si, so = np.sin(ti) / eta, np.sin(to) / eta
    ok = (ti < np.pi / 2) & (to < np.pi / 2) & (si < 1) & (so < 1)
    tti = np.arcsin(np.where(ok, si, 0.0))
    tto = np.arcsin(np.where(ok, so, 0.0))
    mi, mo = np.cos(tti), np.cos(tto)
    d_in = np.stack([-np.sin(tti) * np.cos(pi_), -np.sin(tti) * np.sin(pi_), -mi], -1)
    d_out = np.stack([np.sin(tto) * np.cos(po), np.sin(tto) * np.sin(po), mo], -1)
    cpsi = np.sum(d_in * d_out, -1)
    phase = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cpsi) ** 1.5)
    trans = _fresnel_t(ti, tti, eta) * _fresnel_t(to, tto, eta)
    tau = np.atleast_1d(np.asarray(tau, float))
    x, w = GL_DEPTH
    out = []
    for tc in tau:
        t = 0.5 * tc * (x + 1)  # optical depth nodes on [0, tau]
        path = np.exp(-t[None, :] * (1 / mi + 1 / mo)[:, None]) / (mi * mo)[:, None]
        out.append(0.5 * tc * path @ w)
    depth = np.stack(out, -1)
    f = np.asarray(albedo, float) * (trans * phase)[:, None] * depth
    if solid_angle_factor:
        f = f / eta**2
    return np.where(ok[:, None], f, 0.0)


dirs = random_dirs


def _unit(c, phi=0.3):
    return dir_from_cos(c, phi)


CASES = [
    dict(albedo=[0.8, 0.6, 0.4], tau=[1.0, 1.5, 2.0], g=0.3, eta=1.4),
    dict(albedo=[0.9, 0.5, 0.2], tau=[0.05, 0.5, 3.0], g=-0.7, eta=1.0),
    dict(albedo=[1.0, 1.0, 1.0], tau=[2.0, 2.0, 2.0], g=0.9, eta=2.4),
    dict(albedo=[0.7, 0.7, 0.7], tau=[1.0, 1.0, 1.0], g=-0.2, eta=0.75),  # TIR outside the cone
]


@pytest.mark.parametrize("saf", [True, False], ids=["consistent", "published"])
@pytest.mark.parametrize("case", CASES, ids=[f"eta{c['eta']}" for c in CASES])
def test_matches_depth_quadrature_reference(case, saf):
    rng = np.random.default_rng(10)
    wi, wo = dirs(rng, 300), dirs(rng, 300)
    m = HanrahanKrueger(**{k: jnp.asarray(v) for k, v in case.items()}, solid_angle_factor=saf)
    got = np.asarray(eval_jit(m, jnp.asarray(wi), jnp.asarray(wo)))
    want = reference(wi, wo, **case, solid_angle_factor=saf)
    nz = want > 0
    if case["eta"] < 1:
        assert 0.2 < np.mean(~nz[:, 0]) < 0.9  # many pairs beyond the critical angle
    np.testing.assert_array_equal(got[~nz], 0.0)
    np.testing.assert_allclose(got[nz], want[nz], rtol=1e-10, atol=0)


def test_semi_infinite_limit_is_chandrasekhar_single_scattering():
    """tau -> inf: omega/(4 pi) P(cos psi)/(mu_i + mu_o) (Chandrasekhar 1960, Radiative Transfer,
    the first-order term; P normalised to 4 pi), times T_i T_o/eta^2 in the refracted angles."""
    rng = np.random.default_rng(11)
    wi, wo = dirs(rng, 200), dirs(rng, 200)
    for eta, g in ((1.0, 0.0), (1.0, 0.5), (1.5, -0.4)):
        m = HanrahanKrueger(albedo=0.9, tau=1e3, g=g, eta=eta)
        got = np.asarray(eval_jit(m, jnp.asarray(wi), jnp.asarray(wo)))
        ti, pi_ = _angles(wi)
        to, po = _angles(wo)
        tti, tto = np.arcsin(np.sin(ti) / eta), np.arcsin(np.sin(to) / eta)
        mi, mo = np.cos(tti), np.cos(tto)
        # scattering angle by the spherical law of cosines (reflection: pi - angle between)
        cpsi = -(mi * mo + np.sin(tti) * np.sin(tto) * np.cos(pi_ - po))
        big_p = (1 - g * g) / (1 + g * g - 2 * g * cpsi) ** 1.5
        want = 0.9 / (4 * np.pi) * big_p / (mi + mo)
        if eta != 1.0:
            want = want * _fresnel_t(ti, tti, eta) * _fresnel_t(to, tto, eta) / eta**2
        np.testing.assert_allclose(got, want, rtol=1e-12)


@pytest.mark.parametrize("mu", [1.0, 0.5, 0.2])
def test_lommel_seeliger_albedo(mu):
    """eta = 1, g = 0, tau -> inf: a(mu) = W/2 (1 - mu ln((1 + mu)/mu)) (exact)."""
    m = HanrahanKrueger(albedo=0.8, tau=1e3, g=0.0, eta=1.0)
    a = float(albedo.directional_albedo(m, jnp.asarray(_unit(mu))))
    want = 0.4 * (1 - mu * math.log((1 + mu) / mu))
    assert a == pytest.approx(want, rel=1e-9)


def test_thin_layer_limit():
    """tau -> 0: f = W tau p T_i T_o / (eta^2 mu_i mu_o) + O(tau^2)."""
    rng = np.random.default_rng(12)
    wi, wo = dirs(rng, 100, lo=0.1), dirs(rng, 100, lo=0.1)
    tau, eta, g = 1e-9, 1.3, 0.4
    m = HanrahanKrueger(albedo=1.0, tau=tau, g=g, eta=eta)
    got = np.asarray(eval_jit(m, jnp.asarray(wi), jnp.asarray(wo)))
    ref_thick = reference(wi, wo, 1.0, 1.0, g, eta)[:, 0]  # phase, T and cosines as reference
    ti, to = _angles(wi)[0], _angles(wo)[0]
    mi = np.cos(np.arcsin(np.sin(ti) / eta))
    mo = np.cos(np.arcsin(np.sin(to) / eta))
    atten_1 = -np.expm1(-(1 / mi + 1 / mo)) / (mi + mo)
    want = tau * ref_thick / atten_1 / (mi * mo)
    np.testing.assert_allclose(got, want, rtol=1e-8)


@pytest.mark.parametrize("cos_i", [1.0, 0.6, 0.2])
def test_energy_balance_in_internal_angles(cos_i):
    """The reflected flux computed outside (brdf_fit.core.quadrature of f cos over wo, by
    reciprocity the albedo) equals the single-scattered internal flux leaving through the critical
    cone, integrated in the layer's own angles: Int_cone T(theta_o') L'(w') mu' dw' with
    L' = W p T_i E (1 - e^(...))/(mu_i + mu_o) and E = 1. This fixes the 1/eta^2."""
    eta, g, tau, W = 1.5, -0.6, 2.0, 0.9
    m = HanrahanKrueger(albedo=W, tau=tau, g=g, eta=eta)
    wi = _unit(cos_i, 0.0)
    outside = float(albedo.directional_albedo(m, jnp.asarray(wi), generic=(128, 256)))
    # internal quadrature over the critical cone mu' in [mu_c, 1], phi in [0, 2 pi), in the
    # variable u = the external cosine (mu'^2 = 1 - (1 - u^2)/eta^2, dmu' = u du/(eta^2 mu')):
    # T(theta_o') has a square-root edge at mu_c that slows Gauss-Legendre in mu' itself
    x, w = np.polynomial.legendre.leggauss(200)
    u = 0.5 * (x + 1)
    mu = np.sqrt(1 - (1 - u * u) / eta**2)
    wmu = 0.5 * w * u / (eta**2 * mu)
    phi = (np.arange(256) + 0.5) * 2 * np.pi / 256
    MU, PHI = np.meshgrid(mu, phi, indexing="ij")
    th_i = math.acos(cos_i)
    th_ip = math.asin(math.sin(th_i) / eta)
    mi = math.cos(th_ip)
    st = np.sqrt(1 - MU**2)
    cpsi = -mi * MU - math.sin(th_ip) * st * np.cos(PHI)  # wi at phi = 0, propagation reversed
    p = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cpsi) ** 1.5)
    t_in = _fresnel_t(th_i, th_ip, eta)
    th_o = np.arcsin(np.minimum(eta * st, 1.0))  # external angle of the internal direction
    t_out = _fresnel_t(th_o, np.arccos(MU), eta)
    L = W * p * t_in * -np.expm1(-tau * (1 / mi + 1 / MU)) / (mi + MU)
    inside = float(np.sum(wmu[:, None] * (2 * np.pi / 256) * t_out * L * MU))
    assert outside == pytest.approx(inside, rel=1e-8)


def test_published_form_violates_energy_conservation():
    """Without 1/eta^2 a dense back-scattering layer reflects more than it receives."""
    kw = dict(albedo=1.0, tau=100.0, g=-0.9, eta=2.0)
    wo = jnp.asarray(_unit(1.0))
    pub = float(albedo.directional_albedo(HanrahanKrueger(**kw, solid_angle_factor=False), wo))
    ok = float(albedo.directional_albedo(HanrahanKrueger(**kw), wo))
    assert pub == pytest.approx(1.30797, abs=1e-5) and pub > 1.0
    assert ok == pytest.approx(pub / 4.0, rel=1e-12)
    e = checks.check_energy(HanrahanKrueger(albedo=1.0, tau=100.0, g=-0.9, eta=1.5))
    assert e.passed and 0.40 < e.statistic < 0.41


def test_registry_checks_reciprocity_and_energy():
    res = {r.check: r for r in checks.run_checks("hanrahan-krueger",
                                                 checks=("reciprocity", "energy"))}
    assert res["reciprocity"].passed and res["reciprocity"].statistic < 1e-14
    assert res["energy"].passed
    # the symmetric-phase reciprocity holds for strongly anisotropic HG and eta != 1 as well
    m = HanrahanKrueger(albedo=0.9, tau=0.7, g=-0.95, eta=1.7)
    assert checks.check_reciprocity(m).statistic < 1e-13


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(13)
    wi, wo = jnp.asarray(dirs(rng, 8, lo=0.1)), jnp.asarray(dirs(rng, 8, lo=0.1))
    p0 = {"albedo": np.array([0.7, 0.5, 0.3]), "tau": np.array([0.8, 1.2, 2.5]),
          "g": np.array(-0.35), "eta": np.array(1.45)}
    assert_model_gradient_matches_fd(registry.get("hanrahan-krueger").build, wi, wo, p0,
                                     rel=1e-6, abs=1e-10, weights=jnp.asarray([1.0, 2.0, 3.0]))


@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32], ids=["f64", "f32"])
def test_extreme_parameters_are_finite(dtype):
    """Values and gradients (directions and parameters) on the hard-case directions at the ends of
    the intervals: tau = 0, 1e-8, 1e3; g = +-0.99; albedo 0 and 1; eta = 1, 1/1.5, 1.5, 3."""
    WI, WO = checks.hard_case_directions()
    wi, wo = jnp.asarray(WI, dtype), jnp.asarray(WO, dtype)
    combos = [(a, t, g, e) for a in (0.0, 1.0) for t in (0.0, 1e-8, 1e3) for g in (-0.99, 0.99)
              for e in (1.0, 1 / 1.5, 1.5, 3.0)]
    grid = {k: jnp.asarray([c[j] for c in combos], dtype)
            for j, k in enumerate(("albedo", "tau", "g", "eta"))}

    vals, _, grads = values_pdfs_grads(HanrahanKrueger, grid, wi, wo)
    assert vals.dtype == dtype
    assert_finite((vals, grads))
    assert np.all(np.asarray(vals) >= 0)


def test_float32_agrees():
    m64 = registry.get("hanrahan-krueger").build()
    m32 = astype(m64, jnp.float32)
    rng = np.random.default_rng(14)
    wi, wo = dirs(rng, 64, lo=0.01), dirs(rng, 64, lo=0.01)
    f32 = eval_jit(m32, jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32))
    assert f32.dtype == jnp.float32
    np.testing.assert_allclose(f32, eval_jit(m64, jnp.asarray(wi), jnp.asarray(wo)), rtol=2e-5)


@pytest.mark.parametrize("bad,match", [
    ({"tau": -0.1}, "'tau' must be >= 0"),
    ({"g": 1.0}, "'g' must be < 1"),
    ({"g": -1.0}, "'g' must be > -1"),
    ({"eta": 0.0}, "'eta' must be > 0"),
    ({"albedo": 1.2}, "'albedo' must be <= 1"),
    ({"g": jnp.asarray([0.1, 0.2])}, "'g' must be a scalar"),
    ({"eta": jnp.asarray([1.3, 1.4])}, "'eta' must be a scalar"),
])
def test_bad_parameters_are_named(bad, match):
    with pytest.raises(ParameterError, match=match):
        HanrahanKrueger(**bad)


def test_registry_entry():
    e = registry.get("hk")
    assert e.name == "hanrahan-krueger" and e.year == 1993
    with pytest.raises(ParameterError, match="'g' must be <= 0.99"):
        e.build(g=0.995)
    m = e.build()
    assert m.channels() == 3
    wi = jnp.asarray(_unit(0.7, 0.2))
    wo = jnp.asarray(_unit(0.6, 2.5))
    assert np.all(np.asarray(eval_jit(m, wi, wo)) > 0)
