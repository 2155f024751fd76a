"""Every subcommand, driven with bad paths and bad values: each ends in one line
``brdf-fit: error: ...`` (exit status 2, or argparse's own usage line), never a traceback, and
output paths are refused before any work (so nothing computed is lost on the write)."""

from __future__ import annotations

import json

import pytest

from brdf_fit import cli
from brdf_fit.cli import main

RECIPE = {
    "name": "tiny", "model": "ggx", "params": {"alpha": 0.3}, "seed": 1,
    "plan": {"name": "in_plane", "args": {"theta_i_deg": [0.0, 30.0],
                                          "theta_o_deg": [0.0, 30.0, 60.0]}},
}


def run(capsys, argv) -> tuple[int, str]:
    """Exit status and stderr of ``brdf-fit ARGV``; argparse's usage errors exit through
    SystemExit(2) with a ``brdf-fit ...: error:`` line."""
    try:
        code = main(argv)
    except SystemExit as e:  # argparse
        code = e.code
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return code, err


def one_error(capsys, argv, *fragments):
    code, err = run(capsys, argv)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2, (code, err)
    assert lines and "error:" in lines[-1], err
    assert sum("error:" in ln for ln in lines) == 1, err
    for f in fragments:
        assert f in lines[-1], lines[-1]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    recipe = d / "recipe.json"
    recipe.write_text(json.dumps(RECIPE), encoding="utf-8")
    data = d / "data.csv"
    assert main(["synth", str(recipe), "-o", str(data)]) == 0
    garbage = d / "garbage.csv"
    garbage.write_text("this is not,a gonioreflectometer\nfile,at all\n", encoding="utf-8")
    a_file = d / "a_file"
    a_file.write_text("x", encoding="utf-8")
    (d / "folder.csv").mkdir()
    readme = d / "README.md"
    readme.write_text("# no generated section here\n", encoding="utf-8")
    return {"dir": d, "recipe": recipe, "data": data, "garbage": garbage, "a_file": a_file,
            "readme": readme}


def test_version(capsys):
    from brdf_fit import __version__

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"brdf-fit {__version__}"


def test_check_names_for_help_match_the_checks():
    from brdf_fit.verify.checks import CHECKS

    assert tuple(CHECKS) == cli.CHECK_NAMES


@pytest.mark.parametrize("argv, fragments", [
    (["models", "--nosuch"], ("unrecognized",)),
    (["eval", "nosuch"], ("Valid models",)),
    (["eval", "ggx", "--param", "alpha=-1"], ("alpha", "> 0")),
    (["eval", "ggx", "--param", "nosuch=1"], ("nosuch",)),
    (["eval", "ggx", "--param", "alpha=abc"], ("not a number",)),
    (["eval", "ggx", "--theta-i-deg", "95"], ("95", "horizon")),
    (["check"], ("MODEL",)),
    (["check", "nosuch"], ("Valid models",)),
    (["check", "ggx", "--check", "nosuch"], ("valid checks",)),
    (["check", "ggx", "--param", "alpha=-1"], ("alpha",)),
    (["check", "--all", "ggx"], ("not both",)),
    (["convert", "nosuch"], ("unknown conversion",)),
])
def test_bad_values(capsys, argv, fragments):
    one_error(capsys, argv, *fragments)


def test_bad_paths_and_values_with_files(capsys, files, monkeypatch):
    d, data, recipe = files["dir"], str(files["data"]), str(files["recipe"])
    cases = [
        (["synth", str(d / "missing.json"), "-o", str(d / "x.csv")], ("missing.json",)),
        (["synth", recipe, "-o", str(d / "x.txt")], (".txt",)),
        (["synth", recipe, "-o", str(d / "no" / "dir" / "x.csv")], ("does not exist",)),
        (["synth", recipe, "-o", str(d / "folder.csv")], ("folder",)),
        (["fit", str(d / "missing.csv"), "--model", "ggx"], ("no such file",)),
        (["fit", str(files["garbage"]), "--model", "ggx"], ("garbage.csv",)),
        (["fit", str(d / "data.txt"), "--model", "ggx"], ("unknown data format",)),
        (["fit", data, "--model", "nosuch"], ("Valid models",)),
        (["fit", data, "--model", "ggx", "--metric", "nosuch"], ("metric",)),
        (["fit", data, "--model", "ggx", "--max-steps", "0"], ("--max-steps", ">= 1")),
        (["fit", data, "--model", "ggx", "--multistart", "0"], ("--multistart",)),
        (["fit", data, "--model", "ggx", "--fix", "alpha=2"], ("alpha",)),
        (["fit-batch", data, "--model", "ggx", "--out", str(d / "no" / "r.csv")],
         ("does not exist",)),
        (["fit-batch", data, "--model", "ggx", "--out", str(d / "r.txt")], (".csv or .json",)),
        (["fit-batch", data, "--model", "ggx", "--max-steps", "-3"], ("--max-steps",)),
        (["demo", "--out", str(files["a_file"])], ("existing file",)),
        (["demo", "--out", str(files["a_file"] / "sub")], ("cannot create",)),
        (["catalogue", "--write-readme", str(d / "MISSING.md")], ("no such file",)),
        (["catalogue", "--write-readme", str(files["readme"])], ("no generated catalogue",)),
    ]
    # output paths must be refused before any work: make the work itself fail loudly
    import brdf_fit.demo
    import brdf_fit.fitting.batch

    def no_work(*a, **k):
        raise AssertionError("the work started before the output path was checked")

    monkeypatch.setattr(brdf_fit.fitting.batch, "fit_batch", no_work)
    monkeypatch.setattr(brdf_fit.demo, "run_demo", no_work)
    for argv, fragments in cases:
        one_error(capsys, argv, *fragments)


def test_a_delta_lobe_is_not_fitted(capsys, files):
    """``fit --model mirror`` used to 'converge' with rms 100 (issue 16, defect 9)."""
    one_error(capsys, ["fit", str(files["data"]), "--model", "mirror"], "delta lobe")
    from brdf_fit import Mirror, SchlickFresnel, fit, read
    from brdf_fit.fitting.problem import FitError

    with pytest.raises(FitError, match="delta lobe"):
        fit(read(files["data"]), Mirror(fresnel=SchlickFresnel(1.0)))
