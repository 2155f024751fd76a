"""Albedo and average-albedo tables of registry models: the model path (MicrofacetBRDF through
verify.albedo) against the DFG generator's own integrand, E_avg against Blender Cycles'
published table and exact values, grids over several parameters, and errors before work."""

import numpy as np
import pytest

from brdf_fit.tables.albedo import albedo_table, average_table, parse_axis
from brdf_fit.tables.dfg import dfg_values


def test_ggx_albedo_table_equals_the_dfg_integrand():
    """E of registry 'ggx' with F = 1 (the registry model, its D, masking and Fresnel code) at
    every node equals A + B of tables.dfg (its own slope-space integrand) on the same rule."""
    t = albedo_table("ggx", {"mu": 4, "alpha": 4}, {"f0": 1.0})
    mu, alpha = t.axes[0].nodes(), t.axes[1].nodes()
    A, B = dfg_values(mu[:, None], alpha[None, :])
    assert t.channels == ("E",) and t.values.shape == (4, 4, 1)
    np.testing.assert_allclose(t.values[..., 0], A + B, rtol=0, atol=1e-12)
    assert t.meta["error_estimate"]["max_abs"] < 1e-7
    # E_avg in the metadata: one value per alpha node, within (0, 1]
    avg = np.asarray(t.meta["E_avg"]["values"]).ravel()
    assert avg.shape == (4,) and np.all((avg > 0) & (avg <= 1))
    assert np.all(np.diff(avg) < 0)  # rougher loses more energy


# Blender Cycles' table_ggx_Eavg (intern/cycles/scene/shader.tables): height-correlated GGX,
# F = 1, r = i/31, alpha = r^2, 6 decimals
CYCLES_GGX_EAVG = {8: 0.985805, 16: 0.870874, 31: 0.409137}


def test_average_matches_cycles_published_table():
    t = average_table("ggx", {"alpha": (2, (8 / 31) ** 2, (16 / 31) ** 2)}, {"f0": 1.0},
                      centres=False)
    u = average_table("ggx", {"alpha": (2, 0.5, 1.0)}, {"f0": 1.0}, centres=False)
    got = [t.values[0, 0], t.values[1, 0], u.values[1, 0]]
    ref = [CYCLES_GGX_EAVG[i] for i in (8, 16, 31)]
    np.testing.assert_allclose(got, ref, rtol=0, atol=1.5e-6)  # 6 decimals + Monte Carlo
    assert t.channels == ("E_avg",)


def test_lambert_average_is_rho_and_three_axes_with_channels():
    """Lambert: E(mu) = rho for every mu, so E_avg = rho exactly (checks the GL weights);
    a three-axis table over a model with RGB output has three channels."""
    t = average_table("lambert", {"rho": (3, 0.2, 0.8)}, centres=False)
    np.testing.assert_allclose(t.values[..., 0], [0.2, 0.5, 0.8], rtol=1e-13)
    c = albedo_table("cook-torrance", {"mu": 2, "alpha": 2, "eta": (2, 1.3, 2.0)},
                     error_estimate=False)
    assert c.values.shape[:3] == (2, 2, 2) and c.axes[2].name == "eta"
    assert np.all((c.values > 0) & (c.values < 1))
    # a larger index of refraction reflects more
    assert np.all(c.values[:, :, 1] > c.values[:, :, 0])


@pytest.mark.parametrize("args, fragment", [
    (("ggx", {"alpha": 4}), "'mu' axis"),
    (("ggx", {"mu": 4, "beta": 4}), "unknown parameter 'beta'"),
    (("cook-torrance", {"mu": 4, "eta": 4}), "finite range"),
    (("ggx", {"mu": 4, "alpha": (4, 0.5, 0.2)}), "lo < hi"),
    (("ggx", {"mu": (4, 0.0, 1.5)}), "[0, 1]"),
])
def test_bad_requests_are_refused_before_work(args, fragment):
    with pytest.raises((ValueError, KeyError), match=None) as e:
        albedo_table(*args)
    assert fragment in str(e.value)


def test_parse_axis():
    assert parse_axis("alpha=64") == ("alpha", 64)
    assert parse_axis("eta=8:1.0:3.0") == ("eta", (8, 1.0, 3.0))
    for bad in ("alpha", "alpha=x", "alpha=4:1"):
        with pytest.raises(ValueError, match="NAME=N"):
            parse_axis(bad)


@pytest.mark.parametrize("model, axes, params", [
    # eta (a channel parameter) as the last, then the middle axis; endpoints include eta < 1
    # (2 x 2 x 2 texels: the texel-by-texel path costs per texel, 22 s with 3 x 2 x 3)
    ("cook-torrance", {"mu": 2, "alpha": (2, 0.05, 0.9), "eta": (2, 0.7, 2.5)}, None),
    # the same with eta as the middle axis: 17 s, in the slow set (the suite's time budget)
    pytest.param("cook-torrance", {"mu": 2, "eta": (3, 1.2, 2.0), "alpha": (2, 0.2, 0.6)}, None,
                 marks=pytest.mark.slow),
    # a Schlick f0 channel axis: 15 s, in the slow set (the cook-torrance eta case above runs)
    pytest.param("ggx", {"mu": 2, "f0": (3, 0.02, 0.9), "alpha": (2, 0.1, 1.0)}, None,
                 marks=pytest.mark.slow),
])
def test_channel_axis_equals_texel_by_texel(model, axes, params):
    """A channel-parameter axis computed as the model's channels (one rule per texel for every
    value) gives the table, E_avg and error estimate of the texel-by-texel path."""
    a = albedo_table(model, axes, params, centres=False)
    b = albedo_table(model, axes, params, centres=False, channel_axes=False)
    assert a.meta["channel_axis"] in ("eta", "f0") and b.meta["channel_axis"] is None
    assert a.values.shape == b.values.shape and a.channels == b.channels == ("E",)
    np.testing.assert_allclose(a.values, b.values, rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(a.meta["E_avg"]["values"]),
                               np.asarray(b.meta["E_avg"]["values"]), rtol=0, atol=1e-14)
    assert abs(a.meta["error_estimate"]["max_abs"] - b.meta["error_estimate"]["max_abs"]) < 1e-14
    avg = average_table(model, {k: v for k, v in axes.items() if k != "mu"}, params,
                        centres=False)
    np.testing.assert_allclose(avg.values, np.asarray(a.meta["E_avg"]["values"]), rtol=0,
                               atol=1e-14)


def test_rgb_model_keeps_its_channels():
    """A model with RGB output (ggx's default f0) computes an f0-free axis texel by texel."""
    t = albedo_table("ggx", {"mu": 2, "alpha": 2}, error_estimate=False)
    assert t.meta["channel_axis"] is None and t.channels == ("E_R", "E_G", "E_B")
