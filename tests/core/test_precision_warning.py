"""Defect 3 of issue 16: a microfacet alpha below ALPHA_MIN is clamped by the models; building
one through the registry says so (PrecisionWarning), the CLI prints it as one line."""

import warnings

import numpy as np
import pytest

from brdf_fit import registry
from brdf_fit.cli import main
from brdf_fit.core.numerics import ALPHA_MIN
from brdf_fit.core.validate import PrecisionWarning


@pytest.mark.parametrize("name, param", [("ggx", "alpha"), ("beckmann", "alpha"),
                                         ("cook-torrance", "alpha"), ("ggx-aniso", "alpha_y")])
def test_alpha_below_the_clamp_warns_and_is_evaluated_at_the_clamp(name, param):
    e = registry.get(name)
    with pytest.warns(PrecisionWarning, match=f"{name}: {param} = 1e-06 is below 0.0001"):
        tiny = e.build(**{param: 1e-6})
    at = e.build(**{param: ALPHA_MIN})  # at the clamp: no warning (warnings are errors here)
    wi = np.array([[0.3, 0.1, np.sqrt(0.9)]])
    wo = np.array([[-0.3, -0.1, np.sqrt(0.9)]])
    np.testing.assert_array_equal(np.asarray(tiny.eval(wi, wo)), np.asarray(at.eval(wi, wo)))


def test_cli_prints_the_clamp_as_one_line(capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        assert main(["eval", "ggx", "--param", "alpha=1e-6"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [e for e in err if e.startswith("brdf-fit: warning: ggx: alpha = 1e-06")]
    assert len(err) == 1


def test_float32_albedo_warns_and_float64_does_not():
    import jax.numpy as jnp

    from brdf_fit import astype
    from brdf_fit.verify.albedo import directional_albedo

    m = registry.get("ggx").build()
    wo = np.array([0.0, 0.6, 0.8])
    with pytest.warns(PrecisionWarning, match="directional_albedo in float32"):
        e32 = directional_albedo(astype(m, jnp.float32), jnp.asarray(wo, jnp.float32))
    e64 = directional_albedo(m, wo)  # no warning (warnings are errors here)
    assert abs(float(e32[0]) - float(e64[0])) < 1e-3


def test_a_float32_fit_says_so():
    """Without x64 a fit runs in float32 (the README's gold fit from a neutral start failed
    there and converges in float64): fit warns, naming the switch."""
    import jax

    from brdf_fit.fitting.single import fit
    from data_synth.recipes import synthesize

    data = synthesize({"model": "lambert", "params": {"rho": [0.5, 0.4, 0.3]}, "seed": 1,
                       "plan": {"name": "in_plane", "args": {"theta_i_deg": [0, 30],
                                                             "theta_o_deg": [-30, 0, 30]}}})
    with jax.enable_x64(False), pytest.warns(PrecisionWarning, match="jax_enable_x64 is off"):
        r = fit(data, "lambert")
    assert np.asarray(r.params["rho"]).dtype == np.float32
