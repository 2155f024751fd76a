"""Faults a batch must survive (issue 16): pathological members leave the good members' results
untouched and are flagged; NaN or Inf anywhere in a batch's input is refused before any fitting,
naming the file and line (readers, the CLI) or the problem and sample (fit_batch's arrays).

The batches are test_fit_batch.py's (GGX, alpha + RGB f0, 120 samples, blocks of 16 lanes): the
clean batch reuses its compiled chunks; the faulty one (with weights) compiles once and is
shared by the robust-metric test's log fit and the CLI test. The time a faulty batch costs
against a clean one is measured in ``benchmarks/bench_fit_batch.py --faults``
(results/fit_batch.md), not asserted here.
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_fit_batch import TRUTHS, batch

from brdf_fit.cli import main
from brdf_fit.data import DataError, GonioData
from brdf_fit.fitting.batch import fit_batch
from brdf_fit.fitting.problem import ROBUST_SCALE, robust_residual
from brdf_fit.fitting.single import FitError
from brdf_fit.io import read, write

#: a member is flagged when it did not converge, a parameter sits at a bound, its residual rms
#: is this many times the batch's median or above, or it has fewer than MIN_SAMPLES samples
RMS_FACTOR = 10.0
MIN_SAMPLES = 10
FAULTS = ("all black", "f = 1000", "one outlier of 1e6", "3 samples")


def with_faults(wi, wo, v):
    """The clean batch followed by one member per fault, built from copies of its first four
    members (the same directions): weights mask the 3-sample member's other samples (a batch
    shares one sample count; the CLI would fit a 3-sample file in its own batch)."""
    B = v.shape[0]
    wi2, wo2, v2 = (np.concatenate([x, x[:4]]) for x in (wi, wo, v))
    w = np.ones_like(v2)
    v2[B] = 0.0  # an all-black file
    v2[B + 1] = 1000.0  # physically impossible everywhere
    v2[B + 2, 17, :] = 1e6  # one wild outlier in an otherwise good file
    w[B + 3, 3:] = 0.0  # a file of 3 samples
    return wi2, wo2, v2, w


def flags(r, b):
    """The reasons member ``b`` of result ``r`` is flagged (empty: not flagged)."""
    out = []
    if not r.converged[b]:
        out.append("not converged")
    bound = [k for k, v in r.at_bound.items() if np.asarray(v[b]).any()]
    if bound:
        out.append(f"at bound: {bound}")
    if r.residual_rms[b] > RMS_FACTOR * np.median(r.residual_rms):
        out.append("rms")
    if r.n_samples[b] < MIN_SAMPLES:
        out.append("few samples")
    return out


def test_faulty_members_leave_good_ones_unchanged_and_are_flagged():
    wi, wo, v = batch(TRUTHS, noise=0.02, seed=16)
    clean = fit_batch(wi, wo, v, "ggx")
    B = len(TRUTHS)
    wi2, wo2, v2, w = with_faults(wi, wo, v)
    r = fit_batch(wi2, wo2, v2, "ggx", weight=w)  # all in one call
    assert clean.converged.all()
    for k in ("alpha", "f0"):
        np.testing.assert_allclose(r.params[k][:B], clean.params[k], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(r.steps[:B], clean.steps)
    np.testing.assert_allclose(r.residual_rms[:B], clean.residual_rms, rtol=1e-6)
    for b in range(B):
        assert flags(r, b) == [], (b, flags(r, b))
    why = {name: flags(r, B + i) for i, name in enumerate(FAULTS)}
    assert all(why.values()), why
    # which flag catches which fault (measured: the 3-sample member converges to an exact,
    # meaningless fit with a small rms and finite standard errors: only its sample count
    # tells it apart)
    assert "not converged" in why["all black"] and why["all black"][1].startswith("at bound")
    assert "rms" in why["f = 1000"] and "not converged" in why["f = 1000"]
    assert "rms" in why["one outlier of 1e6"]
    assert why["3 samples"] == ["few samples"] and r.n_samples[B + 3] == 3
    assert np.isfinite(r.loss).all() and np.isfinite(r.residual_rms).all()


@pytest.mark.parametrize("field, index, value, message", [
    ("values", (1, 3, 2), np.nan, "problem 1, sample 3: values is not finite"),
    ("values", (2, 0, 0), np.inf, "problem 2, sample 0: values is not finite"),
    ("values", (0, 5, 1), 1e300, "problem 0, sample 5: values exceeds 1e\\+15"),
    # below -MAX_VALUE: the max/min pre-test (batch._clean) must send it to the element tests
    ("values", (3, 1, 0), -1e300, "problem 3, sample 1: values exceeds 1e\\+15"),
    ("sigma", (1, 2, 2), -0.5, "problem 1, sample 2: sigma is negative"),
    ("wi", (3, 7, 0), np.nan, "problem 3, sample 7: wi is not finite"),
    ("wo", (1, 119, 2), -np.inf, "problem 1, sample 119: wo is not finite"),
    ("weight", (2, 4, 1), np.nan, "problem 2, sample 4: weight is not finite"),
    ("weight", (2, 4, 1), -1.0, "problem 2, sample 4: weight is negative"),
    ("sigma", (0, 9, 0), np.inf, "problem 0, sample 9: sigma is not finite"),
])
def test_fit_batch_refuses_non_finite_arrays_naming_problem_and_sample(field, index, value,
                                                                        message):
    wi, wo, v = batch(TRUTHS, seed=17)
    arrays = {"wi": wi, "wo": wo, "values": v, "weight": np.ones_like(v),
              "sigma": np.full_like(v, 0.01)}
    arrays[field] = arrays[field].copy()
    arrays[field][index] = value
    with pytest.raises(FitError, match=message):
        fit_batch(arrays["wi"], arrays["wo"], arrays["values"], "ggx",
                  weight=arrays["weight"], sigma=arrays["sigma"])


HEADER = "theta_i,phi_i,theta_o,phi_o,brdf_r,brdf_g,brdf_b,sigma_r,sigma_g,sigma_b,weight"


@pytest.mark.parametrize("column, cell", [
    ("brdf_g", "nan"), ("brdf_b", "inf"), ("theta_o", "NaN"), ("phi_i", "-inf"),
    ("sigma_r", "nan"), ("weight", "inf"),
])
def test_csv_reader_refuses_nan_and_inf_naming_file_line_and_column(tmp_path, column, cell):
    cols = HEADER.split(",")
    good = ["10", "0", "20", "180", "0.5", "0.4", "0.3", "0.01", "0.01", "0.01", "1"]
    bad = list(good)
    bad[cols.index(column)] = cell
    path = tmp_path / "nan.csv"
    path.write_text("\n".join([HEADER, ",".join(good), ",".join(good), ",".join(bad)]) + "\n")
    with pytest.raises(DataError) as e:
        read(str(path))
    assert str(e.value).startswith(f"{path}, line 4, column {column!r}:"), e.value
    assert "not a finite number" in str(e.value)


@pytest.mark.parametrize("field", ["value", "wi", "weight", "sigma"])
def test_npz_reader_refuses_nan_naming_file_and_sample(tmp_path, field):
    z = np.array([[0.0, 0.0, 1.0]] * 4)
    kw = dict(wi=z.copy(), wo=z.copy(), value=np.full((4, 1), 0.5), weight=np.ones((4, 1)),
              sigma=np.full((4, 1), 0.01))
    kw[field][2, 0] = np.nan
    path = tmp_path / "nan.npz"
    write(GonioData(**kw), str(path))  # write does not validate: a corrupt file on disk
    with pytest.raises(DataError, match=rf"^{path}: sample 2: {field} .*(not finite|finite and)"):
        read(str(path))


def test_cli_fit_batch_with_a_nan_file(tmp_path, capsys):
    """A NaN in one file: without --skip-bad nothing is fitted (exit 2, the file and line
    named); with it the other files are fitted and the bad one is listed (exit 1)."""
    wi, wo, v = batch(TRUTHS[:2], seed=18)
    paths = []
    for b in range(2):
        p = tmp_path / f"good{b}.csv"
        write(GonioData(wi=wi[b], wo=wo[b], value=v[b], channels=("R", "G", "B")), str(p))
        paths.append(str(p))
    lines = (tmp_path / "good1.csv").read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    cells = lines[head + 5].split(",")
    cells[-1] = "nan"
    lines[head + 5] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    assert main(["fit-batch", paths[0], str(bad), "--model", "ggx", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "bad.csv" in err and f"line {head + 6}" in err and "not a finite number" in err
    assert main(["fit-batch", paths[0], str(bad), "--model", "ggx", "--quiet", "--json",
                 "--skip-bad"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert [r["file"] for r in doc["results"]] == [paths[0]]
    assert doc["results"][0]["converged"]
    np.testing.assert_allclose(doc["results"][0]["params"]["alpha"], TRUTHS[0][0], rtol=1e-6)
    assert len(doc["unreadable"]) == 1 and "bad.csv" in doc["unreadable"][0]


# ----------------------------------------------------------------------------- robust metrics


def test_robust_residuals_are_huber_and_cauchy_losses():
    s = ROBUST_SCALE
    r = jnp.asarray([-30 * s, -2 * s, -0.5 * s, 0.0, 1e-6 * s, 0.5 * s, s, 2 * s, 30 * s])
    x = np.asarray(r) / s
    huber = np.where(np.abs(x) <= 1, x * x / 2, np.abs(x) - 0.5)
    cauchy = np.log1p(x * x) / 2
    for name, rho in (("huber", huber), ("cauchy", cauchy)):
        t = np.asarray(robust_residual(name, r))
        np.testing.assert_allclose(t * t / 2, s * s * rho, rtol=1e-12, atol=1e-300)
        assert np.all(np.sign(t) == np.sign(x))
        d = np.asarray(jax.vmap(jax.grad(lambda z, n=name: robust_residual(n, z)))(r))
        assert np.all(np.isfinite(d)) and np.all(d > 0)
        np.testing.assert_allclose(d[3], 1.0, rtol=1e-12)  # the residual itself near 0
    np.testing.assert_allclose(robust_residual("huber", r[2]), r[2], rtol=1e-15)


@pytest.mark.parametrize("metric", ["huber", pytest.param("cauchy", marks=pytest.mark.slow)])
def test_robust_metric_resists_the_outlier_member(metric):
    """The faulty batch fitted with a robust metric: the member with one sample of 1e6 lands
    near its truth (the log metric's fit of it is pulled to a bound); the good members stay
    near theirs."""
    wi, wo, v = batch(TRUTHS, noise=0.02, seed=16)
    B = len(TRUTHS)
    wi2, wo2, v2, w = with_faults(wi, wo, v)
    log = fit_batch(wi2, wo2, v2, "ggx", weight=w)
    rob = fit_batch(wi2, wo2, v2, "ggx", weight=w, metric=metric)
    ta, tf = np.array([t[0] for t in TRUTHS]), np.array([t[1] for t in TRUTHS])

    def err(r, b, t):
        return (abs(r.params["alpha"][b] / ta[t] - 1), np.abs(r.params["f0"][b] - tf[t]).max())

    b = B + FAULTS.index("one outlier of 1e6")  # a copy of member 2 with the outlier
    e_log, e_rob = err(log, b, 2), err(rob, b, 2)
    assert rob.converged[b] and not any(np.asarray(x[b]).any() for x in rob.at_bound.values())
    assert e_rob[0] < 0.02 and e_rob[1] < 0.03, e_rob  # measured: 0.006, 0.012 (huber)
    assert e_log[0] > 10 * e_rob[0] and e_log[1] > 10 * e_rob[1], (e_log, e_rob)
    for g in range(B):
        assert err(rob, g, g)[0] < 0.03 and err(rob, g, g)[1] < 0.03, (g, err(rob, g, g))
    with pytest.raises(FitError, match="not for data with sigma"):
        fit_batch(wi, wo, v, "ggx", sigma=np.full_like(v, 0.01), metric=metric)
