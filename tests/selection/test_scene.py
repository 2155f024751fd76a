"""Scenes (brdf_fit.selection.scene): a model per material, the scene's model set, the K-model
set that minimises the worst error, exports, and bad input as one-line errors naming the file and
line (nothing fitted lost with --skip-bad)."""

import itertools
import json
import pathlib
import shutil
import textwrap

import numpy as np
import pytest

from brdf_fit.cli import main
from brdf_fit.selection import scene as sc
from data_synth.recipes import synthesize

CANDS = ["lambert", "ggx", "ggx-plastic"]
PLAN = {"name": "in_plane", "args": {"theta_i_deg": [0, 20, 40, 60],
                                     "theta_o_deg": [-75, -60, -45, -30, -15, 0, 10, 20, 30,
                                                     40, 50, 60, 75]}}


def write(tmp_path, text, name="scene.toml"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(text).lstrip(), encoding="utf-8")
    return p


@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    """Measured gold (1% noise), a formula plastic and a formula wall; selected once."""
    tmp = tmp_path_factory.mktemp("scene")
    from brdf_fit import io

    d = synthesize({"model": "ggx-conductor", "params": {"alpha": 0.2}, "seed": 5, "plan": PLAN,
                    "noise": [{"type": "lognormal", "args": {"sigma": 0.01}}]})
    io.write(d, str(tmp / "gold.csv"))
    path = write(tmp, """
        [scene]
        name = "small"
        candidates = ["lambert", "ggx", "ggx-plastic"]

        [[material]]
        name = "gold"
        data = "gold.csv"

        [[material]]
        name = "paint"
        model = "ggx-plastic"
        params = { rho_d = [0.6, 0.1, 0.1], alpha = 0.15, f0 = 0.04 }

        [[material]]
        name = "wall"
        model = "lambert"
        params = { rho = [0.7, 0.7, 0.6] }
        """)
    scene = sc.load_scene(path)
    return tmp, scene, sc.select_scene(scene)


def test_each_material_gets_its_own_choice_and_the_set_is_their_union(small_scene):
    _, scene, res = small_scene
    got = {c.material.name: c.model for c in res.materials}
    # gold: a specular model; the formula materials are fitted exactly by themselves
    assert got == {"gold": "ggx", "paint": "ggx-plastic", "wall": "lambert"}
    assert [m.line for m in scene.materials] == [5, 9, 14]
    assert set(res.model_set) == set(got.values())
    # one cost per kernel, measured once per scene and shared by every material's selection
    assert set(res.costs) == set(CANDS)
    for c in res.materials:
        assert all(x.cost_ns == res.costs[x.model] for x in c.selection.candidates)
    assert res.cost_ns_total == pytest.approx(sum(res.costs[n] for n in res.model_set))
    assert res.worst_error == max(c.error for c in res.materials)
    assert res.materials[1].error < 1e-12 and res.materials[2].error < 1e-12
    # the formula materials are evaluated on the one fixed scene geometry
    wi, wo = sc.scene_geometry()
    assert np.array_equal(res.materials[1].material.data.wi, wi)
    doc = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert doc["model_set"] == res.model_set and doc["materials"][0]["model"] == "ggx"


def test_max_models_picks_the_set_that_minimises_the_worst_error(small_scene):
    _, scene, res = small_scene
    errs = np.array([[sc._err(c.selection, n) for n in CANDS] for c in res.materials])
    for k in (1, 2):
        r = sc.with_max_models(res, k)
        assert len(r.model_set) <= k
        # exhaustive check, independent of best_model_set's loop
        best = min(max(min(errs[i, j] for j in sub) for i in range(errs.shape[0]))
                   for size in range(1, k + 1) for sub in itertools.combinations(range(3), size))
        assert r.worst_error == pytest.approx(best)
    # K = 3 (all candidates) recovers each material's lowest-error model
    r3 = sc.with_max_models(res, 3)
    assert r3.worst_error == pytest.approx(float(np.max(np.min(errs, axis=1))))
    assert sc.with_max_models(r3, None).model_set == res.model_set
    # select_scene with max_models gives what with_max_models gives from the same fits
    r1 = sc.select_scene(scene, max_models=1)
    assert r1.model_set == sc.with_max_models(res, 1).model_set


def test_best_model_set_ties_prefer_fewer_then_cheaper():
    e = np.array([[0.1, 0.1, 0.5], [0.1, 0.1, 0.5]])
    assert sc.best_model_set(e, [2.0, 1.0, 0.5], 2) == (1,)
    e = np.array([[0.01, 0.9], [0.9, 0.02]])
    assert sc.best_model_set(e, [1.0, 1.0], 1) == (0,)
    assert sc.best_model_set(e, [1.0, 1.0], 2) == (0, 1)


