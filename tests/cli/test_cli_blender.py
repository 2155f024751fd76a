"""The Blender target on the command line: fit --target blender --export F.py, select --target
blender --blender F.py, and a .blend asked for where no Blender Python is found (the result is
printed, the failed output named)."""

from __future__ import annotations

import ast
import json

import jax
import numpy as np
import pytest

from brdf_fit.cli import main
from brdf_fit.convert import blender as cb
from tests._helpers import write_model_data

jax.config.update("jax_enable_x64", True)

TRUTH = {"base_color": np.array([0.8, 0.05, 0.05]), "roughness": 0.35, "metallic": 0.0,
         "ior": 1.5}


@pytest.fixture(scope="module")
def plastic(tmp_path_factory):
    """A red plastic as blender-principled evaluates it (1% noise) at 400 random pairs."""
    path = tmp_path_factory.mktemp("blender") / "red_plastic.npz"
    return write_model_data(path, "blender-principled", TRUTH, seed=4)


def _materials(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    node = next(n for n in tree.body if isinstance(n, ast.Assign)
                and n.targets[0].id == "MATERIALS")
    return ast.literal_eval(node.value)


def test_fit_for_blender_writes_the_material_script(plastic, tmp_path, capsys):
    out = tmp_path / "fit.py"
    assert main(["fit", str(plastic), "--target", "blender", "--model", "principled",
                 "--export", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["model"] == "blender-principled" and doc["converged"]
    (mat,) = _materials(out)
    assert mat["name"] == "red_plastic"
    assert np.allclose(mat["inputs"]["Base Color"][:3], TRUTH["base_color"], atol=0.01)
    assert abs(mat["inputs"]["Roughness"] - 0.35) < 0.01
    assert mat["inputs"]["Metallic"] < 1e-3


def test_select_for_blender_takes_no_coat_on_a_plastic(plastic, tmp_path, capsys):
    """The issue's red plastic: the Blender candidates are the base and its coated extension;
    the coat stands for nothing there and is not taken (the nested F test)."""
    out, blend = tmp_path / "chosen.py", tmp_path / "chosen.blend"
    try:
        cb.find_blender_python()
        have_blender = True
    except cb.BlenderNotFound:
        have_blender = False
    rc = main(["select", str(plastic), "--target", "blender", "--blender", str(out),
               "--blend", str(blend), "--no-checks", "--json"])
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert doc["choice"] == "blender-principled"
    assert _materials(out)[0]["name"] == "red_plastic"
    if have_blender:  # --blend saves the same materials in a .blend beside the script
        assert rc == 0, captured.err
        assert [e["target"] for e in doc["exports"]] == ["blender", "blender"]
        assert blend.is_file() and blend.read_bytes()[:7] == b"BLENDER"
    else:  # the script is written, the .blend is reported as failed, the selection kept
        assert rc == 1 and "--blend" in captured.err and "make blender" in captured.err
        assert [e["target"] for e in doc["exports"]] == ["blender"]
        assert not blend.exists()


def test_a_blend_without_blender_keeps_the_fit(plastic, tmp_path, capsys, monkeypatch):
    def nowhere():
        raise cb.BlenderNotFound(f"no Blender Python found: {cb.BLENDER_EXTRA}")

    monkeypatch.setattr(cb, "find_blender_python", nowhere)
    rc = main(["fit", str(plastic), "--target", "blender", "--model", "principled",
               "--export", str(tmp_path / "m.blend")])
    captured = capsys.readouterr()
    assert rc == 1
    assert "converged: yes" in captured.out  # the fit is printed
    assert "make blender" in captured.err
    assert not (tmp_path / "m.blend").exists()
