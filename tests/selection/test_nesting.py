"""brdf_fit.selection.nesting: every nesting claim is an identity (the extension with its lobe
off evaluates as its base, at the base's non-default parameters), and the selection rules that
follow from it: an extension never costs less than its base in the choice, and a plain
material (a glTF plastic with noise) is chosen without the sheen or coat lobe the committed
table rates cheaper, each extra lobe's gain reported; the nested F test (lobe_test) is the F test
on linear models, and in a selection it passes over a lobe that fits the noise and keeps one
that is in the data."""

import numpy as np
import pytest
from _helpers import random_dirs

from brdf_fit import registry
from brdf_fit.selection.nesting import (
    LOBE_TEST_ALPHA,
    NESTED,
    base_of,
    choice_costs,
    lobe_gains,
    lobe_test,
    off_params,
)

#: base parameter values away from the defaults (coloured, rough, part metal)
BASE_VALUES = {
    "gltf-pbr": {"base_color": np.array([0.7, 0.2, 0.1]), "metallic": 0.3, "roughness": 0.45},
    "mitsuba-principled": {"base_color": np.array([0.7, 0.2, 0.1]), "roughness": 0.45,
                           "metallic": 0.3, "specular": 0.6},
    "mitsuba-roughconductor": {"alpha": 0.23},
    "mitsuba-roughconductor-beckmann": {"alpha": 0.23},
    "ggx": {"alpha": 0.23, "f0": np.array([0.9, 0.6, 0.3])},
    "ggx-conductor": {"alpha": 0.23},
    "blender-principled": {"base_color": np.array([0.7, 0.2, 0.1]), "roughness": 0.45,
                           "metallic": 0.3, "ior": 1.6},
    "openpbr-surface": {"base_color": np.array([0.7, 0.2, 0.1]), "specular_roughness": 0.45,
                        "base_metalness": 0.3, "specular_ior": 1.6},
}


@pytest.mark.parametrize("name", sorted(NESTED))
def test_extension_with_its_lobe_off_is_its_base(name):
    base = base_of(name)
    rng = np.random.default_rng(11)
    wi, wo = random_dirs(rng, 400, lo=0.02), random_dirs(rng, 400, lo=0.02)
    params = BASE_VALUES[base]
    want = np.asarray(registry.get(base).build(**params).eval(wi, wo))
    got = np.asarray(registry.get(name).build(**off_params(name, params)).eval(wi, wo))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14 * np.abs(want).max())


def test_choice_costs_and_gains():
    costs = {"gltf-pbr": 17.7, "gltf-pbr-sheen": 16.3, "gltf-pbr-clearcoat": 19.0,
             "lambert": 1.0}
    c = choice_costs(costs)
    assert c == {"gltf-pbr": 17.7, "gltf-pbr-sheen": 17.7, "gltf-pbr-clearcoat": 19.0,
                 "lambert": 1.0}
    g = lobe_gains({"gltf-pbr": 0.04, "gltf-pbr-sheen": 0.03, "lambert": 0.5,
                    "gltf-pbr-clearcoat": float("inf")})
    assert set(g) == {"gltf-pbr-sheen"}
    np.testing.assert_allclose([g["gltf-pbr-sheen"]["error_removed"],
                                g["gltf-pbr-sheen"]["fraction_removed"]], [0.01, 0.25])


#: an in-plane instrument of 52 directions (4 incidences x 13 views)
PLASTIC_PLAN = {"name": "in_plane", "args": {"theta_i_deg": [0, 20, 40, 60],
                                             "theta_o_deg": [-75, -60, -45, -30, -15, 0, 10, 20,
                                                             30, 40, 50, 60, 75]}}


