"""Subsamples of measured data (issue 44): ``GonioData.subsample`` draws a simple random sample
or one stratified by the half and difference angles with proportional allocation
(:func:`brdf_fit.data.subsample_index`); ``fit --max-samples N --subsample stratified``."""

import json

import numpy as np
import pytest
from _helpers import random_dirs

from brdf_fit import registry
from brdf_fit.cli import main
from brdf_fit.data import (
    STRATA_THETA_D,
    STRATA_THETA_H,
    GonioData,
    half_difference_strata,
    subsample_index,
)
from brdf_fit.io import write
from brdf_fit.io.merl import N_PD, N_TD, N_TH, merl_bin_centres

N_STRATA = STRATA_THETA_H * STRATA_THETA_D


def _data(n, seed=0):
    rng = np.random.default_rng(seed)
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    return GonioData(wi, wo, np.ones((n, 1)))


def test_strata_of_the_merl_bin_centres():
    """An independent reading: the MERL grid is made from theta_h (square-root spacing) and
    theta_d (linear), so a bin centre (i + 0.5, j + 0.5) of its theta_h and theta_d indices
    lies in stratum floor((i + 0.5) 16 / 90) x floor((j + 0.5) 8 / 90)."""
    wi, wo = merl_bin_centres()
    ith, itd = np.divmod(np.arange(len(wi)) // N_PD, N_TD)
    keep = slice(None, None, 5)  # every fifth bin: all theta_h and theta_d rows, 0.3 M pairs
    x = (ith[keep] + 0.5) * STRATA_THETA_H / N_TH
    y = (itd[keep] + 0.5) * STRATA_THETA_D / N_TD
    want = np.floor(x).astype(int) * STRATA_THETA_D + np.floor(y).astype(int)
    got = half_difference_strata(wi[keep], wo[keep])
    # centres that lie on a stratum edge (bin 22 of 90 is at 22.5/90 = 1/4 in both) go either
    # way by rounding: left out
    clear = (np.abs(x - np.round(x)) > 1e-6) & (np.abs(y - np.round(y)) > 1e-6)
    assert clear.mean() > 0.9
    np.testing.assert_array_equal(got[clear], want[clear])
    # every stratum is used by the grid; a pair with wi = -wo has no half vector: the last one
    assert np.unique(half_difference_strata(wi, wo)).size == N_STRATA
    assert half_difference_strata(np.array([[0.0, 0.6, 0.8]]),
                                  np.array([[0.0, -0.6, -0.8]]))[0] == N_STRATA - 1


def test_stratified_shares_are_proportional_and_uniform_ones_are_not():
    data = _data(40_000)
    stratum = half_difference_strata(data.wi, data.wo)
    counts = np.bincount(stratum, minlength=N_STRATA)
    n = 1_000
    share = counts * n / data.n
    idx = subsample_index(data, n, seed=3, how="stratified")
    assert idx.size == n and np.unique(idx).size == n and np.all(np.diff(idx) > 0)
    got = np.bincount(stratum[idx], minlength=N_STRATA)
    assert np.all(np.abs(got - share) < 1.0)  # largest remainders: each share rounded
    # the control: a simple random sample misses the shares by several samples somewhere
    uni = np.bincount(stratum[subsample_index(data, n, seed=3)], minlength=N_STRATA)
    assert np.max(np.abs(uni - share)) > 3.0
    # seeded: the same seed the same sample, another seed another
    np.testing.assert_array_equal(idx, subsample_index(data, n, seed=3, how="stratified"))
    assert not np.array_equal(idx, subsample_index(data, n, seed=4, how="stratified"))


def test_subsample_keeps_everything_below_n_and_refuses_bad_requests():
    data = _data(50)
    assert data.subsample(50, how="stratified") is data
    assert data.subsample(20, how="stratified").n == 20
    with pytest.raises(ValueError, match="subsample 'thirds'"):
        subsample_index(data, 10, how="thirds")
    with pytest.raises(ValueError, match="0 < n < 50"):
        subsample_index(data, 50)


def test_fit_command_draws_a_stratified_subsample(tmp_path, capsys):
    rng = np.random.default_rng(5)
    n = 3_000
    wi, wo = random_dirs(rng, n), random_dirs(rng, n)
    f = np.asarray(registry.get("ggx").build(alpha=0.25, f0=0.5).eval(wi, wo))[:, None]
    path = tmp_path / "d.npz"
    write(GonioData(wi, wo, f * rng.lognormal(0.0, 0.01, (n, 1))), path)
    status = main(["fit", str(path), "--model", "ggx", "--max-samples", "400",
                   "--subsample", "stratified", "--json", "--quiet"])
    doc = json.loads(capsys.readouterr().out)
    assert status == 0 and doc["n_samples"] == 400 and doc["converged"]
    assert doc["params"]["alpha"] == pytest.approx(0.25, rel=0.05)
