"""The OpenPBR target on the command line: fit --target openpbr --export F.mtlx, select --target
openpbr --mtlx F.mtlx (the red plastic of issue 42 takes no coat or fuzz lobe), and the
document's validity where MaterialX is installed."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import jax
import numpy as np
import pytest

from brdf_fit.cli import main
from brdf_fit.convert import materialx as cx
from tests._helpers import write_model_data

jax.config.update("jax_enable_x64", True)

TRUTH = {"base_color": np.array([0.8, 0.05, 0.05]), "specular_roughness": 0.35,
         "base_metalness": 0.0, "specular_ior": 1.5}


@pytest.fixture(scope="module")
def plastic(tmp_path_factory):
    """A red plastic as openpbr-surface evaluates it (1% noise) at 400 random pairs."""
    path = tmp_path_factory.mktemp("openpbr") / "red_plastic.npz"
    return write_model_data(path, "openpbr-surface", TRUTH, seed=5)


def _inputs(path, material):
    root = ET.parse(path).getroot()
    mat = root.find(f"surfacematerial[@name='{material}']")
    shader = root.find(f"open_pbr_surface[@name='{mat[0].get('nodename')}']")
    return {i.get("name"): [float(x) for x in i.get("value").split(",")] for i in shader}


def test_fit_for_openpbr_writes_the_mtlx_document(plastic, tmp_path, capsys):
    out = tmp_path / "fit.mtlx"
    assert main(["fit", str(plastic), "--target", "openpbr", "--model", "surface",
                 "--export", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["model"] == "openpbr-surface" and doc["converged"]
    inputs = _inputs(out, "red_plastic")
    assert np.allclose(inputs["base_color"], TRUTH["base_color"], atol=0.01)
    assert abs(inputs["specular_roughness"][0] - 0.35) < 0.01
    assert inputs["base_metalness"][0] < 1e-3
    try:
        import MaterialX  # noqa: F401
    except ImportError:
        return
    assert cx.validate_mtlx(out.read_text(encoding="utf-8")) == (True, "")


def test_select_for_openpbr_takes_no_coat_or_fuzz_on_a_plastic(plastic, tmp_path, capsys):
    """The issue's red plastic: the OpenPBR candidates are the base and its coated and fuzzy
    extensions; neither lobe stands for anything there and neither is taken."""
    out = tmp_path / "chosen.mtlx"
    rc = main(["select", str(plastic), "--target", "openpbr", "--mtlx", str(out), "--no-checks",
               "--json"])
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert rc == 0, captured.err
    assert doc["choice"] == "openpbr-surface"
    assert [e["target"] for e in doc["exports"]] == ["openpbr"]
    assert set(_inputs(out, "red_plastic")) == set(TRUTH)


def test_an_mtlx_export_of_another_target_is_refused(plastic, tmp_path, capsys):
    rc = main(["fit", str(plastic), "--model", "ggx", "--export", str(tmp_path / "m.mtlx")])
    captured = capsys.readouterr()
    assert rc == 1
    assert "converged: yes" in captured.out  # the fit is printed
    assert "openpbr-surface" in captured.err  # the message names the entries that export
    assert not (tmp_path / "m.mtlx").exists()


def test_a_scene_writes_one_openpbr_material_per_material(tmp_path, capsys):
    """select --scene --target openpbr --mtlx: the scene's material name, made a valid
    MaterialX name, and the fitted inputs of the model it was given as."""
    scene = tmp_path / "s.toml"
    scene.write_text('[[material]]\nname = "red paint"\nmodel = "openpbr-surface"\n'
                     'params = { base_color = [0.8, 0.05, 0.05], specular_roughness = 0.35 }\n',
                     encoding="utf-8")
    out = tmp_path / "scene.mtlx"
    rc = main(["select", "--scene", str(scene), "--target", "openpbr", "--candidates",
               "openpbr-surface", "--mtlx", str(out), "--quiet"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    inputs = _inputs(out, "red_paint")
    assert np.allclose(inputs["base_color"], [0.8, 0.05, 0.05], atol=1e-3)
    assert abs(inputs["specular_roughness"][0] - 0.35) < 1e-3
