"""Kelemen & Szirmay-Kalos 2001 coupled BRDF (brdf_fit.models.kelemen).

Independent references: the specular albedo a_s(mu) by SciPy adaptive integration over the
incident direction in spherical angles (not the half-vector rule the model uses); the specular
term in spherical angles with NumPy; energy conservation of the coupling by quadrature.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import assert_model_gradient_matches_fd, dir_from_cos, fd_central
from _helpers import eval_jit as _eval
from _helpers import vec as _dir
from scipy import integrate

from brdf_fit import ParameterError, registry
from brdf_fit.models.kelemen import Kelemen, albedo_table, specular_albedo
from brdf_fit.verify import albedo

# jitted once for the file (eager, every call dispatched the table's and the interpolant's ops)
_specular_albedo = jax.jit(specular_albedo)
ENTRY = registry.get("kelemen")


def spec_reference(wi, wo, f0, m):
    """F(l.h) D(h)/(4 (l.h)^2) with the angle of h from arccos (NumPy)."""
    H = wi + wo
    h = H / np.linalg.norm(H, axis=-1, keepdims=True)
    th = np.arccos(np.clip(h[..., 2], -1, 1))
    D = np.exp(-np.tan(th) ** 2 / m**2) / (np.pi * m**2 * np.cos(th) ** 4)
    c = np.sum(wi * h, -1)
    F = f0 + (1 - f0) * (1 - c) ** 5
    return F * D / (4 * c * c)


def a_s_scipy(mu, f0, m):
    """Int f_s(w', v) cos' dw' over the hemisphere, SciPy dblquad in (theta', phi')."""
    wo = dir_from_cos(mu)

    def g(phi, th):
        wi = _dir(np.array(th), np.array(phi))
        return float(spec_reference(wi[None], wo[None], f0, m)[0]) * math.cos(th) * math.sin(th)

    # symmetric in phi: 2 x [0, pi]; the lobe sits near phi = pi (mirror of wo)
    val = integrate.dblquad(g, 0.0, math.pi / 2, 0.0, math.pi, epsabs=1e-11, epsrel=1e-9)[0]
    return 2 * val


@pytest.mark.parametrize("mu", [0.95, 0.5, 0.1])
def test_albedo_table_matches_scipy(mu):
    """The in-JAX table (interpolated) against SciPy: measured agreement ~1e-6 at alpha = 0.3."""
    f0, m = 0.3, 0.3
    got = float(_specular_albedo(m, f0, jnp.asarray(mu)))
    want = a_s_scipy(mu, f0, m)
    assert got == pytest.approx(want, abs=5e-6)
    assert 0 < want < 1


def test_specular_term_matches_angle_reference():
    rng = np.random.default_rng(0)
    wi = _dir(np.arccos(rng.uniform(0.02, 1, 300)), rng.uniform(0, 2 * np.pi, 300))
    wo = _dir(np.arccos(rng.uniform(0.02, 1, 300)), rng.uniform(0, 2 * np.pi, 300))
    m = Kelemen(rho_m=0.0, f0=0.2, alpha=0.25)
    got = np.asarray(_eval(m, jnp.asarray(wi), jnp.asarray(wo)))
    np.testing.assert_allclose(got, spec_reference(wi, wo, 0.2, 0.25), rtol=1e-10, atol=1e-300)


def test_matte_term_is_the_coupling():
    """f - f_s = rho_m (1 - a_s(l))(1 - a_s(v))/(pi (1 - a_bar)), with a_bar = 2 Int a_s mu dmu
    (here by 64-point Gauss-Legendre in mu of the model's a_s)."""
    rho, f0, al = 0.7, 0.1, 0.4
    m = Kelemen(rho_m=rho, f0=f0, alpha=al)
    s = Kelemen(rho_m=0.0, f0=f0, alpha=al)
    rng = np.random.default_rng(1)
    wi = jnp.asarray(_dir(np.arccos(rng.uniform(0.05, 1, 50)), rng.uniform(0, 6.3, 50)))
    wo = jnp.asarray(_dir(np.arccos(rng.uniform(0.05, 1, 50)), rng.uniform(0, 6.3, 50)))
    matte = np.asarray(_eval(m, wi, wo)) - np.asarray(_eval(s, wi, wo))
    x, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (x + 1)
    a_bar = float(np.sum(0.5 * w * 2 * mu * np.asarray(_specular_albedo(al, f0, jnp.asarray(mu)))))
    al_ = np.asarray(_specular_albedo(al, f0, wi[:, 2]))
    av_ = np.asarray(_specular_albedo(al, f0, wo[:, 2]))
    np.testing.assert_allclose(matte, rho * (1 - al_) * (1 - av_) / (np.pi * (1 - a_bar)),
                               rtol=1e-6)


@pytest.mark.parametrize("alpha", [0.1, 0.3, 0.8])
def test_energy_conserving_and_white_matte_reaches_the_bound(alpha):
    """Total albedo a_s(v) + rho_m (1 - a_s(v)): <= 1, and = 1 for a white matte (to the table's
    interpolation error, measured < 1e-5)."""
    white = Kelemen(rho_m=1.0, f0=0.04, alpha=alpha)
    grey = Kelemen(rho_m=0.5, f0=0.04, alpha=alpha)
    for c in (1.0, 0.5, 0.1, 0.01):
        wo = jnp.asarray(dir_from_cos(c))
        e_white = float(albedo.directional_albedo(white, wo))
        e_grey = float(albedo.directional_albedo(grey, wo))
        assert e_white == pytest.approx(1.0, abs=1e-5)
        a_s = float(_specular_albedo(alpha, 0.04, jnp.asarray(c)))
        assert e_grey == pytest.approx(a_s + 0.5 * (1 - a_s), abs=1e-5)


def test_table_gradient_matches_finite_differences():
    """d table/d alpha. The gradient differentiates the integrand at fixed nodes; the finite
    difference rebuilds the lobe-adapted rule at alpha +- h, so it also sees the change of the
    rule's (~1e-11 here) error, divided by h: hence the absolute tolerance."""
    g = jax.jacfwd(lambda a: albedo_table(a)[0])(0.3)
    h = 1e-6
    fd = fd_central(lambda a: np.asarray(albedo_table(a)[0]), 0.3, h)
    np.testing.assert_allclose(g, fd, rtol=1e-5, atol=5e-5)


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(4)
    wi = jnp.asarray(_dir(np.arccos(rng.uniform(0.2, 1, 8)), rng.uniform(0, 6, 8)))
    wo = jnp.asarray(_dir(np.arccos(rng.uniform(0.2, 1, 8)), rng.uniform(0, 6, 8)))
    params = {"rho_m": np.array([0.6, 0.4, 0.3]), "f0": np.array([0.05, 0.1, 0.2]),
              "alpha": 0.3}
    assert_model_gradient_matches_fd(ENTRY.build, wi, wo, params, rel=1e-5, abs=1e-9)


@pytest.mark.parametrize("bad,name", [({"rho_m": [0.5, 1.2, 0.1]}, "'rho_m'"),
                                      ({"f0": -0.1}, "'f0'"), ({"alpha": 0.0}, "'alpha'")])
def test_bad_parameters_are_named(bad, name):
    with pytest.raises(ParameterError, match=name):
        ENTRY.build(**bad)


def test_entry_metadata():
    assert ENTRY.year == 2001 and ENTRY.catalogue == "Coupled" and ENTRY.sampler



def test_float32_gradient_is_finite_at_the_grazing_mirror_pair():
    """Issue 16: at wi = (-1, 0, 1e-8), wo = (1, 0, 1e-8), alpha = 1e-4 (|H| = |wi + wo| =
    2e-8) the float32 gradient w.r.t. the directions was NaN: sqrt(|H|^2) passed the cotangent
    of |H|^2 through 1/(2 |H|), 6e38 with RGB rho_m, past float32's range. d/d(wi_z) is
    ``-3 D 2 H_z/|H|^4`` (three channels of F = 1 at f0 = 0; D = 1/(pi alpha^2) at h = n, where
    its own derivative vanishes): -2.387e31, finite in float32 (float64 agrees to 1e-7)."""
    dt = jnp.float32
    wi = jnp.asarray([-1.0, 0.0, 1e-8], dt)
    wo = jnp.asarray([1.0, 0.0, 1e-8], dt)
    p = {"rho_m": jnp.asarray([0.6, 0.4, 0.3], dt), "f0": jnp.asarray(0.0, dt),
         "alpha": jnp.asarray(1e-4, dt)}
    g = jax.jit(jax.grad(lambda p, a, b: jnp.sum(Kelemen(**p).eval(a, b)),
                         argnums=(0, 1, 2)))(p, wi, wo)
    for x in jax.tree.leaves(g):
        assert np.all(np.isfinite(np.asarray(x))), g
    want = -3 * 2 * 2e-8 / (math.pi * 1e-8 * 2e-8**4)
    np.testing.assert_allclose([float(g[1][2]), float(g[2][2])], [want, want], rtol=1e-5)
