"""brdf_fit.core.mirror_rule.mirror_lobe_rule: exact identities, the exactly normalised Phong lobe,
and the batched and traced constructions."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdf_fit.core.mirror_rule import mirror_lobe_rule
from brdf_fit.models.phong_normalized import EnergyNormalizedPhong
from brdf_fit.verify.albedo import lobe_rule

COS = [1e-4, 1e-3, 0.01, 0.05, 0.3, 0.7, 0.999, 1.0]
NS = [0.0, 0.5, 1.0, 10.0, 100.0, 1e3, 1e4, 1e5, 1e6]


def _wo(c, phi=0.3):
    s = math.sqrt(1.0 - c * c)
    return np.array([s * math.cos(phi), s * math.sin(phi), c])


@pytest.mark.parametrize("n", [0.0, 1.0, 1e3, 1e6])
def test_hemisphere_identities(n):
    """Int dw = 2 pi and Int cos dw = pi over the upper hemisphere, for any lobe grading."""
    for c in COS:
        r = mirror_lobe_rule(_wo(c), n)
        w = np.asarray(r.weights)
        d = np.asarray(r.directions)
        assert np.all(d[w > 0, 2] > 0)
        np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-15)
        # the square-root kinks at the horizon tangencies limit the constant integrand most
        assert abs(w.sum() / (2 * math.pi) - 1) < 2e-9, (c, w.sum())
        assert abs((w * d[:, 2]).sum() / math.pi - 1) < 1e-9, (c, (w * d[:, 2]).sum())


@jax.jit
@jax.vmap
def _normalised_lobe_albedo(n, wo, dirs, w):
    model = EnergyNormalizedPhong(rho_s=1.0, exponent=n)
    return jnp.sum(model.eval_cos(dirs, wo) * w)


def test_exactly_normalised_lobe():
    """Albedo of the Mallett-Yuksel-normalised lobe is exactly 1 (its normaliser is checked
    independently against SciPy and 30-digit mpmath integrals in tests/test_phong_norm.py).
    One batched rule over every (n, cos_o) pair, one compiled evaluation."""
    n, c = (v.ravel() for v in np.meshgrid(NS, COS, indexing="ij"))
    wos = np.stack([_wo(ci) for ci in c])
    r = mirror_lobe_rule(wos, n)
    e = np.asarray(_normalised_lobe_albedo(jnp.asarray(n), jnp.asarray(wos), r.directions,
                                           r.weights))
    worst = float(np.max(np.abs(e - 1.0)))
    assert worst < 4e-9, (worst, n[np.argmax(np.abs(e - 1.0))], c[np.argmax(np.abs(e - 1.0))])


def test_batched_and_traced_rules_match():
    wos = np.stack([_wo(c) for c in (1e-3, 0.4, 1.0)])
    batched = mirror_lobe_rule(wos, 50.0)
    assert batched.directions.shape == (3, batched.n, 3)
    for k, wo in enumerate(wos):
        single = mirror_lobe_rule(wo, 50.0)
        np.testing.assert_allclose(batched.weights[k], single.weights, rtol=1e-13, atol=1e-300)
        np.testing.assert_allclose(batched.directions[k], single.directions, atol=1e-14)
    traced = jax.jit(lambda w, n: mirror_lobe_rule(w, n).weights)(jnp.asarray(wos[1]), 50.0)
    np.testing.assert_allclose(traced, mirror_lobe_rule(wos[1], 50.0).weights, rtol=1e-12,
                               atol=1e-300)


def test_below_horizon_view_and_bad_exponent():
    r = mirror_lobe_rule(np.array([0.6, 0.0, -0.8]), 10.0)
    assert float(jnp.max(jnp.abs(r.weights))) == 0.0
    with pytest.raises(ValueError, match="exponent"):
        mirror_lobe_rule(_wo(0.5), -1.0)


def test_lobe_rule_dispatches_on_quadrature_hint():
    model = EnergyNormalizedPhong(rho_s=0.5, exponent=jnp.asarray(20.0))
    r = lobe_rule(model, jnp.asarray(_wo(0.5)))
    np.testing.assert_array_equal(r.weights, mirror_lobe_rule(_wo(0.5), 20.0).weights)
