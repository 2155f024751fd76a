"""core.table: multilinear lookup on texel-centre and endpoint grids, under jit/vmap/grad."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit.core.table import Axis, Table


def _table(centres: bool):
    ax0 = Axis("roughness", 0.0, 1.0, 5, centres)
    ax1 = Axis("mu", 0.0, 1.0, 7, centres)
    r, m = np.meshgrid(ax0.nodes(), ax1.nodes(), indexing="ij")
    # affine in each axis -> multilinear interpolation is exact inside the grid
    vals = np.stack([1.0 + 2.0 * r - 3.0 * m + 0.5 * r * m, r * m], axis=-1)
    return Table(vals, (ax0, ax1), ("A", "B"), {"kind": "test"})


@pytest.mark.parametrize("centres", [True, False])
def test_lookup_exact_at_nodes_and_for_bilinear_functions(centres):
    t = _table(centres)
    r, m = np.meshgrid(t.axes[0].nodes(), t.axes[1].nodes(), indexing="ij")
    np.testing.assert_allclose(np.asarray(t.lookup(r, m)), t.values, atol=1e-12)
    lo0, hi0 = t.axes[0].nodes()[[0, -1]]
    lo1, hi1 = t.axes[1].nodes()[[0, -1]]
    rng = np.random.default_rng(0)
    x = rng.uniform(lo0, hi0, 50)
    y = rng.uniform(lo1, hi1, 50)
    out = np.asarray(t.lookup(x, y))
    np.testing.assert_allclose(out[:, 0], 1 + 2 * x - 3 * y + 0.5 * x * y, atol=1e-12)
    np.testing.assert_allclose(out[:, 1], x * y, atol=1e-12)


def test_centres_clamp_to_edge_texel():
    t = _table(True)
    first = np.asarray(t.values[0, 0])
    np.testing.assert_allclose(np.asarray(t.lookup(0.0, 0.0)), first)  # below the first centre
    np.testing.assert_allclose(np.asarray(t.lookup(-5.0, -1.0)), first)
    np.testing.assert_allclose(np.asarray(t.lookup(2.0, 2.0)), np.asarray(t.values[-1, -1]))


def test_lookup_jit_vmap_grad_match_finite_differences():
    t = _table(True)
    f = jax.jit(lambda r, m: t.lookup(r, m)[..., 0])
    x = jnp.array([0.3, 0.55]), jnp.array([0.4, 0.61])
    np.testing.assert_allclose(jax.vmap(f)(*x), f(*x), atol=1e-12)
    g = jax.grad(lambda r: f(r, 0.4))(0.37)
    h = 1e-6
    fd = (f(0.37 + h, 0.4) - f(0.37 - h, 0.4)) / (2 * h)
    np.testing.assert_allclose(g, fd, rtol=1e-6)
    # with respect to the values (a table inside a fitted model)
    gv = jax.grad(lambda v: Table(v, t.axes, t.channels).lookup(0.37, 0.4)[0])(
        jnp.asarray(t.values))
    assert np.isclose(float(jnp.sum(gv)), 1.0)  # interpolation weights sum to 1


def test_bad_tables_and_lookups_are_refused():
    with pytest.raises(ValueError, match="need an integer n >= 2"):
        Axis("mu", 0, 1, 1, centres=False)
    with pytest.raises(ValueError, match="lo < hi"):
        Axis("mu", 1, 0, 4)
    with pytest.raises(ValueError, match="need"):
        Table(np.zeros((3, 4, 2)), (Axis("a", 0, 1, 3), Axis("b", 0, 1, 5)), ("A", "B"))
    t = _table(True)
    with pytest.raises(ValueError, match="2 coordinates"):
        t.lookup(0.5)
    with pytest.raises(KeyError, match="no channel"):
        t.channel("E")
    assert t.meta == {"kind": "test"}
