"""Granier-Heidrich layered RGB BRDF (brdf_fit.models.granier_heidrich).

Independent reference: a NumPy transcription of the shader's *vector* steps (P. Stuart's
``granier.sl``): the RenderMan ``reflect``/``refract`` formulas applied to explicit direction
vectors built from spherical angles, the Fresnel reflectance from Fresnel's sine and tangent laws
(``R_s = sin^2(ti - tt)/sin^2(ti + tt)``, ``R_p = tan^2(ti - tt)/tan^2(ti + tt)``), not the
dot-product closed forms of the JAX module.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import dir_from_cos
from _helpers import eval_jit as _eval
from _helpers import vec as _vec

from brdf_fit.core import quadrature
from brdf_fit.core.validate import ParameterError
from brdf_fit.models._base import astype
from brdf_fit.models.granier_heidrich import (
    WAVELENGTHS_NM,
    GranierHeidrich,
    diffuse_factor,
    registry_entries,
)
from brdf_fit.verify import albedo, checks

PARAMS = dict(kd=np.array([0.7, 0.5, 0.3]), ks=np.array([0.8, 0.9, 1.0]),
              eta=np.array([1.4, 1.45, 1.6]), d=70.0, e0=90.0, e1=170.0)


def _model(**kw):
    p = {**PARAMS, **kw}
    return GranierHeidrich(**{k: jnp.asarray(v) for k, v in p.items()})


# ----------------------------------------------------------------------------- NumPy reference


def _fresnel_sin_tan(theta_i, eta):
    """Unpolarised Fresnel reflectance by Fresnel's sine and tangent laws (theta_i > 0)."""
    theta_t = np.arcsin(np.sin(theta_i) / eta)
    rs = (np.sin(theta_i - theta_t) / np.sin(theta_i + theta_t)) ** 2
    rp = (np.tan(theta_i - theta_t) / np.tan(theta_i + theta_t)) ** 2
    return 0.5 * (rs + rp)


def _refract(I, N, r):
    """RenderMan ``refract(I, N, eta)``: ``eta I - (eta I.N + sqrt(k)) N``."""
    idn = np.sum(I * N, -1, keepdims=True)
    k = 1.0 - r * r * (1.0 - idn * idn)
    return r * I - (r * idn + np.sqrt(k)) * N


def _reflect(I, N):
    return I - 2.0 * np.sum(I * N, -1, keepdims=True) * N


def reference(theta_l, phi_l, theta_v, phi_v, kd, ks, eta, d, e0, e1, lam=WAVELENGTHS_NM):
    """The shader, step by step, per channel; returns ``(n, C)`` (BRDF = shader / pi)."""
    L, V = _vec(theta_l, phi_l), _vec(theta_v, phi_v)
    N = np.broadcast_to(np.array([0.0, 0.0, 1.0]), L.shape)
    out = []
    for c in range(len(lam)):
        ior = eta[c]
        kr = _fresnel_sin_tan(theta_l, ior)
        kt, kto = 1.0 - kr, 1.0 - _fresnel_sin_tan(theta_v, ior)
        ri = _reflect(-L, N)
        ti = _refract(-L, N, 1.0 / ior)
        to = _refract(-V, N, 1.0 / ior)
        ti /= np.linalg.norm(ti, axis=-1, keepdims=True)
        to /= np.linalg.norm(to, axis=-1, keepdims=True)
        rti = _reflect(ti, N)
        tir = (np.sum(rti * to, -1) >= 0)
        kt = np.where(tir, 0.0, kt)
        a = np.maximum(np.sum(ri * V, -1), 0.0)
        b = np.maximum(-np.sum(rti * to, -1), 0.0)
        spec = kr * a ** e0 + kt * kto * b ** e1
        td = (80.0 / 21.0) * ior / (ior + 1.0) ** 2
        diff = (1.0 + 2.0 * np.cos(4.0 * np.pi * ior * d / lam[c]) * np.sqrt(td * (1 - td))) / 2
        out.append((kd[c] * diff + ks[c] * spec) / np.pi)
    return np.stack(out, -1)