@pytest.mark.slow
def test_a_plain_plastic_gets_no_sheen_or_coat_lobe():
    """A glTF plastic (no sheen, no coat) with 1% noise, selected under --target gltf: the
    committed table rates gltf-pbr-sheen cheaper than gltf-pbr (16.3x against 17.7x Lambert),
    and every candidate is within the budget; the choice is the plain model, and the extra
    lobes are reported as removing (almost) nothing."""
    from brdf_fit.selection import select
    from brdf_fit.selection.selector import committed_costs
    from data_synth.recipes import synthesize

    costs = committed_costs()
    assert costs["gltf-pbr-sheen"] < costs["gltf-pbr"]  # what the old rule chose by
    d = synthesize({"model": "gltf-pbr", "seed": 5, "plan": PLASTIC_PLAN,
                    "params": {"base_color": [0.7, 0.05, 0.04], "metallic": 0.0,
                               "roughness": 0.4},
                    "noise": [{"type": "lognormal", "args": {"sigma": 0.01}}]})
    s = select(d, target="gltf", checks=(), anisotropy=False)
    assert s.choice == "gltf-pbr", s.message
    plain = s.candidate("gltf-pbr")
    for name in ("gltf-pbr-sheen", "gltf-pbr-clearcoat", "gltf-pbr-specular"):
        c = s.candidate(name)
        assert c.extends == "gltf-pbr" and c.within_budget
        # a lobe that stands for nothing: under a tenth of the plain model's error removed
        assert c.lobe_gain["fraction_removed"] < 0.1, (name, c.lobe_gain)
        assert c.to_dict()["lobe_gain"] == c.lobe_gain
        assert "supported" not in c.lobe_gain  # the base was the choice: no test was needed
    assert plain.lobe_gain is None and plain.extends is None

    # a budget just below the plain model's error: without the F test the specular or coat
    # extension, a few % better by fitting the noise, would be the choice; the test finds no
    # support for either lobe, and nothing is chosen
    tight = select(d, target="gltf", checks=(), anisotropy=False, budget=0.999 * plain.error)
    tested = [c for c in tight.candidates if c.lobe_gain and "supported" in c.lobe_gain]
    assert tested and tight.choice is None, tight.message
    for c in tested:
        assert c.within_budget and c.lobe_gain["p_value"] >= LOBE_TEST_ALPHA, c.lobe_gain
        assert not c.lobe_gain["supported"] and c.lobe_gain["metric"] == "log / sigma"


@pytest.mark.slow
def test_a_lobe_in_the_data_is_supported():
    """The positive case: a glTF plastic whose specular is scaled down (KHR_materials_specular,
    factor 0.3) with 1% noise; the plain model cannot lower its specular, the extension can. The
    F test supports the lobe overwhelmingly and the extension is the choice."""
    from brdf_fit.selection import select
    from data_synth.recipes import synthesize

    d = synthesize({"model": "gltf-pbr-specular", "seed": 5, "plan": PLASTIC_PLAN,
                    "params": {"base_color": [0.7, 0.05, 0.04], "metallic": 0.0,
                               "roughness": 0.4, "specular_factor": 0.3},
                    "noise": [{"type": "lognormal", "args": {"sigma": 0.01}}]})
    s = select(d, target="gltf", checks=(), anisotropy=False)
    assert s.choice == "gltf-pbr-specular", s.message
    g = s.candidate("gltf-pbr-specular").lobe_gain
    assert g["supported"] and g["p_value"] < 1e-10 and g["df"][0] == 4, g


def test_lobe_test_is_the_f_test_of_nested_linear_models():
    """On nested *linear* least-squares models with Gaussian noise the extra-sum-of-squares
    statistic is exactly F-distributed: under the smaller model (the extra columns' true
    coefficients 0) the p-values are uniform, so the test rejects at its level; with a real
    extra term it rejects almost always. Each p-value is checked against SciPy's F tail."""


    stats = pytest.importorskip("scipy.stats", reason="SciPy is not installed (the test extra)")
    rng = np.random.default_rng(40)
    n, draws = 30, 2000
    x = np.linspace(0.0, 1.0, n)
    base = np.stack([np.ones(n), x], 1)  # k = 2
    ext = np.stack([np.ones(n), x, x * x, np.sin(3 * x)], 1)  # k = 4: two extra scalars

    def rss(X, y):
        beta, *_ = np.linalg.lstsq(X, y, rcond=None)
        return float(np.sum((y - X @ beta) ** 2))

    for extra, want_lo, want_hi in ((0.0, None, None), (3.0, 0.95, 1.0)):
        pvals = []
        for _ in range(draws):
            y = 1.0 + 2.0 * x + extra * x * x + 0.1 * rng.standard_normal(n)
            t = lobe_test(rss(base, y), 2, rss(ext, y), 4, n)
            assert t["df"] == [2, n - 4]
            np.testing.assert_allclose(t["p_value"], stats.f.sf(t["f_statistic"], 2, n - 4),
                                       rtol=1e-6)
            pvals.append(t["p_value"])
        rejected = np.mean(np.array(pvals) < LOBE_TEST_ALPHA)
        if extra == 0.0:
            # uniform p-values: the rejection rate is the level, within 4 binomial sigmas
            sd = np.sqrt(LOBE_TEST_ALPHA * (1 - LOBE_TEST_ALPHA) / draws)
            assert abs(rejected - LOBE_TEST_ALPHA) < 4 * sd, rejected
            assert stats.kstest(pvals, "uniform").pvalue > 1e-3
        else:
            assert want_lo <= rejected <= want_hi, rejected


