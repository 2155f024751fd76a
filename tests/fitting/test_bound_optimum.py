"""A dense fit whose optimum lies on a parameter's bound converges there (fitting.single's
``_converged_at_bounds``): the parameter approaches its bound along the logistic's plateau by a
constant step in the unconstrained variable, so optimistix's step test never passed and such a
fit (a dielectric's metallic = 0, an albedo pushed to 1) ran its 256 steps and said "did not
converge". A parameter held on a bound while the loss would fall by moving it inward is no
optimum and stays not converged."""

from __future__ import annotations

import jax
import numpy as np

from brdf_fit.data import GonioData
from brdf_fit.fitting.single import fit

jax.config.update("jax_enable_x64", True)


def _lambert_data(albedo, seed=0, n=300):
    rng = np.random.default_rng(seed)

    def dirs():
        mu = rng.uniform(0.05, 1.0, n)
        phi = rng.uniform(0.0, 2.0 * np.pi, n)
        s = np.sqrt(1.0 - mu * mu)
        return np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)

    wi, wo = dirs(), dirs()
    value = np.full((n, 1), albedo / np.pi) * (1.0 + 0.01 * rng.standard_normal((n, 1)))
    return GonioData(wi=wi, wo=wo, value=value)


def test_an_optimum_on_the_bound_converges():
    """Data 1.2 times a white Lambertian: the best rho in [0, 1] is 1 (before: not converged
    after 256 steps)."""
    r = fit(_lambert_data(1.2), "lambert")
    assert r.converged, r.message
    assert r.at_bound == ("rho",)
    assert float(r.params["rho"][0]) == 1.0


def test_a_bound_the_loss_leaves_inward_is_not_an_optimum():
    """Started on its upper bound, rho cannot leave the logistic's plateau (its gradient there
    is ~1e-9), but the data want 0.5: the loss falls inward, so the fit is not converged (the
    Karush-Kuhn-Tucker sign test), and says so."""
    r = fit(_lambert_data(0.5), "lambert", init={"rho": 1.0})
    assert not r.converged
    assert "did not converge" in r.message
    free = fit(_lambert_data(0.5), "lambert")
    assert free.converged and abs(float(free.params["rho"][0]) - 0.5) < 0.01
