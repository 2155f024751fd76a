"""Image stacks (issue 29): the JSON description and its checks, the pixels as a memory-mapped
(N, M, C) value array, maps written as .npy and OpenEXR, and ``fit-batch --images``."""

import json
import os

import numpy as np
import pytest

from brdf_fit.data import DataError
from brdf_fit.io.exr import read_exr, write_exr
from brdf_fit.io.stack import read_stack, write_maps, write_stack


def _dirs(m, seed=0):
    rng = np.random.default_rng(seed)
    mu = rng.uniform(0.2, 1.0, (2, m))
    phi = rng.uniform(0, 2 * np.pi, (2, m))
    s = np.sqrt(1 - mu**2)
    d = np.stack([s * np.cos(phi), s * np.sin(phi), mu], -1)
    return d[0], d[1]


@pytest.mark.parametrize("fmt", ["npy", "exr"])
def test_values_are_the_pixels_texel_major(tmp_path, fmt):
    rng = np.random.default_rng(1)
    M, H, W = 5, 3, 4
    images = rng.uniform(0.1, 2.0, (M, H, W, 3)).astype(np.float32)
    wi, wo = _dirs(M)
    path = write_stack(tmp_path / "s", images, wi, wo, fmt=fmt)
    st = read_stack(path)
    assert st.shape == (H, W) and st.channels == ("R", "G", "B") and st.n_images == M
    np.testing.assert_allclose(st.wi, wi, rtol=1e-15)
    np.testing.assert_allclose(st.wo, wo, rtol=1e-15)
    v = st.to_values(tmp_path / "values.npy")
    assert v.shape == (H * W, M, 3)
    # texel (y, x) = problem y * W + x; image j = sample j; float32 pixels exactly
    for y, x, j in [(0, 0, 0), (2, 3, 4), (1, 2, 3)]:
        np.testing.assert_array_equal(v[y * W + x, j], images[j, y, x])
    # a second call reuses the file (the images are not read again)
    t = os.stat(tmp_path / "values.npy").st_mtime_ns
    v2 = st.to_values(tmp_path / "values.npy")
    assert os.stat(tmp_path / "values.npy").st_mtime_ns == t
    np.testing.assert_array_equal(v2, v)


def test_angles_quantities_and_channels(tmp_path):
    """Directions in degrees (the CSV convention), brf / brdfcos converted to BRDF as the CSV
    reader does, a scale, and a chosen channel of a two-channel EXR."""
    img = np.full((2, 2, 2), [0.6, 0.2], np.float32)  # EXR channels R, G
    write_exr(tmp_path / "a.exr", img)
    write_exr(tmp_path / "b.exr", 2 * img)
    d = {"format": "brdf_fit.image_stack/1", "quantity": "brdfcos", "scale": 3.0,
         "channels": ["G"],
         "images": [{"file": "a.exr", "theta_i": 30, "phi_i": 0, "theta_o": 60, "phi_o": 180},
                    {"file": "b.exr", "wi": [0, 0, 2], "wo": [1, 0, 1]}]}
    (tmp_path / "s.json").write_text(json.dumps(d))
    st = read_stack(tmp_path / "s.json")
    np.testing.assert_allclose(st.wi[0], [0.5, 0, np.sqrt(3) / 2], atol=1e-15)
    np.testing.assert_allclose(st.wo[0], [-np.sqrt(3) / 2, 0, 0.5], atol=1e-15)
    np.testing.assert_allclose(st.wi[1], [0, 0, 1])  # normalised
    np.testing.assert_allclose(st.wo[1], [2**-0.5, 0, 2**-0.5])
    v = np.asarray(st.to_values(tmp_path / "v.npy"))
    assert v.shape == (4, 2, 1)
    np.testing.assert_allclose(v[:, 0, 0], 3 * np.float32(0.2) / 0.5, rtol=1e-6)
    np.testing.assert_allclose(v[:, 1, 0], 3 * np.float32(0.4) * 2**0.5, rtol=1e-6)
    d.update(quantity="brf")
    (tmp_path / "s.json").write_text(json.dumps(d))
    np.testing.assert_allclose(read_stack(tmp_path / "s.json").to_brdf, [3 / np.pi, 3 / np.pi])
    del d["channels"]  # R and G: neither RGB nor Y nor one channel
    (tmp_path / "s.json").write_text(json.dumps(d))
    with pytest.raises(DataError, match="channels G, R: say which to fit"):
        read_stack(tmp_path / "s.json")