def test_lobe_test_edge_cases():


    worse = lobe_test(1.0, 2, 1.5, 4, 100)  # the extension fitted worse: no support
    assert worse["p_value"] == 1.0 and not worse["supported"]
    none_left = lobe_test(1.0, 2, 0.5, 4, 4)  # no residual degree of freedom
    assert not none_left["supported"] and none_left["f_statistic"] is None
    exact = lobe_test(1.0, 2, 0.0, 4, 100)  # the extension exact, its base not
    assert exact["supported"] and exact["p_value"] == 0.0 and exact["f_statistic"] is None
    both = lobe_test(0.0, 2, 0.0, 4, 100)  # both exact (noise-free data of the base)
    assert not both["supported"]


@pytest.mark.slow
def test_a_base_that_misses_what_its_extension_finds_gives_way():
    """GGX with alpha_y 1% above alpha_x on a four-axis plan: isotropic ggx misses it by 0.4%,
    inside the 1% budget floor, so the tie-break took the base; noise-free, ggx-aniso removes
    all of that error and its lobe passes the F test, so it is the choice (the rule that brings
    a Cycles-rendered coat back as blender-principled-coat). With 1% noise the anisotropy
    removes under a tenth of the base's error (the base reproduces the data to the noise level)
    and the base stays the choice."""
    from brdf_fit.selection import select
    from brdf_fit.selection.nesting import DECISIVE_FRACTION
    from data_synth.recipes import synthesize

    recipe = {"model": "ggx-aniso", "seed": 5, "plan": {"name": "four_axis", "args": {}},
              "params": {"alpha_x": 0.2, "alpha_y": 0.202, "f0": [0.9, 0.6, 0.3]}}
    exact = select(synthesize(recipe), candidates=["ggx", "ggx-aniso"], checks=(),
                   anisotropy=False)
    base, ext = exact.candidate("ggx"), exact.candidate("ggx-aniso")
    assert base.within_budget and 1e-3 < base.error < exact.budget, base.error
    assert exact.choice == "ggx-aniso", exact.message
    assert ext.lobe_gain["fraction_removed"] >= DECISIVE_FRACTION and ext.lobe_gain["supported"]
    assert "the extra lobe removes" in exact.message
    np.testing.assert_allclose([ext.params["alpha_x"], ext.params["alpha_y"]], [0.2, 0.202],
                               rtol=1e-6)

    noisy = select(synthesize({**recipe, "noise": [{"type": "lognormal",
                                                    "args": {"sigma": 0.01}}]}),
                   candidates=["ggx", "ggx-aniso"], checks=(), anisotropy=False)
    assert noisy.choice == "ggx", noisy.message
    assert noisy.candidate("ggx-aniso").lobe_gain["fraction_removed"] < DECISIVE_FRACTION


#: Mitsuba principled materials (scene-file dicts): a plastic, the same with a clearcoat, a
#: rough blue with sheen, an orange dielectric with tinted specular
MITSUBA_PRINCIPLED = {
    "mitsuba-principled": {"base_color": [0.7, 0.08, 0.05], "roughness": 0.45},
    "mitsuba-principled-clearcoat": {"base_color": [0.7, 0.08, 0.05], "roughness": 0.6,
                                     "clearcoat": 0.8, "clearcoat_gloss": 0.7},
    "mitsuba-principled-sheen": {"base_color": [0.1, 0.2, 0.6], "roughness": 0.7,
                                 "sheen": 0.8},
    "mitsuba-principled-tinted": {"base_color": [0.8, 0.4, 0.1], "roughness": 0.35,
                                  "specular": 0.6, "spec_tint": 0.6},
}


