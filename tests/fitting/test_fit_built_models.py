"""Fitting built models (issue 14): ``fit`` and ``fit_batch`` take any AbstractBRDF pytree, its
floating-point leaves named by attribute path; ``free=`` selects a subset; the flat layout
(:class:`ParamLayout`) and the model source (:class:`TemplateSource`) on their own.

Cost: three fit() calls and one fit_batch() call compile (~10 s each on the 2-core VM); every
other test here runs no solver."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import brdf_fit
from brdf_fit import Lambert, MicrofacetBRDF, Mixture, registry
from brdf_fit.core.fresnel import SchlickFresnel
from brdf_fit.core.microfacet import GGX, SmithHeightCorrelated
from brdf_fit.fitting.batch import fit_batch
from brdf_fit.fitting.problem import (
    FitError,
    FitProblem,
    ParamLayout,
    TemplateSource,
    Transform,
    model_source,
)
from brdf_fit.io import write
from brdf_fit.models import AbstractBRDF
from data_synth.recipes import synthesize

ALPHA, F0 = 0.2, [0.9, 0.6, 0.3]
RHO, ALPHA_MIX, F0_MIX = [0.3, 0.2, 0.1], 0.15, 0.05


def ggx_template():
    return MicrofacetBRDF(GGX(0.4), SmithHeightCorrelated(), SchlickFresnel(f0=[0.5, 0.5, 0.5]))


def mixture_template():
    lobe = MicrofacetBRDF(GGX(0.4), SmithHeightCorrelated(), SchlickFresnel(f0=0.04))
    return Mixture((Lambert(jnp.asarray([0.5, 0.5, 0.5])), lobe))


def csv_of(tmp_path, model, params, n=150, seed=3):
    """Noise-free data of registry ``model`` (data_synth), written to CSV and read back."""
    data = synthesize({"model": model, "params": params, "seed": seed,
                       "plan": {"name": "random_sparse",
                                "args": {"n": n, "max_zenith_deg": 80.0}}})
    path = tmp_path / f"{model}.csv"
    write(data, path)
    return brdf_fit.read(path)


def test_fit_built_microfacet_model_from_csv(tmp_path):
    data = csv_of(tmp_path, "ggx", {"alpha": ALPHA, "f0": F0})
    r = brdf_fit.fit(data, ggx_template())
    # every floating-point leaf is free (alpha_y is None: not a parameter), keyed by path
    assert list(r.params) == ["distribution.alpha_x", "fresnel.f0", "fresnel.f90"]
    assert set(r.stderr) == set(r.params) and r.n_params == 5
    np.testing.assert_allclose(r.params["distribution.alpha_x"], ALPHA, rtol=1e-4)
    assert r.params["fresnel.f0"].shape == (3,)  # the channel axis is kept
    np.testing.assert_allclose(r.params["fresnel.f0"], F0, rtol=1e-3)
    # FitResult.model is the template with the fitted values put back
    m = r.model
    assert isinstance(m, MicrofacetBRDF) and isinstance(m.distribution, GGX)
    assert m.distribution.alpha_y is None
    np.testing.assert_allclose(m.distribution.alpha_x, r.params["distribution.alpha_x"])
    np.testing.assert_allclose(m.fresnel.f0, r.params["fresnel.f0"])
    v = np.asarray(m.eval(jnp.asarray(data.wi), jnp.asarray(data.wo)))
    np.testing.assert_allclose(v, data.value, rtol=1e-3)
    assert r.model_name == "MicrofacetBRDF" and r.to_dict()["params"]["fresnel.f0"]


def test_fit_built_mixture(tmp_path):
    """A Mixture of Lambert and a microfacet lobe: the tuple's entries are path components."""
    data = csv_of(tmp_path, "ggx-plastic", {"rho_d": RHO, "alpha": ALPHA_MIX, "f0": F0_MIX})
    r = brdf_fit.fit(data, mixture_template(),
                     free=("lobes.0", "lobes.1.distribution", "lobes.1.fresnel.f0"))
    assert set(r.stderr) == {"lobes.0.rho", "lobes.1.distribution.alpha_x", "lobes.1.fresnel.f0"}
    assert r.fixed == {"lobes.1.fresnel.f90": 1.0}
    np.testing.assert_allclose(r.params["lobes.1.distribution.alpha_x"], ALPHA_MIX, rtol=1e-4)
    np.testing.assert_allclose(r.params["lobes.0.rho"], RHO, rtol=1e-4)
    np.testing.assert_allclose(r.params["lobes.1.fresnel.f0"], F0_MIX, rtol=1e-3)
    np.testing.assert_allclose(r.model.lobes[0].rho, r.params["lobes.0.rho"])