@pytest.mark.parametrize("body, line, fragment", [
    ("""
     [[material]]
     name = "a"
     model = "lambert"

     [[material]]
     name = "b"
     colour = "red"
     """, 5, "unknown key 'colour'"),
    ("""
     [[material]]
     name = "a"
     """, 1, "unknown material kind: give exactly one of data, mtl, gltf, model"),
    ("""
     [[material]]
     data = "a.csv"
     model = "ggx"
     """, 1, "exactly one of"),
    ("""
     [[material]]
     data = "missing.csv"
     """, 1, "no such file"),
    ("""
     [[material]]
     model = "ggx"
     params = { alpha = -0.2 }
     """, 1, "alpha"),
    ("""
     [[material]]
     model = "shiny"
     """, 1, "shiny"),
    ("""
     [[material]]
     model = "mirror"
     """, 1, "delta"),
    ("""
     [[material]]
     name = "x"
     model = "lambert"
     [[material]]
     name = "x"
     model = "ggx"
     """, 1, "two materials are named 'x'"),
    ("""
     [scene]
     budget = -1
     [[material]]
     model = "lambert"
     """, 1, "budget must be a positive number"),
    ("""
     [scene]
     family = "shiny"
     [[material]]
     model = "lambert"
     """, 1, "unknown family"),
    ("""
     [[material]
     model = "lambert"
     """, 1, "not valid TOML"),
    ("""
     [scene]
     name = "empty"
     """, 0, "no materials"),
])
def test_bad_scenes_are_one_line_errors_naming_file_and_line(tmp_path, body, line, fragment):
    p = write(tmp_path, body)
    with pytest.raises(sc.SceneError) as ei:
        sc.load_scene(p)
    msg = str(ei.value)
    where = f"{p}" if line == 0 else f"{p}:{line}"  # line 0: the file as a whole
    assert "\n" not in msg and msg.startswith(f"{where}: ") and fragment in msg, msg


