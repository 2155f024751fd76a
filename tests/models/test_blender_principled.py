"""Blender's Principled BSDF as Cycles 4.5 renders it (brdf_fit.models.blender_principled):
independent references without Blender (a Lambert limit, the single-scattering metal against a
GGX written here, the white furnace of the compensated metal, Cycles' own printed table values).
The parity with Cycles itself is in tests/convert/test_blender.py (it needs Blender's Python)."""

from __future__ import annotations

import math

import jax
import numpy as np
import pytest
from _helpers import random_dirs

from brdf_fit.models import _cycles as cy
from brdf_fit.models import blender_principled as bp
from brdf_fit.models.blender_principled import BlenderPrincipled
from brdf_fit.verify.albedo import directional_albedo

jax.config.update("jax_enable_x64", True)


def random_pairs(n, seed):
    rng = np.random.default_rng(seed)
    return random_dirs(rng, n, lo=1e-2), random_dirs(rng, n, lo=1e-2)


def _model(**p):
    return BlenderPrincipled(**{k: np.asarray(v, np.float64) for k, v in p.items()})


def test_ior_one_is_lambert():
    """IOR 1: F0 = 0, so Cycles sets up no specular closure (eta = 1) and a dielectric is its
    diffuse closure alone, base_color / pi, whatever the roughness."""
    wi, wo = random_pairs(200, seed=1)
    m = _model(base_color=[0.8, 0.3, 0.1], roughness=0.4, metallic=0.0, ior=1.0)
    np.testing.assert_allclose(np.asarray(m.eval(wi, wo)),
                               np.broadcast_to([0.8, 0.3, 0.1], (200, 3)) / math.pi, rtol=1e-14)