def test_free_subset_keeps_the_other_leaves(tmp_path):
    """free= names a subset: the other leaves stay at the template's values, exactly."""
    data = csv_of(tmp_path, "ggx", {"alpha": ALPHA, "f0": F0}, n=100)
    tmpl = MicrofacetBRDF(GGX(0.4), SmithHeightCorrelated(), SchlickFresnel(f0=jnp.asarray(F0)))
    r = brdf_fit.fit(data, tmpl, free=["distribution.alpha_x"])
    assert r.n_params == 1 and set(r.stderr) == {"distribution.alpha_x"}
    assert set(r.fixed) == {"fresnel.f0", "fresnel.f90"}
    np.testing.assert_array_equal(r.params["fresnel.f0"], F0)
    np.testing.assert_array_equal(r.model.fresnel.f0, F0)
    assert float(r.model.fresnel.f90) == 1.0
    np.testing.assert_allclose(r.params["distribution.alpha_x"], ALPHA, rtol=1e-4)


def test_fit_batch_built_model():
    """fit_batch takes a built model as the template of every problem."""
    alphas = np.array([0.2, 0.1, 0.35])
    f0s = np.array([F0, [0.5, 0.5, 0.5], [0.95, 0.9, 0.2]])
    wi, wo, v = [], [], []
    for k, (a, f0) in enumerate(zip(alphas, f0s, strict=True)):
        d = synthesize({"model": "ggx", "params": {"alpha": a, "f0": f0}, "seed": k,
                        "plan": {"name": "random_sparse", "args": {"n": 100}}})
        wi.append(d.wi), wo.append(d.wo), v.append(d.value)
    r = fit_batch(np.stack(wi), np.stack(wo), np.stack(v), ggx_template(),
                  free=("distribution", "fresnel.f0"))
    assert r.converged.all() and r.model_name == "MicrofacetBRDF"
    assert set(r.stderr) == {"distribution.alpha_x", "fresnel.f0"}
    assert r.params["fresnel.f0"].shape == (3, 3)
    np.testing.assert_array_equal(r.params["fresnel.f90"], 1.0)
    np.testing.assert_allclose(r.params["distribution.alpha_x"], alphas, rtol=1e-4)
    np.testing.assert_allclose(r.params["fresnel.f0"], f0s, rtol=1e-4)
    m = r.model(2)  # the fitted model of problem 2
    np.testing.assert_allclose(m.distribution.alpha_x, r.params["distribution.alpha_x"][2])
    assert r.to_dict()["params"]["distribution.alpha_x"]


# --------------------------------------------------------------------------- errors (no solve)


@pytest.fixture(scope="module")
def tiny():
    data = synthesize({"model": "ggx", "params": {"alpha": ALPHA, "f0": F0}, "seed": 0,
                       "plan": {"name": "random_sparse", "args": {"n": 8}}})
    return data


def test_bad_free_path_is_named(tiny):
    with pytest.raises(FitError, match=r"unknown parameter 'distribution\.alpah_x'.*did you "
                                       r"mean distribution\.alpha_x.*valid parameters: "
                                       r"distribution\.alpha_x, fresnel\.f0, fresnel\.f90"):
        brdf_fit.fit(tiny, ggx_template(), free=("distribution.alpah_x",))
    with pytest.raises(FitError, match=r"'distribution\.alpha_y' \(the model has None there"):
        brdf_fit.fit(tiny, ggx_template(), free=("distribution.alpha_y",))
    with pytest.raises(FitError, match="unknown parameter 'roughness'"):
        brdf_fit.fit(tiny, ggx_template(), init={"roughness": 0.3})
    with pytest.raises(FitError, match="both fixed"):
        brdf_fit.fit(tiny, ggx_template(), fix={"fresnel.f0": 0.5}, free=("fresnel",))
    with pytest.raises(FitError, match="bounds= applies to built models"):
        brdf_fit.fit(tiny, "ggx", bounds={"alpha": (0.0, 0.5)})
    with pytest.raises(FitError, match="unknown bounds 'fresnel.f1'"):
        TemplateSource(ggx_template(), bounds={"fresnel.f1": (0.0, 1.0)})
    with pytest.raises(FitError, match="registry name or a built model"):
        brdf_fit.fit(tiny, 3.0)
    with pytest.raises(ValueError, match="unknown parameter 'alpha_x'"):  # registry: unchanged
        brdf_fit.fit(tiny, "ggx", free=("alpha_x",))