def _angles(n, seed):
    rng = np.random.default_rng(seed)
    tl, tv = np.arccos(rng.uniform(0.02, 1.0, (2, n)))
    pl, pv = rng.uniform(0.0, 2 * np.pi, (2, n))
    # a quarter of the pairs near the mirror configuration, where the lobes are not negligible
    k = n // 4
    tv[:k] = tl[:k] + rng.normal(0.0, 0.05, k)
    tv[:k] = np.clip(tv[:k], 0.01, 1.5)
    pv[:k] = pl[:k] + np.pi + rng.normal(0.0, 0.05, k)
    return tl, pl, tv, pv


@pytest.mark.parametrize("params", [
    PARAMS,
    dict(kd=np.array([0.2, 0.4, 0.6]), ks=np.array([1.0, 0.5, 0.7]),
         eta=np.array([1.1, 2.0, 2.9]), d=413.0, e0=12.0, e1=3.5),
])
def test_matches_vector_reference(params):
    tl, pl, tv, pv = _angles(300, 0)
    got = np.asarray(_eval(_model(**params), jnp.asarray(_vec(tl, pl)), jnp.asarray(_vec(tv, pv))))
    want = reference(tl, pl, tv, pv, **params)
    rel = np.max(np.abs(got - want) / np.abs(want))
    assert rel < 1e-10, rel


def test_eta_one_is_phong_plus_constant():
    """eta = 1: no top reflection (F = 0), T = 1, the refracted lobe is the Phong lobe about the
    mirror direction with exponent e1; T_d = 80/84."""
    tl, pl, tv, pv = _angles(200, 1)
    L, V = _vec(tl, pl), _vec(tv, pv)
    m = _model(eta=np.ones(3))
    got = np.asarray(_eval(m, jnp.asarray(L), jnp.asarray(V)))
    rv = 2 * L[:, 2] * V[:, 2] - np.sum(L * V, -1)
    td = 80.0 / 84.0
    lam = np.asarray(WAVELENGTHS_NM)
    diff = (1 + 2 * np.cos(4 * np.pi * 70.0 / lam) * math.sqrt(td * (1 - td))) / 2
    want = (PARAMS["kd"] * diff + PARAMS["ks"] * np.maximum(rv, 0)[:, None] ** 170.0) / np.pi
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-300)


def test_normal_incidence_values():
    """wi = wo = n: r.v = c1 = 1, F = ((eta - 1)/(eta + 1))^2, f = (kd D + ks (F + (1-F)^2))/pi."""
    n = jnp.array([0.0, 0.0, 1.0])
    got = np.asarray(_eval(_model(), n, n))
    eta = PARAMS["eta"]
    F = ((eta - 1) / (eta + 1)) ** 2
    D = np.asarray(diffuse_factor(jnp.asarray(eta), 70.0))
    want = (PARAMS["kd"] * D + PARAMS["ks"] * (F + (1 - F) ** 2)) / np.pi
    np.testing.assert_allclose(got, want, rtol=1e-14)
    # the printed shader constant at eta = 1.5: T_d = (80/21) 1.5/6.25 = 32/35
    td = 32.0 / 35.0
    d1 = np.asarray(diffuse_factor(jnp.asarray(1.5), 0.0))
    np.testing.assert_allclose(d1, (1 + 2 * math.sqrt(td * (1 - td))) / 2, rtol=1e-15)


def test_non_reciprocity_is_the_top_lobe_only():
    tl, pl, tv, pv = _angles(200, 2)
    L, V = jnp.asarray(_vec(tl, pl)), jnp.asarray(_vec(tv, pv))
    m = _model()
    asym = np.asarray(_eval(m, L, V) - _eval(m, V, L))
    rv = 2 * np.cos(tl) * np.cos(tv) - np.sum(_vec(tl, pl) * _vec(tv, pv), -1)
    rv = np.maximum(rv, 0.0)
    F = lambda t: np.stack([_fresnel_sin_tan(t, e) for e in PARAMS["eta"]], -1)  # noqa: E731
    want = PARAMS["ks"] * (F(tl) - F(tv)) * (rv ** 90.0)[:, None] / np.pi
    np.testing.assert_allclose(asym, want, rtol=1e-9, atol=1e-15)


def test_diffuse_albedo_bounded_by_kd():
    """ks = 0: the albedo is kd D (constant in the view), D <= 1, by the library quadrature."""
    m = _model(ks=np.zeros(3), kd=np.ones(3))
    for c in (1.0, 0.3):
        wo = jnp.asarray(dir_from_cos(c))
        a = np.asarray(albedo.directional_albedo(m, wo))
        D = np.asarray(diffuse_factor(jnp.asarray(PARAMS["eta"]), 70.0))
        np.testing.assert_allclose(a, D, rtol=1e-12)
        assert np.all(a <= 1.0)


