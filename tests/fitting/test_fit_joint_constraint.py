"""A fit whose optimum breaks a joint constraint of the model (modified Phong's
rho_d + rho_s <= 1, which the per-parameter intervals do not express) ends in a FitError that
names the parameters and the constraint, not in a bare ParameterError from deep inside."""

import dataclasses

import pytest

from brdf_fit import fit
from brdf_fit.fitting.problem import FitError
from data_synth.recipes import synthesize

GOLD = {"model": "ggx-conductor", "params": {"alpha": 0.2}, "seed": 2024,
        "plan": {"name": "in_plane", "args": {"theta_i_deg": [0, 30, 60],
                                              "theta_o_deg": [-60, -30, 0, 20, 30, 40, 60]}}}


def test_joint_constraint_violation_is_a_fit_error():
    d = dataclasses.replace(synthesize(GOLD), sigma=None)
    with pytest.raises(FitError, match=r"modified-phong: the fitted parameters .*rho_d \+ rho_s"):
        fit(d, "modified-phong", metric="absolute", cos_weight=True)
