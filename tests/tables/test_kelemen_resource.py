"""The packaged Kelemen albedo table (brdf_fit/resources/tables/kelemen_AB.npz, written by
brdf_fit.tables.kelemen) equals a regeneration, and the model's cubic lookup in log10(alpha)
stays within its stated error of the quadrature it replaces; Table.lookup's cubic order."""

from __future__ import annotations

import importlib.resources

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit.core.table import Axis, Table, load_table
from brdf_fit.models.kelemen import (
    ALBEDO_TABLE_FILE,
    ALBEDO_TABLE_INTERPOLATION_ERROR,
    ALBEDO_TABLE_N_ALPHA,
    TABLE_NODES,
    albedo_nodes,
    albedo_table,
)
from brdf_fit.tables.kelemen import node_values

#: regenerated values must equal the shipped ones to round-off of a differently blocked
#: computation (the same float64 quadrature, other batch shapes)
REGEN_TOL = 1e-12


def test_shipped_table_equals_a_regeneration_at_spot_nodes():
    path = importlib.resources.files("brdf_fit") / "resources" / "tables" / ALBEDO_TABLE_FILE
    with importlib.resources.as_file(path) as p:
        t = load_table(p)
    assert t.shape == (ALBEDO_TABLE_N_ALPHA, 2 * TABLE_NODES)
    x = t.axes[0].nodes()
    k = np.array([0, 1, 64, 128, 200, ALBEDO_TABLE_N_ALPHA - 1])
    np.testing.assert_allclose(np.asarray(t.values)[k], node_values(10.0 ** x[k]), rtol=0,
                               atol=REGEN_TOL)
    assert t.meta["interpolation_error"]["max_abs"] <= ALBEDO_TABLE_INTERPOLATION_ERROR


def test_lookup_against_the_quadrature_off_the_grid():
    """Between the nodes (random alphas in [1e-4, 1] and the model's clamp) the cubic lookup is
    within the stated interpolation error of the quadrature, in A and B at every node mu_k."""
    rng = np.random.default_rng(7)
    alpha = np.concatenate([10.0 ** rng.uniform(-4.0, 0.0, 12), [0.3, 1.0]])
    with jax.enable_x64(True):
        A, B = jax.vmap(albedo_table)(jnp.asarray(alpha))
        A2, B2 = jax.jit(jax.vmap(albedo_nodes))(jnp.asarray(alpha))
    err = max(float(jnp.abs(A - A2).max()), float(jnp.abs(B - B2).max()))
    assert err <= ALBEDO_TABLE_INTERPOLATION_ERROR


def test_float32_lookup():
    with jax.enable_x64(True):
        A64, _ = albedo_table(jnp.float64(0.3))
    A32, B32 = albedo_table(np.float32(0.3))
    assert A32.dtype == jnp.float32 and B32.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(A32), np.asarray(A64), rtol=0, atol=1e-6)


def test_cubic_lookup_is_exact_for_cubics_and_differentiable():
    """Table.lookup(order=3): cubic Lagrange through 4 nodes per axis reproduces any cubic
    exactly (endpoints and texel centres, the shifted end stencils included), in 2-D too, with
    its exact derivative; order=1 stays linear; other orders are refused."""
    ax = Axis("x", 0.0, 2.0, 7, centres=False)
    ay = Axis("y", -1.0, 1.0, 5, centres=True)
    x, y = ax.nodes(), ay.nodes()

    def f(x, y):
        return (x**3 - 2.0 * x + 0.5) * (y**3 + y**2)

    t = Table(f(x[:, None], y[None, :])[..., None], (ax, ay), ("v",))
    qx = np.linspace(x[0], x[-1], 23)
    qy = np.linspace(y[0], y[-1], 19)
    gx, gy = np.meshgrid(qx, qy, indexing="ij")
    with jax.enable_x64(True):
        got = np.asarray(t.lookup(jnp.asarray(gx), jnp.asarray(gy), order=3))[..., 0]
        d = float(jax.grad(lambda a: t.lookup(a, jnp.float64(0.2), order=3)[0])(0.7))
        lin = np.asarray(t.lookup(jnp.asarray(x[2] + 0.25 * (x[3] - x[2])), y[1]))[0]
    np.testing.assert_allclose(got, f(gx, gy), rtol=0, atol=1e-12)
    assert d == pytest.approx((3 * 0.7**2 - 2.0) * (0.2**3 + 0.2**2), abs=1e-12)
    v = np.asarray(t.values)[..., 0]
    assert lin == pytest.approx(0.75 * v[2, 1] + 0.25 * v[3, 1], abs=1e-14)
    with pytest.raises(ValueError, match="order"):
        t.lookup(0.5, 0.5, order=2)
