"""Beard-Maxwell / NEF (brdf_fit.models.beard_maxwell) against an independent NumPy evaluation in
spherical angles (``acos``, complex-arithmetic Fresnel of ``n - ik``), closed-form albedos of
the volume terms, the normal-incidence calibration by quadrature, and finite differences."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import assert_model_gradient_matches_fd, dir_from_cos
from _helpers import eval_jit as _eval
from _helpers import random_dirs as _random_dirs

from brdf_fit import registry
from brdf_fit.core.validate import ParameterError
from brdf_fit.models.beard_maxwell import BeardMaxwell, calibrate_b
from brdf_fit.verify import checks

P = dict(b=3.0, sigma=0.15, tau=0.2, omega=0.5, eta=[1.65, 1.5, 0.3], k=[0.0, 0.4, 3.0],
         rho_d=[0.05, 0.1, 0.0], rho_v=[0.02, 0.0, 0.05])


def model(p, **kw):
    return BeardMaxwell(**{k: jnp.asarray(v) for k, v in p.items()}, **kw)


def random_dirs(rng, n, lo=1e-2):
    return _random_dirs(rng, n, lo)


def fresnel_complex(c, n, k):
    """Unpolarised Fresnel reflectance of the index n - ik by complex Snell's law."""
    m = n - 1j * k
    cos_t = np.sqrt(1 - (1 - c * c) / (m * m))
    rs = (c - m * cos_t) / (c + m * cos_t)
    rp = (m * c - cos_t) / (m * c + cos_t)
    return 0.5 * (abs(rs) ** 2 + abs(rp) ** 2)


def reference(wi, wo, p, form="gaussian"):
    h = (wi + wo) / np.linalg.norm(wi + wo)
    theta_n = math.acos(min(h[2], 1.0))
    beta = math.acos(min(wi @ h, 1.0))
    ci, co = wi[2], wo[2]
    if form == "gaussian":
        rho_fs = p["b"] * math.exp(-(theta_n / p["sigma"]) ** 2)
    else:
        rho_fs = p["b"] / (4 * math.cos(theta_n) ** 3 * (p["sigma"] ** 2 + math.tan(theta_n) ** 2))
    so = ((1 + theta_n / p["omega"] * math.exp(-2 * beta / p["tau"]))
          / (1 + theta_n / p["omega"]))
    out = []
    for c in range(3):
        n, k = p["eta"][c], p["k"][c]
        ratio = fresnel_complex(math.cos(beta), n, k) / fresnel_complex(1.0, n, k)
        fs = ratio * rho_fs * math.cos(theta_n) ** 2 / (ci * co) * so
        out.append(fs + p["rho_d"][c] + 2 * p["rho_v"][c] / (ci + co))
    return np.asarray(out)


@pytest.mark.parametrize("form", ["gaussian", "lorentzian"])
def test_matches_independent_reference(form):
    rng = np.random.default_rng(3)
    wi, wo = random_dirs(rng, 300), random_dirs(rng, 300)
    got = np.asarray(_eval(model(P, fs_form=form), jnp.asarray(wi), jnp.asarray(wo)))
    want = np.stack([reference(a, b, P, form) for a, b in zip(wi, wo, strict=True)])
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=0)


def test_reciprocal_and_finite_at_retro_and_normal():
    m = model(P)
    rng = np.random.default_rng(4)
    wi, wo = jnp.asarray(random_dirs(rng, 200, 1e-4)), jnp.asarray(random_dirs(rng, 200, 1e-4))
    np.testing.assert_allclose(_eval(m, wi, wo), _eval(m, wo, wi), rtol=1e-12)
    n = jnp.asarray([[0.0, 0.0, 1.0], [0.3, 0.4, math.sqrt(0.75)]])

    def total(p):
        mm = model(p)
        return jnp.sum(mm.eval(n, n)) + jnp.sum(mm.pdf(n, n))

    g = jax.jit(jax.grad(total))({k: jnp.asarray(v) for k, v in P.items()})
    for k, v in g.items():
        assert np.all(np.isfinite(np.asarray(v))), k


def test_volume_albedo_closed_form():
    """B = 0: E(v) = pi rho_D + 4 pi rho_V [1 - cv ln(1 + 1/cv)] (models.md 4.5, item 6)."""
    m = model({**P, "b": 0.0})
    for cv in (1.0, 0.5, 0.05):
        wo = dir_from_cos(cv)
        want = (math.pi * np.asarray(P["rho_d"])
                + 4 * math.pi * np.asarray(P["rho_v"]) * (1 - cv * math.log(1 + 1 / cv)))
        np.testing.assert_allclose(checks.directional_albedo(m, wo), want, rtol=1e-7)


def test_normal_incidence_calibration_by_quadrature():
    """The 1D rule of first_surface_albedo_normal against the checks' 2D lobe-adapted quadrature,
    and calibrate_b reproducing a declared DHR."""
    p = {**P, "rho_d": [0.0] * 3, "rho_v": [0.0] * 3}
    m = model(p)
    one_d = np.asarray(m.first_surface_albedo_normal())
    two_d = checks.directional_albedo(m, np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(one_d, two_d, rtol=1e-7)
    kw = {k: jnp.asarray(v) for k, v in p.items() if k != "b"}
    b = calibrate_b(0.04, **kw)
    np.testing.assert_allclose(BeardMaxwell(b=b[1], **kw).first_surface_albedo_normal()[1], 0.04,
                               rtol=1e-12)


def test_gradients_match_finite_differences_lorentzian():
    rng = np.random.default_rng(6)
    wi, wo = jnp.asarray(random_dirs(rng, 8, 0.1)), jnp.asarray(random_dirs(rng, 8, 0.1))
    p0 = {k: np.asarray(v, float) for k, v in P.items()}
    p0["k"] = np.asarray([0.1, 0.4, 3.0])
    assert_model_gradient_matches_fd(lambda **p: model(p, fs_form="lorentzian"), wi, wo, p0,
                                     rel=1e-6, abs=1e-9, relative_step=True)


def test_bad_parameters_are_named():
    entry = registry.get("beard-maxwell")
    for bad, name in [({"b": -1.0}, "'b'"), ({"sigma": 0.0}, "sigma"), ({"tau": -0.1}, "tau"),
                      ({"omega": 0.0}, "omega"), ({"eta": [1.5, 0.0, 1.5]}, "eta"),
                      ({"rho_d": [0.1, 0.5, 0.1]}, "rho_d"), ({"rho_v": [-0.1, 0, 0]}, "rho_v"),
                      ({"sigma": [0.1, 0.2]}, "sigma")]:
        with pytest.raises(ParameterError, match=name):
            entry.build(**bad)
    with pytest.raises(ParameterError, match="fs_form"):
        BeardMaxwell(fs_form="cauchy")


def test_registry_metadata_and_declared_energy_failure():
    e = registry.get("beard-maxwell")
    assert e.year == 1973 and e.catalogue == "Beard-Maxwell" and e.sampler
    assert "energy" in e.expected_failures
