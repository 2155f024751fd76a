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


def _lambert_residual(data, rho):
    """Physical Jacobian and residual of the log metric at a Lambert rho (NumPy, by hand: the
    model is rho/pi, so d log(f)/d rho = 1/rho)."""
    r = (np.log(rho / np.pi) - np.log(np.asarray(data.value))).reshape(-1)
    J = np.full((r.size, 1), 1.0 / rho)
    return J, r


def test_a_bound_the_loss_leaves_inward_is_not_an_optimum():
    """The Karush-Kuhn-Tucker sign test, on its own: rho held on its upper bound while the data
    want 0.5 is no optimum (the loss falls inward); at 1 for data wanting 1.2 it is."""
    from brdf_fit.fitting import bounds
    from brdf_fit.fitting.problem import ParamLayout, model_source

    layout = ParamLayout.of(model_source("lambert"), ["rho"], [(1,)])
    for albedo, optimum in ((0.5, False), (1.2, True)):
        J, r = _lambert_residual(_lambert_data(albedo), 1.0)
        assert bounds.inward_gradient_free(layout, np.array([1.0]), J, r) is optimum
        released = bounds.release_inward(layout, np.array([bounds.PLATEAU_U]), [1.0], J, r)
        assert (released is None) is optimum


def test_a_fit_held_on_a_bound_the_loss_leaves_inward_is_released():
    """Started on its upper bound, rho cannot leave the logistic's plateau by itself (its
    gradient there is ~1e-9), but the data want 0.5: the sign test fails, the entry is released
    just inside its bound (bounds.release_inward) and the fit goes on to 0.5 (before: "did not
    converge" at rho = 1)."""
    r = fit(_lambert_data(0.5), "lambert", init={"rho": 1.0})
    assert r.converged, r.message
    assert abs(float(np.ravel(r.params["rho"])[0]) - 0.5) < 0.01
    free = fit(_lambert_data(0.5), "lambert")
    assert free.converged
    np.testing.assert_allclose(np.ravel(r.params["rho"]), np.ravel(free.params["rho"]), rtol=1e-8)


def test_a_default_start_on_a_bound_does_not_stall_there():
    """gltf-pbr-specular starts at its default specular_factor 1, the end of its interval,
    where the logistic's slope is ~1e-9: the solver's own test passed at once in that entry, and
    the fit said "converged" at specular_factor 1 and roughness 0.378 for data made with 0.7 and
    0.35 (loss 0.036, where 0 is reachable). The sign test now runs on a converged fit too: the
    loss pulls specular_factor inward, it is released, and the fit reaches the values set."""
    from brdf_fit import registry
    from data_synth.plans import four_axis

    plan = four_axis(theta_i_deg=(0, 20, 40, 60, 80), theta_o_deg=tuple(range(0, 81, 10)),
                     phi_o_deg=tuple(range(0, 360, 30)))
    wi, wo = np.asarray(plan.wi), np.asarray(plan.wo)
    truth = {"base_color": np.array([0.7, 0.3, 0.1]), "metallic": 0.0, "roughness": 0.35,
             "specular_factor": 0.7, "specular_color": np.array([0.9, 0.8, 0.7])}
    value = np.asarray(registry.get("gltf-pbr-specular").build(**truth).eval(wi, wo))
    r = fit(GonioData(wi=wi, wo=wo, value=value, channels=("R", "G", "B")),
            "gltf-pbr-specular")
    assert r.converged, r.message
    assert r.loss < 1e-20, r.loss
    np.testing.assert_allclose(r.params["roughness"], 0.35, rtol=1e-9)
    np.testing.assert_allclose(r.params["specular_factor"], 0.7, rtol=1e-6)
