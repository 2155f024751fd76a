"""Lewis's normalised Phong (brdf_fit.models.lewis): an independent spherical-angle reference,
the identity with modified Phong, the albedo ((n+2) normalisation: exactly kd + ks at normal
view; what (n+1) would give), sampler, gradients and parameter errors.

The reference writes ``cos(alpha_r)`` from polar angles (``cos t_i cos t_o - sin t_i sin t_o
cos(p_i - p_o)``) with NumPy; the model uses ``2 (n.wi)(n.wo) - wi.wo``.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import assert_model_gradient_matches_fd, dir_from_cos, random_angles
from _helpers import eval_jit as _eval
from _helpers import pdf_jit as _pdf
from _helpers import vec as _dirs

from brdf_fit.core.validate import ParameterError
from brdf_fit.models.lewis import Lewis, registry_entries
from brdf_fit.models.phong import ModifiedPhong
from brdf_fit.verify import checks
from brdf_fit.verify.chi2 import chi2_test_brdf


def _angles(rng, n):
    return random_angles(rng, n)


def lewis_reference(ti, pi_, to, po, kd, ks, n):
    """kd/pi + ks (n+2)/(2 pi) max(0, cos alpha_r)^n, alpha_r the angle between wi and the mirror
    of wo, from polar angles."""
    ca = np.cos(ti) * np.cos(to) - np.sin(ti) * np.sin(to) * np.cos(pi_ - po)
    # the lobe lives where cos(alpha_r) > 0 (at n = 0 an indicator, not 0^0 = 1)
    lobe = (n + 2) / (2 * np.pi) * np.where(ca > 0, np.abs(ca) ** n, 0.0)
    return np.asarray(kd)[None] / np.pi + np.asarray(ks)[None] * lobe[:, None]


@pytest.mark.parametrize("n", (0.0, 1.0, 7.5, 30.0, 800.0))
def test_matches_spherical_angle_reference(n):
    rng = np.random.default_rng(20)
    ti, pi_ = _angles(rng, 300)
    to, po = _angles(rng, 300)
    # half the pairs near the mirror direction, so the lobe is exercised for large n
    ti[:150], pi_[:150] = to[:150] + rng.normal(0, 0.05, 150), po[:150] + np.pi
    ti = np.clip(np.abs(ti), 0.0, math.acos(1e-3))
    kd, ks = np.array([0.3, 0.2, 0.1]), np.array([0.6, 0.5, 0.4])
    m = Lewis(kd=jnp.asarray(kd), ks=jnp.asarray(ks), exponent=n)
    got = np.asarray(_eval(m, jnp.asarray(_dirs(ti, pi_)), jnp.asarray(_dirs(to, po))))
    want = lewis_reference(ti, pi_, to, po, kd, ks, n)
    # float64 round-off of cos(alpha_r) (1e-16 absolute) becomes n x 1e-16 relative in cos^n
    np.testing.assert_allclose(got, want, rtol=1e-10 + n * 2e-15, atol=0)


def test_identical_to_modified_phong():
    """Lewis 1994 and Lafortune & Willems 1994 normalise the lobe the same way: same eval, pdf
    and samples (models.md 4.7, 4.18)."""
    rng = np.random.default_rng(21)
    wi = jnp.asarray(_dirs(*_angles(rng, 500)))
    wo = jnp.asarray(_dirs(*_angles(rng, 500)))
    kd, ks = jnp.asarray([0.3, 0.2, 0.1]), jnp.asarray([0.5, 0.6, 0.4])
    a, b = Lewis(kd=kd, ks=ks, exponent=25.0), ModifiedPhong(rho_d=kd, rho_s=ks, exponent=25.0)
    np.testing.assert_array_equal(_eval(a, wi, wo), _eval(b, wi, wo))
    np.testing.assert_array_equal(_pdf(a, wi, wo), _pdf(b, wi, wo))
    uc, u = jnp.asarray(rng.random(500)), jnp.asarray(rng.random((500, 2)))
    sa, sb = a.sample(wo, uc, u), b.sample(wo, uc, u)
    np.testing.assert_array_equal(sa.wi, sb.wi)
    np.testing.assert_array_equal(sa.weight, sb.weight)


@pytest.mark.parametrize("n", (0.0, 1.0, 20.0, 300.0))
def test_albedo_normal_view_is_kd_plus_ks(n):
    """(n+2)/(2 pi): Int cos^n cos dw = 2 pi/(n+2), so E(normal) = kd + ks exactly (independent
    1-D Gauss-Legendre in theta at normal view, and the library's mirror-lobe quadrature); the
    (n+1)/(2 pi) normaliser would give ks (n+1)/(n+2) (0.9545 ks at n = 20, 0.5 ks at n = 0)."""
    kd, ks = 0.25, 0.7
    x, w = np.polynomial.legendre.leggauss(200)
    lo = 0.0
    total = 0.0
    # graded panels in theta (the lobe has width ~ 1/sqrt(n + 1))
    edges = [0.0] + [min(math.pi / 2, 2.0**j / math.sqrt(n + 1)) for j in range(-2, 12)]
    for hi in edges[1:]:
        if hi <= lo:
            continue
        th = 0.5 * (hi - lo) * x + 0.5 * (hi + lo)
        total += np.sum(0.5 * (hi - lo) * w * np.cos(th) ** n * np.cos(th) * np.sin(th))
        lo = hi
    spec = (n + 2) / (2 * np.pi) * 2 * np.pi * total
    assert spec == pytest.approx(1.0, rel=1e-12)
    assert (n + 1) / (2 * np.pi) * 2 * np.pi * total == pytest.approx((n + 1) / (n + 2),
                                                                       rel=1e-12)
    E = float(checks.directional_albedo(Lewis(kd=kd, ks=ks, exponent=n), np.array([0, 0, 1.0])))
    assert E == pytest.approx(kd + ks, rel=1e-9)


def test_albedo_decreases_towards_grazing_and_conserves():
    """Default entry (kd = (0.4, 0.3, 0.2), ks = 0.4, n = 30), measured with run_checks: red
    channel E = 0.8 at normal view, 0.6800 at cos_o = 0.7, 0.5406 at 0.35, 0.4291 at 1e-3
    (the lobe is cut by the horizon); the 'energy' check passes (max 0.8)."""
    r = checks.run_checks("lewis", checks=["energy"])[0]
    assert r.passed and r.statistic == pytest.approx(0.8, rel=1e-9)
    E = np.asarray(r.details["albedo"])[:, 0]
    cos_o = np.asarray(r.details["cos_o"])
    order = np.argsort(cos_o)
    assert np.all(np.diff(E[order]) > 0)
    assert E[order][0] == pytest.approx(0.4291, abs=1e-4)
    # the specular part alone at cos_o = 1e-3: 0.4291 - kd
    assert E[order][0] - 0.4 == pytest.approx(0.0291, abs=1e-4)


@pytest.mark.parametrize("n,cos_o", [(5.0, 0.3), (200.0, 0.8)])
def test_sampler_matches_pdf(n, cos_o):
    m = Lewis(kd=0.3, ks=0.6, exponent=n)
    wo = jnp.asarray(dir_from_cos(cos_o))
    res = chi2_test_brdf(m, wo, n_samples=50_000, seed=7, test_count=2)
    assert res.passed, res.reasons


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(22)
    to, po = _angles(rng, 12)
    ti, pi_ = np.clip(to + rng.normal(0, 0.2, 12), 0.0, 1.5), po + np.pi + rng.normal(0, 0.2, 12)
    wi, wo = jnp.asarray(_dirs(ti, pi_)), jnp.asarray(_dirs(to, po))
    p0 = {"kd": [0.3, 0.2], "ks": [0.5, 0.4], "exponent": 17.0}
    assert_model_gradient_matches_fd(Lewis, wi, wo, p0, rel=1e-6, abs=1e-9)


def test_parameter_errors():
    with pytest.raises(ParameterError, match="kd \\+ ks must be <= 1"):
        Lewis(kd=0.6, ks=0.5, exponent=10.0)
    with pytest.raises(ParameterError, match="kd \\+ ks"):
        Lewis(kd=jnp.asarray([0.1, 0.7]), ks=0.4, exponent=10.0)
    Lewis(kd=0.5, ks=0.5, exponent=10.0)  # = 1 is allowed
    with pytest.raises(ParameterError, match="'exponent'"):
        Lewis(kd=0.1, ks=0.5, exponent=-1.0)
    with pytest.raises(ParameterError, match="'ks'"):
        Lewis(kd=0.0, ks=1.5, exponent=1.0)
    (entry,) = registry_entries()
    with pytest.raises(ParameterError, match="'exponent'"):
        entry.build(exponent=2e6)
