"""brdf_fit.core.special.betainc: values against SciPy, a/b/x derivatives against finite
differences."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special as sp
from _helpers import fd_central4

from brdf_fit.core.special import betainc, betaln, lgamma_diff

A = np.array([1e-8, 0.3, 0.5, 1.0, 2.5, 10.0, 100.0, 1e3, 5e4, 5e5, 1e6])
B = np.array([1e-3, 0.5, 1.0, 3.0, 100.0, 5e5])
X = np.array([1e-12, 1e-3, 0.2, 0.5, 0.9, 0.999, 1 - 1e-6, 1 - 1e-8])
GRID = [v.ravel() for v in np.meshgrid(A, B, X, indexing="ij")]

_vg = jax.jit(jax.vmap(jax.value_and_grad(betainc, argnums=(0, 1, 2))))


def _fd4(fn, args, idx, h):
    """Fourth-order central difference of ``fn`` in argument ``idx`` with step ``h``."""
    return fd_central4(lambda t: fn(*args[:idx], t, *args[idx + 1:]), args[idx], h)


def test_values_match_scipy():
    a, b, x = GRID
    v, _ = _vg(a, b, x)
    ref = sp.betainc(a, b, x)
    # absolute floor 1e-14: results 1 - I near 1 are formed by one subtraction from 1. Relative
    # 1e-9: the prefactor's logarithm is a sum of terms of size ~a |log x| (7e5 at a = b = 5e5,
    # x = 1/2), which float64 resolves to ~1e-10 absolute.
    err = np.abs(np.asarray(v) - ref)
    assert np.all(err <= 1e-9 * np.abs(ref) + 1e-14), np.max(err / (1e-9 * np.abs(ref) + 1e-14))


def test_values_half_b_tight():
    """The normaliser's case b = 1/2: relative accuracy 1e-12 where I > 1e-250."""
    a = np.repeat(np.array([1e-6, 0.5, 3.0, 50.0, 500.0, 5e3, 5e4, 5e5]), 9)
    x = np.tile(np.array([1e-6, 0.01, 0.3, 0.7, 0.99, 1 - 1e-4, 1 - 1e-6, 1 - 3e-6, 1 - 1e-8]), 8)
    b = np.full_like(a, 0.5)
    v = np.asarray(jax.jit(jax.vmap(betainc))(a, b, x))
    ref = sp.betainc(a, b, x)
    m = ref > 1e-250
    # relative 1e-10: the prefactor's logarithm sums terms of size a |log x| (up to ~1e5 here)
    assert np.max(np.abs(v[m] / ref[m] - 1)) < 1e-10


@pytest.mark.parametrize("idx", [0, 1, 2])
def test_derivatives_match_finite_differences(idx):
    a, b, x = GRID
    _, grads = _vg(a, b, x)
    g = np.asarray(grads[idx])
    args = [a, b, x]
    if idx == 2:
        # steps well inside (0, 1) and small against the width of the density near x
        h = 1e-4 * np.minimum(x, 1 - x) / np.sqrt(1.0 + np.minimum(a, b))
    else:
        p = args[idx]
        h = 1e-4 * np.minimum(p, np.sqrt(p))  # relative for small p, sqrt(p)-scaled for large
    fd = _fd4(sp.betainc, args, idx, h)
    if idx == 2:
        # near x = 1 difference in y = 1 - x (x itself is only resolved to 1e-16 there):
        # dI_x(a, b)/dx = dI_y(b, a)/dy
        upper = x > 0.5
        fd_y = _fd4(lambda b_, a_, y_: sp.betainc(b_, a_, y_), [b, a, 1.0 - x], 2, h)
        fd = np.where(upper, fd_y, fd)
    # finite-difference rounding noise: ~1e-16 in I, divided by the step
    noise = 1e-15 / h
    err = np.abs(g - fd)
    assert np.all(err <= 1e-6 * np.abs(fd) + noise), np.max(err / (np.abs(fd) + noise))


