"""Wavefront MTL reader (brdf_fit.io.mtl): realistic exporter output is read value by value,
every kind of bad statement is a one-line error naming the file and the right line, skip_bad
keeps the good materials, and the shipped example parses cleanly."""

import pathlib

import pytest

from brdf_fit.io import MtlError, MtlMaterial, MtlReadResult, parse_mtl, read_mtl

EXAMPLE = (pathlib.Path(__file__).resolve().parents[2] / "brdf_fit" / "resources" / "scenes"
           / "example" / "materials.mtl")

# Blender's OBJ exporter, a 3ds Max export (tabs, Tr, Tf, upper/lower case keywords, CRLF),
# and a PBR-extension material; a BOM in front and trailing comments.
SCENE = (
    "\ufeff# Blender 3.6 MTL File: 'scene.blend'\n"
    "# Material Count: 3\n"
    "\n"
    "newmtl Material.001\n"                        # line 4
    "Ns 250.000000\n"
    "Ka 1.000000 1.000000 1.000000\n"
    "Kd 0.800000 0.150000 0.100000\n"
    "Ks 0.500000 0.500000 0.500000\n"
    "Ke 0.000000 0.000000 0.000000\n"
    "Ni 1.450000\n"
    "d 1.000000\n"
    "illum 2\n"
    "map_Kd -s 1 1 1 -o 0.5 0.5 tex folder/brick tex.png   # diffuse texture\n"  # line 13
    "\r\n"
    "newmtl 02 - Default\r\n"                       # line 15
    "\tns\t10.0000\r\n"
    "\tNI\t1.5000\r\n"
    "\tTr\t0.2500\r\n"
    "\tTf\t1.0000 0.9000 0.8000\r\n"
    "\tillum\t2\r\n"
    "\tKA\t0.5880\r\n"
    "\tkd\t0.5880 0.5880 0.5880\r\n"
    "\tKs\t0.0000 0.0000 0.0000\r\n"
    "\tsharpness 60\r\n"                            # line 24
    "\tmap_bump -bm 0.5 bump.png\r\n"
    "newmtl gold_pbr\n"                             # line 26
    "Kd 1.0 0.766 0.336\n"
    "Pr 0.4\n"
    "Pm 1.0\n"
    "Ps 0.1\n"
    "Pc 0.5\n"
    "Pcr 0.03\n"
    "aniso 0.2\n"
    "anisor 0.25\n"
    "norm normal.png\n"
    "Pcc 0.3  # a three.js dialect keyword\n"      # line 36
)


def test_realistic_multi_material_file(tmp_path):
    p = tmp_path / "scene.mtl"
    p.write_bytes(SCENE.encode("utf-8"))
    mats = read_mtl(p)
    assert [m.name for m in mats] == ["Material.001", "02 - Default", "gold_pbr"]
    assert all(isinstance(m, MtlMaterial) and m.path == str(p) for m in mats)
    b, x, g = mats
    assert b.line == 4 and b.where == f"{p}:4"
    assert b.Ns == 250.0 and b.Ka == (1.0, 1.0, 1.0) and b.Kd == (0.8, 0.15, 0.1)
    assert b.Ks == (0.5, 0.5, 0.5) and b.Ke == (0.0, 0.0, 0.0)
    assert b.Ni == 1.45 and b.d == 1.0 and b.illum == 2 and b.Pr is None and b.Tf is None
    assert b.maps == {"map_Kd": "tex folder/brick tex.png"}
    assert b.map_options == {"map_Kd": {"-s": ("1", "1", "1"), "-o": ("0.5", "0.5")}}
    assert b.ignored == ()
    # 3ds Max: case-insensitive keywords, tabs, CRLF, a grey Ka from one value, d = 1 - Tr
    assert x.line == 15 and x.Ns == 10.0 and x.Ni == 1.5 and x.illum == 2
    assert x.d == pytest.approx(0.75) and x.Tf == (1.0, 0.9, 0.8)
    assert x.Ka == (0.588, 0.588, 0.588) and x.Kd == (0.588, 0.588, 0.588)
    assert x.Ks == (0.0, 0.0, 0.0)
    assert x.maps == {"map_bump": "bump.png"} and x.map_options["map_bump"] == {"-bm": ("0.5",)}
    assert x.ignored == ((24, "sharpness 60"),)
    # PBR extension
    assert (g.Pr, g.Pm, g.Ps, g.Pc, g.Pcr, g.aniso, g.anisor) == (0.4, 1.0, 0.1, 0.5, 0.03,
                                                                  0.2, 0.25)
    assert g.maps == {"norm": "normal.png"}
    assert g.ignored == ((36, "Pcc 0.3"),)


