"""``brdf-fit fit --report``: one self-contained HTML page (brdf_fit.report, issue 46).

Every picture is an embedded PNG that decodes and is not blank; there is no script and no
reference outside the file; the parameter table holds the fit's own values with their 95%
intervals; the regions are the fit's; the command that made it is on the page. For dense
MERL data the page renders the data themselves beside the fit with FLIP between the two, and
their Rusinkiewicz slice. Where Debian's chromium is installed (``.ci/run`` installs it), the
page is opened headless and its screenshot compared with the same page with every image
removed: the images are drawn (the difference covers their area), and the page is not blank.
"""

import json
import pathlib
import shutil
import subprocess

import matplotlib.image
import numpy as np
import pytest
from _html import Page as _Page
from _html import decoded as _decoded

from brdf_fit import registry
from brdf_fit.cli import main
from brdf_fit.report import Z95, _num

GOLD = pathlib.Path(__file__).resolve().parents[1] / "examples" / "gold_4axis.csv"


def _fit_report(tmp_path, capsys, argv):
    out = tmp_path / "r.html"
    rc = main(["fit", *argv, "--report", str(out), "--quiet", "--json"])
    doc = json.loads(capsys.readouterr().out)
    page = _Page()
    text = out.read_text(encoding="utf-8")
    page.feed(text)
    return rc, doc, page, text, out


def test_report_of_a_sparse_fit(tmp_path, capsys):
    rc, doc, page, text, _ = _fit_report(tmp_path, capsys, [str(GOLD), "--model", "ggx"])
    assert rc == 0 and doc["converged"]
    assert page.scripts == 0 and page.links == []
    assert len(page.images) == 3  # the fit's sphere, the in-plane slices, the residuals
    for src in page.images:
        img = _decoded(src)
        assert img.ndim == 3 and img.shape[0] > 50 and img[..., :3].std() > 0.01
    # the parameters: value, standard error and interval as the fit gave them
    alpha, se = doc["params"]["alpha"], doc["stderr"]["alpha"]
    k = page.cells.index("alpha")
    assert page.cells[k + 1] == _num(alpha)
    assert page.cells[k + 3] == f"[{_num(alpha - Z95 * se)}, {_num(alpha + Z95 * se)}]"
    for region in doc["regions"]:
        k = page.cells.index(region["region"])
        assert page.cells[k + 1] == str(region["samples"])
    assert "cannot be rendered from themselves" in text
    assert f"brdf-fit fit {GOLD} --model ggx --report" in text


def test_report_path_is_checked_before_the_fit(tmp_path, capsys):
    assert main(["fit", str(GOLD), "--model", "ggx", "--report", str(tmp_path / "r.txt")]) == 2
    err = capsys.readouterr().err
    assert "--report expects .html" in err
    assert main(["fit", str(GOLD), "--model", "ggx,lambert", "--report",
                 str(tmp_path / "r.html")]) == 2
    # several models make a database run, which needs its table first (its --report is the
    # run's page: tests/fitting/test_database.py)
    assert "name the table to write with --table" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists()


@pytest.fixture(scope="module")
def merl_report(tmp_path_factory):
    """A report of ggx fitted to a MERL file made from ggx (30,000 samples of it)."""
    from brdf_fit.io.merl import write_merl

    d = tmp_path_factory.mktemp("report")
    path = d / "ggx.binary"
    write_merl(path, registry.get("ggx").build(alpha=0.25, f0=np.array([0.9, 0.6, 0.3])))
    out = d / "r.html"
    rc = main(["fit", str(path), "--model", "ggx", "--max-samples", "30000", "--quiet",
               "--report", str(out)])
    return rc, out


@pytest.mark.slow
def test_report_of_merl_data(merl_report):
    rc, out = merl_report
    assert rc == 0
    pytest.importorskip("flip_evaluator", reason="flip-evaluator is not installed")
    page = _Page()
    text = out.read_text(encoding="utf-8")
    page.feed(text)
    # data and fit rendered, FLIP, in-plane slices, residuals, the Rusinkiewicz slice
    assert len(page.images) == 6
    for src in page.images:  # (the FLIP map of a near-perfect fit is nearly black: std 0.01)
        assert _decoded(src)[..., :3].std() > 0.001
    mean = float(text.split("mean over the sphere: <b>")[1].split("<")[0])
    assert 0.0 <= mean < 0.01  # a fit of the model that made the data


def _screenshot(chromium: str, page: pathlib.Path, png: pathlib.Path) -> np.ndarray:
    subprocess.run([chromium, "--headless=new", "--no-sandbox", "--disable-gpu",
                    "--hide-scrollbars", f"--screenshot={png}", "--window-size=1200,3200",
                    page.as_uri()], check=True, capture_output=True, timeout=120)
    return matplotlib.image.imread(png)[..., :3]


