"""Model selection on synthetic data with 1% noise: a Lambert surface selects a diffuse model,
rough gold and a GGX plastic a specular one within the budget, the choice is the cheapest
in-budget candidate; the radiance error is the stated definition; the CLI's JSON has the
documented keys; bad requests fail before any fit."""

import json

import numpy as np
import pytest

from brdf_fit.cli import main
from brdf_fit.selection import ERROR_DEFINITION, radiance_error, select
from data_synth.recipes import synthesize

CANDIDATES = ("lambert", "ggx", "ggx-plastic", "ggx-conductor")
PLAN = {"name": "in_plane", "args": {"theta_i_deg": [0, 20, 40, 60],
                                     "theta_o_deg": [-75, -60, -45, -30, -15, 0, 10, 20, 30,
                                                     40, 50, 60, 75]}}
TRUTHS = {
    "lambert": ("lambert", {"rho": [0.5, 0.4, 0.3]}),
    "gold": ("ggx-conductor", {"alpha": 0.2}),
    "plastic": ("ggx-plastic", {"rho_d": [0.6, 0.1, 0.08], "alpha": 0.15, "f0": 0.04}),
}
DIFFUSE = {"lambert", "oren-nayar"}


def dataset(name, seed=3):
    model, params = TRUTHS[name]
    return synthesize({"model": model, "params": params, "seed": seed, "plan": PLAN,
                       "noise": [{"type": "lognormal", "args": {"sigma": 0.01}}]})


# gold brings ggx-conductor (complex Fresnel, 7 parameters; 17 s): in the slow set
@pytest.mark.parametrize(
    "name", ["lambert", "plastic", pytest.param("gold", marks=pytest.mark.slow)])
def test_selects_the_right_kind_of_model(name):
    d = dataset(name)
    cands = CANDIDATES if name == "gold" else CANDIDATES[:3]
    s = select(d, cands, checks=(), anisotropy=False)  # the test's subject: the kind chosen
    assert s.choice is not None
    assert (s.choice in DIFFUSE) == (name == "lambert"), s.choice
    ch = s.candidate(s.choice)
    assert ch.within_budget and ch.error <= s.budget
    # the choice is the cheapest candidate within the budget by the committed cost table (the
    # selector's rule; live ns/eval move with the machine's load, and this assertion on them
    # failed once in a slow-set run beside other work, 2026-12-06)
    assert all(c.cost_rel is not None for c in s.candidates)
    assert all(c.cost_rel >= ch.cost_rel for c in s.candidates if c.within_budget)
    # the true model family reaches the noise: error ~1%, reduced chi-square ~1
    truth = s.candidate(TRUTHS[name][0])
    assert truth.error < 0.02 and 0.5 < truth.reduced_chi2 < 2.0
    # the default budget rule: 2 x the best error, at least 1.5 x the noise level and 1%
    best = min(c.error for c in s.candidates)
    assert s.budget == pytest.approx(max(2 * best, 1.5 * s.noise_level, 0.01))
    assert any(c.pareto for c in s.candidates)


def test_a_budget_below_every_error_names_the_best_and_what_to_give():
    """A budget no candidate meets (below the noise) is not "no candidate represents this
    material" (the best is below the ceiling): the message names the best and its error and
    says what to change."""
    s = select(dataset("lambert"), ["lambert"], budget=1e-4, checks=(), anisotropy=False)
    best = s.candidate("lambert")
    assert s.choice is None and s.represented and not best.within_budget
    assert "lambert" in s.message and f"{best.error:.4g}" in s.message
    assert "give a budget above" in s.message and "--family all" in s.message


def test_error_is_the_stated_radiance_error():
    d = dataset("plastic")
    assert radiance_error(d, d.value) == 0.0
    assert radiance_error(d, 1.1 * d.value) == pytest.approx(0.1)
    c = np.clip(d.wi[:, 2:3], 0, None)
    m = d.value + 0.01
    ref = np.sqrt(np.sum(((m - d.value) * c) ** 2) / np.sum((d.value * c) ** 2))
    assert radiance_error(d, m) == pytest.approx(ref)
    assert "f cos(theta_i)" in ERROR_DEFINITION


