"""Westin, Arvo & Torrance (1992): the virtual gonioreflectometer of ``brdf_fit.tables.westin`` and
the tabulated model ``brdf_fit.models.westin``.

What is checked, and against what:

* the flat micro-geometry (the floor alone) reproduces its local BRDF: the traced cells against
  the exact cosine-weighted bin averages of the local registry BRDF (:func:`W.bin_average`,
  Gauss-Legendre), in units of each cell's Monte Carlo standard error (Lambert: exactly
  ``rho/pi``, every ray escaping with weight ``rho``; GGX: a glossy lobe);
* the shipped velvet table against a fresh, small, differently seeded recomputation, within their
  combined Monte Carlo errors;
* the model: reciprocity (by construction), energy (albedo by the package's quadrature <= 1 and
  equal to the tracer's own albedo), gradients against finite differences, seeded determinism,
  the registry entry and the catalogue row.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import normal_dirs

from brdf_fit import registry
from brdf_fit.models.westin import PRESET_NAMES, Westin, angles
from brdf_fit.tables import westin as W
from brdf_fit.verify import catalogue
from brdf_fit.verify.albedo import directional_albedo

#: small runs share one shape (8 theta bins, 8 phi bins, blocks of 2^13 rays)
SMALL = dict(n_theta=8, n_phi=8, rays=2**13, block=2**13)
#: a z-score is (estimate - target) / se; with ~N(0, 1) scores over a few hundred cells the RMS is
#: 1 +- 0.1 and the largest ~3.5 (measured: see each test). The bound on the RMS leaves room for
#: the noise of the se estimates themselves in sparsely hit cells
Z_RMS_MAX = 1.3
Z_MAX = 6.0
#: bound on the mean score over 512 cells (its noise: 1/sqrt(512) = 0.044)
Z_MEAN_MAX = 0.2


def _zscores(F, se, target, floor=W.CELL_FLOOR):
    m = (target > floor * target.max()) & (se > 0)
    z = (F[m] - target[m]) / se[m]
    return z


# ----------------------------------------------------------------------------- flat geometry


def test_flat_lambert_is_the_local_brdf():
    geo = W.MicroGeometry("flat-lambert", floor=W.Local("lambert", (("rho", 0.7),)), **SMALL)
    raw = W.trace(geo)
    # every ray reflects once and escapes with weight rho: the albedo is exact, nothing truncated
    np.testing.assert_allclose(raw["S1"].sum(axis=(1, 2)) / raw["N"], 0.7, rtol=1e-12)
    assert np.all(raw["trunc"] == 0.0)
    F, se = W.estimate(raw)
    target = W.bin_average(registry.get("lambert").build(rho=0.7), 8, 8)
    np.testing.assert_allclose(target, 0.7 / np.pi, rtol=1e-12)
    z = _zscores(F, se, target)
    # measured (seeds 1992, 5): RMS 0.975, 0.983; max 2.9, 2.8; mean -0.06, 0.007 (512 cells:
    # the mean of 512 unit scores has error 0.044)
    assert z.size == 512
    assert np.sqrt(np.mean(z * z)) < Z_RMS_MAX and np.abs(z).max() < Z_MAX, z
    assert abs(z.mean()) < Z_MEAN_MAX
    # negative control: a local BRDF 5% brighter is rejected (measured mean -0.77, -0.70)
    assert _zscores(F, se, 1.05 * target).mean() < -2.0 * Z_MEAN_MAX
    # determinism: the same seed gives the same sums, another seed different ones
    np.testing.assert_array_equal(W.trace(geo)["S1"], raw["S1"])
    assert not np.array_equal(W.trace(dataclasses.replace(geo, seed=7))["S1"], raw["S1"])


def test_flat_glossy_is_the_local_brdf():
    local = W.Local("ggx", (("alpha", 0.3), ("f0", 1.0)))
    geo = W.MicroGeometry("flat-ggx", floor=local, **SMALL)
    F, se = W.estimate(W.trace(geo))
    target = W.bin_average(local.build(), 8, 8)
    z = _zscores(F, se, target)
    # measured (seeds 1992, 5): RMS 1.06, 1.02; max 2.8, 3.0; mean -0.07, -0.004 (512 cells)
    assert z.size == 512
    assert np.sqrt(np.mean(z * z)) < Z_RMS_MAX and np.abs(z).max() < Z_MAX, z
    assert abs(z.mean()) < Z_MEAN_MAX
    # negative control: a 10% wider lobe (alpha 0.33) is rejected (measured RMS 1.74, 1.68;
    # max 6.1, 6.4)
    wide = W.bin_average(W.Local("ggx", (("alpha", 0.33), ("f0", 1.0))).build(), 8, 8)
    z_bad = _zscores(F, se, wide)
    assert np.sqrt(np.mean(z_bad * z_bad)) > 1.5


@pytest.mark.slow
def test_flat_glossy_is_the_local_brdf_at_preset_resolution():
    local = W.Local("ggx", (("alpha", 0.2), ("f0", 1.0)))
    geo = W.MicroGeometry("flat-ggx", floor=local, rays=2**16, block=2**14)
    F, se = W.estimate(W.trace(geo))
    z = _zscores(F, se, W.bin_average(local.build(), 16, 16))
    # measured: RMS 1.00, max 3.4, mean -0.08 over the 1275 cells above 1% of the peak
    assert z.size > 1000
    assert np.sqrt(np.mean(z * z)) < Z_RMS_MAX and np.abs(z).max() < Z_MAX
    assert abs(z.mean()) < Z_MEAN_MAX


def test_geometry_is_validated():
    with pytest.raises(ValueError, match="coverage"):
        W.MicroGeometry("x", floor=W.Local("lambert"), coverage=1.0)
    with pytest.raises(ValueError, match="fibres need"):
        W.MicroGeometry("x", floor=W.Local("lambert"), coverage=0.5)
    with pytest.raises(ValueError, match="block"):
        W.MicroGeometry("x", floor=W.Local("lambert"), n_theta=16, block=1000)


# ----------------------------------------------------------------------------- shipped table


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_shipped_table_matches_the_preset(preset):
    meta = Westin(preset=preset).table_meta()
    code = json.loads(json.dumps(W.PRESETS[preset].to_dict()))
    assert meta["geometry"] == code
    assert meta["rays_total"] == code["rays"] * code["n_theta"]
    # the truncated weight (paths longer than max_events) is negligible against the MC error
    assert max(meta["truncated"]) < 0.1 * min(meta["albedo_se"]) + 1e-6
    assert meta["mc_error"]["rel_se_median"] < 0.05


def test_shipped_velvet_matches_a_fresh_recomputation():
    geo = dataclasses.replace(W.PRESETS["velvet"], rays=2**12, block=2**14, seed=11)
    raw = W.trace(geo)
    Fs, ses = W.estimate(raw)
    t = Westin(preset="velvet")
    F0, se0 = np.asarray(t.table().channel("f")), np.asarray(t.table().channel("se"))
    # per (theta_i, theta_o) pair, summed over phi_d: enough rays per sum for a Gaussian error
    a, b = Fs.sum(-1), F0.sum(-1)
    s = np.sqrt((ses * ses).sum(-1) + (se0 * se0).sum(-1))
    m = b > W.CELL_FLOOR * b.max()
    z = (a[m] - b[m]) / s[m]
    # measured (seeds 11, 12): RMS 0.94, 1.05; max 2.6, 2.5 over 256 pairs. Single cells of so
    # small a run are not Gaussian (a few rays carry them: max |z| 26), hence the phi sums
    assert z.size > 200
    assert np.sqrt(np.mean(z * z)) < Z_RMS_MAX and np.abs(z).max() < Z_MAX, z
    # the simulation itself is reciprocal (before the symmetrisation) to its Monte Carlo error:
    # (theta_i, theta_o) against (theta_o, theta_i), phi_d sums; measured RMS 1.04 / 0.94, max
    # 2.7 / 2.2 over the 240 off-diagonal pairs (seeds 11, 12)
    Fu, seu = W.estimate(raw, symmetrise=False)
    a, v = Fu.sum(-1), (seu * seu).sum(-1)
    off = ~np.eye(a.shape[0], dtype=bool)
    zr = (a - a.T)[off] / np.sqrt(v + v.T)[off]
    assert np.sqrt(np.mean(zr * zr)) < Z_RMS_MAX and np.abs(zr).max() < Z_MAX, zr
    # the albedo per incident bin (total escaping weight) within the combined errors
    N = raw["N"]
    alb = raw["S1"].sum(axis=(1, 2)) / N
    alb_se = np.sqrt((raw["S2"].sum(axis=(1, 2)) / N - alb * alb) / (N - 1))
    meta = t.table_meta()
    za = (alb - np.asarray(meta["albedo"])) / np.hypot(alb_se, meta["albedo_se"])
    assert np.abs(za).max() < 4.5, za  # measured 1.9, 1.7


@pytest.mark.slow
def test_velvet_table_regenerates_identically():
    # the full preset (327 s on the shared 2-core CPU): same seed, same table
    t = W.build_table(W.PRESETS["velvet"])
    shipped = Westin(preset="velvet").table()
    np.testing.assert_allclose(np.asarray(t.values), np.asarray(shipped.values), rtol=0,
                               atol=1e-12)


# ----------------------------------------------------------------------------- the model


def test_model_is_reciprocal_nonnegative_and_finite():
    rng = np.random.default_rng(0)
    m = Westin(scale=jnp.asarray([1.0, 0.5, 0.2]))
    wi, wo = normal_dirs(rng, 3000), normal_dirs(rng, 3000)
    ev = jax.jit(lambda m, a, b: m.eval(a, b))
    a, b = ev(m, wi, wo), ev(m, wo, wi)
    assert a.shape == (3000, 3)
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=0)
    assert np.all(np.asarray(a) >= 0) and np.all(np.isfinite(np.asarray(a)))
    below = wi.at[:, 2].multiply(-1.0)
    assert np.all(np.asarray(ev(m, below, wo)) == 0.0)
    se = np.asarray(jax.jit(lambda m, a, b: m.mc_error(a, b))(m, wi, wo))
    # the error is a few percent of the value (the table's median relative error is 1.5%)
    assert np.all(se >= 0) and np.median(se / np.asarray(a)) < 0.05


def test_albedo_is_below_one_and_matches_the_tracer():
    m = Westin(scale=1.0)
    meta = m.table_meta()
    nt = meta["geometry"]["n_theta"]
    th = (np.arange(nt) + 0.5) * (0.5 * np.pi / nt)
    wo = jnp.asarray(np.stack([np.sin(th), 0 * th, np.cos(th)], -1))
    E = np.asarray(directional_albedo(m, wo))
    assert np.all(E < 1.0) and np.all(E > 0.0)
    # the quadrature of the interpolated table at the bin centre against the tracer's albedo of
    # the bin (a cosine-weighted average over it): measured max difference 0.21% (the tracer's
    # albedo error is 0.13-0.16%)
    np.testing.assert_allclose(E, meta["albedo"], rtol=0.01)


def test_gradients_match_finite_differences():
    m = Westin(scale=jnp.asarray(0.8))

    def f(x):
        ti, pi_, to, po = x[0], x[1], x[2], x[3]
        wi = jnp.stack([jnp.sin(ti) * jnp.cos(pi_), jnp.sin(ti) * jnp.sin(pi_), jnp.cos(ti)])
        wo = jnp.stack([jnp.sin(to) * jnp.cos(po), jnp.sin(to) * jnp.sin(po), jnp.cos(to)])
        return m.eval(wi, wo)

    vg = jax.jit(jax.value_and_grad(f))
    h = 1e-6
    for x in ([0.41, 0.3, 1.07, 2.2], [1.2, -0.4, 0.7, 0.9], [0.93, 0.0, 0.51, 1.1]):
        x = jnp.asarray(x)
        fd = np.array([(vg(x.at[k].add(h))[0] - vg(x.at[k].add(-h))[0]) / (2 * h)
                       for k in range(4)])
        np.testing.assert_allclose(np.asarray(vg(x)[1]), fd, rtol=1e-5, atol=1e-8)
    # finite at the pole (theta = 0: wi = (0, 0, 1) exactly) and with both directions at the
    # same azimuth (phi_d = 0, where |cross| has a kink)
    for x in ([0.0, 0.3, 1.07, 2.2], [0.7, 0.2, 0.0, 0.0], [0.6, 0.4, 0.9, 0.4]):
        assert np.all(np.isfinite(np.asarray(vg(jnp.asarray(x))[1])))


def test_continuous_at_the_pole():
    m = Westin(scale=jnp.asarray(1.0))
    ev = jax.jit(lambda a, b: m.eval(a, b))
    wo = jnp.asarray([[0.6, 0.0, 0.8]])
    pole = ev(jnp.asarray([[0.0, 0.0, 1.0]]), wo)
    e = 1e-7
    az = np.linspace(0.0, 2.0 * np.pi, 9)
    wi = jnp.asarray(np.stack([e * np.cos(az), e * np.sin(az), np.sqrt(1 - e * e) + 0 * az], -1))
    np.testing.assert_allclose(np.asarray(ev(wi, wo)), np.broadcast_to(np.asarray(pole), (9,)),
                               rtol=1e-5)
    # and the blend is reciprocal
    np.testing.assert_allclose(np.asarray(ev(wo, wi)), np.asarray(ev(wi, wo)), rtol=1e-13)


def test_angles():
    th_i, th_o, ph = angles((jnp.asarray(0.6), jnp.asarray(0.0), jnp.asarray(0.8)),
                            (jnp.asarray(-0.6), jnp.asarray(0.0), jnp.asarray(0.8)))
    np.testing.assert_allclose([th_i, th_o, ph], [np.arctan2(0.6, 0.8)] * 2 + [np.pi])


def test_float32_matches_float64():
    rng = np.random.default_rng(1)
    wi, wo = normal_dirs(rng, 500), normal_dirs(rng, 500)
    m = Westin(scale=jnp.asarray(1.0))
    ev = jax.jit(lambda m, a, b: m.eval(a, b))
    a = np.asarray(ev(m, wi, wo))
    b = np.asarray(ev(jax.tree.map(lambda x: x.astype(jnp.float32), m),
                      wi.astype(jnp.float32), wo.astype(jnp.float32)))
    assert b.dtype == np.float32
    np.testing.assert_allclose(b, a, rtol=2e-4, atol=1e-6)


def test_registry_entry_and_catalogue_row():
    e = registry.get("westin-velvet")
    assert e.param_names == ("scale",) and e.catalogue == "Westin" and e.year == 1992
    s = catalogue.summary()
    assert "Westin" not in s["not_implemented"]
    rows = [r for r in catalogue.table() if r["row"] == "Westin"]
    assert [r["entry"] for r in rows] == ["westin-velvet"]