@pytest.mark.slow
@pytest.mark.parametrize("entry", sorted(MITSUBA_PRINCIPLED))
def test_mitsuba_rendered_principled_comes_back_with_its_lobe(entry):
    """Data rendered by Mitsuba 3 itself (its ``principled``, ``BSDF.eval`` on a four-axis plan,
    noise-free) selected for Mitsuba among the principled base and its three extensions: a
    clearcoated, sheened or tinted material comes back as the entry with that lobe or tint, with
    the values set, and the plastic as the base (issue 40: there was no such Mitsuba entry, so
    a clearcoat came back as the base, error 0.175)."""
    pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (the test extra has it)")
    from brdf_fit.convert.mitsuba import mitsuba_eval
    from brdf_fit.data import GonioData
    from brdf_fit.selection import select
    from data_synth.plans import four_axis

    values = MITSUBA_PRINCIPLED[entry]
    scene = {"type": "principled", **values,
             "base_color": {"type": "rgb", "value": values["base_color"]}}
    wi, wo = four_axis()
    d = GonioData(wi, wo, mitsuba_eval(scene, wi, wo), channels=("R", "G", "B"))
    s = select(d, candidates=sorted(MITSUBA_PRINCIPLED), target="mitsuba", checks=(),
               anisotropy=False)
    assert s.choice == entry, s.message
    chosen = s.candidate(entry)
    # Mitsuba evaluates in float32: the fit reproduces its values to 1e-5 (measured 8.7e-6
    # with the clearcoat's GTR1 peak, 7e-8 and 3e-7 without it)
    assert chosen.error < 2e-5, chosen.error
    for name, want in values.items():
        np.testing.assert_allclose(chosen.params[name], want, rtol=2e-3, atol=2e-3,
                                   err_msg=name)
    if entry != "mitsuba-principled":
        assert chosen.lobe_gain["supported"], chosen.lobe_gain
        assert s.candidate("mitsuba-principled").error > 100 * chosen.error


@pytest.mark.slow
def test_with_noise_an_extension_that_reproduces_the_data_is_chosen():
    """2% noise: a Mitsuba principled dielectric with its specular tinted (spec_tint 0.9) is
    missed by the base (3.5%, within the budget of twice the best error but above 1.5 x the
    noise level), and the tinted entry reproduces it (1.8%). The noise bounds the share of the
    base's error any model removes (here under half, below DECISIVE_FRACTION), so the
    extension is taken because it reproduces the data itself and its lobe passes the F test;
    not the sheen or clearcoat, which take part of the tint's misfit. The same material
    untinted keeps the base."""
    from brdf_fit.selection import select
    from brdf_fit.selection.nesting import DECISIVE_FRACTION, reproduced_level
    from data_synth.recipes import synthesize

    def selection(tint):
        d = synthesize({"model": "mitsuba-principled-tinted", "seed": 5,
                        "plan": {"name": "four_axis", "args": {}},
                        "params": {"base_color": [0.8, 0.4, 0.1], "roughness": 0.35,
                                   "specular": 0.8, "spec_tint": tint},
                        "noise": [{"type": "lognormal", "args": {"sigma": 0.02}}]})
        return select(d, candidates=sorted(MITSUBA_PRINCIPLED), checks=(), anisotropy=False)

    s = selection(0.9)
    base, ext = s.candidate("mitsuba-principled"), s.candidate("mitsuba-principled-tinted")
    level = reproduced_level(s.noise_level)
    assert base.within_budget and base.error > level, (base.error, level, s.budget)
    assert ext.error <= level and ext.lobe_gain["fraction_removed"] < DECISIVE_FRACTION
    assert s.choice == "mitsuba-principled-tinted", s.message
    assert ext.lobe_gain["supported"] and "reproduces the data to the noise" in s.message
    np.testing.assert_allclose(ext.params["spec_tint"], 0.9, atol=0.05)

    plain = selection(0.0)
    assert plain.choice == "mitsuba-principled", plain.message
