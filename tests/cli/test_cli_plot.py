"""brdf-fit plot: model lobes and hemisphere pictures, data against a model (fitted or as
given), and one-line errors before any work."""

from __future__ import annotations

import json

import pytest
from _helpers import cli_one_error as one_error

from brdf_fit.cli import main

RECIPE = {
    "name": "tiny", "model": "ggx", "params": {"alpha": 0.3}, "seed": 1,
    "plan": {"name": "in_plane", "args": {"theta_i_deg": [0.0, 30.0],
                                          "theta_o_deg": [0.0, 15.0, 30.0, 45.0, 60.0]}},
}


def test_plot_models_writes_lobes_and_hemisphere(tmp_path, capsys):
    out = tmp_path / "lobes.png"
    assert main(["plot", "ggx", "modified-phong", "-o", str(out)]) == 0
    assert out.stat().st_size > 10_000
    assert (tmp_path / "lobes_hemisphere.png").stat().st_size > 10_000
    assert main(["plot", "ggx", "--param", "alpha=0.1", "--theta-i-deg", "45", "-o",
                 str(tmp_path / "one.svg")]) == 0


def test_plot_data_against_a_fitted_model(tmp_path, capsys):
    recipe = tmp_path / "r.json"
    recipe.write_text(json.dumps(RECIPE))
    data = tmp_path / "d.csv"
    assert main(["synth", str(recipe), "-o", str(data)]) == 0
    capsys.readouterr()
    out = tmp_path / "fit.png"
    assert main(["plot", "ggx", "--data", str(data), "--fit", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "ggx: fitted alpha=" in printed
    assert out.exists() and (tmp_path / "fit_residuals.png").exists()


@pytest.mark.parametrize("argv, fragment", [
    (["plot"], "needs a MODEL"),
    (["plot", "ggx", "beckmann", "--param", "alpha=0.2"], "exactly one MODEL"),
    (["plot", "ggx", "--fit"], "--fit needs --data"),
    (["plot", "nope"], "nope"),
    (["plot", "ggx", "--theta-i-deg", "90"], "horizon"),
    (["plot", "ggx", "--data", "missing.csv"], "missing.csv"),
])
def test_bad_plot_requests(tmp_path, capsys, argv, fragment):
    one_error(capsys, argv + ["-o", str(tmp_path / "p.png")], fragment)
    assert not list(tmp_path.iterdir())


def test_bad_plot_output(tmp_path, capsys):
    one_error(capsys, ["plot", "ggx", "-o", str(tmp_path / "p.txt")], "-o expects")
    one_error(capsys, ["plot", "ggx", "-o", str(tmp_path / "no" / "p.png")], "does not exist")
