"""Ashikhmin-Shirley (brdf_fit.models.ashikhmin_shirley) against an independent implementation.

The reference is written from the paper (Ashikhmin & Shirley 2000, eqs. 4, 5, 8, 9, 10) in
spherical angles with NumPy: theta and phi of both directions, the half vector's polar angle and
azimuth from ``arccos``/``arctan2`` and the exponent ``nu cos^2 phi_h + nv sin^2 phi_h``; the
model under test uses dot products and the ``log1p`` form of the exponent. Quadratures here use
tests/_lobe_quadrature.py, not brdf_fit.core.quadrature.
"""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import (
    assert_finite,
    assert_model_gradient_matches_fd,
    assert_sampling_finite,
    eval_cos_and_pdf,
    random_angles,
    values_pdfs_grads,
)
from _helpers import eval_cos_jit as _eval_cos
from _helpers import eval_jit as _eval
from _helpers import pdf_jit as _pdf
from _helpers import vec as _vec
from _lobe_quadrature import gauss_hemisphere, halfvector_rule

from brdf_fit import registry
from brdf_fit.core.validate import ParameterError
from brdf_fit.models._base import astype
from brdf_fit.models.ashikhmin_shirley import AshikhminShirley, registry_entries
from brdf_fit.verify import checks
from brdf_fit.verify.albedo import directional_albedo
from brdf_fit.verify.chi2 import chi2_test_brdf

#: polar angles from cosines uniform in [lo, 1], azimuths uniform in [-pi, pi)
_angles = functools.partial(random_angles, phi_range=(-np.pi, np.pi))


def reference(theta_i, phi_i, theta_o, phi_o, Rs, Rd, nu, nv, diffuse=True):
    """f and the mixture pdf straight from the paper, in angles (NumPy, float64)."""
    k1, k2 = _vec(theta_i, phi_i), _vec(theta_o, phi_o)
    H = k1 + k2
    h = H / np.linalg.norm(H, axis=-1, keepdims=True)
    theta_h = np.arccos(np.clip(h[:, 2], -1, 1))
    phi_h = np.arctan2(h[:, 1], h[:, 0])
    kh = np.sum(k1 * h, -1)
    e = nu * np.cos(phi_h) ** 2 + nv * np.sin(phi_h) ** 2
    lobe = np.cos(theta_h) ** e
    F = Rs + (1 - Rs) * (1 - kh) ** 5
    ci, co = np.cos(theta_i), np.cos(theta_o)
    fs = math.sqrt((nu + 1) * (nv + 1)) / (8 * np.pi) * lobe / (kh * np.maximum(ci, co)) * F
    fd = (28 * Rd / (23 * np.pi) * (1 - Rs) * (1 - (1 - ci / 2) ** 5) * (1 - (1 - co / 2) ** 5)
          if diffuse else 0.0)
    ph = math.sqrt((nu + 1) * (nv + 1)) / (2 * np.pi) * lobe / (4 * kh)  # eq. 8, p(k2)
    if diffuse:
        hd, hs = Rd * (1 - Rs), Rs
        pd = hd / (hd + hs)
    else:
        pd = 0.0
    return fs + fd, pd * ci / np.pi + (1 - pd) * ph


@pytest.mark.parametrize("nu, nv", [(10.0, 10.0), (20.0, 500.0), (3000.0, 7.0), (0.0, 1e4)])
def test_matches_angle_reference(nu, nv):
    rng = np.random.default_rng(0)
    ti, pi_ = _angles(rng, 300)
    to, po = _angles(rng, 300)
    wi, wo = jnp.asarray(_vec(ti, pi_)), jnp.asarray(_vec(to, po))
    for Rs, Rd, diffuse in ((0.3, 0.6, True), (0.9, 0.0, False)):
        m = AshikhminShirley(Rs=Rs, Rd=Rd, nu=nu, nv=nv, diffuse=diffuse)
        f_ref, p_ref = reference(ti, pi_, to, po, Rs, Rd, nu, nv, diffuse)
        f, p = np.asarray(_eval(m, wi, wo)), np.asarray(_pdf(m, wi, wo))
        big = f_ref > 1e-250  # (n.h)^e underflows alike in both
        np.testing.assert_allclose(f[big], f_ref[big], rtol=1e-10)
        np.testing.assert_allclose(p[big], p_ref[big], rtol=1e-10)


