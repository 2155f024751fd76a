"""A selection's JSON answer holds no non-finite number: the reduced chi-square counts only
samples with a stated noise (a value of exactly 0 under multiplicative noise has sigma 0, whose
z was infinite for any model, and ``select --scene --json`` then failed after its whole run),
and the command line writes any number a ``to_dict`` left non-finite as null."""

import dataclasses
import json
import math

import numpy as np

from brdf_fit.cli._common import strict_json


def test_a_sample_without_noise_leaves_the_reduced_chi2_finite():
    from brdf_fit.selection import select
    from data_synth.recipes import synthesize

    d = synthesize({"model": "lambert", "seed": 3, "params": {"rho": 0.6},
                    "plan": {"name": "four_axis", "args": {}},
                    "noise": [{"type": "lognormal", "args": {"sigma": 0.02}}]})
    value, sigma = d.value.copy(), d.sigma.copy()
    value[0], sigma[0] = 0.0, 0.0  # a direction the renderer returned 0 for
    d = dataclasses.replace(d, value=value, sigma=sigma)
    c = select(d, candidates=["lambert"], checks=(), anisotropy=False).candidate("lambert")
    assert c.reduced_chi2 is not None and 0.5 < c.reduced_chi2 < 2.0, c.reduced_chi2


def test_strict_json_writes_null_for_what_json_has_not():
    doc = {"a": [1.0, math.inf], "b": {"c": math.nan, "d": (2, -math.inf)}, "e": "x",
           "f": np.float64(0.5).item()}
    assert json.loads(strict_json(doc)) == {"a": [1.0, None], "b": {"c": None, "d": [2, None]},
                                            "e": "x", "f": 0.5}
