"""Fresnel terms against sourced values, exact identities, an independent complex-arithmetic
implementation, and finite differences."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import fd_central
from reference_numpy import ref_fresnel_conductor

from brdf_fit.core import fresnel


def snell_rs_rp(theta_i, n):
    """Independent s and p reflectances from Snell's law in angle form (Born & Wolf 1.5.2):
    Rs = sin^2(ti - tt)/sin^2(ti + tt), Rp = tan^2(ti - tt)/tan^2(ti + tt)."""
    tt = math.asin(math.sin(theta_i) / n)
    rs = math.sin(theta_i - tt) ** 2 / math.sin(theta_i + tt) ** 2
    rp = math.tan(theta_i - tt) ** 2 / math.tan(theta_i + tt) ** 2
    return rs, rp


def test_dielectric_normal_incidence_is_f0():
    # ((n - 1)/(n + 1))^2 = 0.04 for n = 1.5
    assert float(fresnel.dielectric(1.0, 1.5)) == pytest.approx(0.04, abs=1e-15)
    assert float(fresnel.f0_from_ior(1.5)) == pytest.approx(0.04, abs=1e-15)


@pytest.mark.parametrize("deg", [10.0, 30.0, 45.0, 60.0, 80.0, 89.0])
def test_dielectric_matches_snell_angle_form(deg):
    th = math.radians(deg)
    rs, rp = snell_rs_rp(th, 1.5)
    assert float(fresnel.dielectric(math.cos(th), 1.5)) == pytest.approx(0.5 * (rs + rp), rel=1e-12)


def test_dielectric_45_degrees_value():
    # Rs = 0.0920, Rp = 0.0085 at 45 degrees for n = 1.5 (textbook values, e.g. Hecht, Optics,
    # section 4.6): F = 0.0502 to the printed precision.
    assert float(fresnel.dielectric(math.cos(math.pi / 4), 1.5)) == pytest.approx(0.0502, abs=1e-4)


def test_brewster_angle():
    # At Brewster's angle tan(theta_B) = n, Rp = 0 and Rs = ((n^2 - 1)/(n^2 + 1))^2
    n = 1.5
    tb = math.atan(n)
    rs = ((n * n - 1) / (n * n + 1)) ** 2
    assert float(fresnel.dielectric(math.cos(tb), n)) == pytest.approx(0.5 * rs, rel=1e-12)
    # and the p-polarised part is exactly zero there: F is the minimum over angles of F - Rs/2
    ths = np.linspace(tb - 0.2, tb + 0.2, 401)
    rp = [2 * float(fresnel.dielectric(math.cos(t), n)) - snell_rs_rp(t, n)[0] for t in ths]
    assert ths[int(np.argmin(rp))] == pytest.approx(tb, abs=1e-3)


def test_total_internal_reflection():
    n = 1.5
    crit = math.asin(1 / n)
    for deg in [42.0, 50.0, 70.0, 89.9]:
        th = math.radians(deg)
        assert th > crit
        # light from inside (cos < 0), and equivalently eta < 1 from outside
        assert float(fresnel.dielectric(-math.cos(th), n)) == 1.0
        assert float(fresnel.dielectric(math.cos(th), 1 / n)) == 1.0
    # just below the critical angle it is < 1 and continuous to 1
    f = float(fresnel.dielectric(-math.cos(crit - 1e-6), n))
    assert 0.99 < f < 1.0
    # from inside, below the critical angle: same as from outside with the transmitted angle
    th = math.radians(20.0)
    tt = math.asin(math.sin(th) * n)
    assert float(fresnel.dielectric(-math.cos(th), n)) == pytest.approx(
        float(fresnel.dielectric(math.cos(tt), n)), rel=1e-12
    )


def test_grazing_is_one():
    for eta in [1.5, 1 / 1.5, 3.0]:
        assert float(fresnel.dielectric(0.0, eta)) == pytest.approx(1.0)
    for eta, k in [(0.2, 3.9), (1.5, 0.0), (1.0, 0.0), (2.9, 3.0)]:
        assert float(fresnel.conductor(0.0, eta, k)) == pytest.approx(1.0)
    assert float(fresnel.dielectric(0.0, 1.0)) == 1.0
    assert float(fresnel.dielectric(0.3, 1.0)) == pytest.approx(0.0, abs=1e-15)  # round-off only


@pytest.mark.parametrize("eta", [1.5, 1.0, 1 / 1.5, 2.4, 0.3])
def test_conductor_with_k0_equals_dielectric(eta):
    c = jnp.linspace(0.0, 1.0, 1001)
    np.testing.assert_allclose(
        fresnel.conductor(c, eta, 0.0), fresnel.dielectric(c, eta), rtol=1e-12, atol=1e-14
    )


@pytest.mark.parametrize(
    "eta,k", [(0.2, 3.9), (1.5, 0.0), (2.9, 3.0), (0.05, 2.0), (1.0, 1.0), (1.0, 100.0),
              (0.2, 100.0), (50.0, 0.1), (1 / 1.5, 0.0)]
)
def test_conductor_matches_complex_reference(eta, k):
    c = np.concatenate([[1e-7, 1e-4, 1e-2], np.linspace(0.05, 1.0, 40)])
    np.testing.assert_allclose(
        fresnel.conductor(jnp.asarray(c), eta, k), ref_fresnel_conductor(c, eta, k), rtol=1e-10
    )
    assert float(fresnel.conductor(1.0, eta, k)) == pytest.approx(
        float(fresnel.f0_from_ior(eta, k)), rel=1e-12
    )


def test_conductor_large_k_float32_stable():
    # the cancellation-free a^2 keeps float32 within a few ulps of 1 - F at k = 100
    c = np.linspace(1e-3, 1.0, 200)
    ref = ref_fresnel_conductor(c, 1.0, 100.0)
    got = np.asarray(fresnel.conductor(jnp.asarray(c, jnp.float32), np.float32(1.0),
                                       np.float32(100.0)))
    np.testing.assert_allclose(1 - got, 1 - ref, rtol=2e-3, atol=1e-7)


def test_schlick():
    assert float(fresnel.schlick(1.0, 0.04)) == pytest.approx(0.04)
    assert float(fresnel.schlick(0.0, 0.04)) == pytest.approx(1.0)
    assert float(fresnel.schlick(0.5, 0.04)) == pytest.approx(0.04 + 0.96 / 32)
    assert float(fresnel.schlick(0.0, 0.04, f90=0.5)) == pytest.approx(0.5)
    # Schlick vs exact at n = 1.5 (values quoted in the shared model notes, checked here)
    assert float(fresnel.schlick(0.5, 0.04)) == pytest.approx(0.0700, abs=1e-4)
    assert float(fresnel.dielectric(0.5, 1.5)) == pytest.approx(0.0892, abs=1e-4)


def test_ior_f0_roundtrip():
    eta = jnp.asarray([1.2, 1.5, 2.0, 4.0])
    np.testing.assert_allclose(fresnel.ior_from_f0(fresnel.f0_from_ior(eta)), eta, rtol=1e-12)


def test_channel_broadcast():
    eta = jnp.asarray([0.2, 0.5, 1.4])
    k = jnp.asarray([3.0, 2.4, 1.8])
    c = jnp.linspace(0.1, 1.0, 7)[:, None]
    assert fresnel.conductor(c, eta, k).shape == (7, 3)


def _fd(f, x, h=1e-6):
    return fd_central(f, x, h)


@pytest.mark.parametrize("c", [0.05, 0.3, 0.7, 0.99])
@pytest.mark.parametrize("eta,k", [(0.2, 3.9), (1.5, 0.0), (2.9, 3.0), (1.3, 0.5)])
def test_conductor_gradients_match_finite_differences(c, eta, k):
    g = jax.grad(fresnel.conductor, argnums=(0, 1, 2))(c, eta, k)
    fd = (
        _fd(lambda x: fresnel.conductor(x, eta, k), c),
        _fd(lambda x: fresnel.conductor(c, x, k), eta),
        _fd(lambda x: fresnel.conductor(c, eta, x), k),
    )
    for a, b in zip(g, fd, strict=True):
        assert float(a) == pytest.approx(float(b), rel=1e-6, abs=1e-8)


@pytest.mark.parametrize("c", [-0.9, -0.3, 0.05, 0.5, 0.99])
@pytest.mark.parametrize("eta", [1.5, 1 / 1.5, 2.4])
def test_dielectric_gradients_match_finite_differences(c, eta):
    if eta < 1 and abs(c) < math.sqrt(1 - eta * eta) + 0.05:
        pytest.skip("inside or at the TIR boundary: constant 1, gradient 0 (tested below)")
    g = jax.grad(fresnel.dielectric, argnums=(0, 1))(c, eta)
    fd = (_fd(lambda x: fresnel.dielectric(x, eta), c),
          _fd(lambda x: fresnel.dielectric(c, x), eta))
    for a, b in zip(g, fd, strict=True):
        assert float(a) == pytest.approx(float(b), rel=1e-6, abs=1e-8)


_EDGE_FNS = (
    lambda c, e, kk: fresnel.conductor(c, e, kk),
    lambda c, e, kk: fresnel.dielectric(c, e) + 0.0 * kk,
    lambda c, e, kk: fresnel.schlick(c, fresnel.f0_from_ior(e, kk)),
)
#: one jitted value-and-gradient program per function (eta, k as arguments, not constants):
#: compiled once per dtype instead of traced eagerly for each of the 15 (eta, k) pairs
_EDGE_VG = tuple(jax.jit(jax.vmap(jax.value_and_grad(fn, argnums=(0, 1, 2)),
                                  in_axes=(0, None, None))) for fn in _EDGE_FNS)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_values_and_gradients_finite_on_edges(dtype):
    cs = jnp.asarray([0.0, 1e-7, 1e-4, 0.5, 1.0, -1e-7, -0.5, -1.0], dtype)
    for eta in [1.0, 1.5, 1 / 1.5, 1e-3, 100.0]:
        for k in [0.0, 1.0, 100.0]:
            e = jnp.asarray(eta, dtype)
            kk = jnp.asarray(k, dtype)
            for vg in _EDGE_VG:
                v, g = vg(cs, e, kk)
                assert np.all(np.isfinite(v)), (eta, k)
                for gi in g:
                    assert np.all(np.isfinite(gi)), (eta, k)
                assert np.all((np.asarray(v) >= 0) & (np.asarray(v) <= 1 + 1e-6))


# ---------------------------------------------------------------- fast conductor value (issue 15)

_CONDUCTOR_PARAMS = [(0.2, 3.9), (1.5, 0.0), (1 / 1.5, 0.0), (1.0, 0.0), (1.0, 1.0), (1.0, 100.0),
                     (0.2, 100.0), (50.0, 0.1), (1.0, 1e-3), (1e-3, 5.0), (2.0, 1e-8)]
_CONDUCTOR_COS = np.concatenate([[0.0, 1e-12, 1e-7, 1e-4, 1e-2, 1.0 - 1e-12, 1.0],
                                 np.linspace(0.02, 0.99, 50)])


@pytest.mark.parametrize("eta,k", _CONDUCTOR_PARAMS)
def test_conductor_value_agrees_with_its_careful_form(eta, k):
    """The float32 value of ``conductor`` (2 sqrt + 3 divisions per channel), computed in
    float64, and the guarded form (its derivatives, its float64 value) agree to rounding (up to
    the guarded form's cancellation of ``a2b2 - a^2`` at eta = 1, small k: 1e-10 there, where
    the fast form is the more accurate)."""
    c = jnp.asarray(_CONDUCTOR_COS)
    fast = np.asarray(fresnel._conductor_fast(c, eta, k))
    careful = np.asarray(fresnel._conductor_careful(c, eta, k))
    assert np.array_equal(np.asarray(fresnel.conductor(c, eta, k)), careful)  # float64 value
    rtol = 1e-9 if (eta, k) == (1.0, 1e-3) else 1e-13
    np.testing.assert_allclose(fast, careful, rtol=rtol, atol=1e-300)
    if (eta, k) != (1.0, 0.0):  # F = 0 there; the complex reference returns rounding noise
        np.testing.assert_allclose(fast, ref_fresnel_conductor(_CONDUCTOR_COS, eta, k),
                                   rtol=1e-12, atol=1e-300)


#: the gradients of both forms, vmapped over cos (eta, k broadcast), each traced once for the
#: whole parametrisation (eager scalar calls traced 2 x 15 gradients per case: 21 s in all)
_GRAD_CONDUCTOR = jax.vmap(jax.grad(fresnel.conductor, argnums=(0, 1, 2)), (0, None, None))
_GRAD_CAREFUL = jax.vmap(jax.grad(fresnel._conductor_careful, argnums=(0, 1, 2)), (0, None, None))


@pytest.mark.parametrize("eta,k", _CONDUCTOR_PARAMS)
def test_conductor_gradient_is_the_careful_forms(eta, k):
    """The custom JVP: gradients in (cos, eta, k) are exactly those of the guarded form."""
    c = jnp.asarray(_CONDUCTOR_COS[::4])
    g = _GRAD_CONDUCTOR(c, eta, k)
    h = _GRAD_CAREFUL(c, eta, k)
    for x, y in zip(g, h, strict=True):
        assert np.array_equal(np.asarray(x), np.asarray(y))


_GRAD_CONDUCTOR_JIT = jax.jit(_GRAD_CONDUCTOR)  # compiled once for all 11 (eta, k)


@pytest.mark.parametrize("eta,k", _CONDUCTOR_PARAMS)
def test_conductor_float32_value_and_gradient_finite(eta, k):
    c = jnp.asarray(_CONDUCTOR_COS, jnp.float32)
    e, kk = jnp.float32(eta), jnp.float32(k)
    v = np.asarray(fresnel.conductor(c, e, kk))
    assert np.array_equal(v, np.asarray(fresnel._conductor_fast(c, e, kk)))  # float32 value
    assert v.dtype == np.float32 and np.all(np.isfinite(v))
    assert np.all((v >= 0) & (v <= 1 + 2e-7))  # 1 to rounding at grazing
    careful = np.asarray(fresnel._conductor_careful(c, e, kk))
    np.testing.assert_allclose(v, careful, rtol=2e-6, atol=2e-7)
    # gradients on the hard-case cosines (>= 1e-7; the careful form's float32 gradient at
    # eta = 1, k = 0, cos = 1e-12 is NaN, as it was before the fast value was added)
    cg = c[(c == 0) | (c >= 1e-7)]
    g = _GRAD_CONDUCTOR_JIT(cg, e, kk)
    assert all(np.all(np.isfinite(np.asarray(x))) for x in g)