def test_tr_and_d_both_given_d_wins_and_the_conflict_is_noted():
    text = "newmtl a\nTr 0.3\nd 0.9\nnewmtl b\nTr 0.3\n"
    a, b = parse_mtl(text, "t.mtl")
    assert a.d == 0.9 and a.ignored == ((2, "Tr 0.3 -- d on line 3 wins"),)
    assert b.d == pytest.approx(0.7) and b.ignored == ()


def test_repeated_statement_last_wins_and_the_earlier_is_recorded():
    (m,) = parse_mtl("newmtl a\nKd 0.1 0.2 0.3\nKd 0.5\n", "t.mtl")
    assert m.Kd == (0.5, 0.5, 0.5)
    assert m.ignored == ((2, "Kd 0.1 0.2 0.3 -- overridden by line 3"),)


def test_spectral_and_xyz_colours_are_recorded_not_read():
    (m,) = parse_mtl("newmtl a\nKd spectral ident.rfl 1.0\nKs xyz 0.2\n", "t.mtl")
    assert m.Kd is None and m.Ks is None
    assert m.ignored == ((2, "Kd spectral ident.rfl 1.0 -- spectral colours are not read"),
                         (3, "Ks xyz 0.2 -- xyz colours are not read"))


def test_line_continuation_and_comments():
    (m,) = parse_mtl("# header\nnewmtl a # trailing\nKd 0.1 \\\n 0.2 0.3\nNs 5\n", "t.mtl")
    assert m.name == "a" and m.Kd == (0.1, 0.2, 0.3) and m.Ns == 5.0


#: (text, line of the error, words the message must contain)
BAD = [
    ("newmtl a\nKd 0.5 0,5 0.5\n", 2, "unknown numeric syntax"),
    ("newmtl a\nKs 1e\n", 2, "unknown numeric syntax"),
    ("newmtl a\nNs nan\n", 2, "unknown numeric syntax"),
    ("newmtl a\nKd 0.5 0.5\n", 2, "Kd takes 1 value (grey) or 3"),
    ("newmtl a\nKs 1 1 1 1\n", 2, "Ks takes 1 value (grey) or 3"),
    ("newmtl a\n\nKa\n", 3, "Ka takes 1 value (grey) or 3"),
    ("newmtl a\nKe 1 2\n", 2, "Ke takes"),
    ("newmtl a\nTf 1 1\n", 2, "Tf takes"),
    ("newmtl a\nKd 0.5 -0.1 0.5\n", 2, "negative colour"),
    ("newmtl a\nNs -1\n", 2, "Ns -1 out of range"),
    ("newmtl a\nNi 0\n", 2, "Ni 0 out of range"),
    ("newmtl a\nNi -1.5\n", 2, "Ni -1.5 out of range"),
    ("newmtl a\nd 1.5\n", 2, "d 1.5 out of range"),
    ("newmtl a\nd -0.1\n", 2, "d -0.1 out of range"),
    ("newmtl a\nillum 2.0\n", 2, "illum must be an integer 0-10"),
    ("newmtl a\nillum 11\n", 2, "illum must be an integer 0-10"),
    ("newmtl a\nillum\n", 2, "illum takes 1 value"),
    ("# c\nKd 0.5\nnewmtl a\n", 2, "before any newmtl"),
    ("newmtl a\nKd 0.5\nnewmtl b\nnewmtl a\n", 4, "duplicate material name 'a'"),
    ("newmtl\n", 1, "without a material name"),
    ("newmtl a\nmap_Kd -s 1 1 1\n", 2, "no file name"),
    ("", 1, "empty file"),
    ("# only a comment\n\n", 1, "no materials"),
]


