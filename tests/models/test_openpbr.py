"""OpenPBR Surface (brdf_fit.models.openpbr): identities of the MaterialX arithmetic it is built
from, checked independently of MaterialX (its parity with MaterialX's GLSL is
tests/convert/test_materialx.py)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from brdf_fit.models import _materialx as mxf
from brdf_fit.models.openpbr import OpenPBRSurface

jax.config.update("jax_enable_x64", True)


def _hemisphere_rule(n=192):
    """Gauss-Legendre in cos(theta_i) x midpoints in phi: nodes ``(mu, phi)`` and weights of
    ``Int g dwi``."""
    x, w = np.polynomial.legendre.leggauss(n)
    mu, wmu = 0.5 * (x + 1.0), 0.5 * w
    phi = (np.arange(2 * n) + 0.5) * np.pi / n
    m, p = np.meshgrid(mu, phi, indexing="ij")
    return m, p, np.outer(wmu, np.full(2 * n, np.pi / n))


def test_eon_conserves_a_white_base_without_the_shaders_clamp():
    """EON (Portsmouth et al. 2025) is built so that a white base reflects exactly 1 at every
    view: the lobe transcribed here does, by quadrature, at roughness 1 (the hardest case) when
    ``wi.wo`` is the plain dot product; with MaterialX's clamp of ``wi.wo`` at 1e-8 (what the
    shader does, and the model with it) it reflects more at grazing views, as the module
    docstring states. The lobe has a kink where ``wi.wo = (n.wi)(n.wo)`` (``s = 0``), which the
    product rule resolves to 3e-6 at 384 nodes (7e-8 at 768; measured)."""
    m, p, w = _hemisphere_rule(384)
    for mu_o, clamped_albedo in ((1.0, 1.0), (0.5, 1.0564), (0.1, 1.1397)):
        s_o = np.sqrt(1.0 - mu_o * mu_o)
        lv = np.sqrt(1.0 - m * m) * s_o * np.cos(p) + m * mu_o
        for lv_used, want, tol in ((lv, 1.0, 1e-5), (np.clip(lv, mxf.M_FLOAT_EPS, 1.0),
                                                     clamped_albedo, 1e-4)):
            f = np.asarray(mxf.oren_nayar_eon(np.full_like(m, mu_o), m, lv_used, 1.0,
                                              np.ones_like(m)))
            assert abs(np.sum(f * m * w) - want) < tol, (mu_o, np.sum(f * m * w))


def test_the_specular_ior_and_its_mirror_under_a_full_coat_are_one_material():
    """With coat_weight 1 the graph uses specular_ior/coat_ior or its inverse, whichever
    exceeds 1: specular_ior s and coat_ior^2/s give the same values (the identifiability note)."""
    rng = np.random.default_rng(3)
    wi = rng.normal(size=(64, 3))
    wo = rng.normal(size=(64, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    common = dict(base_color=jnp.array([0.7, 0.3, 0.1]), base_metalness=jnp.asarray(0.3),
                  specular_roughness=jnp.asarray(0.35), coat_weight=jnp.asarray(1.0),
                  coat_roughness=jnp.asarray(0.1), coat_ior=jnp.asarray(1.5))
    a = OpenPBRSurface(specular_ior=jnp.asarray(1.45), **common).eval(wi, wo)
    b = OpenPBRSurface(specular_ior=jnp.asarray(1.5 ** 2 / 1.45), **common).eval(wi, wo)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12)
    # the negative control: another specular_ior is another material
    c = OpenPBRSurface(specular_ior=jnp.asarray(1.6), **common).eval(wi, wo)
    assert np.max(np.abs(np.asarray(c) / np.asarray(a) - 1.0)) > 1e-3


def test_the_fuzz_at_a_normal_view_is_the_limit_of_nearby_views():
    """At wo = n the fuzz's LTC frame has no tangent (MaterialX's is float32 noise there); the
    model's value is the limit of views approaching the normal."""
    model = OpenPBRSurface(base_color=jnp.array([0.5, 0.05, 0.2]), fuzz_weight=jnp.asarray(1.0),
                           fuzz_roughness=jnp.asarray(0.3), specular_roughness=jnp.asarray(0.7))
    wi = np.array([[0.9848, 0.0, 0.1736], [0.3, 0.4, np.sqrt(0.75)]])
    at = np.asarray(model.eval(wi, np.array([[0.0, 0.0, 1.0]] * 2)))
    for t in (1e-4, 1e-5):
        for phi in (0.0, 2.0):
            wo = np.array([[t * np.cos(phi), t * np.sin(phi), np.sqrt(1 - t * t)]] * 2)
            near = np.asarray(model.eval(wi, wo))
            assert np.max(np.abs(near / at - 1.0)) < 100 * t