def _ggx_schlick(wi, wo, alpha, f0):
    """GGX with height-correlated Smith masking and Schlick's Fresnel, written from the papers
    (Walter et al. 2007, eq. 33; Heitz 2014, eqs. 72, 99; Schlick 1994), in NumPy."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=-1, keepdims=True)
    ci, co, ch = wi[:, 2], wo[:, 2], h[:, 2]
    a2 = alpha * alpha
    D = a2 / (math.pi * (ch * ch * (a2 - 1.0) + 1.0) ** 2)

    def lam(c):
        t2 = (1.0 - c * c) / (c * c)
        return 0.5 * (np.sqrt(1.0 + a2 * t2) - 1.0)

    G2 = 1.0 / (1.0 + lam(ci) + lam(co))
    d = np.sum(wo * h, axis=-1)
    F = f0 + (1.0 - f0) * (1.0 - d[:, None]) ** 5
    return F * (D * G2 / (4.0 * ci * co))[:, None]


def test_single_scattering_metal_is_schlick_ggx():
    """distribution "GGX" (no compensation), metallic 1, no tint: the F82-tint Fresnel with
    b = 0 is Schlick's with F0 = base colour, and the lobe is GGX with height-correlated
    masking: equal to a transcription of the papers to rounding."""
    wi, wo = random_pairs(300, seed=2)
    f0 = np.array([0.95, 0.64, 0.54])
    m = BlenderPrincipled(base_color=f0, roughness=np.asarray(0.45), metallic=np.asarray(1.0),
                          ior=np.asarray(1.5), multiscatter=False)
    np.testing.assert_allclose(np.asarray(m.eval(wi, wo)), _ggx_schlick(wi, wo, 0.45**2, f0),
                               rtol=1e-11)


@pytest.mark.parametrize("roughness", [0.1, 0.3, 0.6, 1.0])
def test_compensated_white_metal_keeps_its_energy(roughness):
    """Multiscatter GGX with F = 1 (a white metal) scales the lobe by 1/E(mu): the directional
    albedo is 1 but for the tables' bilinear interpolation (measured: within 1.2e-3 for
    mu >= 0.1; at mu = 0.02 the 32 cosine nodes miss the narrow lobes' fall, -5.7% at
    roughness 0.1). Without the compensation it is E itself, 0.53-0.99 here."""
    m = _model(base_color=1.0, roughness=roughness, metallic=1.0, ior=1.5)
    for mu in (1.0, 0.5, 0.1):
        wo = np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])
        assert abs(float(np.asarray(directional_albedo(m, wo))) - 1.0) < 2e-3


def test_dielectric_layering_does_not_create_energy():
    """Specular over diffuse, white base colour: the diffuse gets what Cycles estimates the
    specular layer leaves, so the sum stays near 1 (measured within 7e-3 for mu >= 0.1; the
    estimate is a table and the diffuse is not reflected back down)."""
    for r in (0.1, 0.3, 0.6, 1.0):
        m = _model(base_color=1.0, roughness=r, metallic=0.0, ior=1.5)
        for mu in (1.0, 0.5, 0.1):
            wo = np.array([math.sqrt(1.0 - mu * mu), 0.0, mu])
            assert abs(float(np.asarray(directional_albedo(m, wo))) - 1.0) < 1e-2


#: values printed in Cycles' own tables (Blender 4.5, src/scene/shader.tables, made by
#: src/app/cycles_precompute.cpp): (table, flat index, value). The shipped tables are rebuilt by
#: quadrature (brdf_fit.tables.cycles); these are an independent reading of the same quantities
CYCLES_PRINTED = (
    ("ggx_E", 20 * 32 + 5, 0.998773),
    ("ggx_Eavg", 12, 0.946279),
    ("ggx_gen_schlick_ior_s", 14 * 256 + 0 * 16 + 1, 0.306049),
    ("ggx_gen_schlick_ior_s", 13 * 256 + 0 * 16 + 4, 0.061686),
)
#: the largest differences measured against all of Cycles' printed values
#: (benchmarks/results/cycles_tables.md)
TABLE_DIFFERENCE = {"ggx_E": 1.0e-6, "ggx_Eavg": 6.2e-7, "ggx_gen_schlick_ior_s": 2.0e-5}


@pytest.mark.parametrize("name, index, value", CYCLES_PRINTED)
def test_shipped_tables_agree_with_cycles_printed_values(name, index, value):
    table = cy.tables()[name].reshape(-1)
    assert abs(table[index] - value) <= TABLE_DIFFERENCE[name]


def test_table_lookup_is_cycles_interpolation():
    """At the nodes the lookup returns the node's value; between them it is linear along each
    axis; outside [0, 1] it clamps (lookup_table.h)."""
    E = cy.tables()["ggx_E"]
    xs = np.array([0.0, 5 / 31, 1.0])
    ys = np.array([0.0, 20 / 31, 1.0])
    got = np.asarray(cy.lookup_2d(E, xs[None, :], ys[:, None]))
    np.testing.assert_allclose(got, E[np.ix_([0, 20, 31], [0, 5, 31])], rtol=1e-14)
    mid = float(cy.lookup_2d(E, 5.5 / 31, 20 / 31))
    assert mid == pytest.approx(0.5 * (E[20, 5] + E[20, 6]), rel=1e-14)
    assert float(cy.lookup_2d(E, -1.0, 2.0)) == pytest.approx(E[31, 0], rel=1e-14)
    S = cy.tables()["ggx_gen_schlick_ior_s"]
    got3 = float(cy.lookup_3d(S, 3 / 15, 7 / 15, 11.5 / 15))
    assert got3 == pytest.approx(0.5 * (S[11, 7, 3] + S[12, 7, 3]), rel=1e-14)


def test_inputs_map_to_the_node_sockets():
    inputs = bp.to_blender_inputs({"base_color": np.array([0.1, 0.2, 0.3]), "roughness": 0.4,
                                   "coat_tint": 0.5})
    assert inputs == {"Base Color": [0.1, 0.2, 0.3, 1.0], "Roughness": 0.4,
                      "Coat Tint": [0.5, 0.5, 0.5, 1.0]}
    with pytest.raises(ValueError, match="not an input"):
        bp.to_blender_inputs({"sheen": 1.0})


@pytest.mark.parametrize("mu, r", [(0.9, 0.3), (0.5, 0.5), (0.2, 1.0), (0.05, 0.7)])
def test_sheen_lobe_is_a_normalised_ltc(mu, r):
    """The sheen lobe is the clamped cosine transformed by M^-1 = [[A, 0, B], [0, A, 0],
    [0, 0, 1]] (Zeltner et al. 2022): a density over the upper hemisphere, whose integral is 1
    whatever A and B (the table's albedo R then scales it), checked by a Gauss-Legendre product
    rule; the view's tangent frame (make_orthonormals_safe_tangent) turns it with the view."""
    t = cy.tables()["sheen_ltc"]
    a = float(cy.lookup_2d(t[0], mu, r))
    b = float(cy.lookup_2d(t[1], mu, r))
    x, w = np.polynomial.legendre.leggauss(400)
    c = 0.5 * (x + 1.0)  # cos(theta) in (0, 1)
    phi = math.pi * (x + 1.0)
    C, P = np.meshgrid(c, phi, indexing="ij")
    W = np.outer(0.5 * w, math.pi * w)
    S = np.sqrt(1.0 - C * C)
    for view_phi in (0.0, 1.1):
        so = math.sqrt(1.0 - mu * mu)
        ox, oy = so * math.cos(view_phi), so * math.sin(view_phi)
        lobe = np.asarray(cy.sheen_lobe((a, b), S * np.cos(P), S * np.sin(P), C, ox, oy))
        assert np.sum(W * lobe * C) == pytest.approx(1.0, abs=1e-10)  # measured 2e-14