@pytest.mark.parametrize(("text", "line", "words"), BAD)
def test_each_error_is_one_line_with_path_and_line(text, line, words):
    with pytest.raises(MtlError) as exc:
        parse_mtl(text, "dir/bad.mtl")
    msg = str(exc.value)
    assert "\n" not in msg
    assert msg.startswith(f"dir/bad.mtl:{line}: "), msg
    assert words in msg
    assert exc.value.line == line and exc.value.path == "dir/bad.mtl"
    assert isinstance(exc.value, ValueError)


def test_read_mtl_names_the_file_in_errors(tmp_path):
    p = tmp_path / "x.mtl"
    p.write_text("newmtl a\nKd 1 1 1\nNs 10\nillum 12\n")
    with pytest.raises(MtlError, match=rf"^{p}:4: illum must be"):
        read_mtl(p)
    with pytest.raises(MtlError, match=r"\.mtl: cannot read the file"):
        read_mtl(tmp_path / "missing.mtl")


def test_latin1_file_is_read(tmp_path):
    p = tmp_path / "l.mtl"
    p.write_bytes("newmtl Gr\u00fcn\nKd 0.1 0.5 0.1\n".encode("latin-1"))
    (m,) = read_mtl(p)
    assert m.name == "Gr\u00fcn"


def test_skip_bad_keeps_the_good_materials():
    text = ("newmtl good1\nKd 0.5\n"
            "newmtl bad_colour\nKd 0.5 0.5\nKs 0.5\n"      # line 3, error on 4
            "newmtl good2\nKs 0.2\nNs 10\n"
            "newmtl bad_d\nd 2\n"                          # error on 10
            "newmtl good1\nKd 0.9\n"                       # duplicate name: line 11
            "newmtl good3\nillum 1\n")
    with pytest.raises(MtlError, match="^s.mtl:4: "):
        parse_mtl(text, "s.mtl")
    res = parse_mtl(text, "s.mtl", skip_bad=True)
    assert isinstance(res, MtlReadResult)
    assert [m.name for m in res.materials] == ["good1", "good2", "good3"]
    assert res.materials[0].Kd == (0.5, 0.5, 0.5)  # not the duplicate's 0.9
    assert [(e.line, e.material) for e in res.errors] == [(4, "bad_colour"), (10, "bad_d"),
                                                           (11, None)]
    assert all(str(e).startswith(f"s.mtl:{e.line}: ") for e in res.errors)


def test_skip_bad_on_a_file_without_materials_reports_it():
    res = parse_mtl("", "e.mtl", skip_bad=True)
    assert res.materials == [] and [str(e) for e in res.errors] == ["e.mtl:1: empty file: no "
                                                                     "materials"]


def test_shipped_example_parses_cleanly():
    res = read_mtl(EXAMPLE, skip_bad=True)
    assert res.errors == []
    names = [m.name for m in res.materials]
    assert len(names) >= 6
    assert {"wall_matte", "painted_plastic", "glossy_varnish", "blender_default",
            "brushed_metal", "window_glass"} <= set(names)
    by = {m.name: m for m in res.materials}
    assert by["wall_matte"].illum == 1
    assert 100 <= by["painted_plastic"].Ns <= 250
    assert by["glossy_varnish"].Ns == 900.0
    assert by["brushed_metal"].Pr is not None and by["brushed_metal"].Pm == 1.0
    assert by["window_glass"].d < 1 and by["window_glass"].illum == 4
    assert all(m.ignored == () for m in res.materials)
