"""The catalogue table (brdf_fit.verify.catalogue): generated from the registry, the checks'
declared outcomes and the measured costs; the README shows exactly the generated table."""

import json
from pathlib import Path

import pytest

from brdf_fit import registry
from brdf_fit.cli import main as cli_main
from brdf_fit.verify import catalogue

ROOT = Path(__file__).resolve().parents[2]


def test_every_catalogue_name_is_a_row():
    rows = {r.name for r in catalogue.MONTES_URENA}
    assert len(rows) == 22
    for e in registry.entries():
        if e.catalogue is not None:
            assert catalogue.row_of(e.catalogue) in rows, e.name


def test_table_has_every_row_and_every_catalogue_entry():
    records = catalogue.table(costs={})
    assert [r["row"] for r in records if r["entry"] is None] == [
        r.name for r in catalogue.MONTES_URENA
        if not any(catalogue.row_of(e.catalogue) == r.name for e in registry.entries())
    ]
    named = {e.name for e in registry.entries() if e.catalogue is not None}
    assert {r["entry"] for r in records if r["entry"] is not None} == named


def test_columns_follow_the_declared_check_outcomes():
    for r in catalogue.table(costs={}):
        if r["entry"] is None:
            continue
        e = registry.get(r["entry"])
        assert r["reciprocal"] == ("reciprocity" not in e.expected_failures)
        assert r["energy"] == ("energy" not in e.expected_failures)
        assert r["anisotropic"] == ("anisotropic" in e.tags)
        assert r["sampler"], f"{e.name}: no sampler description"


def test_docs_show_the_generated_table():
    """The catalogue table lives in the site's models page (the README is a landing page)."""
    section = catalogue.readme_section(ROOT / "docs" / "models.md")
    assert section == catalogue.markdown(), (
        "docs/models.md catalogue section is stale: run "
        "`brdf-fit catalogue --write-readme docs/models.md`")


def test_measured_costs_cover_every_non_delta_entry():
    costs = catalogue.load_costs()
    want = {e.name for e in registry.entries() if "delta" not in e.tags}
    missing = want - set(costs)
    assert not missing, (f"no measured cost for {sorted(missing)}: run "
                         "`python benchmarks/bench_catalogue_cost.py`")
    assert costs["lambert"]["eval"] == pytest.approx(1.0)


def test_cli_catalogue_json(capsys):
    assert cli_main(["catalogue", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["summary"]["rows"] == 22
    assert doc["summary"]["rows_implemented"] == len(
        {r["row"] for r in doc["rows"] if r["entry"] is not None})


def test_update_readme_needs_the_markers(tmp_path):
    p = tmp_path / "README.md"
    p.write_text("# no markers\n")
    with pytest.raises(ValueError, match="catalogue"):
        catalogue.update_readme(p, "x")
    p.write_text(f"a\n{catalogue.README_BEGIN}\nold\n{catalogue.README_END}\nb\n")
    assert catalogue.update_readme(p, "new\n")
    assert p.read_text() == f"a\n{catalogue.README_BEGIN}\nnew\n{catalogue.README_END}\nb\n"
    assert not catalogue.update_readme(p, "new\n")
