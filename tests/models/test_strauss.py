"""Strauss 1990 (brdf_fit.models.strauss) against an independent implementation.

The reference follows the paper's recipe with NumPy in angles: ``theta = arccos(cos)``, the
normalised angle ``theta/(pi/2)``, the reflected light vector ``R = 2 (N.L) N - L`` and
``Q/(N.L)``; the model under test uses ``atan2`` angles and the symmetric mirror cosine of
brdf_fit.models.phong. Quadratures here use tests/_lobe_quadrature.py, not brdf_fit.core.quadrature.
"""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import (
    assert_finite,
    assert_model_gradient_matches_fd,
    assert_sampling_finite,
    eval_cos_and_pdf,
    random_angles,
    values_pdfs_grads,
)
from _helpers import eval_cos_jit as _eval_cos
from _helpers import eval_jit as _eval
from _helpers import vec as _vec
from _lobe_quadrature import gauss_hemisphere

from brdf_fit import registry
from brdf_fit.core.validate import ParameterError
from brdf_fit.models._base import astype
from brdf_fit.models.strauss import Strauss, registry_entries, strauss_fresnel, strauss_shadow
from brdf_fit.verify import checks
from brdf_fit.verify.albedo import directional_albedo
from brdf_fit.verify.chi2 import chi2_test_brdf

KF, KS, KJ = 1.12, 1.01, 0.1


#: polar angles from cosines uniform in [lo, 1], azimuths uniform in [-pi, pi)
_angles = functools.partial(random_angles, phi_range=(-np.pi, np.pi))


def reference(L, V, C, s, m, t=0.0):
    """Strauss's recipe (Q_d + Q_s)/(N.L), NumPy float64; C of shape (k,)."""
    N = np.array([0.0, 0.0, 1.0])
    nl, nv = L @ N, V @ N
    xl, xv = np.arccos(nl) / (np.pi / 2), np.arccos(nv) / (np.pi / 2)

    def F(x):
        return (1 / (x - KF) ** 2 - 1 / KF**2) / (1 / (1 - KF) ** 2 - 1 / KF**2)

    def Gs(x):
        return (1 / (1 - KS) ** 2 - 1 / (x - KS) ** 2) / (1 / (1 - KS) ** 2 - 1 / KS**2)

    rd = (1 - s**3) * (1 - t)
    d = 1 - m * s
    rn = (1 - t) - rd
    j = F(xl) * Gs(xl) * Gs(xv)
    rj = np.minimum(1.0, rn + (rn + KJ) * j)
    R = 2 * nl[:, None] * N - L
    rv = np.maximum(np.sum(R * V, -1), 0.0)
    Cs = 1 + m * (1 - F(xl))[:, None] * (C[None] - 1)
    Qd = nl[:, None] * d * rd * C[None]
    Qs = (rv ** (3 / (1 - s)) * rj)[:, None] * Cs
    return (Qd + Qs) / nl[:, None]


@pytest.mark.parametrize("s, m, t", [(0.6, 0.3, 0.0), (0.0, 1.0, 0.0), (0.95, 0.8, 0.0),
                                     (0.5, 0.5, 0.4)])
def test_matches_angle_reference(s, m, t):
    rng = np.random.default_rng(0)
    L = _vec(*_angles(rng, 300))
    V = _vec(*_angles(rng, 300))
    C = np.array([0.8, 0.5, 0.3])
    model = Strauss(color=jnp.asarray(C), smoothness=s, metalness=m, transparency=t)
    f = np.asarray(_eval(model, jnp.asarray(L), jnp.asarray(V)))
    np.testing.assert_allclose(f, reference(L, V, C, s, m, t), rtol=1e-10)


def test_fresnel_and_shadow_ends_angles_not_cosines():
    """Fr: 0 at normal incidence, 1 at grazing; Sh: 1 at normal, 0 at grazing (normalised angles).
    Feeding cosines (the D3DBook/osgSample variant) reverses both: Fr(cos = 1) = 1 at normal."""
    x = jnp.asarray([0.0, 1.0])
    np.testing.assert_allclose(strauss_fresnel(x), [0.0, 1.0], atol=1e-14)
    np.testing.assert_allclose(strauss_shadow(x), [1.0, 0.0], atol=1e-14)
    assert np.all(np.diff(np.asarray(strauss_fresnel(jnp.linspace(0, 1, 50)))) > 0)
    # the model at normal incidence uses x = 0 (its specular tint is the full metal colour)
    model = Strauss(color=0.2, smoothness=0.5, metalness=1.0)
    n = jnp.asarray([0.0, 0.0, 1.0])
    f = float(_eval(model, n, n))
    rd, rn = 1 - 0.125, 0.125
    rj = min(1.0, rn + (rn + KJ) * 0.0)  # Fr(0) = 0 -> j = 0
    want = (1 - 0.5) * rd * 0.2 + 1.0 * rj * (1 + 1.0 * (1 - 0.0) * (0.2 - 1))
    assert f == pytest.approx(want, rel=1e-13)


