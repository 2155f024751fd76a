"""Round trips of brdf_fit.tables.export for .npz, .exr, .png and .h (NumPy only, no JAX jit)."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from brdf_fit.core.table import Axis, Table
from brdf_fit.tables.export import read_table, sidecar_path, values_sha256, write_table

needs_exr = pytest.mark.skipif(importlib.util.find_spec("OpenEXR") is None,
                               reason="OpenEXR not installed")
needs_png = pytest.mark.skipif(importlib.util.find_spec("png") is None,
                               reason="pypng not installed")

META = {"kind": "dfg", "roughness_axis": "r", "masking": "height-correlated",
        "quadrature": {"n": 64}, "error_estimate": 1e-6, "brdf_fit_version": "0.1.0"}


def dfg_table(origin=None, n0=8, n1=6, seed=0):
    rng = np.random.default_rng(seed)
    meta = dict(META)
    if origin is not None:
        meta["layout"] = {"image_origin": origin}
    axes = (Axis("roughness", 0.0, 1.0, n0), Axis("mu", 0.0, 1.0, n1))
    values = rng.random((n0, n1, 2))
    values[0, 0] = [0.0, 1.0]  # the ends of the PNG range
    return Table(values, axes, ("A", "B"), meta)


def albedo_table(seed=1):
    rng = np.random.default_rng(seed)
    axes = (Axis("alpha", 0.0, 1.0, 5), Axis("mu", 0.0, 1.0, 7, centres=False))
    return Table(rng.random((5, 7, 1)), axes, ("E",),
                 {"kind": "albedo", "E_avg": [0.5, 0.25, 0.125, 0.1, 0.05]})


def table3d(seed=2):
    rng = np.random.default_rng(seed)
    axes = (Axis("alpha", 0.0, 1.0, 3), Axis("sigma", 0.0, 2.0, 4), Axis("eta", 1.0, 3.0, 5))
    return Table(rng.random((3, 4, 5, 1)), axes, ("E",), {"kind": "albedo"})


def same_structure(a: Table, b: Table):
    assert a.axes == b.axes
    assert a.channels == b.channels
    assert a.meta == b.meta


TABLES = {"dfg": dfg_table, "albedo": albedo_table}


@pytest.mark.parametrize("make", TABLES.values(), ids=TABLES.keys())
def test_npz_exact(tmp_path, make):
    t = make()
    paths = write_table(t, tmp_path / "t.npz")
    assert paths == [tmp_path / "t.npz", tmp_path / "t.json"]
    r = read_table(tmp_path / "t.npz")
    same_structure(r, t)
    v, w = np.asarray(r.values), np.asarray(t.values)
    assert v.dtype == np.float64 and v.tobytes() == w.tobytes()  # bit for bit
    side = json.loads(sidecar_path(tmp_path / "t.npz").read_text())
    assert side["sha256"] == values_sha256(w)
    import hashlib
    assert side["sha256"] == hashlib.sha256(w.astype("<f8").tobytes()).hexdigest()
    assert side["channels"] == list(t.channels) and side["shape"] == list(w.shape)
    assert side["axes"] == [a.to_dict() for a in t.axes] and side["meta"] == t.meta
    with np.load(tmp_path / "t.npz", allow_pickle=False) as z:
        for k, c in enumerate(t.channels):
            np.testing.assert_array_equal(z[c], w[..., k])
        for a in t.axes:
            np.testing.assert_array_equal(z[a.name], a.nodes())
        assert json.loads(str(z["meta_json"][()]))["sha256"] == side["sha256"]
        if "roughness" in z.files:
            np.testing.assert_array_equal(z["alpha"], t.axis("roughness").nodes() ** 2)
        if "E_avg" in t.meta:
            np.testing.assert_array_equal(z["E_avg"], t.meta["E_avg"])


def test_npz_alone_and_alpha_axis(tmp_path):
    t = dfg_table().with_meta(roughness_axis="alpha")
    write_table(t, tmp_path / "t.npz")
    (tmp_path / "t.json").unlink()  # the .npz alone round-trips
    r = read_table(tmp_path / "t.npz")
    same_structure(r, t)
    with np.load(tmp_path / "t.npz") as z:
        np.testing.assert_array_equal(z["alpha"], z["roughness"])


def test_npz_detects_altered_values(tmp_path):
    t = dfg_table()
    write_table(t, tmp_path / "t.npz")
    with np.load(tmp_path / "t.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["A"][0, 0] += 1.0
    with open(tmp_path / "t.npz", "wb") as fh:
        np.savez(fh, **arrays)
    with pytest.raises(ValueError, match="sha256"):
        read_table(tmp_path / "t.npz")


def test_npz_3d(tmp_path):
    t = table3d()
    write_table(t, tmp_path / "e3.npz")
    r = read_table(tmp_path / "e3.npz")
    same_structure(r, t)
    assert np.asarray(r.values).tobytes() == np.asarray(t.values).tobytes()


@needs_exr
@pytest.mark.parametrize("make", TABLES.values(), ids=TABLES.keys())
@pytest.mark.parametrize("half", [False, True])
def test_exr(tmp_path, make, half):
    t = make()
    assert write_table(t, tmp_path / "t.exr", half=half) == [tmp_path / "t.exr"]
    r = read_table(tmp_path / "t.exr")
    same_structure(r, t)
    want = np.asarray(t.values).astype(np.float16 if half else np.float32).astype(np.float32)
    np.testing.assert_array_equal(np.asarray(r.values), want)
    import OpenEXR

    with OpenEXR.File(str(tmp_path / "t.exr"), separate_channels=True) as f:
        names = set(f.channels())
        dtype = next(iter(f.channels().values())).pixels.dtype
        desc = json.loads(f.header()["brdf_fit"])
    assert names == ({"R", "G"} if len(t.channels) == 2 else {"Y"})
    assert dtype == (np.float16 if half else np.float32)
    assert desc["sha256"] == values_sha256(t.values)


@needs_png
@pytest.mark.parametrize("make", TABLES.values(), ids=TABLES.keys())
def test_png(tmp_path, make):
    import png

    t = make()
    assert write_table(t, tmp_path / "t.png") == [tmp_path / "t.png"]
    r = read_table(tmp_path / "t.png")
    same_structure(r, t)
    err = np.abs(np.asarray(r.values) - np.asarray(t.values)).max()
    assert err <= 0.5 / 65535 + 1e-12
    w, h, rows, info = png.Reader(bytes=(tmp_path / "t.png").read_bytes()).read()
    rows = np.array([np.asarray(x) for x in rows])
    assert info["bitdepth"] == 16 and (w, h) == t.shape[1::-1]
    if len(t.channels) == 2:
        assert info["planes"] == 3 and not info["greyscale"]
        assert np.all(rows.reshape(h, w, 3)[..., 2] == 0)  # B = 0
    else:
        assert info["planes"] == 1 and info["greyscale"]


@pytest.mark.parametrize("make", TABLES.values(), ids=TABLES.keys())
def test_header(tmp_path, make):
    t = make()
    assert write_table(t, tmp_path / "t.h") == [tmp_path / "t.h"]
    r = read_table(tmp_path / "t.h")
    same_structure(r, t)
    np.testing.assert_array_equal(np.asarray(r.values), np.asarray(t.values).astype(np.float32))
    text = (tmp_path / "t.h").read_text()
    assert "static const float t[T_SIZE] = {" in text
    assert f"#define T_SIZE {np.asarray(t.values).size}" in text


def test_header_3d_and_name(tmp_path):
    t = table3d()
    write_table(t, tmp_path / "3d-table.h")
    r = read_table(tmp_path / "3d-table.h")
    same_structure(r, t)
    np.testing.assert_array_equal(np.asarray(r.values), np.asarray(t.values).astype(np.float32))
    text = (tmp_path / "3d-table.h").read_text()
    assert "static const float t_3d_table[T_3D_TABLE_SIZE]" in text
    assert "#define T_3D_TABLE_N_SIGMA 4" in text


@pytest.mark.skipif(shutil.which("cc") is None, reason="no C compiler")
def test_header_compiles(tmp_path):
    t = dfg_table()
    write_table(t, tmp_path / "dfg_lut.h")
    src = tmp_path / "main.c"
    src.write_text('#include "dfg_lut.h"\n#include <stdio.h>\n'
                   'int main(void) { printf("%.9g %d\\n", dfg_lut[DFG_LUT_SIZE - 1], '
                   "DFG_LUT_N_MU); return 0; }\n")
    exe = tmp_path / "main"
    subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", "-o", str(exe), str(src)], check=True,
                   cwd=tmp_path, timeout=60)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True, timeout=10)
    last, n_mu = out.stdout.split()
    assert np.float32(last) == np.float32(np.asarray(t.values)[-1, -1, -1]) and n_mu == "6"


@needs_exr
@needs_png
@pytest.mark.parametrize("ext", ["exr", "png"])
def test_image_origin_bottom(tmp_path, ext):
    top, bottom = dfg_table("top"), dfg_table("bottom")
    write_table(top, tmp_path / f"top.{ext}")
    write_table(bottom, tmp_path / f"bottom.{ext}")
    for t, name in ((top, "top"), (bottom, "bottom")):
        r = read_table(tmp_path / f"{name}.{ext}")
        same_structure(r, t)
        np.testing.assert_allclose(np.asarray(r.values), np.asarray(t.values), atol=1e-4)
    if ext == "png":
        import png

        def pixels(p):
            w, h, rows, _ = png.Reader(bytes=p.read_bytes()).read()
            return np.array([np.asarray(x) for x in rows]).reshape(h, w, 3)
    else:
        import OpenEXR

        def pixels(p):
            with OpenEXR.File(str(p), separate_channels=True) as f:
                return np.stack([f.channels()[c].pixels for c in "RG"], axis=-1)
    a, b = pixels(tmp_path / f"top.{ext}"), pixels(tmp_path / f"bottom.{ext}")
    assert not np.array_equal(a, b)
    np.testing.assert_array_equal(a[::-1, :, :2], b[..., :2])  # rows flipped


@pytest.mark.parametrize("ext", ["png", "exr"])
def test_3d_to_image_raises(tmp_path, ext):
    with pytest.raises(ValueError, match="2-D"):
        write_table(table3d(), tmp_path / f"e3.{ext}")
    assert not list(tmp_path.iterdir())


def test_bad_paths_raise_before_writing(tmp_path):
    t = dfg_table()
    with pytest.raises(ValueError, match="unknown extension"):
        write_table(t, tmp_path / "t.tiff")
    with pytest.raises(ValueError, match="does not exist"):
        write_table(t, tmp_path / "missing" / "t.npz")
    with pytest.raises(ValueError, match="half=True"):
        write_table(t, tmp_path / "t.png", half=True)
    assert not list(tmp_path.iterdir())
    assert not (tmp_path / "missing").exists()


@needs_png
def test_png_range_raises_before_writing(tmp_path):
    t = dfg_table()
    bad = Table(np.asarray(t.values) * 1.5 - 0.25, t.axes, t.channels, t.meta)
    with pytest.raises(ValueError, match=r"\[0, 1\].*min -0\.25.*max 1\.25"):
        write_table(bad, tmp_path / "t.png")
    assert not list(tmp_path.iterdir())
    four = Table(np.zeros((2, 3, 4)), (Axis("x", 0, 1, 2), Axis("y", 0, 1, 3)), "ABCD")
    with pytest.raises(ValueError, match="1 to 3 channels"):
        write_table(four, tmp_path / "t.png")
    assert not list(tmp_path.iterdir())


@needs_png
def test_fmt_overrides_extension_and_sniffing(tmp_path):
    t = albedo_table()
    write_table(t, tmp_path / "albedo.lut", fmt="png")
    r = read_table(tmp_path / "albedo.lut")
    same_structure(r, t)


def test_missing_optional_package(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "OpenEXR", None)
    monkeypatch.setitem(sys.modules, "png", None)
    with pytest.raises(ImportError, match=r"OpenEXR package: pip install 'brdf_fit\[tables\]'"):
        write_table(dfg_table(), tmp_path / "t.exr")
    with pytest.raises(ImportError, match="pypng"):
        write_table(dfg_table(), tmp_path / "t.png")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_tables_are_written_with_the_users_umask(tmp_path, mask):
    """Issue 28: tables were written -rw------- (mkstemp's mode) whatever the umask; an output
    gets 0o666 & ~umask like a file made by open()."""
    import os
    import stat

    old = os.umask(mask)
    try:
        path = tmp_path / "t.npz"
        write_table(dfg_table(), path)
        ref = tmp_path / "plain.txt"
        ref.write_text("x")
    finally:
        os.umask(old)
    expected = 0o666 & ~mask
    assert stat.S_IMODE(path.stat().st_mode) == expected
    assert stat.S_IMODE(ref.stat().st_mode) == expected