@pytest.mark.slow
def _assert_drawn_in_chromium(page: pathlib.Path, tmp_path: pathlib.Path) -> None:
    """``page`` in headless chromium: not blank; against the same page with every image
    removed, the images are what differs, over their area (9.5% measured for a fit's MERL page:
    figures are mostly white); and its three square renders have a black background outside
    the sphere (35% of 256^2 each) that the page's own colours (white, dark grey #222) lack."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("Debian's chromium is not installed (.ci/run installs it)")
    shot = _screenshot(chromium, page, tmp_path / "page.png")
    assert shot.std() > 0.05  # not blank
    text = page.read_text(encoding="utf-8")
    bare = tmp_path / "bare.html"
    parts = text.split('src="data:image/png;base64,')
    bare.write_text(parts[0] + "".join('src="' + p.split('"', 1)[1] for p in parts[1:]),
                    encoding="utf-8")
    bare_shot = _screenshot(chromium, bare, tmp_path / "bare.png")
    changed = np.abs(shot - bare_shot).max(-1) > 0.1
    assert changed.mean() > 0.05, changed.mean()
    black = lambda a: int((a.max(-1) < 0.03).sum())  # noqa: E731
    assert black(shot) > 3 * 20_000 and black(bare_shot) < 1_000, (black(shot),
                                                                    black(bare_shot))


def test_report_opens_in_a_browser(merl_report, tmp_path):
    """A fit's MERL page (its three renders: data, fit, FLIP map)."""
    _assert_drawn_in_chromium(merl_report[1], tmp_path)


# ----------------------------------------------------------------------------- select --report


def test_report_of_a_selection(tmp_path, capsys):
    """``select --report``: the candidates' table holds the selection's own errors and the
    choice; speed against error, the choice and the next most accurate candidates rendered,
    in-plane slices and residuals; no script, no outside reference; the command on the page."""
    out = tmp_path / "s.html"
    rc = main(["select", str(GOLD), "--candidates", "lambert,ggx,beckmann,ggx-conductor",
               "--no-checks", "--quiet", "--json", "--report", str(out)])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0 and doc["report"] == str(out)
    text = out.read_text(encoding="utf-8")
    page = _Page()
    page.feed(text)
    assert page.scripts == 0 and page.links == []
    # the front, three spheres (the choice and the two most accurate others), slices, residuals
    assert len(page.images) == 6
    for src in page.images:
        img = _decoded(src)
        assert img.ndim == 3 and img.shape[0] > 50 and img[..., :3].std() > 0.01
    for c in doc["candidates"]:
        k = page.cells.index(c["model"] + (" (choice)" if c["model"] == doc["choice"] else ""))
        assert page.cells[k + 1] == _num(c["error"], 4)
        assert page.cells[k + 2] == ("yes" if c["within_budget"] else "no")
    assert f"Choice: {doc['choice']}" in text
    chosen = next(c for c in doc["candidates"] if c["model"] == doc["choice"])
    for name, value in chosen["params"].items():
        if np.ndim(value) == 0:
            k = page.cells.index(name)
            assert page.cells[k + 1] == _num(value)
    assert f"brdf-fit select {GOLD} --candidates" in text


def test_select_report_is_checked_before_the_fits(tmp_path, capsys):
    assert main(["select", str(GOLD), "--candidates", "lambert", "--report",
                 str(tmp_path / "s.txt")]) == 2
    assert "--report expects .html" in capsys.readouterr().err
    assert main(["select", "--scene", "example", "--report", str(tmp_path / "s.html")]) == 2
    assert "--report is the page of one data file's selection" in capsys.readouterr().err
    assert not (tmp_path / "s.html").exists()


@pytest.mark.slow
def test_selection_report_opens_in_a_browser(tmp_path, capsys):
    """The selection page in headless chromium: not blank, its images drawn (the difference
    with the same page without them covers their area), the three spheres' black backgrounds
    there only with the images."""
    if shutil.which("chromium") is None and shutil.which("chromium-browser") is None:
        pytest.skip("Debian's chromium is not installed (.ci/run installs it)")
    out = tmp_path / "s.html"
    assert main(["select", str(GOLD), "--candidates", "lambert,ggx,beckmann", "--no-checks",
                 "--quiet", "--report", str(out)]) == 0
    capsys.readouterr()
    _assert_drawn_in_chromium(out, tmp_path)


def test_only_the_entry_at_its_bound_is_flagged():
    """A colour whose blue channel sits at 0 (ggx-plastic fitted to Mitsuba's roughplastic with
    no blue diffuse): the page flags rho_d[B] at an interval end, not rho_d[R] and rho_d[G],
    whose intervals are given (all three were flagged)."""
    from _helpers import random_dirs

    from brdf_fit.data import GonioData
    from brdf_fit.fitting.single import fit
    from brdf_fit.report import fit_report

    rng = np.random.default_rng(3)
    wi, wo = random_dirs(rng, 3000, 0.05), random_dirs(rng, 3000, 0.05)
    src = registry.get("mitsuba-roughplastic").build(
        alpha=np.array(0.15), int_ior=np.array(1.5),
        diffuse_reflectance=np.array([0.6, 0.25, 0.0]))
    d = GonioData(wi, wo, np.asarray(src.eval(wi, wo)), channels=("R", "G", "B"))
    r = fit(d, "ggx-plastic")
    at = np.ravel(r.stderr_note["rho_d"]) == "at bound"
    assert "rho_d" in r.at_bound and at.any() and not at.all(), r.stderr_note
    page = _Page()
    page.feed(fit_report(r, d, source="x", command="brdf-fit fit x"))
    for j, ch in enumerate("RGB"):
        k = page.cells.index(f"rho_d[{ch}]")
        assert ("at an interval end" in page.cells[k + 4]) == bool(at[j]), page.cells[k:k + 5]
