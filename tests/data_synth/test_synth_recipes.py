"""Dataset recipes (JSON / TOML): the dataset is the named model on the named plan with the
named noise, deterministic from the seed; bad recipes raise RecipeError naming the problem."""

import json

import numpy as np
import pytest

from brdf_fit import registry
from data_synth.noise import Lognormal, run_pipeline
from data_synth.plans import make_plan
from data_synth.recipes import RecipeError, normalize_recipe, synthesize

TOML = """
name = "ggx-test"
model = "ggx"
seed = 7

[params]
alpha = 0.25
f0 = [0.9, 0.6, 0.5]

[plan]
name = "four-axis"

[plan.args]
theta_i_deg = [0.0, 30.0, 60.0]
theta_o_deg = [10.0, 40.0, 70.0]
phi_o_deg = [0.0, 90.0, 180.0]
min_separation_deg = 10.0

[[noise]]
type = "lognormal"
args = { sigma = 0.02 }

[[noise]]
type = "dark"
sigma = 1e-4

[[noise]]
type = "gain"
sigma = 0.05
"""


def _recipe():
    return {"model": "ggx", "seed": 7, "params": {"alpha": 0.25, "f0": [0.9, 0.6, 0.5]},
            "plan": {"name": "four-axis",
                     "args": {"theta_i_deg": [0.0, 30.0, 60.0],
                              "theta_o_deg": [10.0, 40.0, 70.0],
                              "phi_o_deg": [0.0, 90.0, 180.0], "min_separation_deg": 10.0}},
            "noise": [{"type": "lognormal", "args": {"sigma": 0.02}},
                      {"type": "dark", "sigma": 1e-4}, {"type": "gain", "sigma": 0.05}],
            "name": "ggx-test"}


def test_toml_and_json_recipes_give_the_same_dataset(tmp_path):
    (tmp_path / "r.toml").write_text(TOML)
    (tmp_path / "r.json").write_text(json.dumps(_recipe()))
    a = synthesize(tmp_path / "r.toml")
    b = synthesize(str(tmp_path / "r.json"))
    c = synthesize(_recipe())
    for other in (b, c):
        np.testing.assert_array_equal(a.value, other.value)
        np.testing.assert_array_equal(a.sigma, other.sigma)
        np.testing.assert_array_equal(a.wi, other.wi)
    assert a.channels == ("R", "G", "B")
    assert a.metadata["model"] == "ggx" and a.metadata["seed"] == 7
    assert a.metadata["plan"]["name"] == "four_axis"
    assert [m["type"] for m in a.metadata["noise"]] == ["lognormal", "dark", "gain"]
    assert len(a.metadata["truth"]["gain"]) == 3
    json.dumps(a.metadata)  # JSON-able, so it can go into a sidecar