def test_channels_and_reciprocity():
    rng = np.random.default_rng(1)
    ti, pi_ = _angles(rng, 500)
    to, po = _angles(rng, 500)
    wi, wo = jnp.asarray(_vec(ti, pi_)), jnp.asarray(_vec(to, po))
    Rs, Rd = np.array([0.1, 0.3, 0.5]), np.array([0.7, 0.5, 0.2])
    m = AshikhminShirley(Rs=jnp.asarray(Rs), Rd=jnp.asarray(Rd), nu=30.0, nv=300.0)
    f = np.asarray(_eval(m, wi, wo))
    assert f.shape == (500, 3)
    for c in range(3):
        f_ref, _ = reference(ti, pi_, to, po, Rs[c], Rd[c], 30.0, 300.0)
        np.testing.assert_allclose(f[:, c], f_ref, rtol=1e-10)
    np.testing.assert_allclose(f, np.asarray(_eval(m, wo, wi)), rtol=1e-12)


def test_diffuse_albedo_closed_form():
    """Int f_d cl dw = Rd (1 - Rs)(1 - (1 - cv/2)^5): the 28/23 of eq. 5 normalises
    2 Int_0^1 (1 - (1 - mu/2)^5) mu dmu = 23/28 (the integrand is a polynomial in mu, so the
    Gauss-Legendre rule is exact)."""
    d, w = gauss_hemisphere(16, 4)
    Rs, Rd = 0.2, 0.9
    full = AshikhminShirley(Rs=Rs, Rd=Rd, nu=5.0, nv=50.0)
    spec = AshikhminShirley(Rs=Rs, Rd=0.0, nu=5.0, nv=50.0, diffuse=False)
    for cv in (1e-3, 0.3, 0.8, 1.0):
        wo = _vec(np.array(math.acos(cv)), np.array(0.4))
        fd = lambda wi, wo=wo: (_eval_cos(full, wi, jnp.asarray(wo))  # noqa: E731
                                - _eval_cos(spec, wi, jnp.asarray(wo)))
        E = float(jnp.sum(w * fd(jnp.asarray(d))))
        assert E == pytest.approx(Rd * (1 - Rs) * (1 - (1 - cv / 2) ** 5), rel=1e-12)
    x, wk = np.polynomial.legendre.leggauss(8)
    mu = 0.5 * (x + 1)
    assert 2 * np.sum(0.5 * wk * (1 - (1 - mu / 2) ** 5) * mu) == pytest.approx(23 / 28,
                                                                              rel=1e-14)


@pytest.mark.parametrize("n", (1.0, 10.0, 100.0, 1e4))
def test_specular_albedo_normal_view_closed_form(n):
    """F = 1 (Rs = 1), nu = nv = n, wo = n: theta_i = 2 theta_h, max(cl, cv) = 1, so
    E = (n+1) Int_{cos th_h > 1/sqrt 2} cos^n(th_h) cos(2 th_h) d cos(th_h)
      = (n+1) [2 (1 - 2^(-(n+3)/2))/(n+3) - (1 - 2^(-(n+1)/2))/(n+1)]."""
    exact = (n + 1) * (2 * (1 - 2 ** (-(n + 3) / 2)) / (n + 3)
                       - (1 - 2 ** (-(n + 1) / 2)) / (n + 1))
    m = AshikhminShirley(Rs=1.0, Rd=0.0, nu=n, nv=n, diffuse=False)
    wo = np.array([0.0, 0.0, 1.0])
    wi, w = halfvector_rule(wo, math.sqrt(2 / (n + 2)))
    E = float(np.sum(w * np.asarray(_eval_cos(m, jnp.asarray(wi), jnp.asarray(wo)))))
    assert E == pytest.approx(exact, rel=1e-9)
    # the library's albedo (lobe-adapted half-vector rule from quadrature_lobe()) agrees
    assert float(directional_albedo(m, jnp.asarray(wo))) == pytest.approx(exact, rel=1e-7)


