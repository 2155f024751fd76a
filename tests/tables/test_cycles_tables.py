"""The shipped Cycles tables (brdf_fit/resources/tables/cycles_ggx.npz) are what
brdf_fit.tables.cycles computes: sample nodes recomputed, and the grids' conventions."""

from __future__ import annotations

import numpy as np
import pytest

from brdf_fit.models._cycles import tables as _tables
from brdf_fit.tables import cycles as tc
from brdf_fit.tables.dfg import dfg_values


def test_shipped_e_nodes_are_the_quadrature():
    E = _tables()["ggx_E"]
    for j, i in ((31, 31), (20, 5), (3, 17), (0, 9)):
        mu, rough = max(j / 31, tc.GRID_CLAMP), max(i / 31, tc.GRID_CLAMP)
        A, B = dfg_values(np.array([mu]), np.array([rough * rough]))
        assert E[j, i] == pytest.approx(float(A[0] + B[0]), abs=1e-12)
    assert np.all(E[:, 0] == 1.0)  # rough 1e-4: alpha^2 below 2e-10, Cycles' mirror


def test_shipped_s_nodes_are_the_quadrature():
    S = _tables()["ggx_gen_schlick_ior_s"]
    for k, j, i in ((13, 0, 4), (7, 8, 12), (15, 15, 15)):
        z = min(max(k / 15, tc.IOR_Z_CLAMP[0]), tc.IOR_Z_CLAMP[1])
        mu, rough = max(j / 15, tc.GRID_CLAMP), max(i / 15, tc.GRID_CLAMP)
        s = tc.s_values(mu, rough, tc.ior_from_z(z), n_theta=tc.S_ORDER[0], n_phi=tc.S_ORDER[1])
        assert S[k, j, i] == pytest.approx(float(s), abs=1e-12)
    assert np.all(S[0] == 0.0)  # ior 1 in float32


def test_mirror_limit_is_the_remapped_fresnel():
    """At rough = 0 the lobe is a mirror: s is the remapped Fresnel at the view cosine."""
    ior = tc.ior_from_z(0.6)
    f0 = ((ior - 1) / (ior + 1)) ** 2
    mu = np.array([1.0, 0.5, 0.1])
    s = tc.s_values(mu, 0.0, ior)
    c = mu
    g = np.sqrt(ior * ior - 1 + c * c)
    F = 0.5 * ((g - c) / (g + c)) ** 2 * (1 + ((c * (g + c) - 1) / (c * (g - c) + 1)) ** 2)
    np.testing.assert_allclose(s, (F - f0) / (1 - f0), rtol=1e-12)
