"""The CLI prints an undefined standard error as such (issue 16): ``fit`` says "stderr undefined:
<reason>" where the old code printed a confident "+- 0", ``fit --json`` carries null and the
reason (strict JSON), ``fit-batch`` writes the reason into its table."""

import csv
import json

from brdf_fit.cli import main

#: Lambertian data: fitted by ward with rho_s fixed at 0, alpha_x and alpha_y do nothing.
RECIPE = {
    "name": "test-lambert",
    "model": "lambert",
    "params": {"rho": [0.3, 0.2, 0.1]},
    "seed": 3,
    "plan": {"name": "four_axis",
             "args": {"theta_i_deg": [0.0, 30.0, 60.0],
                      "theta_o_deg": [0.0, 20.0, 40.0, 60.0, 80.0],
                      "phi_o_deg": [0.0, 90.0, 180.0, 270.0]}},
}


def synth(tmp_path):
    recipe = tmp_path / "recipe.json"
    recipe.write_text(json.dumps(RECIPE), encoding="utf-8")
    out = tmp_path / "lambert.csv"
    assert main(["synth", str(recipe), "-o", str(out)]) == 0
    return out


def test_fit_prints_undefined_stderr_with_its_reason(tmp_path, capsys):
    data = synth(tmp_path)
    capsys.readouterr()
    main(["fit", str(data), "--model", "ward", "--fix", "rho_s=0"])
    out = capsys.readouterr().out
    rows = {ln.split()[0]: ln for ln in out.splitlines() if ln.startswith("  alpha_")}
    assert set(rows) == {"alpha_x", "alpha_y"}, out
    for ln in rows.values():
        assert "stderr undefined: not identifiable" in ln and "+-" not in ln, ln
    assert [ln for ln in out.splitlines() if ln.startswith("  rho_d[")][0].count("+-") == 1

    main(["fit", str(data), "--model", "ward", "--fix", "rho_s=0", "--json"])
    d = json.loads(capsys.readouterr().out)  # strict: no NaN token
    assert d["stderr"]["alpha_x"] is None and d["stderr_note"]["alpha_x"] == "not identifiable"


def test_fit_batch_table_carries_the_reason(tmp_path, capsys):
    data = synth(tmp_path)
    table = tmp_path / "fits.csv"
    main(["fit-batch", str(data), str(data), "--model", "ward", "--fix", "rho_s=0", "--quiet",
          "--out", str(table)])
    out = capsys.readouterr().out
    assert "not identifiable: alpha_x, alpha_y" in out, out
    with table.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2
    for r in rows:
        assert r["stderr_note"] == "alpha_x: not identifiable;alpha_y: not identifiable"
        assert r["stderr_alpha_x"] == "nan"