def test_declared_failures_are_real_and_measured():
    e = registry.get("strauss")
    assert set(e.expected_failures) == {"reciprocity", "energy"}
    m = e.build()
    rng = np.random.default_rng(4)
    wi = jnp.asarray(_vec(*_angles(rng, 2000)))
    wo = jnp.asarray(_vec(*_angles(rng, 2000)))
    a, b = np.asarray(_eval(m, wi, wo)), np.asarray(_eval(m, wo, wi))
    assert np.max(np.abs(a - b)) / np.max(a) > 1.0
    # albedo: independent Gauss rule (f cos is bounded and smooth up to the Sh knee near the
    # horizon) against the library's mirror-lobe rule; the diffuse part alone is pi d rd C
    d, w = gauss_hemisphere(256, 256)
    for cos_o in (0.5, 1.0):
        wo1 = _vec(np.array(math.acos(cos_o)), np.array(0.3))
        E_ind = np.sum(w[:, None] * np.asarray(_eval_cos(m, jnp.asarray(d), jnp.asarray(wo1))), 0)
        E_lib = np.asarray(directional_albedo(m, jnp.asarray(wo1)))
        np.testing.assert_allclose(E_lib, E_ind, rtol=1e-6)
        assert E_ind[0] > math.pi * (1 - 0.3 * 0.6) * (1 - 0.6**3) * 0.8 > 1.6
    res = checks.run_checks("strauss", checks=["reciprocity", "energy"])
    stats = {r.check: r.statistic for r in res}
    assert stats["reciprocity"] == pytest.approx(2.233, abs=2e-3)
    assert stats["energy"] == pytest.approx(1.780, abs=2e-3)


def test_registry_entry_passes_the_other_checks():
    (entry,) = registry_entries()
    assert entry.name == "strauss" and entry.year == 1990 and entry.catalogue == "Strauss"
    res = checks.run_checks("strauss", checks=["non-negative", "pdf-normalisation"])
    assert all(r.passed for r in res), [(r.check, r.statistic) for r in res]


@pytest.mark.parametrize("s, cos_o", [(0.3, 0.8), (0.97, 0.4), (0.999, 0.9)])
def test_chi2(s, cos_o):
    m = Strauss(color=0.7, smoothness=s, metalness=0.5)
    wo = _vec(np.array(math.acos(cos_o)), np.array(0.2))
    res = chi2_test_brdf(m, jnp.asarray(wo), n_samples=100_000, seed=5, test_count=3)
    assert res.passed, str(res)


def test_gradients_match_finite_differences():
    rng = np.random.default_rng(3)
    wi = jnp.asarray(_vec(*_angles(rng, 40, lo=0.05)))
    wo = jnp.asarray(_vec(*_angles(rng, 40, lo=0.05)))
    p0 = {"color": 0.6, "smoothness": 0.55, "metalness": 0.4, "transparency": 0.2}
    assert_model_gradient_matches_fd(Strauss, wi, wo, p0, rel=1e-6, abs=1e-10,
                                     objective=eval_cos_and_pdf)


def test_extreme_parameters_finite():
    """smoothness 0 and 1 (exponent capped at 1e6), metalness and colour at 0 and 1."""
    WI, WO = checks.hard_case_directions()
    grid = [(0.0, 0.0, 1.0), (1.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 1.0, 1.0), (0.5, 0.5, 0.5)]
    P = {k: np.array([g[i] for g in grid]) for i, k in
         enumerate(("color", "smoothness", "metalness"))}
    for dt in (jnp.float64, jnp.float32):
        wi, wo = jnp.asarray(WI, dt), jnp.asarray(WO, dt)
        out = values_pdfs_grads(Strauss, {k: jnp.asarray(v, dt) for k, v in P.items()}, wi, wo)
        assert_finite(out, str(dt))
        assert np.all(np.asarray(out[0]) >= 0) and np.all(np.asarray(out[1]) >= 0)
        for s in (0.0, 1.0):
            assert_sampling_finite(astype(Strauss(color=0.5, smoothness=s, metalness=0.5), dt), dt,
                                   failed_weight_zero=False)
    assert float(Strauss(smoothness=1.0).exponent()) == pytest.approx(1e6)


def test_parameter_errors_name_the_parameter():
    for bad, name in (({"smoothness": 1.2}, "smoothness"), ({"metalness": -0.1}, "metalness"),
                      ({"transparency": 2.0}, "transparency"), ({"color": -0.5}, "color")):
        with pytest.raises(ParameterError, match=f"'{name}'"):
            Strauss(**bad)
    with pytest.raises(ParameterError, match="'smoothness'"):
        registry.get("strauss").build(smoothness=-1.0)
    with pytest.raises(ParameterError, match="kf and ks"):
        Strauss(ks=0.9)