def test_mirror_hint_matches_fine_generic_rule():
    m = _model()
    for c in (0.9, 0.1):
        wo = jnp.asarray(dir_from_cos(c))
        a = np.asarray(albedo.directional_albedo(m, wo))
        b = np.asarray(quadrature.integrate(lambda w, wo=wo: m.eval_cos(w, wo),
                                            quadrature.gauss_legendre_hemisphere(384, 768)))
        np.testing.assert_allclose(a, b, rtol=1e-9)


def test_registry_checks_declared():
    (entry,) = registry_entries()
    assert entry.name == "granier-heidrich" and entry.year == 2003
    assert entry.catalogue == "Granier-Heidrich"
    res = {r.check: r for r in checks.run_checks(
        "granier-heidrich", checks=("non-negative", "reciprocity", "energy"))}
    assert not res["reciprocity"].passed
    assert abs(res["reciprocity"].statistic - 0.212) < 5e-3
    assert res["energy"].passed and res["non-negative"].passed


def _gh_total(p, L, V):
    return jnp.sum(GranierHeidrich(**p).eval(L, V))


# one compilation for all six parametrised cases (values for the differences, and the gradient)
_gh_value_and_grad = jax.jit(jax.value_and_grad(_gh_total))


@pytest.mark.parametrize("name", ["kd", "ks", "eta", "d", "e0", "e1"])
def test_gradients_match_finite_differences(name):
    tl, pl, tv, pv = _angles(16, 3)
    L, V = jnp.asarray(_vec(tl, pl)), jnp.asarray(_vec(tv, pv))
    base = {k: jnp.asarray(v) for k, v in PARAMS.items()}

    def total(x):
        return _gh_value_and_grad({**base, name: jnp.asarray(x)}, L, V)[0]

    x0 = base[name]
    g = np.atleast_1d(np.asarray(_gh_value_and_grad(base, L, V)[1][name]))
    h = 1e-6 * max(1.0, float(np.max(np.abs(np.asarray(x0)))))
    fd = []
    for i in range(np.size(x0)):
        e = np.zeros(np.shape(x0))
        e.flat[i] = h
        fd.append((float(total(x0 + e)) - float(total(x0 - e))) / (2 * h))
    np.testing.assert_allclose(g, np.asarray(fd), rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("kw, name", [
    (dict(e0=-1.0), "e0"), (dict(e1=-1.0), "e1"), (dict(d=-1.0), "d"), (dict(kd=-0.1), "kd"),
    (dict(ks=-0.1), "ks"), (dict(eta=0.9), "eta"), (dict(eta=np.ones(4) * 1.5), "eta"),
    (dict(d=np.array([1.0, 2.0, 3.0])), "d"),
])
def test_bad_parameters(kw, name):
    with pytest.raises(ParameterError, match=name):
        GranierHeidrich(**{**PARAMS, **kw})


def test_float32_jit_vmap_and_hard_directions():
    m32 = astype(_model(), jnp.float32)
    wi, wo = checks.hard_case_directions()
    v = jax.jit(jax.vmap(m32.eval))(jnp.asarray(wi, jnp.float32), jnp.asarray(wo, jnp.float32))
    assert v.dtype == jnp.float32 and v.shape == (len(wi), 3)
    assert np.all(np.isfinite(np.asarray(v)))


def test_thickness_and_kd_are_not_separately_identifiable():
    """d enters only through the constant kd_c D_c(eta_c, d): changing d and rescaling kd by
    D(d)/D(d') leaves eval unchanged (the fit must hold d or kd fixed)."""
    tl, pl, tv, pv = _angles(50, 4)
    L, V = jnp.asarray(_vec(tl, pl)), jnp.asarray(_vec(tv, pv))
    eta = jnp.asarray(PARAMS["eta"])
    ratio = np.asarray(diffuse_factor(eta, 70.0)) / np.asarray(diffuse_factor(eta, 90.0))
    a = _eval(_model(), L, V)
    b = _eval(_model(d=90.0, kd=PARAMS["kd"] * ratio), L, V)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13)