# --------------------------------------------------------------------------- the abstraction


class _Const(AbstractBRDF):
    """A component that declares no interval (a user's own model)."""

    value: object = 0.5
    label: str = eqx.field(static=True, default="a")

    def eval(self, wi, wo):
        return self.value * jnp.ones(wi.shape[:-1])

    def pdf(self, wi, wo):  # pragma: no cover - not sampled here
        return jnp.zeros(wi.shape[:-1])

    def sample(self, wo, uc, u):  # pragma: no cover
        raise NotImplementedError


def test_template_source_paths_intervals_and_key():
    src = TemplateSource(mixture_template())
    assert src.names == ("lobes.0.rho", "lobes.1.distribution.alpha_x", "lobes.1.fresnel.f0",
                         "lobes.1.fresnel.f90")
    assert src.param("lobes.0.rho").shape == (3,)
    assert src.match("lobes.1.fresnel") == ("lobes.1.fresnel.f0", "lobes.1.fresnel.f90")
    # an undeclared leaf is unbounded unless bounds= gives it an interval
    assert TemplateSource(_Const()).param("value").transform == Transform(None, None)
    b = TemplateSource(_Const(), bounds={"value": (0.0, None)})
    assert b.param("value").transform == Transform(0.0, None)
    # the compiled-solver cache key: equal for the same structure with other values, not for
    # another static field or another structure
    assert TemplateSource(_Const(0.7)).key == TemplateSource(_Const(0.5)).key
    assert TemplateSource(_Const(label="b")).key != TemplateSource(_Const()).key
    assert TemplateSource(ggx_template()).key != TemplateSource(mixture_template()).key
    # build puts values back by path; the template is unchanged
    m = src.build({"lobes.1.distribution.alpha_x": jnp.asarray(0.3)})
    assert float(m.lobes[1].distribution.alpha_x) == 0.3
    assert mixture_template().lobes[1].distribution.alpha_x == 0.4
    assert model_source("ggx").names == ("alpha", "f0")


def test_param_layout_round_trip():
    prob = FitProblem.of(ggx_template(), free=("fresnel.f0", "distribution.alpha_x"))
    lay = prob.layout
    assert isinstance(lay, ParamLayout) and hash(lay) == hash(prob.layout)
    assert lay.names == ("fresnel.f0", "distribution.alpha_x")
    assert lay.slices == (slice(0, 3), slice(3, 4)) and lay.size == 4
    assert lay.channel_index(3).tolist() == [0, 1, 2, -1]
    assert lay.structured(3) == (True, False) and lay.structured(1) == (False, False)
    assert lay.mask(["distribution.alpha_x"]).tolist() == [False, False, False, True]
    values = {"fresnel.f0": np.array([[0.2, 0.4, 0.6]] * 2), "distribution.alpha_x":
              np.array([0.1, 0.3])}
    u = lay.inverse(values, lead=(2,))
    assert u.shape == (2, 4)
    back = lay.forward(lay.split(jnp.asarray(u)))
    for k, v in values.items():
        np.testing.assert_allclose(back[k], v, rtol=1e-12)
    np.testing.assert_array_equal(lay.join(lay.split(jnp.asarray(u))), u)
    # the registry problem has the same layout machinery, by registry name
    reg = FitProblem.of(registry.get("ggx"), n_channels=3)
    assert reg.layout.names == ("alpha", "f0") and reg.layout.shapes == ((), (3,))
    assert reg.layout.channel_index(3).tolist() == [-1, 0, 1, 2]
