"""Identifiability flags: a parameter the data do not determine is named as such
(brdf_fit.fitting.problem.undetermined), in fit, fit_batch, select and the demo."""

import numpy as np
import pytest

from brdf_fit.fitting.problem import (
    STDERR_NOTES,
    UNDETERMINED_REL_STDERR,
    entry_labels,
    undetermined,
)


def test_rule_on_arrays():
    t = UNDETERMINED_REL_STDERR
    v = np.array([1.0, 1.0, -2.0, 0.0, 1.0, 1.0])
    se = np.array([0.99 * t, 1.01 * t, 2.02 * t, 1e-9, np.nan, np.nan])
    note = np.array(["", "", "", "", STDERR_NOTES[1], STDERR_NOTES[2]], object)
    got = undetermined(v, se, note)
    # below / above the threshold, relative to |value|; a zero value with any error; at bound
    # (no standard error) is not this flag; not identifiable is
    assert got.tolist() == [False, True, True, True, False, True]
    assert undetermined(2.0, 0.1).shape == ()
    assert not undetermined(2.0, 0.1)


def test_labels():
    assert entry_labels("alpha", ()) == ["alpha"]
    assert entry_labels("k", (3,), ("R", "G", "B")) == ["k[R]", "k[G]", "k[B]"]
    assert entry_labels("k", (2,), ("R", "G", "B")) == ["k[0]", "k[1]"]


@pytest.fixture(scope="module")
def gold_fit():
    import jax

    jax.config.update("jax_enable_x64", True)
    from brdf_fit.demo import DEMO_FITS, DEMO_METRIC, DEMO_RECIPE
    from brdf_fit.fitting.single import fit
    from data_synth.recipes import synthesize

    data = synthesize(DEMO_RECIPE)
    init = dict(DEMO_FITS)["ggx-conductor"]
    return data, fit(data, "ggx-conductor", init=init, metric=DEMO_METRIC)


def test_demo_gold_flags_red_eta_and_k(gold_fit):
    """The demo's gold: F0 in red is ~0.99, which a whole curve of (eta, k) gives; the fit lands
    far from the truth (k 7.5, eta 0.06) and must say so. Every other entry is determined."""
    data, r = gold_fit
    assert set(r.undetermined) == {"eta[R]", "k[R]"}
    d = r.to_dict()
    assert sorted(d["undetermined"]) == ["eta[R]", "k[R]"]
    # the flagged values are the wrong ones, the unflagged ones near the truth
    assert abs(float(r.params["k"][0]) - 7.545) > 3 * float(r.stderr["k"][0])
    assert abs(float(r.params["alpha"]) - 0.2) < 0.002


def test_fit_output_names_them(gold_fit, capsys):
    from brdf_fit.cli.fit import _print_fit

    data, r = gold_fit
    _print_fit(r, data, "gold.csv")
    out = capsys.readouterr().out
    assert "undetermined: eta[R], k[R]" in out
    lines = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("  ") and ln.split()}
    assert "UNDETERMINED" in lines["k[R]"] and "UNDETERMINED" in lines["eta[R]"]
    assert "UNDETERMINED" not in lines["k[G]"] and "UNDETERMINED" not in lines["alpha"]


def test_batch_rows_and_flags():
    """fit_batch's result flags per problem; the CLI rows name the entries and add a flag."""
    from brdf_fit.cli._batch_rows import batch_rows as _batch_rows
    from brdf_fit.cli._batch_rows import flag_rows as _flag_rows
    from brdf_fit.fitting.batch import BatchFitResult

    B = 2
    res = BatchFitResult(
        model_name="ggx", params={"alpha": np.array([0.2, 0.3]),
                                  "f0": np.array([[0.9, 0.5, 0.3], [0.9, 0.01, 0.3]])},
        stderr={"alpha": np.array([0.001, 0.2]),
                "f0": np.array([[0.01, 0.01, 0.01], [0.01, 0.01, 0.01]])},
        converged=np.ones(B, bool), steps=np.ones(B, int), loss=np.zeros(B),
        residual_rms=np.ones(B), n_samples=np.full(B, 100), n_params=4, metric="log",
        solver="batch-lm", seconds=0.0)
    u = res.undetermined
    assert u["alpha"].tolist() == [False, True] and u["f0"][1].tolist() == [False, True, False]
    assert res.to_dict()["undetermined"]["alpha"] == [False, True]
    rows = _batch_rows(["a.csv", "b.csv"], res, ("R", "G", "B"))
    _flag_rows(rows)
    assert rows[0]["undetermined"] == [] and rows[1]["undetermined"] == ["alpha", "f0[G]"]
    assert "undetermined: alpha, f0[G]" in rows[1]["flags"]
    assert not any(f.startswith("undetermined") for f in rows[0]["flags"])