def test_edges_are_finite():
    a = jnp.asarray([1e-8, 0.5, 1.0, 2.0, 1e-8, 0.5, 1.0, 2.0, 1e-30, 1e-30])
    b = jnp.asarray([0.5, 0.5, 2.0, 0.5, 0.5, 0.5, 1.0, 3.0, 0.5, 0.5])
    x = jnp.asarray([0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.3, 0.0])
    v, grads = _vg(a, b, x)
    assert np.all(np.isfinite(np.asarray(v)))
    for g in grads:
        assert np.all(np.isfinite(np.asarray(g)))
    np.testing.assert_array_equal(np.asarray(v)[:4], 0.0)
    np.testing.assert_array_equal(np.asarray(v)[4:8], 1.0)
    # a = 1 at x = 0: dI/dx = 1/B(1, b) = b
    assert float(grads[2][2]) == pytest.approx(2.0, rel=1e-14)
    # tiny a: I_x(a, b) -> 1 for x > 0 (to ~69 eps: log a and log B(a, b) ~ +-69 cancel)
    assert float(v[8]) == pytest.approx(1.0, abs=1e-13)


def test_float32_large_a_finite():
    a = jnp.asarray([5e5, 5e5, 5e5, 1e-8, 1e6], jnp.float32)
    b = jnp.full((5,), 0.5, jnp.float32)
    x = jnp.asarray([0.5, 0.99, 0.999999, 0.3, 0.9999999], jnp.float32)
    v, grads = _vg(a, b, x)
    assert v.dtype == jnp.float32
    assert np.all(np.isfinite(np.asarray(v)))
    for g in grads:
        assert g.dtype == jnp.float32
        assert np.all(np.isfinite(np.asarray(g)))


def test_float32_near_one_uses_the_exact_complement():
    """Issue 16 (float32 over every interval): with ``x = 1 - y`` rounded to float32 near 1, the
    prefactor's ``a log x`` at a = 5e5 was formed from the rounded ``x`` (6% off in ``1 - x`` at
    y = 1e-6), 2.1e-3 relative error in I. It is now ``a log1p(-y)``: float32 agrees with
    float64 (SciPy) given the same, exactly representable ``y``."""
    from brdf_fit.core.special import betainc_complement

    y64 = np.array([1e-6, 2e-6, 1e-5, 1e-7])
    y = y64.astype(np.float32).astype(np.float64)  # the float32 values, exactly
    a = np.array([5e5, 5e5, 5e4, 5e6])
    ref = sp.betainc(a, 0.5, 1.0 - y)
    f32 = betainc_complement(jnp.asarray(a, jnp.float32), jnp.float32(0.5),
                             jnp.asarray(1.0 - y, jnp.float32), jnp.asarray(y, jnp.float32))
    np.testing.assert_allclose(np.asarray(f32, np.float64), ref, rtol=1e-5)


def test_log_gamma_helpers():
    z = np.array([0.5, 3.0, 9.99, 10.0, 50.0, 5e5, 1e6])
    w = np.array([0.5, 0.5, 2.0, 0.5, 50.0, 0.5, 1e6])
    # SciPy's difference of two log-gammas loses ~eps * lgamma(z + w) absolutely
    ref = sp.gammaln(z + w) - sp.gammaln(z)
    tol = 1e-12 * np.abs(ref) + 4e-16 * np.abs(sp.gammaln(z + w))
    assert np.all(np.abs(np.asarray(lgamma_diff(z, w)) - ref) <= tol)
    # SciPy's betaln itself is off by 2e-10 at (5e5, 1/2); mpmath at 40 digits is the reference
    mpmath = pytest.importorskip("mpmath")
    mpmath.mp.dps = 40
    ref_b = np.array([float(mpmath.log(mpmath.beta(zi, wi))) for zi, wi in zip(z, w, strict=True)])
    np.testing.assert_allclose(np.asarray(betaln(z, w)), ref_b, rtol=1e-14, atol=1e-14)