def _good(tmp_path):
    np.save(tmp_path / "a.npy", np.ones((2, 3, 3)))
    np.save(tmp_path / "b.npy", np.ones((2, 3, 3)))
    np.save(tmp_path / "small.npy", np.ones((2, 2, 3)))
    np.save(tmp_path / "grey.npy", np.ones((2, 3)))
    (tmp_path / "folder.npy").mkdir()
    return {"format": "brdf_fit.image_stack/1",
            "images": [{"file": "a.npy", "wi": [0, 0, 1], "wo": [0, 0, 1]},
                       {"file": "b.npy", "wi": [0, 0.6, 0.8], "wo": [0, 0, 1]}]}


@pytest.mark.parametrize("change, fragment", [
    (lambda d: d.update(images=[]), "no images"),
    (lambda d: d.update(light=1), "unknown key 'light'"),
    (lambda d: d.update(format="other/2"), "this version reads"),
    (lambda d: d.update(quantity="radiance"), "quantity 'radiance'"),
    (lambda d: d.update(scale=-1), "scale must be a positive number"),
    (lambda d: d["images"][1].update(file="c.npy"), "image 1: c.npy: no such file"),
    # a folder where an image is expected is named as such, not "no such file" (issue 45)
    (lambda d: d["images"][1].update(file="folder.npy"),
     "image 1: folder.npy: a folder, not an image file"),
    (lambda d: d["images"][1].update(file="c.png"), "8-bit images are not measurements"),
    (lambda d: d["images"][1].update(wi=[0, 0, -1]), "image 1: wi = [0.0, 0.0, -1.0] is below"),
    (lambda d: d["images"][1].update(wi=[0, 0, 0]), "zero length"),
    (lambda d: d["images"][1].update(wi=[0, 1]), "wi must be three finite numbers"),
    (lambda d: d["images"][1].pop("wo"), "image 1: no wo"),
    (lambda d: d["images"][1].update(theta_i=10), "give wi or theta_i/phi_i, not both"),
    (lambda d: d["images"][0].update(wo=None, theta_o=95, phi_o=0) or d["images"][0].pop("wo"),
     "theta_o = 95 degrees is below the horizon"),
    # NaN is not below the horizon: it is no angle (issue 45)
    (lambda d: d["images"][0].update(wo=None, theta_o=float("nan"), phi_o=0)
     or d["images"][0].pop("wo"), "theta_o and phi_o must be finite numbers (degrees), got nan"),
    (lambda d: d["images"][1].update(file="small.npy"), "size 2x2; the stack's first image"),
    (lambda d: d["images"][1].update(file="grey.npy"), "no channel 'R'"),
    (lambda d: d.update(channels="RGB"), "channels must be a list"),
])
def test_bad_descriptions_name_the_problem(tmp_path, change, fragment):
    d = _good(tmp_path)
    change(d)
    (tmp_path / "s.json").write_text(json.dumps(d))
    with pytest.raises(DataError, match="s.json|npy") as e:
        read_stack(tmp_path / "s.json")
    assert fragment in str(e.value)