def test_dataset_is_the_model_on_the_plan_with_the_noise():
    r = _recipe()
    d = synthesize(r)
    plan = make_plan("four_axis", r["plan"]["args"])
    np.testing.assert_array_equal(d.wi, plan.wi)
    np.testing.assert_array_equal(d.wo, plan.wo)
    model = registry.get("ggx").build(alpha=0.25, f0=np.array([0.9, 0.6, 0.5]))
    clean = np.asarray(model.eval(plan.wi, plan.wo))
    # the same pipeline by hand reproduces the values
    _, want, want_sigma, truth = run_pipeline(r["noise"], plan.wi, plan.wo,
                                              lambda a, b: np.asarray(model.eval(a, b)), 7)
    np.testing.assert_allclose(d.value, want, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(d.sigma, want_sigma, rtol=1e-12)
    assert d.metadata["truth"]["gain"] == pytest.approx(truth["gain"], rel=1e-15)
    # no noise: exactly the model
    r0 = {**r, "noise": []}
    d0 = synthesize(r0)
    np.testing.assert_allclose(d0.value, clean, rtol=1e-12)
    assert d0.sigma is None


def test_seed_decides_noise_and_random_plans():
    r = {"model": "lambert", "seed": 1, "plan": {"name": "random_sparse", "args": {"n": 50}},
         "noise": [Lognormal(0.05).spec()]}
    a, b = synthesize(r), synthesize(r)
    np.testing.assert_array_equal(a.value, b.value)
    c = synthesize({**r, "seed": 2})
    assert not np.array_equal(a.value, c.value)
    assert not np.array_equal(a.wi, c.wi)  # random_sparse without its own seed takes the recipe's
    fixed = {**r, "plan": {"name": "random_sparse", "args": {"n": 50, "seed": 5}}}
    np.testing.assert_array_equal(synthesize(fixed).wi, synthesize({**fixed, "seed": 9}).wi)


def test_channels_names_and_wavelengths():
    r = {"model": "lambert", "seed": 0, "plan": "in_plane", "params": {"rho": 0.5}}
    assert synthesize(r).channels == ("Y",)
    spec = synthesize({**r, "params": {"rho": [0.2, 0.4, 0.6, 0.8]},
                       "channels": [450, 500, 550, 600]})
    assert spec.channels == ("450nm", "500nm", "550nm", "600nm")
    np.testing.assert_allclose(spec.value[0], np.array([0.2, 0.4, 0.6, 0.8]) / np.pi,
                               rtol=1e-14)
    with pytest.raises(RecipeError, match=r"the model gives 4 channels; name them"):
        synthesize({**r, "params": {"rho": [0.2, 0.4, 0.6, 0.8]}})
    with pytest.raises(RecipeError, match=r"2 channel name\(s\) \['X', 'Z'\] but the model "
                                          r"gives 1"):
        synthesize({**r, "channels": ["X", "Z"]})


@pytest.mark.parametrize("change,match", [
    ({"model": "ggxx"}, r"model: unknown model 'ggxx'\. Did you mean ggx"),
    ({"params": {"alpha": -1.0}}, r"params: .*alpha"),
    ({"params": {"roughness": 0.2}}, r"params: ggx: unknown parameter 'roughness'"),
    ({"plan": {"name": "spiral"}}, r"plan: unknown plan 'spiral'; valid plans"),
    ({"plan": {"name": "in_plane", "args": {"zenith": 1}}}, r"plan: plan 'in_plane': unknown"),
    ({"plan": {"name": "in_plane", "n": 3}}, r"\[plan\] has unknown key\(s\) \['n'\]"),
    ({"noise": [{"type": "speckle"}]}, r"noise: unknown noise type 'speckle'"),
    ({"noise": "lognormal"}, r"'noise' must be a list of tables"),
    ({"seed": -1}, r"'seed' must be a non-negative integer"),
    ({"seed": 1.5}, r"'seed' must be a non-negative integer"),
    ({"colour": "red"}, r"unknown key\(s\) 'colour'; valid keys: name"),
    ({"channels": []}, r"'channels' must be a non-empty list"),
])
def test_bad_recipes_are_named(change, match):
    r = {"model": "ggx", "seed": 0, "plan": {"name": "in_plane"}, **change}
    with pytest.raises(RecipeError, match=match):
        synthesize(r)


def test_bad_files(tmp_path):
    with pytest.raises(RecipeError, match=r"missing required key\(s\) seed"):
        normalize_recipe({"model": "ggx", "plan": "in_plane"})
    (tmp_path / "r.yaml").write_text("model: ggx")
    with pytest.raises(RecipeError, match=r"must end in \.json or \.toml"):
        synthesize(tmp_path / "r.yaml")
    (tmp_path / "bad.toml").write_text("model = ")
    with pytest.raises(RecipeError, match=r"bad.toml: invalid TOML"):
        synthesize(tmp_path / "bad.toml")
    (tmp_path / "bad.json").write_text("[1, 2]")
    with pytest.raises(RecipeError, match=r"a recipe must be a JSON object"):
        synthesize(tmp_path / "bad.json")
    with pytest.raises(RecipeError, match="cannot read recipe"):
        synthesize(tmp_path / "none.toml")