def test_energy_claim_rs_plus_diffuse_at_most_one():
    """The paper's design claim: Rd = 1 gives albedo <= 1 for every Rs (measured, independent
    rule; the maximum is at normal view, 0.96876 for Rs = 0 (31/32 + a Fresnel tail) and 0.9996
    for Rs = 1, n = 1e4)."""
    worst = 0.0
    for Rs in (0.0, 0.3, 1.0):
        for nu, nv in ((10.0, 10.0), (100.0, 1000.0)):
            m = AshikhminShirley(Rs=Rs, Rd=1.0, nu=nu, nv=nv)
            for cv in (1e-2, 0.3, 0.7, 1.0):
                wo = _vec(np.array(math.acos(cv)), np.array(0.3))
                wi, w = halfvector_rule(wo, math.sqrt(2 / (min(nu, nv) + 2)), n_v=192, n_phi=192)
                E = float(np.sum(w * np.asarray(_eval_cos(m, jnp.asarray(wi), jnp.asarray(wo)))))
                worst = max(worst, E)
    assert 0.96 < worst <= 1.0


def test_registry_entries_and_checks():
    """No declared failures; energy passes at the defaults (the other checks, chi-square
    included, run in tests/test_checks.py and tests/test_sampling.py)."""
    names = {e.name for e in registry_entries()}
    assert names == {"ashikhmin-shirley", "ashikhmin-shirley-specular"}
    for name in names:
        e = registry.get(name)
        assert e.year == 2000 and "anisotropic" in e.tags and not e.expected_failures
    (res,) = checks.run_checks("ashikhmin-shirley", checks=["energy"])
    assert res.passed and 0.66 < res.statistic < 0.67, res.statistic  # measured 0.6613


@pytest.mark.parametrize("nu, nv, cos_o", [(10.0, 10.0, 0.7), (5.0, 2000.0, 0.2),
                                           (1e4, 50.0, 0.9)])
def test_chi2_specular_sampler(nu, nv, cos_o):
    m = AshikhminShirley(Rs=0.5, Rd=0.3, nu=nu, nv=nv)
    wo = _vec(np.array(math.acos(cos_o)), np.array(0.8))
    r = chi2_test_brdf(m, jnp.asarray(wo), n_samples=100_000, seed=7, test_count=3)
    assert r.passed, str(r)


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(3)
    ti, pi_ = _angles(rng, 40, lo=0.05)
    to, po = _angles(rng, 40, lo=0.05)
    wi, wo = jnp.asarray(_vec(ti, pi_)), jnp.asarray(_vec(to, po))
    p0 = {"Rs": 0.3, "Rd": 0.5, "nu": 20.0, "nv": 150.0}
    assert_model_gradient_matches_fd(AshikhminShirley, wi, wo, p0, rel=1e-6, abs=1e-10,
                                     relative_step=True, objective=eval_cos_and_pdf)


def test_extreme_parameters_finite():
    """nu, nv at both ends of [0, 1e5], Rs and Rd at 0 and 1, on the repo's hard-case directions,
    float64 and float32: values, pdfs and gradients (both directions, every parameter) finite."""
    WI, WO = checks.hard_case_directions()
    grid = [(0.0, 1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 1e5), (1.0, 1.0, 1e5, 0.0),
            (0.0, 0.0, 1e5, 1e5), (0.5, 0.5, 1.0, 1e5)]
    P = {k: np.array([g[i] for g in grid]) for i, k in enumerate(("Rs", "Rd", "nu", "nv"))}
    for dt in (jnp.float64, jnp.float32):
        wi, wo = jnp.asarray(WI, dt), jnp.asarray(WO, dt)
        out = values_pdfs_grads(AshikhminShirley, {k: jnp.asarray(v, dt) for k, v in P.items()},
                                wi, wo)
        assert_finite(out, str(dt))
        assert np.all(np.asarray(out[0]) >= 0) and np.all(np.asarray(out[1]) >= 0)
        # sampling at extreme uniforms never gives NaN; failed samples have weight 0
        for nu, nv in ((0.0, 1e5), (1e5, 1e5)):
            assert_sampling_finite(astype(AshikhminShirley(Rs=0.5, Rd=0.5, nu=nu, nv=nv), dt), dt)


def test_parameter_errors_name_the_parameter():
    for bad, name in (({"nu": -1.0}, "nu"), ({"nv": -0.5}, "nv"), ({"Rs": 1.5}, "Rs"),
                      ({"Rd": -0.1}, "Rd")):
        with pytest.raises(ParameterError, match=f"'{name}'"):
            AshikhminShirley(**bad)
    with pytest.raises(ParameterError, match="'nu'"):
        registry.get("ashikhmin-shirley").build(nu=-3.0)
    with pytest.raises(ParameterError, match="'nv' must be a scalar"):
        AshikhminShirley(nv=jnp.asarray([1.0, 2.0]))
