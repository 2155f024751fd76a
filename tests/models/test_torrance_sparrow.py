"""Torrance-Sparrow 1967 with the Gaussian facet-angle distribution
(brdf_fit.models.torrance_sparrow).

Independent references: the normaliser b by SciPy adaptive quadrature in the angle; the BRDF in
spherical angles with NumPy (angle from arccos, Fresnel from Snell's law with angles, V-groove
from the angles of h), not the dot-product JAX code.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import assert_model_gradient_matches_fd, fd_central
from _helpers import eval_jit as _eval
from _helpers import vec as _dir
from scipy import integrate

from brdf_fit import ParameterError, registry
from brdf_fit.models import torrance_sparrow as ts
from brdf_fit.models.torrance_sparrow import GaussianAngle

ENTRY = registry.get("torrance-sparrow-gaussian")
SIGMAS = (1e-3, 0.05, 0.3, 1.0)


def _b_scipy(sigma):
    """1/b = 2 pi Int_0^{pi/2} exp(-a^2/sigma^2) cos a sin a da (adaptive, in the angle a)."""
    hi = min(math.pi / 2, 12 * sigma)
    val = integrate.quad(lambda a: math.exp(-a * a / sigma**2) * math.cos(a) * math.sin(a),
                         0.0, hi, epsabs=0.0, epsrel=1e-13, limit=200)[0]
    return 1.0 / (2 * math.pi * val)


@pytest.mark.parametrize("sigma", SIGMAS)
def test_normaliser_matches_scipy(sigma):
    b = float(GaussianAngle(sigma).b())
    assert b == pytest.approx(_b_scipy(sigma), rel=1e-12)


def test_narrow_lobe_limit():
    """b -> c^2/pi = 1/(pi sigma^2) as sigma -> 0 (models.md 4.4), with relative correction
    O(sigma^2)."""
    for s in (1e-4, 1e-3):
        assert float(GaussianAngle(s).b()) * math.pi * s * s == pytest.approx(1.0, abs=2 * s * s)


def test_fixed_rule_error_of_the_normaliser():
    """The docstring's measured quadrature error: 64 nodes vs 256 nodes, < 1e-14 relative."""
    for s in np.geomspace(1e-4, 1.0, 9):
        s = jnp.asarray(s)
        k64 = float(ts.normaliser_K(s))
        k256 = float(ts._integral(ts._t_max(s), s, ts._gl(256)))
        assert abs(k64 - k256) <= 1e-14 * k256


def fresnel_angles(theta, eta):
    """Unpolarised Fresnel reflectance from the angle of incidence and Snell's law."""
    st = np.sin(theta)[:, None] / eta
    tt = np.arcsin(np.clip(st, -1, 1))
    ci, ct = np.cos(theta)[:, None], np.cos(tt)
    rs = (ci - eta * ct) / (ci + eta * ct)
    rp = (eta * ci - ct) / (eta * ci + ct)
    return np.where(st >= 1, 1.0, 0.5 * (rs**2 + rp**2))


def reference(thi, pi_, tho, po, kd, ks, alpha, eta):
    sigma = alpha
    wi, wo = _dir(thi, pi_), _dir(tho, po)
    H = wi + wo
    h = H / np.linalg.norm(H, axis=-1, keepdims=True)
    alpha = np.arccos(np.clip(h[..., 2], -1, 1))
    D = _b_scipy(sigma) * np.exp(-(alpha**2) / sigma**2)
    c = np.sum(wo * h, -1)
    G = np.minimum(1, np.minimum(2 * np.cos(alpha) * np.cos(tho) / c,
                                 2 * np.cos(alpha) * np.cos(thi) / c))
    F = fresnel_angles(np.arccos(c), np.asarray(eta)[None])
    spec = F * (D * G / (4 * np.cos(thi) * np.cos(tho)))[:, None]
    return np.asarray(kd)[None] / np.pi + ks * spec


PARAMS = {"kd": np.array([0.3, 0.2, 0.1]), "ks": 0.7, "alpha": 0.2,
          "eta": np.array([1.4, 1.6, 1.2])}


def test_matches_angle_reference():
    rng = np.random.default_rng(0)
    thi, tho = np.arccos(rng.uniform(0.02, 1, 300)), np.arccos(rng.uniform(0.02, 1, 300))
    pi_, po = rng.uniform(0, 2 * np.pi, 300), rng.uniform(0, 2 * np.pi, 300)
    got = np.asarray(_eval(ENTRY.build(**PARAMS), jnp.asarray(_dir(thi, pi_)),
                           jnp.asarray(_dir(tho, po))))
    want = reference(thi, pi_, tho, po, **PARAMS)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=0)


@pytest.mark.parametrize("sigma", (1e-3, 0.3, 1.0))
def test_sampler_inverts_the_cdf(sigma):
    """theta = sigma t(u) satisfies C(t) = u, with C from an independent SciPy integral."""
    u = np.array([1e-6, 0.1, 0.37, 0.5, 0.9, 0.999])
    mx, my, mz = GaussianAngle(sigma).sample_normal(jnp.asarray(u), jnp.asarray(0.3 + 0 * u))
    theta = np.arctan2(np.hypot(mx, my), mz)
    b = _b_scipy(sigma)
    C = [2 * math.pi * b * integrate.quad(
        lambda a: math.exp(-a * a / sigma**2) * math.cos(a) * math.sin(a), 0.0, t,
        epsabs=1e-15, epsrel=1e-13)[0] for t in theta]
    np.testing.assert_allclose(C, u, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.hypot(mx, my) ** 2 + np.asarray(mz) ** 2, 1.0, rtol=1e-14)


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(4)
    wi = jnp.asarray(_dir(np.arccos(rng.uniform(0.2, 1, 12)), rng.uniform(0, 6, 12)))
    wo = jnp.asarray(_dir(np.arccos(rng.uniform(0.2, 1, 12)), rng.uniform(0, 6, 12)))
    assert_model_gradient_matches_fd(ENTRY.build, wi, wo, PARAMS, rel=1e-6, abs=1e-9)


def test_normaliser_gradient_matches_finite_differences():
    vg = jax.jit(jax.value_and_grad(lambda s: GaussianAngle(s).b()))  # one compile, not eager
    for s in (1e-3, 0.3, 0.9):
        h = 1e-6 * s
        fd = fd_central(lambda x: float(vg(jnp.asarray(x))[0]), s, h)
        assert float(vg(jnp.asarray(s))[1]) == pytest.approx(fd, rel=1e-6)


@pytest.mark.parametrize("bad,name", [({"alpha": -0.1}, "'alpha'"), ({"ks": 1.5}, "'ks'"),
                                      ({"eta": -1.0}, "'eta'")])
def test_bad_parameters_are_named(bad, name):
    with pytest.raises(ParameterError, match=name):
        ENTRY.build(**bad)
    with pytest.raises(ParameterError, match="'alpha'"):
        GaussianAngle(0.0)


def test_entry_metadata():
    assert ENTRY.year == 1967 and ENTRY.catalogue == "Torrance-Sparrow" and ENTRY.sampler