def test_cli_select_json_and_plot(tmp_path, capsys):
    d = dataset("gold")
    path = tmp_path / "gold.npz"
    from brdf_fit import io

    io.write(d, str(path))
    plot = tmp_path / "front.png"
    code = main(["select", str(path), "--candidates", "lambert,ggx", "--budget", "0.05",
                 "--check", "reciprocity", "--plot", str(plot), "--json", "--quiet"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["choice"] == "ggx" and doc["budget"] == 0.05
    assert doc["error_definition"] == ERROR_DEFINITION
    keys = {"model", "params", "stderr", "error", "cost_ns", "n_params", "aic", "bic",
            "within_budget", "converged", "checks"}
    assert all(keys <= set(c) for c in doc["candidates"])
    assert doc["candidates"][0]["checks"] == {"reciprocity": "pass"} or \
        doc["candidates"][1]["checks"] == {"reciprocity": "pass"}
    assert plot.stat().st_size > 10_000


@pytest.mark.parametrize("argv, fragment", [
    (["--candidates", "ggx,nope"], "nope"),
    (["--budget", "-1"], "--budget"),
    (["--check", "bogus"], "unknown check"),
    (["--plot", "x.txt"], "--plot"),
    (["--family", "shiny"], "unknown family 'shiny'"),
    (["--family", "diffuse", "--candidates", "ggx"], "not both"),
])
def test_bad_select_requests(tmp_path, capsys, argv, fragment):
    argv = [a if a != "x.txt" else str(tmp_path / a) for a in argv]
    try:
        code = main(["select", str(tmp_path / "missing.csv"), *argv])
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and "Traceback" not in err


@pytest.fixture(scope="module")
def demo_selection():
    """select over the demo's models on the demo's data (gold, GGX alpha 0.2, 1% noise)."""
    from brdf_fit import demo

    d = synthesize(demo.DEMO_RECIPE)
    return d, select(d, [name for name, _ in demo.DEMO_FITS], checks=(), anisotropy=False)


def test_a_candidate_that_cannot_be_fitted_loses_no_other():
    """modified-phong fitted to gold in the radiance error ends at rho_d + rho_s > 1, which the
    model refuses: the candidate is reported with its reason, the others are selected. (Two of
    the demo's candidates: the demo's full list, with ggx-conductor's 17 s compilation, runs in
    the slow multistart test below.)"""
    from brdf_fit import demo

    s = select(synthesize(demo.DEMO_RECIPE), ["modified-phong", "ggx"], checks=(),
               anisotropy=False)
    bad = s.candidate("modified-phong")
    assert "rho_d + rho_s" in bad.message and not bad.within_budget and not bad.pareto
    assert s.choice == "ggx" and s.candidates[-1].model == "modified-phong"
    doc = json.loads(json.dumps(s.to_dict(), allow_nan=False))  # strict JSON
    assert doc["candidates"][-1]["message"] and doc["candidates"][-1]["error"] is None
    doc = json.loads(json.dumps(s.to_dict(), allow_nan=False))  # strict JSON
    assert doc["candidates"][-1]["message"] and doc["candidates"][-1]["error"] is None


@pytest.mark.slow  # the demo's five candidates, ggx-conductor among them (28 s)
def test_each_candidate_error_is_no_worse_than_eight_multistarts(demo_selection):
    """Issue 18: every candidate's reported error is no worse than the best of 8 multistarts of
    that model in the same error (a fit in the radiance error from 8 random starts, seeded
    differently from select's). Measured: equal to 1e-14 for ggx-conductor, ggx, beckmann and
    blinn-phong-approx; modified-phong fails the same way from every start."""
    import dataclasses

    import jax.numpy as jnp

    from brdf_fit.fitting.problem import FitError
    from brdf_fit.fitting.single import fit

    d, s = demo_selection
    plain = dataclasses.replace(d, sigma=None)
    for c in s.candidates:
        try:
            r = fit(plain, c.model, metric="absolute", cos_weight=True, multistart=8, seed=1)
        except FitError as exc:
            assert c.message and "rho_d + rho_s" in str(exc), c.model
            continue
        best8 = radiance_error(d, r.model.eval(jnp.asarray(d.wi), jnp.asarray(d.wo)))
        assert c.error <= best8 * (1 + 1e-9), (c.model, c.error, best8)


def test_families_name_registry_entries_and_select_takes_one(monkeypatch):
    from brdf_fit import registry
    from brdf_fit.selection import FAMILIES, family_candidates

    for fam, names in FAMILIES.items():
        assert names == family_candidates(fam)
        assert all(registry.get(n).name == n for n in names), fam  # canonical names only
    every = family_candidates("all")
    assert "mirror" not in every and "ggx" in every and len(every) == len(set(every))
    with pytest.raises(ValueError, match="unknown family"):
        family_candidates("shiny")
    with pytest.raises(ValueError, match="not both"):
        select(dataset("lambert"), ["lambert"], family="diffuse")
    # select takes a family's names (a two-model family here: the five diffuse fits cost 12 s)
    from brdf_fit.selection import selector

    monkeypatch.setitem(selector.FAMILIES, "pair", ("lambert", "ggx"))
    s = select(dataset("lambert"), family="pair", checks=(), anisotropy=False)
    assert [c.model for c in s.candidates if c.message] == []
    assert {c.model for c in s.candidates} == {"lambert", "ggx"} and s.choice == "lambert"


def test_workers_and_given_fits():
    """Two candidates fitted at once (threads) give the sequential selection's numbers exactly;
    fits given to select are judged as they are (no refit), and the error definition says so.
    """
    from brdf_fit.fitting.single import fit

    d = dataset("plastic")
    names = ["lambert", "ggx"]
    one = select(d, names, checks=(), anisotropy=False)
    two = select(d, names, checks=(), anisotropy=False, workers=2)
    for a, b in zip(one.candidates, two.candidates, strict=True):
        assert a.model == b.model and a.error == b.error and a.aic == b.aic
        assert np.isfinite(b.cost_ns) and b.cost_ns > 0  # measured after the fits
        for k in a.params:
            np.testing.assert_array_equal(a.params[k], b.params[k])
    assert one.choice == two.choice
    # given fits: here the selection's own fits (its metric, without sigma), so its errors
    import dataclasses

    plain = dataclasses.replace(d, sigma=None)
    fits = {n: fit(plain, n, metric="absolute", cos_weight=True) for n in names}
    given = select(d, fits=fits, checks=())
    assert "not refitted" in given.error_definition and given.anisotropy is None
    for a, b in zip(one.candidates, given.candidates, strict=True):
        assert a.model == b.model and b.error == pytest.approx(a.error, rel=1e-12)
    # a log-metric fit judged in the radiance error is no better than the radiance fit
    logged = select(d, fits={n: fit(d, n) for n in names}, checks=())
    for a, b in zip(one.candidates, logged.candidates, strict=True):
        assert b.error >= a.error * (1 - 1e-9)
    with pytest.raises(ValueError, match="not both"):
        select(d, names, fits=fits)
    with pytest.raises(ValueError, match="workers"):
        select(d, names, workers=0)
