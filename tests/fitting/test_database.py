"""Database runs (brdf_fit.fitting.database, `brdf-fit fit FILES --model A,B --table T`) and the
published error measures (brdf_fit.fitting.errors)."""

import json
import math
import os
import signal
import subprocess
import sys
import time

import jax.numpy as jnp
import numpy as np
import pytest
from _helpers import random_dirs

from brdf_fit import io, registry
from brdf_fit.cli import main
from brdf_fit.data import GonioData
from brdf_fit.fitting import database
from brdf_fit.fitting.errors import ERRORS, errors_of_values, measure_weights

MODELS = ("ggx", "lambert")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Three small materials (GGX with 2% noise) as .npz files."""
    d = tmp_path_factory.mktemp("db")
    rng = np.random.default_rng(11)
    for i, (a, f0) in enumerate([(0.1, [0.9, 0.6, 0.3]), (0.3, [0.5, 0.5, 0.5]),
                                 (0.2, [0.95, 0.8, 0.5])]):
        wi, wo = random_dirs(rng, 200, 0.05), random_dirs(rng, 200, 0.05)
        m = registry.get("ggx").build(alpha=np.array(a), f0=np.array(f0))
        v = np.asarray(m.eval(jnp.asarray(wi), jnp.asarray(wo)))
        v = v * np.exp(0.02 * rng.standard_normal(v.shape))
        io.write(GonioData(wi=wi, wo=wo, value=v, channels=("R", "G", "B")), d / f"mat{i}.npz")
    return d


def _files(folder):
    return sorted(str(p) for p in folder.glob("*.npz"))


def _same(a, b):
    """Rows equal but for the time each fit took."""
    strip = [{k: v for k, v in r.items() if k != "seconds"} for r in (a, b)]
    return strip[0] == strip[1]


# ----------------------------------------------------------------------------- error measures


def test_error_measures_by_hand():
    """Each measure written out sample by sample from its definition (module docstring of
    brdf_fit.fitting.errors) on a few samples, one of them beyond Ngan's 80 degree cut."""
    wi = np.array([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.0, 0.99, math.sqrt(1 - 0.99**2)]])
    wo = np.array([[0.0, 0.6, 0.8], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    f = np.array([[1.0, 2.0], [0.5, 0.25], [3.0, 1.0]])
    g = np.array([[0.9, 2.5], [0.5, 0.5], [1.0, 1.0]])
    w = np.array([1.0, 2.0, 0.5])
    got = errors_of_values(f, g, wi, wo, w)
    assert list(got) == list(ERRORS)
    c = wi[:, 2]
    num = den = e1 = e2 = ng = ngw = 0.0
    for n in range(3):
        for ch in range(2):
            d2 = ((f[n, ch] - g[n, ch]) * c[n]) ** 2
            num += w[n] * d2
            den += w[n] * (f[n, ch] * c[n]) ** 2
            e1 += w[n] * d2
            e2 += w[n] * (math.log(1 + f[n, ch] * c[n]) - math.log(1 + g[n, ch] * c[n])) ** 2
            if c[n] > math.cos(math.radians(80)) and wo[n, 2] > math.cos(math.radians(80)):
                ng += w[n] * d2
        if c[n] > math.cos(math.radians(80)) and wo[n, 2] > math.cos(math.radians(80)):
            ngw += w[n]
    want = {"rel_rms": math.sqrt(num / den), "ngan2005": math.sqrt(ng / ngw),
            "low2012_e1": e1 / w.sum(), "low2012_e2": e2 / w.sum()}
    for k, v in want.items():
        assert got[k] == pytest.approx(v, rel=1e-13), k
    assert all(v == 0.0 for v in errors_of_values(f, f, wi, wo, w).values())
    # the log measure is this package's default metric: E2 with unit weights = 2 loss / M
    assert want["low2012_e2"] > 0 and got["ngan2005"] != got["rel_rms"]


def test_merl_measure_weights_integrate_to_the_pair_measure():
    """The MERL bins' weights (4 cos(theta_d) sin(theta_h) sin(theta_d) dtheta_h dtheta_d dphi_d
    dphi_h, Rusinkiewicz 1998) over every valid bin: the measure of the pairs of upper
    directions, (2 pi)^2, halved (MERL keeps phi_d in [0, pi): reciprocity), to the midpoint
    rule's 1.5e-4 at the horizon."""
    from brdf_fit.io.merl import half_diff_angles, merl_bin_centres

    wi, wo = merl_bin_centres()
    v = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    d = GonioData(wi=wi[v], wo=wo[v], value=np.ones((int(v.sum()), 1)), channels=("Y",),
                  metadata={"format": "merl"})
    w = measure_weights(d)
    th, _, _ = half_diff_angles(wi[v], wo[v])
    i = np.floor(np.sqrt(th / (np.pi / 2)) * 90)
    # the bin measure written with its theta_h width (pi/2)(2i + 1)/90^2; the weights are
    # proportional to it
    dth = (np.pi / 2) * (2 * i + 1) / 90**2
    _, td, _ = half_diff_angles(wi[v], wo[v])
    exact = 4 * np.cos(td) * np.sin(th) * np.sin(td) * dth * (np.pi / 2 / 90) * (np.pi / 180)
    ratio = exact / w
    assert np.std(ratio) / np.mean(ratio) < 1e-8
    assert exact.sum() * 2 * np.pi == pytest.approx((2 * np.pi) ** 2 / 2, rel=2e-4)


# ----------------------------------------------------------------------------- runs


def test_database_run_keeps_pairs_and_shards_agree(folder, tmp_path):
    """Two shards then an assembling run give the table of one run; the same run again fits
    nothing; a file that cannot be read is a failure of its pairs, the others are kept."""
    files = _files(folder)
    opts = {"max_steps": 64}
    one = database.fit_database(files, MODELS, str(tmp_path / "one"), fit_options=opts)
    assert (one.fitted_now, one.already_done, one.failed, one.total) == (6, 0, 0, 6)
    a = database.fit_database(files, MODELS, str(tmp_path / "sh"), fit_options=opts,
                              shard=(0, 2))
    b = database.fit_database(files, MODELS, str(tmp_path / "sh"), fit_options=opts,
                              shard=(1, 2))
    assert (a.fitted_now, b.fitted_now) == (3, 3)
    both = database.fit_database(files, MODELS, str(tmp_path / "sh"), fit_options=opts)
    assert (both.fitted_now, both.already_done) == (0, 6)
    assert len(both.rows) == 6
    assert all(_same(x, y) for x, y in zip(one.rows, both.rows, strict=True))
    assert [(r["material"], r["model"]) for r in both.rows] == [
        (f"mat{i}", m) for i in range(3) for m in MODELS]
    # other options are other pairs
    again = database.fit_database(files, MODELS[:1], str(tmp_path / "one"),
                                  fit_options={"max_steps": 65})
    assert again.fitted_now == 3
    bad = tmp_path / "broken.npz"
    bad.write_bytes(b"not a zip file")
    run = database.fit_database([*files[:1], str(bad)], MODELS, str(tmp_path / "one"),
                                fit_options=opts)
    assert (run.fitted_now, run.already_done, run.failed) == (0, 2, 2)
    assert all("broken" in f for f in run.failures) and len(run.rows) == 2
    row = one.rows[0]
    assert set(row["errors"]) == set(ERRORS) and row["params"]["alpha"] == pytest.approx(
        0.1, rel=0.05)


def test_cli_table_and_figure(folder, tmp_path, capsys):
    out = tmp_path / "results.csv"
    assert main(["fit", str(folder), "--model", ",".join(MODELS), "--table", str(out),
                 "--max-steps", "64", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "6 fitted now + 0 done before + 0 failed = 6 pairs (3 files x 2 models)" in text
    header = out.read_text().splitlines()[0].split(",")
    assert header[:2] == ["material", "model"] and "low2012_e2" in header and "alpha" in header
    doc = json.loads(out.with_suffix(".json").read_text())
    assert len(doc["rows"]) == 6 and doc["models"] == list(MODELS)
    assert out.with_suffix(".png").stat().st_size > 0
    # again: nothing to fit, the same table; a table in the folder read is not data
    assert main(["fit", str(folder), "--model", ",".join(MODELS), "--table", str(out),
                 "--max-steps", "64", "--quiet", "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["fitted_now"] == 0 and again["already_done"] == 6
    assert all(_same(x, y) for x, y in zip(doc["rows"], again["rows"], strict=True))
    for argv, words in ((["--model", "ggx,lambert"], "--table"),
                        (["--model", "ggx,lambert", "--table", str(out), "--report",
                          str(tmp_path / "r.txt")], "--report expects .html"),
                        (["--model", "ggx,lambert", "--table", str(out), "--shard", "0/2",
                          "--report", str(tmp_path / "r.html")], "not by one --shard"),
                        (["--model", "ggx", "--table", str(tmp_path / "t.txt")], ".csv"),
                        (["--model", "ggx,nosuch", "--table", str(out)], "nosuch"),
                        (["--model", "ggx,lambert", "--table", str(out), "--init", "alpha=0.2"],
                         "one model")):
        assert main(["fit", str(folder), *argv]) == 2
        assert words in capsys.readouterr().err


@pytest.mark.slow
def test_processes_and_a_killed_run(folder, tmp_path):
    """--processes 2 gives the single-process table; a run killed after its first pair keeps
    it, and the same command fits only the rest."""
    files = _files(folder)
    one = database.fit_database(files, MODELS, str(tmp_path / "ref"),
                                fit_options={"max_steps": 64, "metric": "log",
                                             "cos_weight": False, "max_zenith_deg": None,
                                             "multistart": 1, "seed": 0, "guess": "grid",
                                             "time_limit": 60.0, "fix": {}, "init": {}})
    env = {**os.environ, "BRDF_FIT_CACHE_DIR": str(tmp_path / "cache")}
    base = [sys.executable, "-m", "brdf_fit.cli", "fit", str(folder), "--model",
            ",".join(MODELS), "--max-steps", "64", "--quiet"]
    p2 = tmp_path / "p2.csv"
    out = subprocess.run([*base, "--table", str(p2), "--processes", "2", "--json"],
                         capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    doc = json.loads(out.stdout)
    assert doc["fitted_now"] == 6 and doc["already_done"] == 0
    assert all(_same(x, y) for x, y in zip(one.rows, doc["rows"], strict=True))
    killed = tmp_path / "killed.csv"
    parts = tmp_path / "killed.csv.parts"
    proc = subprocess.Popen([*base, "--table", str(killed)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    def finished():  # the pairs written; pathlib's "*" also matches the hidden temporary
        # ".KEY.json.XXXX.tmp.json" of a pair being written (core.atomic), and a kill on seeing
        # that one left it behind (the race that failed this test once)
        return [p for p in parts.glob("*.json") if not p.name.startswith(".")]

    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and not (parts.is_dir() and finished()):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    kept = len(finished())
    assert 1 <= kept < 6 and not list(parts.glob(".*.tmp*"))
    out = subprocess.run([*base, "--table", str(killed), "--json"], capture_output=True,
                         text=True, env=env, timeout=600)
    doc = json.loads(out.stdout)
    assert doc["already_done"] == kept and doc["fitted_now"] == 6 - kept
    assert all(_same(x, y) for x, y in zip(one.rows, doc["rows"], strict=True))


def test_cli_database_report(folder, tmp_path, capsys):
    """``--report`` on a database run: the page's table holds every pair's rel. RMS as the
    JSON table has it, the best per material in bold; the figure and one sphere per material
    are embedded PNGs that decode and are not blank; no script, no outside reference."""
    from _html import Page, decoded

    from brdf_fit.report import _num

    out, page_path = tmp_path / "results.csv", tmp_path / "db.html"
    assert main(["fit", str(folder), "--model", ",".join(MODELS), "--table", str(out),
                 "--max-steps", "64", "--quiet", "--report", str(page_path)]) == 0
    capsys.readouterr()
    rows = json.loads(out.with_suffix(".json").read_text())["rows"]
    text = page_path.read_text(encoding="utf-8")
    page = Page()
    page.feed(text)
    assert page.scripts == 0 and page.links == []
    assert len(page.images) == 2 + 3  # two figures, a sphere per material
    for src in page.images:
        img = decoded(src)
        assert img.ndim == 3 and img[..., :3].std() > 0.01
    for r in rows:
        k = page.cells.index(r["material"])  # the first table: rel. RMS by material x model
        cell = page.cells[k + 1 + list(MODELS).index(r["model"])]
        assert cell.startswith(_num(r["errors"]["rel_rms"], 4)), (cell, r)
    # each material's best pair (GGX, which made the data) is the bold cell of its row
    for mat in {r["material"] for r in rows}:
        best = min((r for r in rows if r["material"] == mat),
                   key=lambda r: r["errors"]["rel_rms"])
        assert best["model"] == "ggx"
        assert f"<td><b>{_num(best['errors']['rel_rms'], 4)}" in text
    # speed against error over the materials: the front holds exactly the non-dominated models
    from brdf_fit.plot import database_front_points

    points = database_front_points(rows)
    assert {p["model"] for p in points} == set(MODELS)
    for p in points:
        dominated = any(o["cost"] <= p["cost"] and o["median"] <= p["median"]
                        and (o["cost"], o["median"]) != (p["cost"], p["median"])
                        for o in points)
        assert p["pareto"] == (not dominated), points
        assert p["median"] == np.median([r["errors"]["rel_rms"] for r in rows
                                         if r["model"] == p["model"]])


def test_database_front_holds_the_non_dominated_models():
    """Three models over two materials at costs 1, 2 and 3: the middle one, dearer and worse
    than the first at its median, is off the front; the dearest and best is on it; a model
    without a committed cost, and non-finite errors, are left out."""
    from brdf_fit.plot import database_front, database_front_points

    def row(model, material, e):
        return {"model": model, "material": material, "errors": {"rel_rms": e},
                "converged": True}

    rows = [row("a", "m1", 0.1), row("a", "m2", 0.3), row("b", "m1", 0.2), row("b", "m2", 0.5),
            row("c", "m1", 0.01), row("c", "m2", float("nan")), row("d", "m1", 0.001)]
    points = database_front_points(rows, costs={"a": 1.0, "b": 2.0, "c": 3.0})
    got = {p["model"]: (p["median"], p["pareto"]) for p in points}
    assert got == {"a": (0.2, True), "b": (0.35, False), "c": (0.01, True)}
    assert database_front(rows, costs={"a": 1.0, "b": 2.0, "c": 3.0}).axes
