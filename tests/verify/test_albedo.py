"""Lobe-adapted hemisphere rules and the directional albedo (brdf_fit.core.quadrature).

The accuracy claims are checked against references computed *differently* from the library:

* **Adaptive SciPy reference.** ``E(wo) = Int f(wi, wo) cos(theta_i) dwi`` is integrated with
  nested adaptive Gauss-Kronrod quadrature (:func:`scipy.integrate.quad`) directly over ``wi`` in
  spherical coordinates, ``dwi = dmu_i dphi_i`` with ``mu_i = cos(theta_i)`` outer on (0, 1) and
  ``phi_i`` inner over a full turn centred on the mirror azimuth, with breakpoints placed at
  multiples of the lobe width around the mirror direction. No half vector Jacobian, no slope
  space, no library code: the BRDF is written below in scalar ``math`` form from the papers, GGX
  ``D(h) = 1 / (pi ax ay (hx^2/ax^2 + hy^2/ay^2 + hz^2)^2)`` (Walter et al. 2007, eq. 33;
  Heitz 2014, eq. 85) evaluated on the unnormalised ``H = wi + wo``, height-correlated Smith
  ``G2 = 1/(1 + Lambda(wi) + Lambda(wo))`` with ``Lambda = (sqrt(1 + alpha(phi)^2 tan^2) - 1)/2``
  (Heitz 2014, eqs. 86, 99) and ``F = 1``, so ``f cos_i = D G2 / (4 cos_o)``. The requested
  absolute error of the reference is 1e-11.
* **Closed form.** For ``alpha = 1`` GGX has ``D = 1/pi`` and ``Lambda(w) = (1/mu - 1)/2``, hence
  ``G2 = 2 mu_i mu_o / (mu_i + mu_o)`` and ``E(mu_o) = Int_0^1 mu_i/(mu_i + mu_o) dmu_i
  = 1 - mu_o ln(1 + 1/mu_o)`` (so ``1 - ln 2`` at normal incidence). Both the SciPy reference and
  the library rule are checked against it.

The fast subset runs by default; the full (alpha, cos_o) sweep is marked ``slow``.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import fd_central
from scipy import integrate as sint

from brdf_fit.core import quadrature as q
from brdf_fit.core.fresnel import ConstantFresnel, SchlickFresnel
from brdf_fit.core.microfacet import GGX, Beckmann, BlinnPhongNDF, SmithHeightCorrelated
from brdf_fit.models import Lambert, MicrofacetBRDF, Mirror, Mixture, Scaled
from brdf_fit.verify import albedo as qa

TOL = 1e-6  # the Done-means accuracy
MAX_EVALS = 4096  # "about 4,000 integrand evaluations per direction" for alpha >= 0.01

ALPHAS = (0.001, 0.01, 0.1, 0.5, 1.0)
COSINES = (0.001, 0.01, 0.5, 1.0)
FAST = ((0.001, 0.001), (0.01, 0.001), (0.01, 0.01), (0.1, 0.5), (1.0, 0.001), (0.5, 1.0))



# --------------------------------------------------------------------------- independent reference


def _half_vector(mu_i, phi_i, mu_o, phi_o):
    """``(si, so, hx, hy, hz)``: the sines of both polar angles and the unnormalised half vector
    ``wi + wo`` from cosines and azimuths (scalar math)."""
    si = math.sqrt(max(0.0, 1.0 - mu_i * mu_i))
    so = math.sqrt(max(0.0, 1.0 - mu_o * mu_o))
    hx = si * math.cos(phi_i) + so * math.cos(phi_o)
    hy = si * math.sin(phi_i) + so * math.sin(phi_o)
    return si, so, hx, hy, mu_i + mu_o


def _ggx_fcos(mu_i, phi_i, mu_o, phi_o, ax, ay):
    """``f(wi, wo) cos(theta_i)`` of GGX + height-correlated Smith + F = 1 (scalar math)."""
    if mu_i <= 0.0:
        return 0.0
    si, so, hx, hy, hz = _half_vector(mu_i, phi_i, mu_o, phi_o)
    h2 = hx * hx + hy * hy + hz * hz
    s = (hx * hx / (ax * ax) + hy * hy / (ay * ay) + hz * hz) / h2
    d = 1.0 / (math.pi * ax * ay * s * s)

    def lam(mu, phi, sn):
        a2 = (ax * math.cos(phi)) ** 2 + (ay * math.sin(phi)) ** 2
        return 0.5 * (math.sqrt(1.0 + a2 * sn * sn / (mu * mu)) - 1.0)

    return d / (1.0 + lam(mu_i, phi_i, si) + lam(mu_o, phi_o, so)) / (4.0 * mu_o)


def _phong_fcos(mu_i, phi_i, mu_o, phi_o, n):
    """Blinn-Phong ``D = (n + 2)/(2 pi) cos^n(theta_h)`` with the exact Beckmann Lambda at
    ``alpha_b = sqrt(2/(n + 2))`` (Walter et al. 2007, eq. 30 and section 5.2), height-correlated
    Smith, F = 1."""
    if mu_i <= 0.0:
        return 0.0
    si, so, hx, hy, hz = _half_vector(mu_i, phi_i, mu_o, phi_o)
    cos_h2 = hz * hz / (hx * hx + hy * hy + hz * hz)
    d = (n + 2.0) / (2.0 * math.pi) * cos_h2 ** (0.5 * n)
    ab = math.sqrt(2.0 / (n + 2.0))

    def lam(mu, sn):
        if sn == 0.0:
            return 0.0
        a = mu / (ab * sn)
        return 0.5 * (math.exp(-a * a) / (a * math.sqrt(math.pi)) - math.erfc(a))

    return d / (1.0 + lam(mu_i, si) + lam(mu_o, so)) / (4.0 * mu_o)


def _scipy_albedo(fcos, mu_o, phi_o, widths, eps=1e-11):
    """Nested adaptive quadrature over (mu_i, phi_i) with breakpoints around the mirror lobe."""
    th_o = math.acos(mu_o)
    pc = phi_o + math.pi  # mirror azimuth

    def inner(mu_i):
        th_i = math.acos(mu_i)
        pts = {pc}
        for a in widths:
            w = max(a, abs(th_i - th_o)) / max(math.sin(th_i), 1e-9)
            pts |= {pc + sg * k * w for k in (0.3, 1, 3, 10, 30) for sg in (-1, 1)}
        pts = sorted(p for p in pts if pc - math.pi < p < pc + math.pi)
        v, _ = sint.quad(
            lambda p: fcos(mu_i, p, mu_o, phi_o), pc - math.pi, pc + math.pi,
            points=pts, epsabs=0.1 * eps, epsrel=1e-12, limit=800,
        )
        return v

    s = math.sin(th_o)
    pts = {mu_o + k * a * s for k in (-30, -10, -3, -1, -0.3, 0, 0.3, 1, 3, 10, 30) for a in widths}
    pts |= {mu_o * f for f in (0.1, 0.3, 0.6, 0.9, 1.1, 1.5, 2.0)}
    pts = sorted(p for p in pts if 0.0 < p < 1.0)
    v, _ = sint.quad(inner, 0.0, 1.0, points=pts, epsabs=eps, epsrel=1e-12, limit=800)
    return v


@functools.cache
def ref_ggx(alpha_x, cos_o, alpha_y=None, phi_o=0.0):
    ay = alpha_x if alpha_y is None else alpha_y

    def fcos(mu_i, phi_i, mu_o, po):
        return _ggx_fcos(mu_i, phi_i, mu_o, po, alpha_x, ay)

    return _scipy_albedo(fcos, cos_o, phi_o, (alpha_x, ay))


@functools.cache
def ref_phong(n, cos_o):
    def fcos(mu_i, phi_i, mu_o, po):
        return _phong_fcos(mu_i, phi_i, mu_o, po, n)

    return _scipy_albedo(fcos, cos_o, 0.0, (math.sqrt(2.0 / (n + 2.0)),))


def closed_form_alpha1(cos_o):
    return 1.0 - cos_o * math.log1p(1.0 / cos_o)


# ------------------------------------------------------------------------------------- helpers


def _wo(cos_o, phi=0.0):
    s = math.sqrt(max(0.0, 1.0 - cos_o * cos_o))
    return jnp.asarray([s * math.cos(phi), s * math.sin(phi), cos_o])


def _ggx_model(ax, ay=None):
    """GGX + height-correlated Smith + F = 1 (parameters as arrays: one compilation for all)."""
    ay = None if ay is None else jnp.asarray(ay)
    return MicrofacetBRDF(GGX(jnp.asarray(ax), ay), SmithHeightCorrelated(), ConstantFresnel(1.0))


def _albedo(model, wo, **kw):
    e, n = qa.directional_albedo(model, wo, return_n_evals=True, **kw)
    return float(e), n


# ------------------------------------------------------------------------ the Done-means target


def _check_ggx(alpha, cos_o):
    ref = ref_ggx(alpha, cos_o)
    e, n = _albedo(_ggx_model(alpha), _wo(cos_o, 0.3))
    assert abs(e - ref) <= TOL, (alpha, cos_o, e, ref, e - ref)
    if alpha >= 0.01:
        assert n <= MAX_EVALS, n


@pytest.mark.parametrize(("alpha", "cos_o"), FAST)
def test_ggx_albedo_against_scipy(alpha, cos_o):
    _check_ggx(alpha, cos_o)


@pytest.mark.slow
@pytest.mark.parametrize("cos_o", COSINES + (0.003, 0.03, 0.1, 0.9))
@pytest.mark.parametrize("alpha", ALPHAS + (0.002, 0.03, 0.2))
def test_ggx_albedo_against_scipy_sweep(alpha, cos_o):
    _check_ggx(alpha, cos_o)


@pytest.mark.slow
def test_ggx_albedo_random_points():
    """Log-uniform random (alpha, cos_o) in [1e-3, 1]^2 and random view azimuths."""
    rng = np.random.default_rng(20240607)
    for _ in range(24):
        alpha, cos_o = (float(10 ** rng.uniform(-3, 0)) for _ in range(2))
        phi = float(rng.uniform(0, 2 * np.pi))
        e, n = _albedo(_ggx_model(alpha), _wo(cos_o, phi))
        assert abs(e - ref_ggx(alpha, cos_o)) <= TOL, (alpha, cos_o)
        assert n <= MAX_EVALS


@pytest.mark.parametrize("cos_o", (1.0, 0.5, 1e-3))
def test_scipy_reference_reproduces_closed_form(cos_o):
    assert abs(ref_ggx(1.0, cos_o) - closed_form_alpha1(cos_o)) <= 1e-10


@pytest.mark.parametrize("cos_o", np.geomspace(1e-3, 1.0, 7).tolist())
def test_ggx_alpha1_closed_form(cos_o):
    e, _ = _albedo(_ggx_model(1.0), _wo(cos_o, 1.0))
    assert abs(e - closed_form_alpha1(cos_o)) <= 1e-10


def test_n_evals_default():
    _, n = _albedo(_ggx_model(0.3), _wo(0.5))
    assert n == q.HALFVECTOR_N_THETA * q.HALFVECTOR_N_PHI == 3072
    _, n = _albedo(MicrofacetBRDF(Beckmann(0.3)), _wo(0.5))
    assert n == qa.GAUSSIAN_N_THETA * q.HALFVECTOR_N_PHI == 4096


# ------------------------------------------------------------------- other lobes and composites


def test_phong_exponent_1e4():
    """A Blinn-Phong exponent of 1e4 (equivalent width 0.0141) against its own SciPy reference."""
    dist = BlinnPhongNDF(jnp.asarray(1e4))
    m = MicrofacetBRDF(dist, SmithHeightCorrelated(), ConstantFresnel(1.0))
    for cos_o in (0.01, 0.5):
        e, n = _albedo(m, _wo(cos_o))
        assert abs(e - ref_phong(1e4, cos_o)) <= TOL, cos_o
        assert n <= MAX_EVALS


@pytest.mark.parametrize(("ax", "ay", "cos_o"), [(0.02, 0.04, 0.01), (0.02, 0.04, 0.6)])
def test_anisotropic_ggx(ax, ay, cos_o):
    phi = 0.7
    e, _ = _albedo(_ggx_model(ax, ay), _wo(cos_o, phi))
    assert abs(e - ref_ggx(ax, cos_o, ay, phi)) <= TOL


@pytest.mark.slow
@pytest.mark.parametrize(("ax", "ay"), [(0.01, 0.1), (0.3, 0.02), (0.005, 0.5)])
@pytest.mark.parametrize("cos_o", (0.003, 0.4, 1.0))
def test_anisotropic_ggx_strong(ax, ay, cos_o):
    """Aspect ratios 10 to 100 need more rays than the default for 1e-6 (docs/quadrature.md)."""
    phi = 0.4
    e, _ = _albedo(_ggx_model(ax, ay), _wo(cos_o, phi), n_theta=64, n_phi=256)
    assert abs(e - ref_ggx(ax, cos_o, ay, phi)) <= TOL


def test_lambert_albedo_is_rho_exactly():
    rho = jnp.asarray([0.2, 0.5, 0.9])
    wo = jnp.stack([_wo(c, 0.4) for c in (1e-3, 0.3, 1.0)])
    e, n = qa.directional_albedo(Lambert(rho), wo, return_n_evals=True)
    assert e.shape == (3, 3)
    np.testing.assert_allclose(e, np.broadcast_to(rho, (3, 3)), rtol=1e-14, atol=0)
    assert n == 4
    # any Gauss-Legendre x trapezoid rule is exact for rho/pi * mu, even a single node
    one = q.cosine_rule(1, 1)
    val = q.integrate(lambda d: 0.7 / math.pi * d[:, 2], one)
    np.testing.assert_allclose(val, 0.7, rtol=1e-15)


def test_mixture_is_sum_of_lobes_and_scaled_scales():
    spec = _ggx_model(0.05)
    diff = Lambert(jnp.asarray([0.1, 0.4, 0.8]))
    wo = jnp.stack([_wo(c, 1.2) for c in (0.002, 0.2, 0.9)])
    e_s = qa.directional_albedo(spec, wo)
    e_d = qa.directional_albedo(diff, wo)
    mix, n = qa.directional_albedo(Mixture((diff, Scaled(spec, 0.25))), wo, return_n_evals=True)
    assert mix.shape == (3, 3) and n == 4 + 3072
    np.testing.assert_allclose(mix, e_d + 0.25 * e_s[:, None], rtol=1e-13)
    np.testing.assert_allclose(qa.directional_albedo(Scaled(spec, 0.5), wo), 0.5 * e_s, rtol=1e-14)


def test_mirror_uses_closed_form():
    m = Mirror(SchlickFresnel(jnp.asarray([0.04, 0.5])))
    wo = jnp.stack([_wo(c) for c in (0.05, 0.7)])
    e, n = qa.directional_albedo(Scaled(m, 0.5), wo, return_n_evals=True)
    assert n == 0
    np.testing.assert_allclose(e, 0.5 * m.albedo(wo), rtol=1e-15)


def test_below_horizon_and_shapes():
    m = _ggx_model(0.2)
    wo = jnp.asarray([[0.6, 0.0, -0.8], [0.0, 0.0, 1.0]])
    e = qa.directional_albedo(m, wo)
    assert e.shape == (2,)
    assert float(e[0]) == 0.0 and 0.9 < float(e[1]) < 1.0
    rule = q.halfvector_rule(np.asarray(wo), 0.2)
    assert rule.directions.shape == (2, 3072, 3) and rule.weights.shape == (2, 3072)
    assert rule.n == 3072
    assert float(jnp.max(jnp.abs(rule.weights[0]))) == 0.0


# ------------------------------------------------------------------------------ rule properties


@pytest.mark.parametrize(("alpha", "cos_o"), [(1e-3, 1e-3), (0.01, 0.01), (0.3, 0.2), (1.0, 1.0)])
def test_halfvector_rule_nodes(alpha, cos_o):
    rule = q.halfvector_rule(_wo(cos_o, 2.0), alpha, 1.5 * alpha)
    d, w = np.asarray(rule.directions), np.asarray(rule.weights)
    assert rule.n == q.HALFVECTOR_N_THETA * q.HALFVECTOR_N_PHI
    assert np.all(d[:, 2] > 0), "every node strictly above the horizon"
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-13)
    assert np.all(w > 0) and np.all(np.isfinite(w))
    # smooth cosine-weighted integrands are integrated accurately too
    np.testing.assert_allclose(np.sum(w * d[:, 2]), math.pi, rtol=1e-6)


def test_halfvector_rule_dtype_and_validation():
    r32 = q.halfvector_rule(_wo(0.5), 0.1, dtype=jnp.float32)
    assert r32.directions.dtype == r32.weights.dtype == jnp.float32
    with pytest.raises(ValueError):
        q.halfvector_rule(_wo(0.5), 0.1, n_phi=63)
    with pytest.raises(ValueError):
        q.halfvector_rule(_wo(0.5), 0.0)


def test_traced_rule_matches_numpy_rule_and_gradients():
    wo = _wo(0.05, 0.7)
    r_np = q.halfvector_rule(np.asarray(wo), 0.03, 0.06)
    r_jx = jax.jit(q.halfvector_rule)(wo, jnp.asarray(0.03), jnp.asarray(0.06))
    np.testing.assert_allclose(r_jx.directions, r_np.directions, rtol=0, atol=1e-13)
    np.testing.assert_allclose(r_jx.weights, r_np.weights, rtol=1e-12, atol=0)

    def albedo(a):
        return qa.directional_albedo(_ggx_model(a), wo)

    a, h = 0.1, 1e-5
    val, g = jax.jit(jax.value_and_grad(albedo))(jnp.asarray(a))  # traced alpha: jnp rule
    fd = fd_central(albedo, a, h)  # concrete alpha: NumPy rule
    np.testing.assert_allclose(val, albedo(a), rtol=1e-13)
    assert np.isfinite(float(g))
    np.testing.assert_allclose(g, fd, rtol=1e-6)


def test_integrate_accepts_halfvector_rule():
    m = _ggx_model(0.1)
    wo = _wo(0.3)
    rule = q.halfvector_rule(np.asarray(wo), 0.1)
    val = q.integrate(lambda d: m.eval_cos(d, wo[None]), rule)
    np.testing.assert_allclose(val, qa.directional_albedo(m, wo), rtol=1e-13)