def test_unreadable_files(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        read_stack(tmp_path / "none.json")
    (tmp_path / "s.json").write_text("{not json")
    with pytest.raises(DataError, match="not a readable JSON"):
        read_stack(tmp_path / "s.json")
    (tmp_path / "a.exr").write_bytes(b"not an exr at all")
    (tmp_path / "s.json").write_text(json.dumps(
        {"images": [{"file": "a.exr", "wi": [0, 0, 1], "wo": [0, 0, 1]}]}))
    with pytest.raises(DataError, match="a.exr: not a readable OpenEXR image"):
        read_stack(tmp_path / "s.json")


def test_maps_as_npy_and_exr(tmp_path):
    rng = np.random.default_rng(2)
    maps = {"params_alpha": rng.uniform(0, 1, (3, 5)), "params_f0": rng.uniform(0, 1, (3, 5, 3)),
            "converged": rng.uniform(0, 1, (3, 5)) > 0.5, "two": rng.uniform(0, 1, (3, 5, 2)),
            "many": rng.uniform(0, 1, (3, 5, 6))}
    written = write_maps(tmp_path / "maps", maps, exr=True, attributes={"model": "ggx"})
    assert len(written) == 10
    for name, a in maps.items():
        np.testing.assert_array_equal(np.load(tmp_path / "maps" / f"{name}.npy"), a)
        img, names, header = read_exr(tmp_path / "maps" / f"{name}.exr")
        np.testing.assert_array_equal(img, a.astype(np.float32).reshape(3, 5, -1))
        assert header["model"] == "ggx"
    assert read_exr(tmp_path / "maps" / "params_alpha.exr")[1] == ("Y",)
    assert read_exr(tmp_path / "maps" / "params_f0.exr")[1] == ("R", "G", "B")
    assert read_exr(tmp_path / "maps" / "many.exr")[1] == tuple("012345")
    assert not list((tmp_path / "maps").glob(".*"))  # no temporary file left


def test_fit_batch_images(tmp_path, capsys):
    """``fit-batch --images``: a synthetic 8x6 GGX texture (alpha and f0 varying) of 24 EXR
    images, one texel never measured (NaN in every image): maps of the image's size, equal
    (1e-12) to fit_batch of the pixels gathered here texel by texel, near the truth (1% noise),
    EXR maps equal to the .npy ones, the empty texel NaN and not counted against the exit
    status."""
    from brdf_fit.cli import main
    from brdf_fit.fitting.batch import fit_batch
    from data_synth.plans import make_plan
    from data_synth.stack import synth_stack

    H, W = 6, 8
    yy, xx = np.mgrid[0:H, 0:W]
    alpha = 0.08 + 0.4 * xx / (W - 1)
    f0 = np.stack([0.2 + 0.6 * yy / (H - 1), 0.5 + 0 * yy, 0.9 - 0.6 * yy / (H - 1)], -1)
    plan = make_plan("random_sparse", {"n": 24, "seed": 3, "max_zenith_deg": 70})
    path = synth_stack(tmp_path / "cap", "ggx", {"alpha": alpha, "f0": f0}, plan, seed=7,
                       noise_sigma=0.01)
    images = []
    for f in sorted((tmp_path / "cap").glob("img_*.exr")):
        img, _, _ = read_exr(f)
        img[2, 5] = np.nan
        write_exr(f, img)
        images.append(img)
    out = tmp_path / "fit"
    rc = main(["fit-batch", "--images", str(path), "--out-dir", str(out), "--model", "ggx",
               "--quiet", "--json"])
    report = json.loads(capsys.readouterr().out)
    assert rc == 0 and report["shape"] == [H, W] and report["unmeasured"] == 1
    maps = out / "maps"
    a, f = np.load(maps / "params_alpha.npy"), np.load(maps / "params_f0.npy")
    assert a.shape == (H, W) and f.shape == (H, W, 3)
    assert np.isnan(a[2, 5]) and np.isnan(f[2, 5]).all()
    assert not np.load(maps / "converged.npy")[2, 5]
    assert np.load(maps / "n_samples.npy")[2, 5] == 0
    ok = np.ones((H, W), bool)
    ok[2, 5] = False
    # the same problems gathered here: texel (y, x)'s samples are its pixels, image by image
    vals = np.stack([img[ok] for img in images], axis=1).astype(float)  # (47, 24, 3)
    ref = fit_batch(plan.wi, plan.wo, vals, "ggx", progress=None)
    np.testing.assert_allclose(a[ok], ref.params["alpha"], rtol=1e-12, atol=0)
    np.testing.assert_allclose(f[ok], ref.params["f0"], rtol=1e-12, atol=0)
    np.testing.assert_allclose(np.load(maps / "stderr_f0.npy")[ok], ref.stderr["f0"],
                               rtol=1e-12, atol=0)
    # and near the truth (1% noise, 24 samples): every texel where it belongs
    assert np.max(np.abs(a / alpha - 1)[ok]) < 0.05
    assert np.max(np.abs(f - f0)[ok]) < 0.05
    for name in ("params_alpha", "params_f0", "stderr_f0", "converged"):
        img = read_exr(maps / f"{name}.exr")[0]
        np.testing.assert_array_equal(img, np.load(maps / f"{name}.npy").astype(np.float32)
                                      .reshape(img.shape))


@pytest.mark.parametrize("argv, fragment", [
    (["--images", "S"], "--images needs --out-dir"),
    (["--images", "S", "--out-dir", "O", "--geometry", "G"], "not --geometry"),
    (["--images", "S", "--out-dir", "O", "x.csv"], "one of them"),
    (["--images", "missing.json", "--out-dir", "O"], "missing.json: no such file"),
])
def test_bad_image_requests(tmp_path, capsys, monkeypatch, argv, fragment):
    from brdf_fit.cli import main

    monkeypatch.chdir(tmp_path)
    path = write_stack(tmp_path, np.ones((2, 2, 2)), *_dirs(2), fmt="npy", name="S.json")
    names = {"S": str(path), "G": "G.npz"}
    rc = main(["fit-batch", "--model", "lambert", *[names.get(a, a) for a in argv]])
    assert rc == 2 and fragment in capsys.readouterr().err


def test_negative_pixels_are_refused_by_file_count_and_place(tmp_path, capsys):
    """A negative pixel is no reflectance: the stack's values are refused, naming the image,
    how many and the first pixel (x, y, channel), as negative values are in every other input;
    through the command line a one-line error, exit status 2, and no values file left. A NaN
    pixel is not refused: it marks a texel not measured in that image (issue 45: negative
    pixels were accepted, and every fit of those texels failed with nothing saying why)."""
    from brdf_fit.cli import main

    images = np.full((3, 2, 4, 3), 0.5)
    images[1, 0, 2, 1] = np.nan  # not measured: allowed
    images[2, 1, 3, 0] = -0.25
    images[2, 1, 1, 2] = -1.0
    path = write_stack(tmp_path, images, *_dirs(3), fmt="npy", name="S.json")
    st = read_stack(path)
    with pytest.raises(DataError) as e:
        st.to_values(tmp_path / "v.npy")
    msg = str(e.value)
    assert "2 negative pixel value(s), the first at x=1, y=1, channel 2 (-1.0)" in msg, msg
    assert msg.startswith(str(st.files[2])), msg
    assert not list(tmp_path.glob("*v.npy*"))  # the partial values file is removed
    rc = main(["fit-batch", "--model", "lambert", "--images", str(path), "--out-dir",
               str(tmp_path / "out"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "negative pixel value(s)" in err, err
    images[2] = np.abs(images[2])
    path = write_stack(tmp_path, images, *_dirs(3), fmt="npy", name="S.json")
    assert read_stack(path).to_values(tmp_path / "v.npy").shape == (8, 3, 3)


def test_an_image_too_large_for_memory_is_refused_from_its_header(tmp_path, monkeypatch):
    """Each image is read whole: its size, from the header before a pixel is read, is checked
    against the memory limit (issue 45: an image header can claim any size). Under a 100 kB
    limit a 64 x 64 RGB image (64 * 64 * 3 values at 24 bytes: 295 kB) is refused, naming the
    image, its size and the limit; at the default limit it is read."""
    from brdf_fit.core.limits import ENV, LimitError

    path = write_stack(tmp_path, np.ones((2, 64, 64, 3)), *_dirs(2), fmt="npy", name="S.json")
    monkeypatch.setenv(ENV, "100K")
    with pytest.raises(LimitError) as e:
        read_stack(path)
    assert "an image of 64x64 x 3 channel(s), read whole would take 295 kB" in str(e.value)
    monkeypatch.delenv(ENV)
    assert read_stack(path).shape == (64, 64)