def test_skip_bad_lists_bad_materials_and_keeps_the_others(tmp_path, capsys):
    p = write(tmp_path, """
        [[material]]
        name = "wall"
        model = "lambert"

        [[material]]
        name = "ghost"
        data = "missing.csv"

        [[material]]
        name = "odd"
        kind = "velvet"
        """)
    with pytest.raises(sc.SceneError, match=r":5: data: .*missing.csv: no such file"):
        sc.load_scene(p)
    s = sc.load_scene(p, skip_bad=True)
    assert [m.name for m in s.materials] == ["wall"]
    assert [b["where"] for b in s.bad] == [f"{p}:5", f"{p}:9"]
    # the CLI selects the good material, lists the bad ones, exits 1
    code = main(["select", "--scene", str(p), "--skip-bad", "--candidates", "lambert,ggx",
                 "--quiet", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 1 and [m["name"] for m in doc["materials"]] == ["wall"]
    assert len(doc["bad"]) == 2 and "missing.csv" in doc["bad"][0]["error"]


@pytest.mark.parametrize("argv, fragment", [
    ([], "DATA file or --scene"),
    (["x.csv", "--scene", "s.toml"], "one of them"),
    (["x.csv", "--max-models", "2"], "--max-models needs --scene"),
    (["--scene", "s.toml", "--gltf", "out.txt"], "--gltf"),
    (["--scene", "s.toml", "--max-models", "0"], "--max-models must be"),
    (["--scene", "nope.toml"], "cannot read the scene file"),
])
def test_bad_scene_requests(tmp_path, capsys, monkeypatch, argv, fragment):
    monkeypatch.chdir(tmp_path)
    try:
        code = main(["select", *argv])
    except SystemExit as e:
        code = e.code
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and "Traceback" not in err, err


SCHEMA = pathlib.Path(__file__).resolve().parents[1] / "convert" / "gltf_material.schema.json"


def test_example_scene_loads_every_material():
    """The embedded example scene reads without a fit (the default run; the whole selection
    and export of it below is in the slow set)."""
    s = sc.load_scene(sc.EXAMPLE_SCENE)
    kinds = [m.kind for m in s.materials]
    assert kinds.count("mtl") >= 5 and "data" in kinds and "model" in kinds and not s.bad
    assert all(m.data is not None and m.data.n > 0 for m in s.materials)


#: 30 s (27 fits and 9 x 2 exports): the suite's time budget. The same path (scene -> selection
#: -> glTF and Mitsuba exports, schema and Mitsuba load) runs by default on the small scenes of
#: this file and in tests/convert/test_{gltf,mitsuba}_export.py
@pytest.mark.slow
def test_example_scene_prints_choices_and_set_and_writes_gltf_and_mitsuba(tmp_path, capsys):
    """Issue 18: the embedded example scene (an MTL file of 7 materials of the kinds OBJ
    exports hold, a measured-style gonioreflectometer file, a registry model), from a copy (paths
    relative to the scene file): the per-material choices and the model set are printed, glTF
    and Mitsuba output written; the glTF passes the schema check, the Mitsuba XML loads in
    Mitsuba 3 (when installed). Three candidates keep it short (lambert, ggx, ggx-plastic: each
    exports to both targets); the README runs all ten."""
    src = sc.EXAMPLE_SCENE
    dst = tmp_path / "scene"
    shutil.copytree(src.parent, dst)
    s = sc.load_scene(dst / src.name)
    kinds = [m.kind for m in s.materials]
    assert kinds.count("mtl") >= 5 and "data" in kinds and "model" in kinds and not s.bad
    gl, xml = tmp_path / "out.gltf", tmp_path / "out.xml"
    code = main(["select", "--scene", str(dst / src.name), "--candidates",
                 "lambert,ggx,ggx-plastic", "--gltf", str(gl), "--mitsuba", str(xml),
                 "--quiet"])
    out = capsys.readouterr().out
    # issue 28: the MTL file's Blinn-Phong materials are beyond the ceiling (0.05) for these
    # three candidates: the command says which and exits 1 (the exports are written anyway)
    assert code == 1
    assert "not represented by any candidate:" in out and "no candidate represents" in out
    for m in s.materials:
        assert f"  {m.name} " in out
    assert "model set (" in out and f"wrote {gl}" in out and f"wrote {xml}" in out
    import xml.etree.ElementTree as ET

    ET.parse(xml)  # well-formed XML (issue 28: "--" inside the comment was not)
    doc = json.loads(gl.read_text())
    assert [m["name"] for m in doc["materials"]] == [m.name for m in s.materials]
    jsonschema = pytest.importorskip("jsonschema")
    jsonschema.Draft202012Validator(json.loads(SCHEMA.read_text())).validate(doc)
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    mi.load_file(str(xml))  # raises on an invalid scene


def test_gltf_materials_are_appendix_b_and_a_bad_one_names_file_and_index(tmp_path):
    from brdf_fit.convert import gltf as cg

    doc = cg.gltf_document([cg.to_gltf("ggx", {"alpha": 0.2, "f0": [0.9, 0.6, 0.5]},
                                       name="metal"),
                            cg.to_gltf("lambert", {"rho": [0.5, 0.5, 0.5]}, name="matte")])
    (tmp_path / "m.gltf").write_text(json.dumps(doc))
    p = write(tmp_path, """
        [[material]]
        gltf = "m.gltf"
        materials = ["metal"]
        """)
    s = sc.load_scene(p)
    assert [m.name for m in s.materials] == ["metal"]
    wi, wo = sc.scene_geometry()
    want = np.asarray(cg.appendix_b_eval(doc["materials"][0], wi, wo))
    np.testing.assert_allclose(s.materials[0].data.value, want, rtol=1e-12)
    bad = json.loads(json.dumps(doc))
    bad["materials"][1]["pbrMetallicRoughness"]["roughnessFactor"] = 1.5
    (tmp_path / "m.gltf").write_text(json.dumps(bad))
    with pytest.raises(sc.SceneError) as ei:
        sc.load_scene(p)
    msg = str(ei.value)
    assert msg.startswith(f"{p}:1: gltf: ") and "m.gltf" in msg and "materials[1]" in msg, msg
    p2 = write(tmp_path, """
        [[material]]
        gltf = "m.gltf"
        materials = ["nope"]
        """, "s2.toml")
    (tmp_path / "m.gltf").write_text(json.dumps(doc))
    with pytest.raises(sc.SceneError, match="has no material 'nope'"):
        sc.load_scene(p2)


def test_a_malformed_mtl_line_names_the_mtl_file_and_line(tmp_path):
    (tmp_path / "m.mtl").write_text("newmtl good\nKd 0.5 0.5 0.5\n\nnewmtl bad\nKd 0.5 oops 0.5\n")
    p = write(tmp_path, """
        [[material]]
        mtl = "m.mtl"
        """)
    with pytest.raises(sc.SceneError) as ei:
        sc.load_scene(p)
    assert f"{tmp_path / 'm.mtl'}:5:" in str(ei.value) and "\n" not in str(ei.value)
    s = sc.load_scene(p, skip_bad=True)  # the good material is kept, the bad one listed
    assert [m.name for m in s.materials] == ["good"]
    assert s.bad[0]["where"] == f"{tmp_path / 'm.mtl'}:5" and s.bad[0]["material"] == "bad"


def test_without_mitsuba_the_export_is_written_and_marked_not_verified(tmp_path, capsys,
                                                                     monkeypatch):
    """A package installed without the mitsuba extra still writes the Mitsuba XML; each export
    says it was not verified (found by `pip install .` without extras: the CLI's table crashed
    on the missing error)."""
    import sys

    monkeypatch.setitem(sys.modules, "mitsuba", None)  # `import mitsuba` raises ImportError
    p = write(tmp_path, """
        [[material]]
        name = "wall"
        model = "lambert"
        params = { rho = [0.5, 0.4, 0.3] }
        """)
    xml = tmp_path / "out.xml"
    code = main(["select", "--scene", str(p), "--candidates", "lambert,ggx", "--mitsuba",
                 str(xml), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0 and "mitsuba exact (not verified)" in out and xml.exists()
    import xml.etree.ElementTree as ET

    ET.parse(xml)  # well-formed: a strict parser reads every written file (issue 28)
