"""Tests of brdf_fit.core.quadrature: exactness, kinked integrands, convergence, dtypes."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpy.polynomial import polynomial as P
from scipy import special

from brdf_fit.core import quadrature as q

TWO_PI = 2.0 * math.pi


def _mu(d):
    return d[:, 2]


def _phi(d):
    return jnp.arctan2(d[:, 1], d[:, 0])


def test_rule_shapes_unit_directions_and_default_dtype():
    rule = q.gauss_legendre_hemisphere(5, 7)
    assert rule.n == 35
    assert rule.directions.shape == (35, 3) and rule.weights.shape == (35,)
    assert rule.directions.dtype == rule.weights.dtype == jnp.float64  # x64 is on in the suite
    np.testing.assert_allclose(np.linalg.norm(np.asarray(rule.directions), axis=1), 1.0, atol=1e-15)
    assert np.all(np.asarray(rule.directions)[:, 2] > 0)
    r32 = q.gauss_legendre_hemisphere(5, 7, dtype=jnp.float32)
    assert r32.directions.dtype == r32.weights.dtype == jnp.float32


def test_hemisphere_constant_and_cosine():
    rule = q.gauss_legendre_hemisphere(3, 4)
    np.testing.assert_allclose(
        q.integrate(lambda d: jnp.ones(d.shape[0]), rule), TWO_PI, rtol=1e-14
    )
    np.testing.assert_allclose(q.integrate(_mu, rule), math.pi, rtol=1e-14)


@pytest.mark.parametrize("n", [1, 4, 10])
def test_cosine_power_lobe(n):
    rule = q.gauss_legendre_hemisphere(n // 2 + 1, 3)  # degree 2 n_mu - 1 >= n
    np.testing.assert_allclose(
        q.integrate(lambda d: _mu(d) ** n, rule), TWO_PI / (n + 1), rtol=1e-13
    )


def test_vector_valued_integrand():
    rule = q.gauss_legendre_hemisphere(4, 6)
    out = q.integrate(lambda d: jnp.stack([jnp.ones(d.shape[0]), _mu(d), _mu(d) ** 2], -1), rule)
    assert out.shape == (3,)
    np.testing.assert_allclose(out, [TWO_PI, math.pi, TWO_PI / 3], rtol=1e-14)


def test_mixed_precision_integrand_under_strict_promotion():
    rule = q.gauss_legendre_hemisphere(4, 6)
    out = q.integrate(lambda d: _mu(d).astype(jnp.float32), rule)
    np.testing.assert_allclose(out, math.pi, rtol=1e-6)


@pytest.mark.parametrize("n_mu", [1, 2, 3, 6])
def test_product_rule_exactness_and_its_limits(n_mu):
    n_phi = 4
    rng = np.random.default_rng(n_mu)
    c = rng.normal(size=2 * n_mu)  # degree 2 n_mu - 1
    exact_mu = P.polyval(1.0, P.polyint(c)) - P.polyval(0.0, P.polyint(c))
    cj = jnp.asarray(c)

    def g(d):  # P(mu) (2 + cos 3 phi): exact = 4 pi * int_0^1 P
        return jnp.polyval(cj[::-1], _mu(d)) * (2.0 + jnp.cos(3.0 * _phi(d)))

    rule = q.gauss_legendre_hemisphere(n_mu, n_phi)
    np.testing.assert_allclose(
        q.integrate(g, rule), 2.0 * TWO_PI * exact_mu, rtol=1e-12, atol=1e-13
    )

    # one degree more in mu, or a trigonometric degree equal to n_phi, is no longer exact
    assert (
        abs(float(q.integrate(lambda d: _mu(d) ** (2 * n_mu), rule)) - TWO_PI / (2 * n_mu + 1))
        > 1e-10
    )
    assert abs(float(q.integrate(lambda d: jnp.cos(n_phi * _phi(d)), rule))) > 1.0


def test_mu_range_and_sphere():
    sub = q.gauss_legendre_hemisphere(3, 4, mu_range=(0.2, 0.7))
    np.testing.assert_allclose(jnp.sum(sub.weights), TWO_PI * 0.5, rtol=1e-14)
    mu = np.asarray(sub.directions[:, 2])
    assert mu.min() > 0.2 and mu.max() < 0.7
    sph = q.gauss_legendre_sphere(4, 4)
    np.testing.assert_allclose(jnp.sum(sph.weights), 2.0 * TWO_PI, rtol=1e-14)
    np.testing.assert_allclose(
        q.integrate(lambda d: _mu(d) ** 2, sph), 4.0 * math.pi / 3, rtol=1e-14
    )
    np.testing.assert_allclose(q.integrate(_mu, sph), 0.0, atol=1e-14)
    with pytest.raises(ValueError):
        q.gauss_legendre_hemisphere(3, 4, mu_range=(0.5, 0.2))


def test_composite_rule_integrates_a_kink_exactly():
    def g(d):
        return jnp.abs(_mu(d) - 0.3)

    exact = TWO_PI * (0.3**2 / 2 + 0.7**2 / 2)
    comp = q.composite_gauss_legendre_hemisphere((0.3,), 2, 3)
    np.testing.assert_allclose(q.integrate(g, comp), exact, rtol=1e-14)
    # same node count without the break: the kink costs accuracy
    plain = q.gauss_legendre_hemisphere(comp.n // 3, 3)
    assert plain.n == comp.n
    assert abs(float(q.integrate(g, plain)) - exact) > 1e-3
    # the ends of mu_range are optional, and node counts may differ per panel
    full = q.composite_gauss_legendre_hemisphere((0.0, 0.3, 1.0), 2, 3)
    np.testing.assert_array_equal(np.asarray(full.directions), np.asarray(comp.directions))
    mixed = q.composite_gauss_legendre_hemisphere((0.3,), (2, 5), 3)
    assert mixed.n == 7 * 3
    np.testing.assert_allclose(q.integrate(g, mixed), exact, rtol=1e-14)


def test_composite_rule_on_the_sphere_with_a_horizon_jump():
    def g(d):  # cosine lobe cut at the horizon: jump in the derivative, zero below
        return jnp.maximum(_mu(d), 0.0)

    comp = q.composite_gauss_legendre_hemisphere((0.0,), 1, 2, mu_range=(-1.0, 1.0))
    np.testing.assert_allclose(q.integrate(g, comp), math.pi, rtol=1e-14)


def test_composite_rule_argument_errors():
    with pytest.raises(ValueError):
        q.composite_gauss_legendre_hemisphere((1.3,), 2, 3)
    with pytest.raises(ValueError):
        q.composite_gauss_legendre_hemisphere((0.3,), (2, 3, 4), 3)


def test_geometric_convergence_for_a_smooth_integrand():
    def g(d):  # exp(2 mu) exp(cos phi): analytic, not polynomial in either variable
        return jnp.exp(2.0 * _mu(d)) * jnp.exp(jnp.cos(_phi(d)))

    exact = 0.5 * (math.e**2 - 1.0) * TWO_PI * float(special.i0(1.0))
    errs = [
        abs(float(q.integrate(g, q.gauss_legendre_hemisphere(n, 2 * n))) - exact)
        for n in (1, 2, 3, 4, 6)
    ]
    assert all(b < a for a, b in zip(errs, errs[1:], strict=False)), errs
    assert errs[-1] < 1e-9 * exact


def test_rule_is_a_pytree_usable_under_jit():
    rule = q.gauss_legendre_hemisphere(4, 4)
    f = jax.jit(lambda r: q.integrate(_mu, r))
    np.testing.assert_allclose(f(rule), math.pi, rtol=1e-14)
